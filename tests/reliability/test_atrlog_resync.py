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
