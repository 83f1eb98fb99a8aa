"""Quirks of older XTF files are counted per kind and reported in one line, not one line per
packet (issue 18 item 7): attitude packets with zero dates, impossible dates, packets too short
for their header, packet types the reader does not know."""

from __future__ import annotations

import ctypes
import subprocess
import sys

from pyxtf.xtf_ctypes import XTFAttitudeData, XTFPacketStart

from atr_node.io.xtf import XtfReader
from atr_node.io.xtf_write import XtfWriter

from .conftest import make_tile

ZERO_DATES = 2643  # as many as the older file of the issue had


def _attitude(year: int, month: int, day: int, heading: float = 90.0) -> bytes:
    a = XTFAttitudeData()
    a.NumBytesThisRecord = ctypes.sizeof(XTFAttitudeData)
    a.Year, a.Month, a.Day = year, month, day
    a.Hour, a.Minute, a.Second = 12, 30, 15
    a.Heading = heading
    return bytes(a)


def _quirky_file(path):
    with XtfWriter(path) as w:
        for seq in range(2):
            w.write_tile(make_tile("port", rows=8, seq=seq, t0=1_700_000_000.0 + 2 * seq))
            w.write_tile(make_tile("stbd", rows=8, seq=seq, t0=1_700_000_000.0 + 2 * seq))
    short = XTFPacketStart()
    short.HeaderType = 3  # attitude, but 24 bytes: its header alone is 64
    short.NumBytesThisRecord = ctypes.sizeof(XTFPacketStart) + 10
    unknown = XTFPacketStart()
    unknown.HeaderType = 250
    unknown.NumBytesThisRecord = ctypes.sizeof(XTFPacketStart) + 6
    extra = (_attitude(0, 0, 0) * ZERO_DATES + _attitude(2023, 13, 40) * 5 + (bytes(short) + b"\0" * 10) * 2
             + (bytes(unknown) + b"\1" * 6) * 7 + _attitude(2023, 11, 14, heading=45.0))
    path.write_bytes(path.read_bytes() + extra)
    return path


def test_zero_dates_are_counted_per_kind(tmp_path):
    reader = XtfReader(_quirky_file(tmp_path / "old.xtf"))
    records = list(reader)
    st = reader.stats
    assert st.quirks == {"zero date (attitude)": ZERO_DATES, "bad date (attitude)": 5, "short packet (attitude)": 2}
    assert st.bad == ZERO_DATES + 5 + 2 and st.skipped == {"unknown_250": 7}
    assert "attitude packet at byte" in st.quirk_examples["zero date (attitude)"]
    assert "2023-13-40" in st.quirk_examples["bad date (attitude)"]
    assert st.errors == []  # no per-packet lines
    # the packets around them are read: every ping, and the one good attitude packet's heading
    assert st.pings == 16 and st.tiles >= 2
    assert any(r.link == "nmea" and r.msg.startswith(b"$HEHDT,45.00") for r in records)


def test_convert_reports_the_quirks_in_a_few_lines(tmp_path):
    src = _quirky_file(tmp_path / "old.xtf")
    r = subprocess.run([sys.executable, "-m", "atr_node", "convert", str(src), str(tmp_path / "old.atrlog")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    lines = (r.stdout + r.stderr).strip().splitlines()
    assert len(lines) <= 12, "\n".join(lines[:20])
    total = ZERO_DATES + 5 + 2
    assert (f"  {total} packets with quirks (not used): bad date (attitude) x 5, short packet (attitude) x 2, "
            f"zero date (attitude) x {ZERO_DATES}") in lines
    assert sum(line.startswith("    first ") for line in lines) == 3
    assert any(line.startswith("  skipped: unknown_250 7") for line in lines)


def test_unknown_packet_types_of_a_real_file_in_one_line(nav_only):
    reader = XtfReader(nav_only)
    list(reader)
    text = reader.stats.summary()
    assert len(text.splitlines()) <= 5, text
    assert [line for line in text.splitlines() if "qinsy_r2sonic_bathy" in line and "skipped" in line] == [
        "  skipped: qinsy_r2sonic_bathy 923"]
    assert reader.stats.quirks == {}
