"""Damage in an .atrlog costs only itself (issue 21 item 2): a record whose frame is whole but
whose content cannot be decoded is rejected and reading goes on; garbage bytes mid-file are
skipped up to the next valid record; a file with no record at all fails in one line.

Every test writes a real file (the small mission's recording, damaged in place) and reads it
with the real reader or the ``atr-node replay`` command. Before the fix, the first undecodable
byte ended the file with exit 0 (``the rest of the file is ignored``).
"""

from __future__ import annotations

import json
import subprocess
import sys

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from atr_node.errors import LogFormatError
from atr_node.io.atrlog import AtrLogReader, AtrLogWriter

MISSION_KEY = b"\xa7mission"  # the tile map's key "mission" as msgpack writes it (fixstr of 7)


@pytest.fixture(scope="module")
def original(small_mission):
    """(bytes of the small mission's .atrlog, its records, the offsets of its sonar records)."""
    _, _, files = small_mission
    data = files.atrlog.read_bytes()
    recs = list(AtrLogReader(files.atrlog))
    return data, recs, [r.offset for r in recs if r.link == "sonar"]


def _key_of(rec):
    return rec.t, rec.link, rec.offset


def _replay(path, tmp_path):
    """Run ``atr-node replay`` on ``path``: (return code, stderr, summary dict or None)."""
    summary = tmp_path / f"{path.stem}.json"
    r = subprocess.run([sys.executable, "-m", "atr_node", "replay", str(path), "--online-calibration", "off",
                        "--publish", "none", "--workers", "0", "--quiet", "--summary", str(summary)],
                       capture_output=True, text=True, timeout=600)
    return r.returncode, r.stderr, json.loads(summary.read_text()) if summary.exists() else None


def _damage_tile(data: bytes, tile_offset: int, how: str) -> bytes:
    """The recording with the tile record at ``tile_offset`` damaged, its frame kept whole
    (same length): the mission string made bad UTF-8, or the key "mission" made an array."""
    i = data.index(MISSION_KEY, tile_offset)
    if how == "undecodable str":
        n = data[i + len(MISSION_KEY)] - 0xA0  # the value is a fixstr of n bytes
        j = i + len(MISSION_KEY) + 1
        return data[:j] + b"\xff" * n + data[j + n:]
    # an array of 7 ints is 8 bytes, as the fixstr key was: an unhashable map key
    return data[:i] + b"\x97" + b"\x01" * 7 + data[i + len(MISSION_KEY):]


@pytest.mark.parametrize("how", ["undecodable str", "unhashable key"])
def test_replay_of_one_undecodable_tile_loses_only_that_tile(original, tmp_path, how):
    data, recs, tiles = original
    n_tiles = len(tiles)
    assert n_tiles == 36
    path = tmp_path / "damaged.atrlog"
    path.write_bytes(_damage_tile(data, tiles[10], how))
    assert path.stat().st_size == len(data)
    code, err, s = _replay(path, tmp_path)
    assert code == 0, err
    assert "Traceback" not in err
    assert s["tiles_in"] == n_tiles - 1 and s["tiles_done"] == n_tiles - 1
    assert s["records"] == len(recs) - 1
    assert s["recording"]["reasons"] == {how: 1} and s["recording"]["rejected"] == 1
    assert s["rejections"][f"recording: {how}"] == 1
    end = err.strip().splitlines()[-1]
    assert end.startswith(f"atr-node replay: {n_tiles - 1} tiles in") and end.endswith(
        f"1 record rejected: {how} x 1"), end
    assert "rest of the file is ignored" not in err


def test_reader_skips_exactly_the_undecodable_records(original, tmp_path):
    """Three tiles damaged (two kinds): every other record is read, at its own offset."""
    data, recs, tiles = original
    damaged = data
    for off, how in ((tiles[3], "undecodable str"), (tiles[20], "unhashable key"), (tiles[35], "undecodable str")):
        damaged = _damage_tile(damaged, off, how)
    path = tmp_path / "three.atrlog"
    path.write_bytes(damaged)
    reader = AtrLogReader(path)
    got = [_key_of(r) for r in reader]
    assert got == [_key_of(r) for r in recs if r.offset not in (tiles[3], tiles[20], tiles[35])]
    assert reader.reasons == {"undecodable str": 2, "unhashable key": 1} and reader.skipped_bytes == 0
    assert reader.summary_text() == "3 records rejected: undecodable str x 2, unhashable key x 1"
    with pytest.raises(LogFormatError, match=f"at byte {tiles[3]}: record at byte {tiles[3]} rejected: undecodable"):
        list(AtrLogReader(path, strict=True))


def test_one_bad_byte_mid_file_costs_only_its_record(original, tmp_path):
    """The header byte of a record in the middle overwritten with 0xc1 (never used in msgpack)."""
    data, recs, _ = original
    victim = recs[len(recs) // 2]
    path = tmp_path / "byte.atrlog"
    path.write_bytes(data[:victim.offset] + b"\xc1" + data[victim.offset + 1:])
    reader = AtrLogReader(path)
    got = [_key_of(r) for r in reader]
    assert got == [_key_of(r) for r in recs if r is not victim]
    assert reader.reasons == {"garbage skipped": 1}
    nxt = recs[recs.index(victim) + 1]
    assert reader.skipped_bytes == nxt.offset - victim.offset
    assert any(f"bytes {victim.offset}-{nxt.offset} rejected" in e for e in reader.errors)


def test_a_block_of_garbage_between_records_loses_nothing(original, tmp_path):
    """412 bytes of zeros and 412 of 0xff inserted between two records: every record is read."""
    data, recs, tiles = original
    at = tiles[12]  # the start of a tile record
    for junk in (b"\x00" * 412, b"\xff" * 412, bytes(range(256)) + bytes(156)):
        path = tmp_path / "block.atrlog"
        path.write_bytes(data[:at] + junk + data[at:])
        reader = AtrLogReader(path)
        got = [(r.t, r.link) for r in reader]
        assert got == [(r.t, r.link) for r in recs]
        assert reader.reasons == {"garbage skipped": 1} and reader.skipped_bytes == 412
        assert reader.summary_text() == "1 record rejected: garbage skipped x 1 (412 bytes)"


def test_a_record_partly_overwritten_costs_only_itself(original, tmp_path):
    """4 kB of zeros written over the end of a tile record and the records after it (a power cut
    while a block was rewritten): every record outside those 4 kB is read, at its own offset."""
    data, recs, tiles = original
    hit = tiles[20] - 2000  # from inside the record before tile 20 to well inside tile 20
    path = tmp_path / "overwritten.atrlog"
    path.write_bytes(data[:hit] + bytes(4096) + data[hit + 4096:])
    ends = [r.offset for r in recs[1:]] + [len(data)]
    damaged = {r.offset for r, end in zip(recs, ends) if r.offset < hit + 4096 and end > hit}
    assert len(damaged) >= 2
    reader = AtrLogReader(path)
    got = {_key_of(r) for r in reader}
    assert {_key_of(r) for r in recs if r.offset not in damaged} <= got  # nothing outside is lost
    assert {k[2] for k in got} - {r.offset for r in recs} == set()  # and nothing is invented
    assert reader.reasons["garbage skipped"] >= 1 and not reader.truncated


def test_truncated_last_record_stays_a_warning(original, tmp_path):
    data, recs, tiles = original
    path = tmp_path / "cut.atrlog"
    path.write_bytes(data[:tiles[-1] + 1000])  # power cut inside the last tile
    reader = AtrLogReader(path)
    got = list(reader)
    assert [_key_of(r) for r in got] == [_key_of(r) for r in recs if r.offset < tiles[-1]]
    assert reader.truncated and reader.rejected == 0


def test_a_text_file_is_one_line_and_exit_1(tmp_path):
    path = tmp_path / "notes.atrlog"
    path.write_text("Mission notes: leg 3 repeated, INS reset at 10:42.\n" * 2000)
    code, err, s = _replay(path, tmp_path)
    assert code == 1 and s is None
    assert err.strip().splitlines() == [
        f"atr-node replay: error: {path}: no valid record in {path.stat().st_size} bytes (not an .atrlog recording?)"]


def test_an_empty_file_is_one_line_and_exit_1(tmp_path):
    path = tmp_path / "empty.atrlog"
    path.write_bytes(b"")
    code, err, _ = _replay(path, tmp_path)
    assert code == 1 and err.strip().splitlines() == [f"atr-node replay: error: {path}: empty file"]
    # the live node's own recording, just created, is not an error when it resumes from it
    assert list(AtrLogReader(path, allow_empty=True)) == []


def test_a_missing_file_is_one_line_and_exit_1(tmp_path):
    code, err, _ = _replay(tmp_path / "nowhere.atrlog", tmp_path)
    assert code == 1 and len(err.strip().splitlines()) == 1 and "cannot open" in err


NAV = [b"$GPHDT,%d.0,T*00" % i for i in range(360)]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(1, 12), junk=st.dictionaries(st.integers(0, 12), st.binary(min_size=1, max_size=64), max_size=4),
       can_every=st.integers(2, 5))
def test_garbage_between_records_loses_no_record_outside_it(tmp_path_factory, n, junk, can_every):
    """Random bytes inserted at record boundaries (before the first, between any two): every
    record is read, exactly, and exactly the inserted bytes are skipped, one block each."""
    path = tmp_path_factory.mktemp("junk") / "j.atrlog"
    recs = [(1.7e9 + 0.1 * i, "can", {"id": 0x100 + i, "data": bytes([i] * 8), "ext": False}) if i % can_every == 0
            else (1.7e9 + 0.1 * i, "nmea", NAV[i]) for i in range(n)]
    packer = msgpack.Packer(use_bin_type=True)
    with open(path, "wb") as fh:
        for i, (t, link, msg) in enumerate(recs):
            fh.write(junk.get(i, b""))
            fh.write(packer.pack({"t": t, "link": link, "msg": msg}))
    reader = AtrLogReader(path)
    got = [(r.t, r.link, r.msg) for r in reader]
    assert got == recs
    blocks = [b for i, b in junk.items() if i < n]
    assert reader.skipped_bytes == sum(map(len, blocks))
    assert dict(reader.reasons) == ({"garbage skipped": len(blocks)} if blocks else {})
    assert len(reader.errors) == len(blocks) and not reader.truncated


def test_a_record_far_in_time_after_garbage_needs_a_second_one(tmp_path):
    """After garbage, a record found 10 days off the last good one is believed only when the
    record after it is valid too (a tile's pixels can look like a record, rarely)."""
    path = tmp_path / "gap.atrlog"
    with AtrLogWriter(path) as w:
        w.write(1.7e9, "nmea", b"$A*00")
    late = msgpack.packb({"t": 1.7e9 + 864000.0, "link": "nmea", "msg": b"$B*00"}, use_bin_type=True)
    with open(path, "ab") as fh:
        fh.write(b"\xc1" * 5 + late + b"\xc1" * 7 + late + late)
    reader = AtrLogReader(path)
    got = [r.t for r in reader]
    # the first late record is followed by garbage: skipped with it; the next two are believed
    assert got == [1.7e9, 1.7e9 + 864000.0, 1.7e9 + 864000.0]
    assert reader.skipped_bytes == 5 + len(late) + 7


def test_a_look_alike_head_swallowing_the_next_record_does_not_hide_it(tmp_path):
    """Garbage b"\\x00\\xde\\x00" before a record: at byte 1 a map16 header (0xde 0x00 0x83, the
    record's own fixmap byte read as its size) is followed by the record's key "t", so it looks
    like a record head, and its frame runs past the end. The record starting inside it, at byte 3,
    must still be found (found by the Hypothesis property above)."""
    path = tmp_path / "head.atrlog"
    rec = msgpack.packb({"t": 1.7e9, "link": "nmea", "msg": b"$GPHDT,1.0,T*00"}, use_bin_type=True)
    path.write_bytes(b"\x00\xde\x00" + rec)
    reader = AtrLogReader(path)
    assert [(r.t, r.link, r.msg, r.offset) for r in reader] == [(1.7e9, "nmea", b"$GPHDT,1.0,T*00", 3)]
    assert reader.skipped_bytes == 3 and dict(reader.reasons) == {"garbage skipped": 1}


# -- a record too long to load (issue 21 item 4) ---------------------------------------------
def _write_with_huge_nmea(path, original_data: bytes, at: int, payload_bytes: int) -> None:
    """The recording with one ``nmea`` record of ``payload_bytes`` bytes of "A" inserted at
    byte ``at`` (a record boundary), written in chunks: the test never holds the record."""
    head = (b"\x83\xa1t" + msgpack.packb(1.0e9, use_single_float=False) + b"\xa4link\xa4nmea\xa3msg\xc6"
            + payload_bytes.to_bytes(4, "big"))
    chunk = b"A" * (1 << 20)
    with open(path, "wb") as fh:
        fh.write(original_data[:at])
        fh.write(head)
        left = payload_bytes
        while left:
            n = min(left, len(chunk))
            fh.write(chunk[:n])
            left -= n
        fh.write(original_data[at:])


def test_a_record_too_long_is_skipped_by_its_length_without_being_loaded(original, tmp_path):
    """A 300 MB NMEA record past the reader's limit (16 MiB here; 128 MiB by default): rejected
    as ``record too long``, skipped exactly by the length in its header, every other record
    kept; the reading process (a fresh one) peaks at about twice the limit (msgpack's buffer),
    far below the record's size. Before: msgpack loaded the whole record (a 1 GB line peaked
    at 3.5 GB)."""
    data, recs, offsets = original
    path = tmp_path / "huge_nmea.atrlog"
    payload = 300 << 20
    _write_with_huge_nmea(path, data, offsets[3], payload)
    # VmHWM: this process's own peak (ru_maxrss would carry the forking pytest's over exec)
    code = ("import json, sys\n"
            "from atr_node.io.atrlog import AtrLogReader\n"
            "r = AtrLogReader(sys.argv[1], max_record_bytes=16 << 20)\n"
            "keys = [(x.t, x.link) for x in r]\n"
            "hwm = [int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM:')][0]\n"
            "print(json.dumps({'keys': keys, 'reasons': dict(r.reasons), 'errors': r.errors,"
            " 'peak_mib': hwm / 1024}))\n")
    p = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    got = json.loads(p.stdout)
    assert got["reasons"] == {"record too long": 1}, got["reasons"]
    assert [tuple(k) for k in got["keys"]] == [(r.t, r.link) for r in recs]
    assert "record too long" in got["errors"][0] and f"byte {offsets[3]}" in got["errors"][0]
    assert got["peak_mib"] < 150, got["peak_mib"]  # 300 MB loaded whole would be > 300


def test_the_reader_limit_is_a_setting_and_the_walk_finds_exact_frame_ends(tmp_path):
    """``max_record_bytes``: a record just over it is rejected, just under it read; the header
    walk gives msgpack's own frame end for every type of object (checked against the packer)."""
    from atr_node.io.atrlog import _walk_frame_end

    objs = [{"t": 1.5, "link": "sonar", "msg": {"a": [1, -1, 2 ** 40, -2 ** 40, 1.5, None, True, "x" * 40,
                                                     b"y" * 300, "z" * 70000, list(range(20)),
                                                     {str(i): i for i in range(20)}, msgpack.ExtType(5, b"e" * 3),
                                                     msgpack.ExtType(6, b"f" * 300), 2 ** 64 - 1, -2 ** 63]}},
            {"t": 2.0, "link": "nmea", "msg": b"$GPGGA"}]
    path = tmp_path / "walk.bin"
    blobs = [msgpack.packb(o, use_bin_type=True) for o in objs]
    path.write_bytes(b"".join(blobs))
    with open(path, "rb") as fh:
        assert _walk_frame_end(fh, 0, path.stat().st_size) == len(blobs[0])
        assert _walk_frame_end(fh, len(blobs[0]), path.stat().st_size) == path.stat().st_size
        assert _walk_frame_end(fh, 0, len(blobs[0]) - 1) is None  # not whole
    log = tmp_path / "limit.atrlog"
    with AtrLogWriter(log) as w:
        w.write(1.0, "nmea", b"$" + b"A" * 5000)
        w.write(2.0, "nmea", b"$GPHDT,1.0,T*00")
    short = AtrLogReader(log, max_record_bytes=4096)
    assert [r.t for r in short] == [2.0] and short.reasons == {"record too long": 1}
    assert [r.t for r in AtrLogReader(log, max_record_bytes=8192)] == [1.0, 2.0]
