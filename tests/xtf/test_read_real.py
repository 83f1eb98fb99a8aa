"""The real Iver2 recording read into tiles and NMEA records, checked against pyxtf's own reading."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from pyxtf import XTFHeaderType, xtf_read

from atr_node.io.xtf import XtfReader, XtfStats, iter_xtf_records
from atr_node.records.nav import NavTrack, _haversine_m
from atr_node.records.tile import Tile
from hw.nmea import parse_sentence
from hw.nmea_decoder import NmeaDecoder


@pytest.fixture(scope="module")
def reference(iver2):
    """The pings as pyxtf reads them: the independent reference."""
    header, packets = xtf_read(str(iver2))
    return header, packets[XTFHeaderType.sonar]


def _stack(tiles, side):
    return [t for t in tiles if t.side == side]


def test_pixels_and_channel_sizes_match_the_file(iver2_read, reference):
    _, stats, tiles = iver2_read
    header, pings = reference
    assert stats.pings == len(pings) == 461
    assert [header.ChanInfo[i].TypeOfChannel for i in (0, 1)] == [1, 2]  # channel 0 port, 1 starboard
    for side, ch in (("port", 0), ("stbd", 1)):
        mine = _stack(tiles, side)
        assert sum(t.rows for t in mine) == len(pings)
        assert all(t.cols == pings[0].ping_chan_headers[ch].NumSamples == 1024 for t in mine)
        assert all(t.wire_dtype == "uint16" and t.slant for t in mine)
        got = np.vstack([np.frombuffer(t.to_map()["data"], "<u2").reshape(t.shape) for t in mine])
        want = np.vstack([p.data[ch] for p in pings])
        if side == "port":  # stored far range first; tiles count columns from the nadir
            want = want[:, ::-1]
        np.testing.assert_array_equal(got, want)
    assert sum(t.rows * t.cols for t in tiles) == 2 * 461 * 1024


def test_ranges_and_times_match_the_ping_headers(iver2_read, reference):
    _, _, tiles = iver2_read
    _, pings = reference
    slant = float(pings[0].ping_chan_headers[1].SlantRange)
    for t in tiles:
        assert t.dr_m == pytest.approx(slant / 1024, rel=1e-12)
        assert t.range0_m == pytest.approx(0.5 * t.dr_m, rel=1e-12)  # TimeDelay 0: centre of sample 0
        assert t.ranges_m[-1] + 0.5 * t.dr_m == pytest.approx(slant, rel=1e-9)
    want = np.array([(p.get_time() - np.datetime64("1970-01-01")) / np.timedelta64(1, "us") * 1e-6 for p in pings])
    got = np.concatenate([t.ping_time for t in _stack(tiles, "stbd")])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)


def test_nav_matches_the_ping_headers(iver2_read, reference):
    _, stats, tiles = iver2_read
    _, pings = reference
    stbd = _stack(tiles, "stbd")
    # ping 0 has no position (all nav fields 0): it makes a one-ping tile without a nav map
    assert stbd[0].rows == 1 and stbd[0].nav is None and stats.pings_without_nav == 1
    assert pings[0].SensorXcoordinate == 0.0
    lat = np.concatenate([t.nav.lat_deg for t in stbd[1:]])
    np.testing.assert_array_equal(lat, [p.SensorYcoordinate for p in pings[1:]])
    lon = np.concatenate([t.nav.lon_deg for t in stbd[1:]])
    np.testing.assert_array_equal(lon, [p.SensorXcoordinate for p in pings[1:]])
    hdg = np.concatenate([t.nav.heading_deg for t in stbd[1:]])
    np.testing.assert_allclose(hdg, [p.SensorHeading for p in pings[1:]], rtol=0, atol=1e-9)
    alt = np.concatenate([t.nav.altitude_m for t in stbd[1:]])
    np.testing.assert_allclose(alt, [p.SensorPrimaryAltitude for p in pings[1:]], rtol=0, atol=1e-9)
    assert 2.6 < alt.min() and alt.max() < 11.5
    assert stats.nav_jumps == 0


def test_ping_spacing_uses_speed_in_knots(iver2_read):
    """dx_m from SensorSpeed (knots) agrees with the distance the positions travel."""
    _, _, tiles = iver2_read
    for t in _stack(tiles, "stbd")[1:]:
        travelled = float(_haversine_m(t.nav.lat_deg[0], t.nav.lon_deg[0], t.nav.lat_deg[-1], t.nav.lon_deg[-1]))
        per_ping = travelled / (t.rows - 1)
        assert t.dx_m == pytest.approx(per_ping, rel=0.15)  # read as m/s it would be 1.9x too long


def test_sensor_map_from_the_file(iver2_read):
    _, stats, tiles = iver2_read
    for t in tiles:
        assert t.sensor.frequency_hz == 600e3 and not t.sensor.sas and t.sensor.n_rx == 1
    assert set(stats.sensor_defaults) == {"bandwidth_hz", "tx_length_m", "rx_length_m"}


def test_records_in_time_order_and_well_formed(iver2_read):
    records, stats, tiles = iver2_read
    t = np.array([r.t for r in records])
    assert np.all(np.diff(t) >= 0)
    assert [r.link for r in records].count("sonar") == stats.tiles == 6
    assert {t.seq for t in tiles if t.side == "port"} == {0, 1, 2}
    for r in records:
        if r.link == "nmea":
            parse_sentence(r.msg)  # framing and checksum
        else:  # a tile arrives once its last ping is in
            assert r.t == Tile.from_map(r.msg).ping_time[-1]
    assert stats.nmea["GGA"] == 219 and stats.nmea["HDT"] == stats.nmea["DPT"] == 460


def test_nmea_decodes_back_to_the_ping_nav(iver2_read):
    """The synthesised sentences, through the links' decoder and nav track, give the tile nav."""
    records, _, tiles = iver2_read
    dec, track = NmeaDecoder(date_from_arrival=False), NavTrack(max_gap_s=2.0)
    for r in records:
        if r.link == "nmea":
            track.extend(dec.feed(r.msg, r.t))
    assert dec.rejected == 0
    for t in _stack(tiles, "stbd")[1:]:
        s = track.interpolate(t.ping_time)
        assert s.valid.all(), s.reason
        # header positions are held from fix to fix, the track interpolates between fix times:
        # they differ by at most one step between consecutive fixes
        step = _haversine_m(t.nav.lat_deg[:-1], t.nav.lon_deg[:-1], t.nav.lat_deg[1:], t.nav.lon_deg[1:])
        d = _haversine_m(s.nav.lat_deg, s.nav.lon_deg, t.nav.lat_deg, t.nav.lon_deg)
        assert np.max(d) <= np.max(step) + 1e-3
        assert np.median(d) < 0.1
        # headings: HDT is untimed; the decoder stamps it on the GGA clock (fix time, up to 0.3 s earlier)
        assert np.max(np.abs((s.nav.heading_deg - t.nav.heading_deg + 180) % 360 - 180)) < 3.0
        assert np.median(np.abs(s.nav.altitude_m - t.nav.altitude_m)) < 0.01


def test_iter_xtf_records_fills_the_given_stats(iver2):
    stats = XtfStats()
    n = sum(1 for _ in iter_xtf_records(iver2, tile_pings=100, stats=stats))
    assert stats.tiles == 2 * (1 + math.ceil(460 / 100))
    assert n == stats.tiles + sum(stats.nmea.values())
    assert "sonar 461" in stats.summary()


def test_reading_prints_and_warns_nothing(iver2, nav_only, capsys):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for path in (iver2, nav_only):
            for _ in XtfReader(path):
                pass
    assert caught == []
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""
