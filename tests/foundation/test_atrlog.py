"""The .atrlog recording format (ICD section 4): exact round trip, streaming, truncation."""

from __future__ import annotations

import logging

import msgpack
import numpy as np
import pytest

from atr_node.errors import LogFormatError
from atr_node.io import AtrLogReader, AtrLogWriter, read_atrlog
from atr_node.records import Tile

from .test_tile import make_tile


def sample_records():
    tile = make_tile().to_map()
    return [
        (1.7e9 + 0.0, "nmea", b"$GPGGA,000000.00,4404.80,N,00951.00,E,1,08,1.0,0.0,M,0.0,M,,*47\r\n"),
        (1.7e9 + 0.1, "can", {"id": 0x101, "data": b"\x01\x02\x03", "ext": False}),
        (1.7e9 + 0.2, "sonar", tile),
        (1.7e9 + 0.3, "nmea", b"$HEHDT,359.9,T*2B"),
    ]


def test_write_read_exact(tmp_path):
    path = tmp_path / "m.atrlog"
    recs = sample_records()
    with AtrLogWriter(path) as w:
        offsets = [w.write(*r) for r in recs]
    got = list(read_atrlog(path))
    assert [(g.t, g.link, g.msg) for g in got] == [(t, link, msg) for t, link, msg in recs]
    assert [g.offset for g in got] == offsets
    assert Tile.from_map(got[2].msg).equals(make_tile())


def test_truncated_last_record_is_ignored_with_warning(tmp_path, caplog):
    path = tmp_path / "cut.atrlog"
    recs = sample_records()
    with AtrLogWriter(path) as w:
        for r in recs:
            w.write(*r)
    data = path.read_bytes()
    for cut in (1, 5, 40):
        path.write_bytes(data[:-cut])
        reader = AtrLogReader(path)
        with caplog.at_level(logging.WARNING):
            got = list(reader)
        assert len(got) == len(recs) - 1
        assert reader.truncated
        assert "truncated" in caplog.text
    # cutting inside the big tile record keeps the two before it
    path.write_bytes(data[: len(data) // 2])
    reader = AtrLogReader(path)
    assert [r.link for r in reader] == ["nmea", "can"] and reader.truncated


def test_malformed_records_are_skipped_and_named(tmp_path):
    path = tmp_path / "bad.atrlog"
    good = {"t": 1.0, "link": "nmea", "msg": b"$X*00"}
    bads = [
        {"t": 2.0, "link": "radio", "msg": b""},
        {"t": "now", "link": "nmea", "msg": b""},
        {"t": 3.0, "link": "can", "msg": {"id": -1, "data": b"", "ext": False}},
        {"t": 4.0, "link": "sonar", "msg": b"tile"},
        {"t": 5.0, "link": "nmea"},
    ]
    with open(path, "wb") as fh:
        fh.write(msgpack.packb(good, use_bin_type=True))
        for b in bads:
            fh.write(msgpack.packb(b, use_bin_type=True))
        fh.write(msgpack.packb(good, use_bin_type=True))
        fh.write(msgpack.packb([1, 2, 3]))  # not a record at all: garbage, skipped to the next valid record
        fh.write(msgpack.packb(good, use_bin_type=True))
    reader = AtrLogReader(path)
    got = list(reader)
    assert len(got) == 3 and reader.rejected == len(bads) + 1
    assert reader.reasons == {"bad link": 1, "bad t": 1, "bad msg": 2, "missing key": 1, "garbage skipped": 1}
    assert all("byte" in e for e in reader.errors)
    with pytest.raises(LogFormatError, match="byte"):
        list(read_atrlog(path, strict=True))


def test_garbage_stops_reading_keeps_everything_before(tmp_path):
    path = tmp_path / "garbage.atrlog"
    with AtrLogWriter(path) as w:
        w.write(1.0, "nmea", b"$A*00")
    with open(path, "ab") as fh:
        fh.write(b"\xc1" * 10)  # 0xc1 is never used in msgpack
    reader = AtrLogReader(path)
    assert len(list(reader)) == 1 and reader.rejected == 1


def test_writer_rejects_bad_record_and_appends(tmp_path):
    path = tmp_path / "w.atrlog"
    with AtrLogWriter(path) as w:
        with pytest.raises(LogFormatError):
            w.write(1.0, "video", b"")
        w.write(1.0, "nmea", b"$A*00")
    with AtrLogWriter(path, append=True) as w:
        w.write(2.0, "nmea", b"$B*00")
    assert [r.t for r in read_atrlog(path)] == [1.0, 2.0]


def test_streaming_reads_a_large_log_with_bounded_buffer(tmp_path):
    """Many tiles: the reader yields them one by one (the file is ~40 MB, the buffer 1 MB)."""
    path = tmp_path / "big.atrlog"
    px = np.random.default_rng(0).random((200, 500), dtype=np.float32)
    tile = make_tile().replace(pixels=px, ping_time=np.arange(200, dtype=float), nav=None, sensor=None)
    m = tile.to_map()
    n = 100
    with AtrLogWriter(path, flush_every=10) as w:
        for i in range(n):
            m["seq"] = i
            w.write(float(i), "sonar", m)
    count = 0
    for rec in read_atrlog(path):
        assert rec.msg["seq"] == count
        count += 1
    assert count == n
