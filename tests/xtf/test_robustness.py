"""Damaged, odd and unknown input: counted and reported, never fatal past the file header."""

from __future__ import annotations

import ctypes
import logging
import struct

import numpy as np
import pytest
from pyxtf.xtf_ctypes import XTFNotesHeader, XTFPacketStart, XTFRawSerialHeader

from atr_node.errors import LogFormatError
from atr_node.io.xtf import XtfReader
from atr_node.io.xtf_write import XtfWriter
from atr_node.records.tile import Tile

from .conftest import T0, make_tile

HEADER = 1024
IVER_PING = 4480  # bytes of one Iver2 ping packet (256 + 2 x (64 + 2048))


def _read(path):
    reader = XtfReader(path)
    records = list(reader)
    return reader.stats, [Tile.from_map(r.msg) for r in records if r.link == "sonar"], records


def _write(path, tiles):
    with XtfWriter(path) as w:
        for t in tiles:
            w.write_tile(t)
    return path


def test_truncated_file_keeps_every_complete_ping(iver2, tmp_path, caplog):
    cut = tmp_path / "cut.xtf"
    cut.write_bytes(iver2.read_bytes()[:HEADER + 10 * IVER_PING + 100])
    with caplog.at_level(logging.WARNING):
        stats, tiles, _ = _read(cut)
    assert stats.pings == 10 and stats.truncated
    assert sum(t.rows for t in tiles if t.side == "stbd") == 10
    assert f"at byte {HEADER + 10 * IVER_PING}" in stats.errors[0] and "past the end" in stats.errors[0]
    assert "rest of the file is ignored" in caplog.text


def test_bad_magic_number_ends_the_read_with_its_offset(iver2, tmp_path):
    data = bytearray(iver2.read_bytes())
    at = HEADER + 20 * IVER_PING
    data[at:at + 2] = b"\x00\x00"
    (tmp_path / "bad.xtf").write_bytes(bytes(data))
    stats, tiles, _ = _read(tmp_path / "bad.xtf")
    assert stats.pings == 20 and stats.truncated
    assert f"at byte {at}: packet magic number 0x0000" in stats.errors[0]


def test_unparsable_ping_is_skipped_and_the_rest_read(iver2, tmp_path):
    data = bytearray(iver2.read_bytes())
    at = HEADER + 5 * IVER_PING
    struct.pack_into("<H", data, at + 4, 6)  # NumChansToFollow: 6 channels cannot fit the packet
    (tmp_path / "chans.xtf").write_bytes(bytes(data))
    stats, tiles, _ = _read(tmp_path / "chans.xtf")
    assert stats.bad == 1 and stats.pings == 460 and not stats.truncated
    assert stats.quirks == {"unparsable (sonar)": 1}
    assert f"sonar packet at byte {at}" in stats.quirk_examples["unparsable (sonar)"]


def test_unknown_and_unused_packet_types_are_counted(tmp_path):
    path = _write(tmp_path / "u.xtf", [make_tile("port", rows=3), make_tile("stbd", rows=3)])
    unknown = XTFPacketStart()
    unknown.HeaderType = 250
    unknown.NumBytesThisRecord = ctypes.sizeof(XTFPacketStart) + 10
    notes = XTFNotesHeader()
    notes.NumBytesThisRecord = ctypes.sizeof(XTFNotesHeader)
    notes.NotesText = b"a note"
    data = path.read_bytes()
    ping = (len(data) - HEADER) // 3
    extra = bytes(unknown) + b"\x01" * 10 + bytes(notes)
    path.write_bytes(data[:HEADER + ping] + extra + data[HEADER + ping:] + extra)
    stats, tiles, _ = _read(path)
    assert stats.pings == 3 and len(tiles) == 2 and tiles[0].rows == 3
    assert stats.skipped == {"unknown_250": 2, "notes": 2}
    assert stats.packets["sonar"] == 3 and not stats.truncated and stats.bad == 0


@pytest.mark.parametrize("content", [b"", b"not an xtf file at all" * 100])
def test_not_an_xtf_file_is_a_clear_error(tmp_path, content):
    path = tmp_path / "x.xtf"
    path.write_bytes(content)
    with pytest.raises(LogFormatError, match=r"x\.xtf at byte 0: not an XTF file"):
        list(XtfReader(path))


def test_pings_back_in_time_are_dropped_duplicates_kept(tmp_path):
    late = make_tile("stbd", rows=3, t0=T0 + 10.0)
    early = make_tile("stbd", rows=2, t0=T0, seq=1)
    dup = make_tile("stbd", rows=3, t0=T0 + 20.0, seq=2)
    dup = dup.replace(ping_time=np.array([T0 + 20.0, T0 + 20.0, T0 + 20.13]))
    stats, tiles, records = _read(_write(tmp_path / "t.xtf", [late, early, dup]))
    assert stats.pings_dropped == {"time_backwards": 2} and stats.pings == 6
    assert [t.rows for t in tiles] == [3, 3]  # 10 s without pings: a new tile
    np.testing.assert_array_equal(tiles[1].ping_time, dup.ping_time)
    assert all(b.t >= a.t for a, b in zip(records, records[1:]))


def test_geometry_or_nav_change_starts_a_new_tile(tmp_path):
    a = make_tile("stbd", rows=3, cols=16)
    b = make_tile("stbd", rows=2, cols=20, t0=T0 + 1.0, seq=1)
    c = make_tile("stbd", rows=2, cols=20, t0=T0 + 2.0, seq=2, nav=False)
    stats, tiles, _ = _read(_write(tmp_path / "g.xtf", [a, b, c]))
    assert [(t.rows, t.cols, t.nav is not None) for t in tiles] == [(3, 16, True), (2, 20, True), (2, 20, False)]
    assert [t.seq for t in tiles] == [0, 1, 2] and stats.pings_without_nav == 2


def test_all_zero_pings_are_no_data_and_nav_jumps_are_counted(tmp_path):
    t = make_tile("stbd", rows=4)
    t.pixels[:] = np.nan
    lat = t.nav.lat_deg.copy()
    lat[2:] += 0.01  # 1.1 km in 0.13 s
    t = t.with_nav(type(t.nav)(lat, t.nav.lon_deg, t.nav.heading_deg, t.nav.altitude_m))
    stats, tiles, _ = _read(_write(tmp_path / "z.xtf", [t]))
    assert np.all(np.isnan(tiles[0].pixels)) and stats.nav_jumps == 1
    np.testing.assert_array_equal(tiles[0].nav.lat_deg, lat)


def test_tile_pings_bounds_the_tile_size(iver2):
    reader = XtfReader(iver2, tile_pings=1)
    n = sum(r.link == "sonar" for r in reader)
    assert n == 2 * 461 == reader.stats.tiles
    with pytest.raises(ValueError, match="tile_pings"):
        XtfReader(iver2, tile_pings=0)


def test_raw_serial_nmea_comes_out_as_recorded(tmp_path):
    path = _write(tmp_path / "r.xtf", [make_tile("stbd", rows=2)])
    text = b"$GPHDT,123.45,T*04\r\n$GPZDA,000000.00,01,01,2020,,*66\r\nnot nmea\r\n"
    serial = XTFRawSerialHeader()
    serial.Year, serial.Month, serial.Day, serial.Hour, serial.Minute, serial.Second = 2023, 11, 14, 22, 13, 21
    serial.HSeconds = 50
    serial.StringSize = len(text)
    serial.NumBytesThisRecord = ctypes.sizeof(XTFRawSerialHeader) + len(text)
    path.write_bytes(path.read_bytes() + bytes(serial) + text)
    stats, _, records = _read(path)
    nmea = [r for r in records if r.msg in (b"$GPHDT,123.45,T*04\r\n", b"$GPZDA,000000.00,01,01,2020,,*66\r\n")]
    assert len(nmea) == 2 and stats.nmea["raw_serial"] == 2 and stats.skipped["raw_serial_text"] == 1
    assert stats.packets["raw_serial"] == 1
    # stamped with the packet time, or later if the file was already past it
    assert nmea[0].t == max(1700000001.5, max(r.t for r in records[:records.index(nmea[0])]))


def test_projected_navigation_needs_crs(tmp_path):
    path = _write(tmp_path / "p.xtf", [make_tile("stbd", rows=2)])
    data = bytearray(path.read_bytes())
    struct.pack_into("<H", data, 164, 0)  # XTFFileHeader.NavUnits: 0 = metres
    path.write_bytes(bytes(data))
    # a fuller test of --crs is in test_crs.py
    with pytest.raises(LogFormatError, match=r"NavUnits 0\): give their CRS with --crs"):
        XtfReader(path)
