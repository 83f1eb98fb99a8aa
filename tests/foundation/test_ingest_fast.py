"""Fast paths of the ingest foundation give what the general paths give.

* ``AtrLogReader``: its exact-type fast path against :func:`check_record` (the reference), on
  records at both sides of the fast/slow boundary.
* ``NavTrack``: the append path (``last`` mirror, element stores) against a sorted reference,
  through out-of-order and repeated times, ``forget_before`` and ``restore``.
"""

from __future__ import annotations

import dataclasses
import math
import random

import msgpack
import numpy as np
import pytest

from atr_node.io.atrlog import AtrLogReader, LogRecord, _record, check_record
from atr_node.records.nav import NavFix, NavTrack

_RECORDS = [
    [5.0, "nmea", b""],  # not a record at all: skipped as garbage up to the next valid record
    {"t": 1.5, "link": "nmea", "msg": b"$GPHDT,1.0,T*00"},
    {"t": 2, "link": "nmea", "msg": b"int t: slow path, valid, t becomes 2.0"},
    {"t": 3.0, "link": "can", "msg": {"id": 256, "data": b"\x00" * 8, "ext": False}},
    {"t": 3.5, "link": "can", "msg": {"id": 256, "data": b"", "ext": True, "extra": 1}, "x": "extra keys"},
    {"t": 4.0, "link": "sonar", "msg": {"any": "map"}},
    {"t": float("nan"), "link": "nmea", "msg": b"x"},
    {"t": float("inf"), "link": "nmea", "msg": b"x"},
    {"t": True, "link": "nmea", "msg": b"x"},
    {"t": 5.0, "link": b"nmea", "msg": b"x"},
    {"t": 5.0, "link": "nmea", "msg": "str"},
    {"t": 5.0, "link": "can", "msg": {"id": True, "data": b"", "ext": False}},
    {"t": 5.0, "link": "can", "msg": {"id": -1, "data": b"", "ext": False}},
    {"t": 5.0, "link": "can", "msg": {"id": 1, "data": "s", "ext": False}},
    {"t": 5.0, "link": "can", "msg": {"id": 1, "data": b"", "ext": 1}},
    {"t": 5.0, "link": "can", "msg": [1, b"", False]},
    {"t": 5.0, "link": "sonar", "msg": b"not a map"},
    {"t": 5.0, "link": "radio", "msg": b""},
    {"link": "nmea", "msg": b""},
    {"t": 6.25, "link": "nmea", "msg": b"last, valid"},
]


def test_reader_fast_path_equals_check_record(tmp_path):
    path = tmp_path / "mixed.atrlog"
    blobs = [msgpack.packb(r, use_bin_type=True) for r in _RECORDS]
    path.write_bytes(b"".join(blobs))
    want, offset = [], 0
    for obj, blob in zip(_RECORDS, blobs):
        if check_record(obj) is None:
            want.append(LogRecord(t=float(obj["t"]), link=obj["link"], msg=obj["msg"], offset=offset))
        offset += len(blob)
    reader = AtrLogReader(path)
    got = list(reader)
    assert got == want and [type(r.t) for r in got] == [float] * len(want)
    assert reader.records == len(want) == 6
    assert reader.rejected == len(_RECORDS) - len(want)
    # every rejection names its byte offset and check_record's reason
    reasons = [check_record(o) for o in _RECORDS if check_record(o) is not None]
    # (the array, not a record at all, is skipped as garbage: its message goes on with the bytes skipped)
    assert len(reader.errors) == len(reasons)
    assert all(e.split("rejected: ", 1)[1].startswith(r) for e, r in zip(reader.errors, reasons))


def test_fast_record_is_a_log_record_in_every_respect():
    ref = LogRecord(t=2.5, link="can", msg=b"m", offset=17)
    rec = _record(2.5, "can", b"m", 17)
    assert type(rec) is LogRecord and rec == ref and hash(rec) == hash(ref) and repr(rec) == repr(ref)
    with pytest.raises(dataclasses.FrozenInstanceError):
        rec.t = 0.0  # type: ignore[misc]


def _reference_series(fixes: list[tuple[float, float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """Sorted by time, the last value received winning on repeated times."""
    last: dict[float, tuple[float, float]] = {}
    for t, lat, lon in fixes:
        last[t] = (lat, lon)
    ts = sorted(last)
    return np.array(ts), np.array([last[t] for t in ts]).reshape(-1, 2)


def test_navtrack_append_path_equals_sorted_reference():
    rng = random.Random(2)
    fixes = []
    t = 100.0
    for _ in range(500):  # mostly in order, some late, some repeated times
        t += rng.choice([0.1, 0.2, 0.0, -0.35, 0.5])
        fixes.append((round(t, 2), rng.uniform(-60, 60), rng.uniform(-180, 180)))
    track = NavTrack()
    for i, (ft, lat, lon) in enumerate(fixes):
        track.add(NavFix(t=ft, lat_deg=lat, lon_deg=lon, heading_deg=float(i), altitude_m=None))
        if i == 250:  # a snapshot round trip in the middle: the mirror of the last time is rebuilt
            state = track.state()
            track = NavTrack()
            track.restore(state)
    ts, vs = _reference_series(fixes)
    s = track.state()
    assert np.array_equal(s["pos_t"], ts) and np.array_equal(s["pos_v"], vs)
    assert track.span == (ts[0], ts[-1])
    assert track._pos.last == s["pos_t"][-1] and track._hdg.last == s["hdg_t"][-1]
    assert np.array_equal(s["hdg_v"][:, 0], np.array([float(i) for i in range(500)])[
        [max(i for i, f in enumerate(fixes) if f[0] == tt) for tt in ts]] % 360.0)
    track.forget_before(ts[-10])
    assert track.span == (ts[-11], ts[-1])
    track.add(NavFix(t=ts[-1] + 1.0, lat_deg=1.0, lon_deg=2.0))
    assert track.span == (ts[-11], ts[-1] + 1.0) and tuple(track.state()["pos_v"][-1]) == (1.0, 2.0)


def test_navtrack_skips_non_finite_and_out_of_range_as_before():
    track = NavTrack()
    track.add(NavFix(t=math.nan, lat_deg=1.0, lon_deg=1.0))
    track.add(NavFix(t=1.0, lat_deg=91.0, lon_deg=1.0, heading_deg=math.inf, altitude_m=-1.0))
    track.add(NavFix(t=2.0, lat_deg=np.float64(math.nan), lon_deg=1.0, heading_deg=np.float64(370.0),
                     altitude_m=np.float64(5.0)))
    s = track.state()
    assert s["fixes"] == 2 and s["pos_t"].size == 0
    assert s["hdg_t"].tolist() == [2.0] and s["hdg_v"].tolist() == [[10.0]]
    assert s["alt_t"].tolist() == [2.0] and s["alt_v"].tolist() == [[5.0]]
    empty = NavTrack()
    empty.restore(NavTrack().state())
    assert empty.span is None and empty._pos.last == -math.inf
