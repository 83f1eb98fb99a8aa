"""Review findings on reading XTF/JSF (issue 18): pings with a position but no altitude keep
their nav, port and starboard on different range axes, JSF projected positions without --crs,
bottom tracking on the near columns only, the fix-time midnight rule."""

from __future__ import annotations

import numpy as np
import pytest

from atr_node.errors import LogFormatError
from atr_node.io.atrlog import LogRecord
from atr_node.io.jsf import JsfReader
from atr_node.io.jsf_write import write_jsf
from atr_node.io.xtf import XtfReader
from atr_node.io.xtf_bottom import track_bottom
from atr_node.io.xtf_packets import fix_time
from atr_node.io.xtf_write import XtfWriter, write_xtf
from atr_node.records.tile import Tile, TileNav

from .conftest import make_tile
from .test_altitude_tiling import _pings
from .test_jsf import spec_ping

ALT_M = 3.0
DR_M = 0.05


def _records(tiles):
    return [LogRecord(t=float(t.ping_time[-1]), link="sonar", msg=t.to_map(), offset=0) for t in tiles]


def _block(recorded_alt_m, *, cols=(400, 400), rows=40, seed=5):
    """Port and starboard tiles of the same pings, seabed from ALT_M, the given recorded altitude."""
    rng = np.random.default_rng(seed)
    tiles = []
    for side, n in zip(("port", "stbd"), cols):
        t = make_tile(side, rows=rows, cols=n, dr_m=DR_M, range0_m=0.5 * DR_M, rng=rng)
        nav = TileNav(t.nav.lat_deg, t.nav.lon_deg, t.nav.heading_deg, np.full(rows, recorded_alt_m))
        px = np.clip(_pings(np.full(rows, ALT_M), dr_m=DR_M, cols=n, rng=rng), 1, 65535)
        tiles.append(t.replace(pixels=px, nav=nav))
    return tiles


def _sonar(reader):
    return [Tile.from_map(r.msg) for r in reader if r.link == "sonar"]


# -- 2: a position without an altitude keeps its nav ---------------------------------------
@pytest.mark.parametrize("altitude", ["auto", "sonar", "altimeter"])
def test_jsf_without_an_altimeter_keeps_its_nav_and_takes_the_image_altitude(tmp_path, altitude):
    path = tmp_path / "no_altimeter.jsf"
    write_jsf(path, _records(_block(0.0)))  # JSF altitude 0 = not filled
    reader = JsfReader(path, altitude=altitude)
    tiles = _sonar(reader)
    assert len(tiles) == 2 and all(t.nav is not None for t in tiles)  # was: no nav, dropped by the node
    for t in tiles:
        np.testing.assert_allclose(t.nav.altitude_m, ALT_M, atol=2 * DR_M)  # the seabed built in
    assert reader.stats.pings_without_nav == 0
    assert reader.stats.altitude_recorded_bad["missing"] == 40
    src = reader.stats.altitude_source
    assert (src["image"], src["nominal"], src["recorded"]) == (40, 0, 0)
    assert "recorded altitude missing in 40" in reader.stats.altitude_line()


def test_xtf_missing_altitude_is_filled_and_the_nominal_one_where_the_image_has_none(tmp_path):
    tiles = _block(-1.0)  # a negative altitude is no altitude
    dark = [t.replace(pixels=np.full_like(t.pixels, 5.0)) for t in _block(-1.0)]  # no seabed in sight
    dark = [t.replace(ping_time=t.ping_time + 100.0, seq=1) for t in dark]
    path = tmp_path / "no_altitude.xtf"
    with XtfWriter(path) as w:  # tiles as they are (a negative altitude is not a valid tile map)
        for t in (tiles[0], tiles[1], dark[0], dark[1]):
            w.write_tile(t)
    reader = XtfReader(path)
    got = _sonar(reader)
    assert [t.nav is not None for t in got] == [True] * 4
    np.testing.assert_allclose(got[0].nav.altitude_m, ALT_M, atol=2 * DR_M)
    np.testing.assert_array_equal(got[2].nav.altitude_m, reader.sensor.altitude_m)
    src = reader.stats.altitude_source
    assert (src["image"], src["nominal"], src["recorded"]) == (40, 40, 0)
    assert reader.stats.altitude_recorded_bad["missing"] == 80
    assert "nominal (sensor.altitude_m) for 40" in reader.stats.altitude_line()


# -- 3: port and starboard on different range axes -------------------------------------------
@pytest.mark.parametrize("cols", [(400, 300), (300, 400)])
def test_sides_with_different_sample_counts_are_tracked(tmp_path, cols):
    path = tmp_path / "asym.xtf"
    write_xtf(path, _records(_block(0.0, cols=cols)))
    reader = XtfReader(path)  # auto: was ValueError "both sides must share the range axis"
    got = _sonar(reader)
    assert sorted(t.cols for t in got) == sorted(cols)
    for t in got:
        np.testing.assert_allclose(t.nav.altitude_m, ALT_M, atol=2 * DR_M)
    assert reader.stats.altitude_sides_resampled == 40
    assert "different range axes" in reader.stats.altitude_line()


def test_a_side_on_a_coarser_axis_is_resampled_onto_the_finer_one():
    rng = np.random.default_rng(8)
    alt = np.full(60, 4.0)
    fine = make_tile("port", rows=60, cols=400, dr_m=0.05, range0_m=0.025, rng=rng)
    fine = fine.replace(pixels=_pings(alt, dr_m=0.05, cols=400, rng=rng))
    coarse = make_tile("stbd", rows=60, cols=250, dr_m=0.08, range0_m=0.04, rng=rng)
    coarse = coarse.replace(pixels=_pings(alt, dr_m=0.08, cols=250, rng=rng))
    both = track_bottom(fine, coarse)
    np.testing.assert_allclose(both.altitude_m, 4.0, atol=2 * 0.05)  # on the fine side's axis
    assert np.allclose((both.altitude_m - 0.025) / 0.05, np.rint((both.altitude_m - 0.025) / 0.05))


# -- 5: JSF projected positions without --crs ------------------------------------------------
def test_jsf_projected_positions_without_crs_fail_in_one_line_naming_crs(tmp_path):
    env = np.arange(1, 9, dtype="<u2").tobytes()
    path = tmp_path / "utm.jsf"
    path.write_bytes(b"".join(spec_ping(channel=1, samples=env, n=8, units=3, ping_number=k, x=5_000_000,
                                        y=50_000_000) for k in range(3)))
    with pytest.raises(LogFormatError) as exc:
        list(JsfReader(path, altitude="altimeter"))
    msg = str(exc.value)
    assert "\n" not in msg and "--crs" in msg and "coordinate units 3" in msg and str(path) in msg
    assert "at byte 0" in msg  # the first ping that needs it


# -- 7: bottom tracking on the near columns --------------------------------------------------
def _blocks(path):
    """Port/stbd slant tiles of the file's blocks, as the reader makes them."""
    tiles = _sonar(XtfReader(path, altitude="altimeter"))
    port = [t for t in tiles if t.side == "port" and t.rows > 16]
    stbd = [t for t in tiles if t.side == "stbd" and t.rows > 16]
    return list(zip(port, stbd))


@pytest.mark.parametrize("name", ["scotsman-iver2", "river-000_1236"])
def test_near_columns_give_the_full_width_altitudes_on_the_real_files(real_data, name):
    """The reader's default (the search limit from the previous block, seabed levels from a
    subsample) against the full-width computation; forced tighter limits and a sparse
    subsample make the near path do the work on every block of both files. Tolerance: equal
    on 99 % of pings, within 2 samples on all."""
    blocks = _blocks(real_data / "xtf" / f"{name}.xtf")
    assert len(blocks) >= 2
    for kw in ({}, {"seabed_columns": 32}, "tight"):
        prior_full = prior_near = None
        for port, stbd in blocks:
            full = track_bottom(port, stbd, prior=prior_full, max_altitude_m=np.inf, seabed_columns=None)
            opts = kw if kw != "tight" else {"max_altitude_m": 1.3 * float(np.max(full.altitude_m)) + 1.0,
                                             "seabed_columns": 32}
            near = track_bottom(port, stbd, prior=prior_near, **opts)
            diff = np.abs(near.altitude_m - full.altitude_m)
            assert np.mean(diff == 0) >= 0.99 and np.max(diff) <= 2 * port.dr_m + 1e-9, (kw, np.max(diff))
            assert np.mean(near.found == full.found) >= 0.99
            prior_full, prior_near = full, near


def test_a_limit_the_track_reaches_falls_back_to_the_full_width():
    rng = np.random.default_rng(4)
    alt = np.linspace(6.0, 9.0, 80)  # climbs past the limit
    port = make_tile("port", rows=80, cols=600, dr_m=0.05, range0_m=0.025, rng=rng)
    port = port.replace(pixels=_pings(alt, dr_m=0.05, cols=600, rng=rng))
    track = track_bottom(port, None, max_altitude_m=7.0)
    np.testing.assert_allclose(track.altitude_m, alt, atol=2 * 0.05)


# -- 9: one midnight rule ------------------------------------------------------------------------
def test_fix_time_before_midnight_of_a_ping_after_it_is_the_day_before():
    day = 1_700_006_400.0  # 2023-11-15 00:00:00 UTC
    assert fix_time(day + 5.0, 86399.0) == day - 1.0  # fix 23:59:59, ping 00:00:05
    assert fix_time(day + 3600.0, 3599.0) == day + 3599.0
