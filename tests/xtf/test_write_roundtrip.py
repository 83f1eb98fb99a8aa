"""Writing XTF: round trips through our reader, and our files read by pyxtf (the independent parser)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyxtf import XTFHeaderType, xtf_read

from atr_node.io.atrlog import AtrLogWriter, LogRecord, read_atrlog
from atr_node.io.xtf import XtfReader
from atr_node.io.xtf_write import XtfWriter, write_xtf
from atr_node.records.tile import Tile

from .conftest import T0, make_tile


def _tiles(path) -> list[Tile]:
    return [Tile.from_map(r.msg) for r in XtfReader(path) if r.link == "sonar"]


def _to_atrlog(records, path):
    with AtrLogWriter(path) as w:
        for r in records:
            w.write_record(r)
    return path


def test_xtf_atrlog_xtf_atrlog_gives_the_same_tiles(iver2, tmp_path):
    # the format round trip: altitude as recorded (the image's would be re-derived on each read)
    log1 = _to_atrlog(XtfReader(iver2, altitude="altimeter"), tmp_path / "one.atrlog")
    stats = write_xtf(tmp_path / "two.xtf", read_atrlog(log1))
    assert stats.pings == 461 and stats.tiles == 6 and stats.unpaired_tiles == 0 and not stats.rejected
    assert stats.skipped["nmea"] == 1411
    log2 = _to_atrlog(XtfReader(tmp_path / "two.xtf", altitude="altimeter"), tmp_path / "three.atrlog")
    t1 = [Tile.from_map(r.msg) for r in read_atrlog(log1) if r.link == "sonar"]
    t2 = [Tile.from_map(r.msg) for r in read_atrlog(log2) if r.link == "sonar"]
    assert len(t1) == len(t2) == 6
    for a, b in zip(t1, t2):
        # dx_m goes through the float32 SensorSpeed field of the ping header: equal to 1e-7
        assert b.dx_m == pytest.approx(a.dx_m, rel=1e-6)
        assert a.equals(b.replace(dx_m=a.dx_m)), a.ident


def test_pyxtf_reads_what_we_write(iver2_read, tmp_path):
    _, _, tiles = iver2_read
    path = tmp_path / "ours.xtf"
    with XtfWriter(path) as w:
        for t in tiles:
            w.write_tile(t)
    header, packets = xtf_read(str(path))
    pings = packets[XTFHeaderType.sonar]
    assert list(packets) == [XTFHeaderType.sonar] and len(pings) == 461
    assert header.NumberOfSonarChannels == 2 and header.NavUnits == 3
    assert [header.ChanInfo[i].TypeOfChannel for i in (0, 1)] == [1, 2]
    assert header.ChanInfo[0].Frequency == 600.0
    port = np.vstack([p.data[0] for p in pings])[:, ::-1]  # XTF port: far range first
    stbd = np.vstack([p.data[1] for p in pings])
    for side, got in (("port", port), ("stbd", stbd)):
        want = np.vstack([np.frombuffer(t.to_map()["data"], "<u2").reshape(t.shape) for t in tiles if t.side == side])
        np.testing.assert_array_equal(got, want)
    p = pings[281]
    t = [t for t in tiles if t.side == "stbd"][2]
    assert p.SensorYcoordinate == t.nav.lat_deg[24] and p.SensorXcoordinate == t.nav.lon_deg[24]
    assert p.ping_chan_headers[1].SlantRange == pytest.approx(t.dr_m * 1024, rel=1e-7)
    assert (p.get_time() - np.datetime64("1970-01-01")) / np.timedelta64(10, "ms") == round(t.ping_time[24] * 100)


@pytest.mark.parametrize("dtype", ["uint16", "uint8", "float32"])
@pytest.mark.parametrize("slant", [True, False])
def test_synthetic_tiles_round_trip(tmp_path, dtype, slant):
    tiles = [make_tile(side, rows=5, cols=12, seq=3, dtype=dtype, slant=slant, dr_m=0.05, range0_m=0.025)
             for side in ("port", "stbd")]
    stats = write_xtf(tmp_path / "s.xtf", [LogRecord(t.ping_time[-1], "sonar", t.to_map()) for t in tiles])
    assert stats.pings == 5
    back = _tiles(tmp_path / "s.xtf")
    assert [b.side for b in back] == ["port", "stbd"]
    for a, b in zip(tiles, back):
        assert (b.mission, b.leg, b.seq, b.wire_dtype, b.slant) == (a.mission, a.leg, a.seq, dtype, slant)
        np.testing.assert_array_equal(b.pixels, a.pixels)  # NaN where no data, both ways
        np.testing.assert_array_equal(b.ping_time, a.ping_time)
        # slant range and time delay are float32 fields of the channel header
        assert b.dr_m == pytest.approx(a.dr_m, rel=1e-7) and b.range0_m == pytest.approx(a.range0_m, abs=1e-6)
        np.testing.assert_array_equal(b.nav.lat_deg, a.nav.lat_deg)
        np.testing.assert_array_equal(b.nav.heading_deg, a.nav.heading_deg)  # float32-exact values
        assert b.sensor == a.sensor


def test_unpaired_tiles_are_written_alone(tmp_path):
    port = make_tile("port", rows=3, seq=0)
    stbd = make_tile("stbd", rows=3, seq=0, t0=T0 + 10.0)  # other pings: no pair
    with XtfWriter(tmp_path / "u.xtf") as w:
        w.write_tile(port)
        w.write_tile(stbd)
    assert w.stats.unpaired_tiles == 2 and w.stats.pings == 6
    back = _tiles(tmp_path / "u.xtf")
    assert [(b.side, b.rows) for b in back] == [("port", 3), ("stbd", 3)]
    np.testing.assert_array_equal(back[1].pixels, stbd.pixels)


def test_tiles_without_nav_and_other_links(tmp_path):
    tile = make_tile("stbd", nav=False)
    records = [LogRecord(T0, k, m) for k, m in
               (("nmea", b"$GPZDA,000000.00,01,01,2020,,*66\r\n"), ("sonar", tile.to_map()),
                ("sonar", {"type": "tile"}))]
    stats = write_xtf(tmp_path / "n.xtf", records)
    assert stats.skipped["nmea"] == 1 and len(stats.rejected) == 1 and "missing key" in stats.rejected[0]
    (back,) = _tiles(tmp_path / "n.xtf")
    assert back.nav is None and np.array_equal(back.pixels, tile.pixels, equal_nan=True)


def test_empty_record_stream_writes_a_readable_header(tmp_path):
    assert write_xtf(tmp_path / "e.xtf", []).pings == 0
    reader = XtfReader(tmp_path / "e.xtf")
    assert list(reader) == [] and reader.stats.tiles == 0 and not reader.stats.truncated


@settings(max_examples=25, deadline=None)
@given(rows=st.integers(1, 6), cols=st.integers(1, 9), seed=st.integers(0, 2 ** 31),
       hundredths=st.integers(0, 10 ** 11))
def test_property_uint16_tiles_round_trip_exactly(tmp_path_factory, rows, cols, seed, hundredths):
    t0 = hundredths / 100.0  # XTF holds ping times to the hundredth of a second
    rng = np.random.default_rng(seed)
    tiles = [make_tile(s, rows=rows, cols=cols, rng=rng, t0=t0) for s in ("port", "stbd")]
    for t in tiles:
        t.pixels[rng.random(t.pixels.shape) < 0.2] = np.nan
    path = tmp_path_factory.mktemp("p") / "p.xtf"
    with XtfWriter(path) as w:
        for t in tiles:
            w.write_tile(t)
    back = _tiles(path)
    assert len(back) == 2
    for a, b in zip(tiles, back):
        assert np.array_equal(a.pixels, b.pixels, equal_nan=True)
        assert np.all(np.abs(b.ping_time - a.ping_time) <= 0.005 + 1e-6)
        assert math.isclose(b.dr_m, a.dr_m, rel_tol=1e-7)
