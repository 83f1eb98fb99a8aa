"""The QINSy R2Sonic XTF: navigation and attitude out as NMEA, unknown packet types counted."""

from __future__ import annotations

import warnings
from collections import Counter
from datetime import datetime, timezone

import numpy as np
from pyxtf import XTFHeaderType, xtf_read

from atr_node.io.xtf import XtfReader
from hw.nmea_decoder import NmeaDecoder


def _reference(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pyxtf warns on the type it does not implement
        return xtf_read(str(path))


def test_zero_tiles_and_every_packet_counted(nav_only):
    reader = XtfReader(nav_only)
    records = list(reader)
    _, packets = _reference(nav_only)
    want = Counter({XTFHeaderType(k).name: len(v) for k, v in packets.items()})
    assert reader.stats.packets == want
    assert want == Counter(pos_raw_navigation=1204, attitude=1203, qinsy_r2sonic_bathy=923)
    assert reader.stats.skipped == Counter(qinsy_r2sonic_bathy=923)
    assert reader.stats.tiles == reader.stats.pings == 0
    assert reader.stats.bad == 0 and not reader.stats.truncated and reader.stats.errors == []
    assert {r.link for r in records} == {"nmea"}
    assert reader.stats.nmea["GGA"] == 1204 and reader.stats.nmea["HDT"] == 1203
    assert "skipped: qinsy_r2sonic_bathy 923" in reader.stats.summary()


def test_positions_and_headings_decode_back(nav_only):
    records = list(XtfReader(nav_only))
    _, packets = _reference(nav_only)
    dec = NmeaDecoder(date_from_arrival=False)
    fixes = [f for r in records for f in dec.feed(r.msg, r.t)]
    assert dec.rejected == 0
    pos = [f for f in fixes if f.lat_deg is not None]
    nav = packets[XTFHeaderType.pos_raw_navigation]
    np.testing.assert_allclose([f.lat_deg for f in pos], [p.RawYcoordinate for p in nav], rtol=0, atol=2e-8)
    np.testing.assert_allclose([f.lon_deg for f in pos], [p.RawXcoordinate for p in nav], rtol=0, atol=2e-8)
    hdg = [f.heading_deg for f in fixes if f.heading_deg is not None]
    np.testing.assert_allclose(hdg, [p.Heading for p in packets[XTFHeaderType.attitude]], rtol=0, atol=0.006)


def test_raw_navigation_time_unit_agrees_with_attitude(nav_only):
    """Packet 107 counts 'Microsecond' in 1e-4 s: its times interleave with the attitude
    packets' millisecond times (read as microseconds they would all sit at .00x s)."""
    _, packets = _reference(nav_only)
    nav, att = packets[XTFHeaderType.pos_raw_navigation], packets[XTFHeaderType.attitude]
    records = [r for r in XtfReader(nav_only) if r.msg.startswith(b"$GPGGA")]
    t_gga = np.array([r.t for r in records])
    t_att = np.array([datetime(p.Year, p.Month, p.Day, p.Hour, p.Minute, p.Second, tzinfo=timezone.utc).timestamp()
                      + p.Millisecond / 1000 for p in att])
    assert nav[0].Microsecond == 9080 and att[0].Millisecond == 908
    # the file alternates position and attitude packets stamped together
    assert np.median(np.abs(t_gga[:len(t_att)] - t_att)) < 0.005
