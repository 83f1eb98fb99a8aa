"""Silent acceptance (issue 21 item 7): out-of-range NMEA fields and over-long CAN frames are
rejected, counted by reason, and logged once per reason, on the real transports (``loop://``
serial, python-can's virtual bus)."""

from __future__ import annotations

import logging
import uuid

import can
import pytest

import hw
from atr_node.io.atrlog import LogRecord
from hw.can_link import CanLink
from hw.can_nav import CanNavDecoder, encode_attitude, encode_position, encode_time
from hw.decode import NavDecoder
from hw.nmea import encode_gga, format_sentence
from hw.nmea_decoder import NmeaDecoder


def _drain(link, n):
    out = []
    for _ in range(n):
        rec = link.recv(timeout=5.0)
        assert rec is not None, f"only {len(out)} of {n} records arrived"
        out.append(rec)
    return out


BAD_HEADINGS = ["400", "-90", "1e308", "360.00", "360"]


def test_nmea_headings_outside_0_360_are_rejected_as_on_can(caplog):
    lines = [format_sentence("HEHDT", [h, "T"]) for h in BAD_HEADINGS]
    lines += [format_sentence("INTHS", [h, "A"]) for h in BAD_HEADINGS]
    good = [format_sentence("HEHDT", ["359.99", "T"]), format_sentence("HEHDT", ["0.00", "T"])]
    with hw.open_link("loop://") as link, caplog.at_level(logging.WARNING):
        link.write(b"".join(lines + good))
        recs = _drain(link, len(lines) + len(good))
        d = NmeaDecoder()
        fixes = [f for r in recs for f in d.feed(r.msg, r.t)]
    assert [f.heading_deg for f in fixes] == [359.99, 0.0]  # nothing wrapped: 400 is not 40
    assert d.counts["out_of_range"] == len(lines) and d.counts["accepted"] == 2
    # the same headings on CAN (the raw field holds up to 655.35 deg): rejected for the same reason
    c = CanNavDecoder()
    for raw in (40000, 36000):
        assert c.feed(0x101, raw.to_bytes(2, "little") + bytes(6), False, 0.0) == []
    assert c.counts["out_of_range"] == 2
    # one warning per reason, naming the sentence; the rest are counted
    said = [r.getMessage() for r in caplog.records if "out_of_range" in r.getMessage()]
    assert len(said) == 2 and "HDT heading" in said[0] and "400" in said[0]


@pytest.mark.parametrize("sentence, what", [
    (format_sentence("GPRMC", ["120000.00", "A", "4400.00", "N", "00900.00", "E", "-5.0", "10.0", "010824", "", ""]),
     "RMC speed"),
    (format_sentence("GPRMC", ["120000.00", "A", "4400.00", "N", "00900.00", "E", "5.0", "400.0", "010824", "", ""]),
     "RMC course"),
    (format_sentence("GPVTG", ["10.0", "T", "", "M", "1e308", "N", "", "K", "A"]), "VTG speed"),
    (format_sentence("GPVTG", ["-90.0", "T", "", "M", "2.0", "N", "", "K", "A"]), "VTG course"),
    (format_sentence("SDDPT", ["-3.0", "0.0"]), "DPT depth"),
    (format_sentence("SDDPT", ["1e308", "0.0"]), "DPT depth"),
    (format_sentence("GPGGA", ["120000.00", "4400.00", "N", "00900.00", "E", "1", "08", "1.0", "-1e308", "M", "", "M",
                               "", ""]), "GGA depth"),
    (format_sentence("GPGGA", ["120000.00", "9100.00", "N", "00900.00", "E", "1", "08", "1.0", "0.0", "M", "", "M",
                               "", ""]), "position"),
])
def test_every_decoded_sentence_checks_its_ranges(sentence, what):
    d = NmeaDecoder()
    assert d.feed(sentence, 1.7e9) == []
    assert d.counts["out_of_range"] == 1, d.last_reject
    assert what in d.last_reject


def test_in_range_sentences_still_decode():
    d = NmeaDecoder()
    (gga,) = d.feed(encode_gga(1.7e9, 44.0, 9.0, height_m=-35.0), 1.7e9)
    assert gga.depth_m == pytest.approx(35.0)
    (dpt,) = d.feed(format_sentence("SDDPT", ["4674.70", "8.62", "12000.0"]), 1.7e9)  # a ship's sounder (real log)
    assert dpt.altitude_m == pytest.approx(4674.7)
    assert d.rejected == 0


@pytest.mark.parametrize("n_bytes", [9, 12, 64, 65, 1000, 100_000])
def test_over_long_can_frames_are_not_fixes(n_bytes):
    fid, data, ext = encode_position(44.1, 9.85)
    d = NavDecoder()
    rec = LogRecord(t=1.0, link="can", msg={"id": fid, "data": data + bytes(n_bytes - len(data)), "ext": ext})
    assert d.feed(rec) == []
    reason = "too_long" if n_bytes > 64 else "bad_length"
    assert d.can.counts == {reason: 1}, d.can.counts
    assert str(n_bytes) in d.can.last_reject


def test_dlc_mismatches_on_a_virtual_bus_are_counted_by_reason(caplog):
    """Frames off a real (virtual) bus: CAN FD frames of 12 and 64 bytes and a 3-byte frame on
    DBC ids; an over-long frame of an id not in the DBC is foreign traffic, not ours."""
    channel = f"dlc-{uuid.uuid4().hex}"
    pos, att, t = encode_position(44.1, 9.85), encode_attitude(90.0), encode_time(1.7e9)
    frames = [can.Message(arbitration_id=pos[0], data=pos[1] + bytes(4), is_fd=True, is_extended_id=False),
              can.Message(arbitration_id=att[0], data=att[1] + bytes(56), is_fd=True, is_extended_id=False),
              can.Message(arbitration_id=t[0], data=t[1][:3], is_extended_id=False),
              can.Message(arbitration_id=0x555, data=bytes(64), is_fd=True, is_extended_id=False),
              can.Message(arbitration_id=pos[0], data=pos[1], is_extended_id=False)]
    with CanLink("virtual", channel) as link, can.Bus(interface="virtual", channel=channel) as tx, \
            caplog.at_level(logging.WARNING):
        for m in frames:
            tx.send(m)
        recs = _drain(link, len(frames))
        nav = NavDecoder()
        events = [e for r in recs for e in nav.feed(r)]
    assert len(events) == 1 and events[0].lat_deg == pytest.approx(44.1)
    assert nav.can.counts == {"bad_length": 3, "unknown": 1, "accepted": 1}
    said = [r.getMessage() for r in caplog.records if "bad_length" in r.getMessage()]
    assert len(said) == 1 and "ATR_NavPosition" in said[0] and "12 data bytes" in said[0]


def test_can_signals_outside_their_dbc_range_are_rejected():
    d = CanNavDecoder()
    # pitch raw 20000 = 200 deg: outside the DBC's [-90, 90]; heading fine
    data = (9000).to_bytes(2, "little") + (20000).to_bytes(2, "little", signed=True) + bytes(2) + b"\xff\xff"
    assert d.feed(0x101, data, False, 0.0) == []
    assert d.counts["out_of_range"] == 1 and "Pitch" in d.last_reject
    # microseconds 1_000_000 (20-bit field): outside [0, 999999]
    data = (1_700_000_000).to_bytes(4, "little") + (1_000_000).to_bytes(4, "little")
    assert d.feed(0x103, data, False, 0.0) == []
    assert d.counts["out_of_range"] == 2 and "Microseconds" in d.last_reject
