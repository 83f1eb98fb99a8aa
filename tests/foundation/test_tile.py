"""Tile model (ICD section 1): round trips, every rule broken once, slant-to-ground conversion."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from atr_node.errors import GeometryError, TileError
from atr_node.records import SensorInfo, Tile, TileNav


def make_tile(rows=6, cols=9, dtype="float32", slant=False, nav=True, sensor=True, seed=0) -> Tile:
    rng = np.random.default_rng(seed)
    if dtype == "float32":
        px = rng.random((rows, cols), dtype=np.float32) * 100
        px[0, 0] = np.nan
    else:
        hi = 65535 if dtype == "uint16" else 255
        px = rng.integers(0, hi + 1, size=(rows, cols)).astype(np.float32)
        px[px == 0] = np.nan
        px[1, 2] = np.nan
    t = 1.7e9 + 0.1 * np.arange(rows)
    tnav = TileNav(lat_deg=44.0 + 1e-6 * np.arange(rows), lon_deg=np.full(rows, 9.85),
                   heading_deg=np.full(rows, 359.5), altitude_m=np.full(rows, 14.0)) if nav else None
    sens = SensorInfo(120e3, 15e3, 0.2, 1.2, 24, True) if sensor else None
    return Tile(mission="m1", leg=2, side="stbd", seq=7, pixels=px, kind="intensity", range0_m=5.0,
                dr_m=0.1, dx_m=0.1, slant=slant, ping_time=t, nav=tnav, sensor=sens, wire_dtype=dtype)


@pytest.mark.parametrize("dtype", ["float32", "uint16", "uint8"])
@pytest.mark.parametrize("with_nav", [True, False])
def test_round_trip_exact(dtype, with_nav):
    tile = make_tile(dtype=dtype, nav=with_nav, sensor=with_nav)
    back = Tile.unpack(tile.pack())
    assert back.equals(tile)
    # and the bytes are stable: map -> tile -> map gives the same data field
    assert back.to_map()["data"] == tile.to_map()["data"]


def test_float32_pixels_are_the_records_bytes_read_only():
    """A float32 tile is not copied out of its record: its pixels view the map's bytes,
    read-only (records are never modified after they are made)."""
    m = make_tile(rows=40, cols=30).to_map()
    back = Tile.from_map(m)
    assert np.shares_memory(back.pixels, np.frombuffer(m["data"], np.uint8))
    with pytest.raises(ValueError):
        back.pixels[0, 0] = 1.0
    assert back.pixels.dtype == np.float32 and back.equals(make_tile(rows=40, cols=30))
    ints = Tile.from_map(make_tile(dtype="uint16").to_map())  # converted: its own, writable array
    assert ints.pixels.flags.writeable and ints.pixels.dtype == np.float32


def test_integer_zero_is_nodata_and_written_back_as_zero():
    m = make_tile(dtype="uint16").to_map()
    raw = np.frombuffer(m["data"], dtype="<u2").reshape(m["shape"])
    tile = Tile.from_map(m)
    assert np.array_equal(np.isnan(tile.pixels), raw == 0)
    assert np.array_equal(tile.pixels[raw != 0], raw[raw != 0].astype(np.float32))


@settings(max_examples=60, deadline=None)
@given(rows=st.integers(1, 12), cols=st.integers(1, 12), dtype=st.sampled_from(["float32", "uint16", "uint8"]),
       seed=st.integers(0, 2**31 - 1))
def test_round_trip_property(rows, cols, dtype, seed):
    rng = np.random.default_rng(seed)
    if dtype == "float32":
        px = (rng.random((rows, cols)) * 10 ** rng.uniform(-6, 6)).astype(np.float32)
        px[rng.random((rows, cols)) < 0.2] = np.nan
    else:
        hi = 65535 if dtype == "uint16" else 255
        px = rng.integers(0, hi + 1, size=(rows, cols)).astype(np.float32)
        px[px == 0] = np.nan
    tile = Tile("m", 0, "port", 0, px, "amplitude", 0.0, 0.05, 0.2, True, np.sort(rng.random(rows)) + 1e9,
                wire_dtype=dtype)
    assert Tile.unpack(tile.pack()).equals(tile)


# -- every ICD rule broken once -----------------------------------------------------------

def _broken(**changes):
    m = make_tile().to_map()
    for k, v in changes.items():
        if v is KeyError:
            del m[k]
        else:
            m[k] = v
    return m


REQUIRED = ["type", "v", "mission", "leg", "side", "seq", "shape", "dtype", "data", "kind", "range0_m", "dr_m",
            "dx_m", "slant", "ping_time"]


@pytest.mark.parametrize("key", REQUIRED)
def test_missing_key_names_field_and_tile(key):
    with pytest.raises(TileError) as ei:
        Tile.from_map(_broken(**{key: KeyError}))
    assert ei.value.field == key
    assert "missing key" in str(ei.value)
    if key not in ("mission", "side", "seq"):
        assert "tile m1/stbd/seq 7" in str(ei.value)


BAD_VALUES = [
    ("type", "ping", "type"),
    ("v", 2, "v"),
    ("v", "1", "v"),
    ("mission", "", "mission"),
    ("mission", 5, "mission"),
    ("leg", -1, "leg"),
    ("leg", 1.5, "leg"),
    ("side", "left", "side"),
    ("seq", -3, "seq"),
    ("seq", True, "seq"),
    ("shape", [6], "shape"),
    ("shape", [6, 0], "shape"),
    ("shape", [6, 10], "data"),  # data length no longer matches
    ("shape", "6x9", "shape"),
    ("dtype", "float64", "dtype"),
    ("data", b"\x00" * 10, "data"),
    ("data", "text", "data"),
    ("kind", "db", "kind"),
    ("range0_m", float("nan"), "range0_m"),
    ("range0_m", -1.0, "range0_m"),
    ("dr_m", 0.0, "dr_m"),
    ("dx_m", -0.1, "dx_m"),
    ("dx_m", "0.1", "dx_m"),
    ("slant", 1, "slant"),
    ("ping_time", b"\x00" * 8, "ping_time"),
    ("ping_time", np.array([5, 4, 3, 2, 1, 0], "<f8").tobytes(), "ping_time"),
    ("ping_time", np.array([0, 1, 2, np.inf, 4, 5], "<f8").tobytes(), "ping_time"),
    ("nav", "north", "nav"),
    ("sensor", [1, 2], "sensor"),
]


@pytest.mark.parametrize("key,value,field", BAD_VALUES, ids=[f"{k}={v!r}"[:40] for k, v, _ in BAD_VALUES])
def test_bad_value_names_field(key, value, field):
    with pytest.raises(TileError) as ei:
        Tile.from_map(_broken(**{key: value}))
    assert ei.value.field == field, str(ei.value)
    assert "tile " in str(ei.value)


@pytest.mark.parametrize("nkey", ["lat_deg", "lon_deg", "heading_deg", "altitude_m"])
def test_nav_rules(nkey):
    m = make_tile().to_map()
    del m["nav"][nkey]
    with pytest.raises(TileError, match=f"nav.{nkey}"):
        Tile.from_map(m)
    m = make_tile().to_map()
    m["nav"][nkey] = b"\x00" * 8  # one value for six rows
    with pytest.raises(TileError, match="one per row"):
        Tile.from_map(m)
    m = make_tile().to_map()
    m["nav"][nkey] = np.full(6, np.nan, "<f8").tobytes()
    with pytest.raises(TileError, match="non-finite"):
        Tile.from_map(m)


def test_nav_ranges_and_sensor_rules():
    m = make_tile().to_map()
    m["nav"]["lat_deg"] = np.full(6, 91.0, "<f8").tobytes()
    with pytest.raises(TileError, match="latitude"):
        Tile.from_map(m)
    m = make_tile().to_map()
    m["nav"]["altitude_m"] = np.full(6, -1.0, "<f8").tobytes()
    with pytest.raises(TileError, match="altitude"):
        Tile.from_map(m)
    m = make_tile().to_map()
    m["sensor"]["n_rx"] = 0
    with pytest.raises(TileError, match="sensor.n_rx"):
        Tile.from_map(m)
    m = make_tile().to_map()
    del m["sensor"]["sas"]
    with pytest.raises(TileError, match="sensor.sas"):
        Tile.from_map(m)


def test_pixel_rules():
    m = make_tile().to_map()
    px = np.frombuffer(m["data"], "<f4").copy()
    px[3] = np.inf
    m["data"] = px.tobytes()
    with pytest.raises(TileError, match="infinite"):
        Tile.from_map(m)
    px[3] = -2.0
    m["data"] = px.tobytes()
    with pytest.raises(TileError, match="negative"):
        Tile.from_map(m)


def test_not_a_map_and_not_msgpack():
    with pytest.raises(TileError, match="expected a msgpack map"):
        Tile.from_map([1, 2, 3])
    with pytest.raises(TileError, match="not a msgpack map"):
        Tile.unpack(b"\xc1\xc1\xc1")
    with pytest.raises(TileError):
        Tile.unpack(msgpack.packb("hello"))


def test_duplicate_ping_times_are_monotonic_enough():
    m = make_tile().to_map()
    m["ping_time"] = np.array([0, 1, 1, 2, 3, 4], "<f8").tobytes()
    assert Tile.from_map(m).rows == 6


def test_all_nan_tile_is_accepted():
    m = make_tile().to_map()
    m["data"] = np.full(54, np.nan, "<f4").tobytes()
    tile = Tile.from_map(m)
    assert not tile.valid.any()


def test_as_intensity_squares_amplitude_and_keeps_intensity():
    amp = make_tile(dtype="uint16").replace(kind="amplitude")
    amp.pixels[1, 2] = np.nan  # no data stays no data
    orig = amp.pixels.copy()
    got = amp.as_intensity()
    assert got.kind == "intensity" and got.wire_dtype == "float32" and got.pixels.dtype == np.float32
    want = amp.pixels.astype(np.float64) ** 2  # the direct float64 square, to float32 rounding
    np.testing.assert_allclose(got.pixels, want, rtol=1e-7)
    assert np.isnan(got.pixels[1, 2])
    np.testing.assert_array_equal(amp.pixels, orig)  # the original is not touched
    assert amp.kind == "amplitude" and not np.shares_memory(got.pixels, amp.pixels)
    back = Tile.from_map(got.to_map())  # what the node keeps (state snapshots) reads back the same
    np.testing.assert_array_equal(back.pixels, got.pixels)
    inten = make_tile()
    assert inten.as_intensity() is inten


# -- slant to ground ---------------------------------------------------------------------

def test_ground_range_against_direct_formula():
    rows, cols, dr, h = 4, 400, 0.05, 3.75
    slant_r = dr * np.arange(cols)
    # a pixel value that is a known smooth function of slant range
    px = np.tile((1.0 + slant_r).astype(np.float32), (rows, 1))
    tile = Tile("m", 0, "port", 0, px, "intensity", 0.0, dr, 0.1, True, np.arange(rows, dtype=float),
                nav=TileNav(np.zeros(rows), np.zeros(rows), np.zeros(rows), np.full(rows, h)), wire_dtype="float32")
    g = tile.ground_range()
    assert not g.slant and g.range0_m == 0.0 and g.dr_m == dr
    expect_cols = math.floor(math.sqrt((dr * (cols - 1)) ** 2 - h * h) / dr + 1e-9) + 1
    assert g.cols == expect_cols
    gr = g.ranges_m
    expected = 1.0 + np.sqrt(gr ** 2 + h * h)  # value at slant range sqrt(r^2 + H^2)
    np.testing.assert_allclose(g.pixels[0], expected, rtol=1e-5)
    assert np.isfinite(g.pixels).all()


def test_ground_range_water_column_and_per_ping_altitude():
    rows, cols, dr = 3, 200, 0.1
    px = np.ones((rows, cols), np.float32)
    alt = np.array([2.0, 5.0, 8.0])
    # slant tile starting beyond nadir: r0 = 6 m slant
    tile = Tile("m", 0, "stbd", 0, px, "amplitude", 6.0, dr, 0.1, True, np.arange(rows, dtype=float),
                wire_dtype="float32")
    g = tile.ground_range(alt)
    assert g.range0_m == 0.0  # sqrt(max(36 - 64, 0)) = 0
    for i, h in enumerate(alt):
        r_first = math.sqrt(max(36 - h * h, 0))
        has = np.isfinite(g.pixels[i])
        assert not has[g.ranges_m < r_first - 1e-9].any()  # water column / before first sample: no data
        assert has[(g.ranges_m > r_first + 1e-6) & (g.ranges_m < math.sqrt(25.9 ** 2 - h * h))].all()


def test_ground_range_needs_altitude():
    tile = make_tile(slant=True, nav=False)
    with pytest.raises(GeometryError, match="altitude"):
        tile.ground_range()
    with pytest.raises(GeometryError):
        tile.ground_range(-1.0)
    assert make_tile(slant=False).ground_range() is not None


def test_ground_range_on_a_fixed_axis():
    rows, cols, dr, h = 2, 300, 0.1, 5.0
    px = np.tile(np.arange(cols, dtype=np.float32) + 1, (rows, 1))
    tile = Tile("m", 0, "port", 0, px, "intensity", 0.0, dr, 0.1, True, np.arange(rows, dtype=float),
                wire_dtype="float32")
    g = tile.ground_range(h, range0_m=2.0, cols=350)
    assert g.range0_m == 2.0 and g.cols == 350
    expected = 1 + np.sqrt(g.ranges_m ** 2 + h * h) / dr
    ok = np.sqrt(g.ranges_m ** 2 + h * h) <= dr * (cols - 1)
    np.testing.assert_allclose(g.pixels[0, ok], expected[ok], rtol=1e-5)
    assert np.isnan(g.pixels[0, ~ok]).all() and (~ok).any()
