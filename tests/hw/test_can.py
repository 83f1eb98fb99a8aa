"""CAN codec (DBC) against a struct-level reference, decoder rules, and the CAN link on a virtual bus."""

from __future__ import annotations

import math
import struct
import uuid

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hw.can_link import CanLink
from hw.can_nav import (CanNavDecoder, LegChange, encode_altitude, encode_attitude, encode_leg, encode_position,
                        encode_time, load_dbc)
from hw.decode import NavDecoder
from hw.replay import CandumpLink
from hw.errors import CanCodecError, LinkSpecError
from atr_node.io.atrlog import LogRecord


@settings(max_examples=200, deadline=None)
@given(lat=st.floats(-90, 90), lon=st.floats(-180, 179.9999999))
def test_position_layout_matches_struct_reference(lat, lon):
    fid, data, ext = encode_position(lat, lon)
    assert (fid, ext, len(data)) == (0x100, False, 8)
    raw_lat, raw_lon = struct.unpack("<ii", data)  # Intel int32, 1e-7 deg
    assert raw_lat == round(lat * 1e7) and raw_lon == round(lon * 1e7)
    (fix,) = CanNavDecoder().feed(fid, data, ext, 100.0)
    assert abs(fix.lat_deg - lat) <= 0.5e-7 + 1e-12 and abs(fix.lon_deg - lon) <= 0.5e-7 + 1e-12


@settings(max_examples=200, deadline=None)
@given(hdg=st.floats(-720, 720), pitch=st.floats(-90, 90), roll=st.floats(-180, 180),
       speed=st.none() | st.floats(0, 65.534))
def test_attitude_layout_matches_struct_reference(hdg, pitch, roll, speed):
    fid, data, _ = encode_attitude(hdg, pitch_deg=pitch, roll_deg=roll, speed_m_s=speed)
    h, p, r, s = struct.unpack("<HhhH", data)
    assert h == round(hdg * 100) % 36000 and p == round(pitch * 100) and r == round(roll * 100)
    assert s == (0xFFFF if speed is None else round(speed * 1000))
    (fix,) = CanNavDecoder().feed(fid, data, False, 0.0)
    assert abs(((fix.heading_deg - hdg + 180) % 360) - 180) <= 0.005 + 1e-9
    assert (fix.speed_m_s is None) == (speed is None)


@settings(max_examples=200, deadline=None)
@given(t=st.floats(0, 4.29e9))
def test_time_resolution_and_clock_offset(t):
    fid, data, ext = encode_time(t)
    sec, rest = struct.unpack("<II", data)
    us = rest & 0xFFFFF
    assert sec + us * 1e-6 == pytest.approx(t, abs=1e-6 + abs(t) * 1e-15) and us <= 999_999
    d = CanNavDecoder()
    d.feed(fid, data, ext, 1000.0)  # vehicle clock t, arrival clock 1000 s
    (fix,) = d.feed(*encode_altitude(3.0), 1000.25)
    assert fix.t == pytest.approx(sec + us * 1e-6 + 0.25, abs=1e-5)


def test_altitude_not_available_and_leg_changes():
    fid, data, _ = encode_altitude(None, depth_m=42.123)
    alt, depth = struct.unpack("<HI", data[:6])
    assert alt == 0xFFFF and depth == 42123
    d = CanNavDecoder()
    (fix,) = d.feed(fid, data, False, 0.0)
    assert fix.altitude_m is None and fix.depth_m == pytest.approx(42.123)
    events = [d.feed(*encode_leg(leg, survey=s), float(i)) for i, (leg, s) in
              enumerate([(1, True), (1, True), (1, False), (2, True), (2, True)])]
    assert [e for ev in events for e in ev] == [LegChange(0.0, 1, True), LegChange(2.0, 1, False),
                                                LegChange(3.0, 2, True)]


@pytest.mark.parametrize("call", [lambda: encode_position(91, 0), lambda: encode_position(math.nan, 0),
                                  lambda: encode_altitude(700.0), lambda: encode_altitude(-1.0),
                                  lambda: encode_time(-5), lambda: encode_leg(70000), lambda: encode_leg(1.5),
                                  lambda: encode_attitude(math.inf)])
def test_encoders_refuse_values_that_do_not_fit(call):
    with pytest.raises(CanCodecError):
        call()


def test_decoder_counts_unknown_and_bad_frames_and_goes_on():
    d = CanNavDecoder()
    assert d.feed(0x7FF, b"\x00" * 8, False, 0.0) == []  # not in the DBC
    assert d.feed(0x100, b"\x00" * 8, True, 0.0) == []  # right id, extended: another frame
    assert d.feed(0x100, b"\x00" * 3, False, 0.0) == []  # short
    bad_lat = struct.pack("<ii", 1_000_000_000, 0)  # 100 deg
    assert d.feed(0x100, bad_lat, False, 0.0) == []
    assert (d.counts["unknown"], d.counts["bad_length"], d.counts["out_of_range"]) == (2, 1, 1)
    assert d.feed(*encode_position(1.0, 2.0), 0.0)[0].lat_deg == pytest.approx(1.0)


def test_dbc_defines_the_documented_frames():
    db = load_dbc()
    names = {m.frame_id: m.name for m in db.messages}
    assert names == {0x100: "ATR_NavPosition", 0x101: "ATR_NavAttitude", 0x102: "ATR_NavAltitude",
                     0x103: "ATR_Time", 0x104: "ATR_MissionLeg"}
    with pytest.raises(LinkSpecError):
        load_dbc("/nonexistent/x.dbc")


def test_can_link_on_virtual_bus_feeds_the_decoder():
    channel = f"test-{uuid.uuid4().hex}"
    frames = [encode_time(1.7e9), encode_position(44.1, 9.85), encode_attitude(90.0), encode_altitude(12.5),
              encode_leg(3)]
    with CanLink("virtual", channel) as link, can.Bus(interface="virtual", channel=channel) as tx:
        tx.send(can.Message(arbitration_id=0x1, is_error_frame=True))
        for fid, data, ext in frames:
            tx.send(can.Message(arbitration_id=fid, data=data, is_extended_id=ext))
        recs = [link.recv(timeout=5.0) for _ in frames]
        assert link.recv(timeout=0.05) is None
    assert [(r.link, r.msg["id"], r.msg["data"], r.msg["ext"]) for r in recs] == [("can", *f) for f in frames]
    assert link.counts["error_frames"] == 1
    nav = NavDecoder()
    events = [e for r in recs for e in nav.feed(r)]
    assert len(events) == 4 and events[-1].leg == 3
    assert events[0].lat_deg == pytest.approx(44.1) and events[2].altitude_m == pytest.approx(12.5)


def test_real_nmea2000_bus_is_counted_unknown_never_fatal(real_data):
    path = real_data / "can" / "candumpSample3.txt"
    with CandumpLink(path) as dump:
        frames = [can.Message(timestamp=r.t, arbitration_id=r.msg["id"], data=r.msg["data"], is_extended_id=r.msg["ext"])
                  for r in dump]
        assert dump.counts["bad_lines"] == 0
    channel = f"n2k-{uuid.uuid4().hex}"
    nav = NavDecoder()
    with CanLink("virtual", channel) as link, can.Bus(interface="virtual", channel=channel) as tx:
        for m in frames:
            tx.send(m)
        got = []
        while (rec := link.recv(timeout=1.0)) is not None:
            got.append(rec)
            assert nav.feed(rec) == []
    assert len(frames) == 2368 and len(got) == len(frames)
    assert [r.msg["id"] for r in got] == [m.arbitration_id for m in frames]
    assert nav.can.counts["unknown"] == len(frames) and nav.can.counts["accepted"] == 0
    # the decoder still works after thousands of foreign frames
    assert nav.feed(LogRecord(t=0.0, link="can", msg=dict(zip(("id", "data", "ext"), encode_position(1, 1)))))
