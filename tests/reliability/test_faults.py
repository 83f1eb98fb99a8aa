"""Fault injection (issue 10): a ZeroMQ tile sender restarted, the INS silent for a minute, a
nav jump inside a tile, disk full while snapshotting and recording. Real sockets, real files
and a real (small) tmpfs. The serial link that drops and comes back is in
``tests/hw/test_links.py::test_socket_url_reconnects_after_the_server_drops``; SIGKILL at
random points is in ``test_kill_soak.py`` (and ``tools/soak/kill_restart.py`` for many)."""

from __future__ import annotations

import contextlib
import os
import subprocess
import time
import uuid
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zmq

from atr_node.calibration.model import PerformanceModel
from atr_node.io.atrlog import AtrLogReader, AtrLogWriter, LogRecord, read_atrlog
from atr_node.node import state as node_state
from atr_node.node.pipeline import Pipeline
from atr_node.node.service import NodeService
from atr_node.records.nav import NavFix
from atr_node.records.tile import Tile
from hw.can_nav import LegChange
from hw.decode import NavDecoder
from hw.recorder import RecordingLink
from hw.replay import IterLink
from hw.zmq_sonar import ZmqTileLink


def _pipeline(settings, fused: list | None = None) -> Pipeline:
    p = Pipeline(settings, model=PerformanceModel.shipped(), workers=0, mode="replay")
    if fused is not None:
        p.on_fused = lambda unit, model, res: fused.append(unit)
    return p


def _run(settings, records, fused=None) -> Pipeline:
    p = _pipeline(settings, fused)
    for rec in records:
        p.feed(rec)
    p.finish()
    return p


# -- ZeroMQ peer restarted ------------------------------------------------------------------

def test_tile_sender_restarted_on_the_same_endpoint_delivers_again(small_mission):
    settings, _, files = small_mission
    maps = [r.msg for r in read_atrlog(files.atrlog) if r.link == "sonar"][:10]
    ctx = zmq.Context.instance()

    def sender(port: int | None):
        s = ctx.socket(zmq.PUSH)
        s.setsockopt(zmq.LINGER, 0)
        if port is None:
            return s, s.bind_to_random_port("tcp://127.0.0.1")
        s.bind(f"tcp://127.0.0.1:{port}")
        return s, port

    s1, port = sender(None)
    link = ZmqTileLink(f"tcp://127.0.0.1:{port}", socket="pull")
    got = []
    try:
        for m in maps[:5]:
            s1.send(msgpack.packb(m, use_bin_type=True))
        while len(got) < 5:
            rec = link.recv(timeout=5.0)
            assert rec is not None, f"only {len(got)} tiles before the restart"
            got.append(rec)
        s1.close()  # the sonar processor dies ...
        time.sleep(0.3)
        s2, _ = sender(port)  # ... and comes back on the same endpoint
        try:
            for m in maps[5:]:
                s2.send(msgpack.packb(m, use_bin_type=True))
            while len(got) < 10:
                rec = link.recv(timeout=10.0)
                assert rec is not None, f"only {len(got) - 5} tiles after the restart"
                got.append(rec)
        finally:
            s2.close()
    finally:
        link.shutdown()
    pipe = _run(settings, got)
    try:
        assert [Tile.from_map(r.msg).seq for r in got] == [Tile.from_map(m).seq for m in maps]
        assert pipe.stats.tiles_in == 10 and pipe.stats.tiles_rejected == 0
    finally:
        pipe.close()


# -- INS silent for a minute ----------------------------------------------------------------

def _ins_times(records) -> np.ndarray:
    """Times of every position fix the INS records give (decoded as the node decodes them)."""
    d = NavDecoder()
    return np.array(sorted(ev.t for r in records if r.link != "sonar" for ev in d.feed(r)
                           if isinstance(ev, NavFix) and ev.lat_deg is not None))


def _silenced(files, t_from: float, t_to: float) -> list[LogRecord]:
    """The mission with tile nav removed (the node must use the INS) and the INS silent in
    [t_from, t_to) by arrival time; leg-change frames kept."""
    d = NavDecoder()
    out = []
    for r in read_atrlog(files.atrlog):
        if r.link == "sonar":
            m = dict(r.msg)
            m.pop("nav")
            out.append(LogRecord(r.t, r.link, m))
        elif t_from <= r.t < t_to and not any(isinstance(ev, LegChange) for ev in d.feed(r)):
            continue
        else:
            out.append(r)
    return out


def test_ins_silent_for_a_minute_never_georeferences_with_stale_nav(small_mission):
    settings, _, files = small_mission
    t0 = next(iter(read_atrlog(files.atrlog))).t
    records = _silenced(files, t0 + 60.0, t0 + 120.0)
    fixes = _ins_times(records)
    assert not np.any((fixes >= t0 + 60.0) & (fixes < t0 + 120.0))
    fused: list = []
    gap = settings.node.nav_max_gap_s
    held_seen = 0
    p = _pipeline(settings, fused)
    try:
        for rec in records:
            p.feed(rec)
            held_seen = max(held_seen, p.merger.held)
        p.finish()
        st = vars(p.merger.stats)
    finally:
        p.close()
    assert held_seen >= 1  # tiles waited for nav instead of being placed at once
    assert st["tiles_interpolated"] == files.tiles and st["pings_without_nav"] > 0
    # every ping that gave evidence lies between two INS fixes at most nav_max_gap_s apart (or
    # within nav_max_gap_s of the first or last fix: NavTrack extrapolates no further)
    evidence_t = np.concatenate([u.ping_time[u.core][np.isfinite(u.pixels[u.core]).any(axis=1)] for u in fused])
    k = np.searchsorted(fixes, evidence_t)
    before, after = fixes[np.maximum(k - 1, 0)], fixes[np.minimum(k, fixes.size - 1)]
    inside = (k > 0) & (k < fixes.size)
    assert np.all(after[inside] - before[inside] <= gap)
    assert np.all(np.minimum(np.abs(evidence_t - before), np.abs(after - evidence_t))[~inside] <= gap)
    in_silence = (evidence_t > t0 + 60.0 + gap) & (evidence_t < t0 + 120.0 - gap)
    assert not in_silence.any()
    # the tiles of the minute of silence were counted (dropped for want of nav), not placed
    silent = [np.frombuffer(r.msg["ping_time"], "<f8") for r in records if r.link == "sonar"]
    silent = sum(1 for t in silent if t[0] > t0 + 60.0 + gap and t[-1] < t0 + 120.0 - gap)
    assert silent >= 4 and st["tiles_without_nav"] >= silent


# -- nav jump inside a tile -----------------------------------------------------------------

def test_a_nav_jump_inside_a_tile_blanks_the_pings_on_both_sides(small_mission):
    settings, _, files = small_mission
    records = list(read_atrlog(files.atrlog))
    i = next(k for k, r in enumerate(records) if r.link == "sonar" and r.msg["seq"] == 3 and r.msg["side"] == "port")
    m = dict(records[i].msg)
    nav = dict(m["nav"])
    lat = np.frombuffer(nav["lat_deg"], "<f8").copy()
    lat[64:] += 0.01  # 1.1 km in one ping
    nav["lat_deg"] = lat.tobytes()
    m["nav"] = nav
    jump_t = np.frombuffer(m["ping_time"], "<f8")[63:65]
    records[i] = LogRecord(records[i].t, "sonar", m)
    fused: list = []
    p = _run(settings, records, fused)
    try:
        assert p.merger.stats.nav_jump_pings == 2
    finally:
        p.close()
    port = [u for u in fused if u.side == "port"]
    for u in port:
        rows = np.isin(u.ping_time, jump_t)
        assert not np.isfinite(u.pixels[rows]).any()
    assert sum(np.isin(u.ping_time[u.core], jump_t).sum() for u in port) == 2  # both rows reached a unit


# -- disk full --------------------------------------------------------------------------------

@contextlib.contextmanager
def tmpfs(path: Path, size: str):
    path.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here ({r.stderr.strip()}); tools/soak/kill_restart.py needs none")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


def _fill(path: Path) -> Path:
    """Fill the file system of ``path`` to the last byte."""
    filler = path / f"filler-{uuid.uuid4().hex}"
    with open(filler, "wb", buffering=0) as fh:
        block = b"\0" * 65536
        while True:
            try:
                fh.write(block)
            except OSError:
                break
        for n in (4096, 512, 1):
            while True:
                try:
                    fh.write(b"\0" * n)
                except OSError:
                    break
    return filler


def test_disk_full_while_snapshotting_keeps_the_previous_snapshot_intact(small_mission, tmp_path):
    settings, _, files = small_mission
    records = list(read_atrlog(files.atrlog))
    with tmpfs(tmp_path / "disk", "8m") as disk:
        state = disk / "state"
        service = NodeService(settings, model=PerformanceModel.shipped(), workers=0, state_dir=state)
        try:
            half = len(records) // 2
            service.run(records[:half], finish=False)  # snapshots along the way
            assert service.snapshots >= 1
            good = node_state.read_current(state)
            before = sorted(p.name for p in state.iterdir())
            filler = _fill(disk)
            n_ok = service.snapshots
            service.run(records[half:], start=half, finish=False)  # every snapshot now fails
            assert service.snapshots == n_ok and service.snapshot_failures >= 1
            assert node_state.read_current(state) == good
            assert sorted(p.name for p in state.iterdir()) == before  # partial snapshots removed
            fresh = _pipeline(settings)
            try:
                meta = node_state.load(state, fresh)  # the previous snapshot loads
            finally:
                fresh.close()
            assert meta["position"] <= half
            filler.unlink()
            service.snapshot()  # space again: snapshots resume
            assert service.snapshots == n_ok + 1 and node_state.read_current(state) != good
        finally:
            service.close()


def test_disk_full_while_recording_keeps_the_recording_whole_and_the_records_flowing(small_mission, tmp_path):
    _, _, files = small_mission
    records = [r for r in read_atrlog(files.atrlog)][:3000]
    with tmpfs(tmp_path / "disk", "1m") as disk:
        filler = disk / "filler"
        filler.write_bytes(b"\0" * (700 << 10))
        link = RecordingLink(IterLink(iter(records), name="mission"), disk / "rec.atrlog")
        delivered = []
        while (rec := link.recv(timeout=1.0)) is not None:
            delivered.append(rec)
            if link.counts["record_failed"] == 50 and filler.exists():
                filler.unlink()  # an operator frees space: recording goes on
        link.shutdown()
        assert [r.offset for r in delivered] == [r.offset for r in records]  # nothing withheld
        failed = link.counts["record_failed"]
        assert failed >= 50
        reader = AtrLogReader(disk / "rec.atrlog")
        got = list(reader)
        assert not reader.truncated and reader.rejected == 0  # whole records only
        assert len(got) == len(records) - failed
        assert [(r.t, r.link) for r in got] == [(r.t, r.link) for r in records if r.t in {g.t for g in got}]
        assert got[-1].t == records[-1].t  # recording resumed after the space came back


def test_disk_full_writer_error_then_resume_leaves_no_partial_record(tmp_path):
    with tmpfs(tmp_path / "disk", "256k") as disk:
        w = AtrLogWriter(disk / "x.atrlog")
        payload = b"$GPHDT,1.0,T*00" + b"x" * 2000
        n = 0
        with pytest.raises(OSError):
            while True:
                w.write(float(n), "nmea", payload)
                n += 1
        reader = AtrLogReader(disk / "x.atrlog")
        assert len(list(reader)) == n and not reader.truncated  # every record written before, whole
        assert os.path.getsize(disk / "x.atrlog") == w.bytes
        w.close()
