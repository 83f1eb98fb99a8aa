"""Smoke runs of the long tools: SIGKILL at random points then restart (``tools/soak/kill_restart.py``)
and the soak (``tools/soak/soak.py``). The long runs and their figures are in docs/reliability.md."""

from __future__ import annotations

import json

from ..waiting import WAIT_S, wait_until
from .conftest import load_tool


def test_kill_restart_quick_loses_nothing_and_leaves_loadable_snapshots(small_mission, tmp_path, capsys):
    kr = load_tool("kill_restart")
    _, cfg, files = small_mission
    st, ref_wall = kr.run_rounds(files.atrlog, cfg, tmp_path, kills=3, seed=4, workers=0)
    assert st.kills == 3 and ref_wall > 0
    assert st.failures == [] and st.snapshots_corrupted == 0
    assert st.rounds >= 1 and st.rounds_equal == st.rounds  # every round ends with the reference contacts
    assert st.restarts == st.kills  # every kill was followed by a restart that resumed


def test_verify_snapshot_reports_a_current_that_names_no_snapshot(small_mission, tmp_path):
    kr = load_tool("kill_restart")
    _, cfg, _ = small_mission
    assert kr.verify_snapshot(tmp_path, cfg) is None  # no snapshot yet: fine
    (tmp_path / "CURRENT").write_text("snap-7\n")
    assert "not a complete snapshot" in kr.verify_snapshot(tmp_path, cfg)
    (tmp_path / "CURRENT").write_text("snap-../../etc\n")
    assert "not a complete snapshot" in kr.verify_snapshot(tmp_path, cfg)


def test_soak_quick_samples_memory_and_queue_and_finds_them_bounded(tmp_path, capsys):
    soak = load_tool("soak")
    out = tmp_path / "soak.json"
    rc = soak.main(["--quick", "--workers", "0", "--json", str(out)])
    text = capsys.readouterr().out
    assert "RSS node + worker (MB)" in text and "queue depth" in text
    body = json.loads(out.read_text())
    v = body["verdict"]
    assert v["samples"] >= 2 and v["tiles"] == body["summary"]["tiles_in"] > 0
    assert v["queue_bounded"] and 0 < v["rss_total_mb"][0] <= v["rss_total_mb"][1]
    assert rc == 0


def test_resume_from_a_snapshot_at_any_cut_gives_the_uninterrupted_contacts(small_mission, tmp_path):
    """In-process: snapshot after k records, restore into a fresh pipeline, feed the rest. Before
    the fixes, a restored tracker summed its cells in another order (last-bit differences, so
    spurious updates) and finish() after a resume stamped contacts with t = 0."""
    from atr_node.calibration.model import PerformanceModel
    from atr_node.io.atrlog import read_atrlog
    from atr_node.node import state as node_state
    from atr_node.node.pipeline import Pipeline

    settings, _, files = small_mission
    records = list(read_atrlog(files.atrlog))

    def fresh() -> Pipeline:
        return Pipeline(settings, model=PerformanceModel.shipped(), workers=0)

    ref = fresh()
    for r in records:
        ref.feed(r)
    ref.finish()
    want = ref.contacts
    ref.close()
    assert want
    for k in (len(records) // 3, 2 * len(records) // 3, len(records)):
        a = fresh()
        for r in records[:k]:
            a.feed(r)
        node_state.save(tmp_path / f"s{k}", a, position=k)
        a.close()
        b = fresh()
        try:
            assert node_state.load(tmp_path / f"s{k}", b)["position"] == k
            for r in records[k:]:
                b.feed(r)
            b.finish()
            assert b.contacts == want, f"cut after record {k}"
        finally:
            b.close()


def test_the_detection_worker_exits_when_the_node_is_killed(small_mission, tmp_path):
    import os
    import signal
    import subprocess

    _, cfg, files = small_mission
    kr = load_tool("kill_restart")
    proc = subprocess.Popen(kr.replay_cmd(files.atrlog, cfg, tmp_path / "o.jsonl", tmp_path / "st", workers=1,
                                          online="off") + ["--speed", "1"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    found: list[int] = []

    def worker_started() -> bool:
        kids = load_tool("soak").children(proc.pid)
        found.extend(k for k in kids if "spawn_main" in open(f"/proc/{k}/cmdline").read())
        return bool(found) or proc.poll() is not None

    def worker_alive() -> bool:
        try:
            return "Z" not in open(f"/proc/{worker}/stat").read().split(")")[-1].split()[0]
        except FileNotFoundError:
            return False

    try:
        wait_until(worker_started, poll_s=0.1)
        assert found, "the replay started no worker process"
        worker = found[0]
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=WAIT_S)
    wait_until(lambda: not worker_alive(), poll_s=0.1)  # its end, however long the machine takes
    alive = worker_alive()
    if alive:
        os.kill(worker, signal.SIGKILL)  # do not leave it behind
    assert not alive, "the worker outlived the node"


def test_live_node_sigkilled_resumes_from_its_own_recording_and_loses_nothing(small_mission, tmp_path):
    """``atr-node run`` on a live ZeroMQ tile link: SIGKILL after 20 tiles, restart (it replays
    its previous recording past the snapshot), 16 more tiles, SIGTERM. The final snapshot holds
    the contacts of all 36 tiles fed straight through a pipeline."""
    import signal
    import subprocess
    import sys
    import time

    import msgpack
    import zmq

    from atr_node.calibration.model import PerformanceModel
    from atr_node.config import load_settings
    from atr_node.io.atrlog import LogRecord, read_atrlog
    from atr_node.node import state as node_state
    from atr_node.node.pipeline import Pipeline

    _, _, files = small_mission
    tiles = [r.msg for r in read_atrlog(files.atrlog) if r.link == "sonar"]
    data = tmp_path / "data"
    ctx = zmq.Context.instance()
    push = ctx.socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 0)
    port = push.bind_to_random_port("tcp://127.0.0.1")
    cfg = tmp_path / "live.toml"
    cfg.write_text(f'[links]\nsonar_endpoint = "tcp://127.0.0.1:{port}"\npublish_endpoint = "tcp://127.0.0.1:*"\n'
                   f'[node]\ndata_dir = "{data}"\nsnapshot_every_tiles = 4\nqueue_tiles = 10000\n'
                   f'[calibration]\nonline = false\n')
    cmd = [sys.executable, "-m", "atr_node", "run", "--config", str(cfg)]

    def recorded() -> int:
        return sum(r.link == "sonar" for f in (data / "recordings").glob("*.atrlog") for r in read_atrlog(f, allow_empty=True)) \
            if (data / "recordings").is_dir() else 0

    def feed(batch: list[dict], want: int, proc) -> None:
        sent = [0]

        def send_next() -> None:
            if sent[0] < len(batch):
                try:
                    push.send(msgpack.packb(batch[sent[0]], use_bin_type=True), zmq.NOBLOCK)
                    sent[0] += 1
                except zmq.Again:
                    pass
            time.sleep(0.02)

        wait_until(lambda: recorded() >= want or proc.poll() is not None, step=send_next)
        assert recorded() >= want, f"only {recorded()} of {want} tiles recorded; " + (
            proc.stderr.read()[-3000:] if proc.poll() is not None else "")

    procs = []
    try:
        p1 = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        procs.append(p1)
        feed(tiles[:20], 20, p1)
        p1.send_signal(signal.SIGKILL)
        p1.wait(timeout=WAIT_S)
        assert node_state.read_current(data / "state") is not None
        p2 = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        procs.append(p2)
        feed(tiles[20:], 36, p2)
        p2.send_signal(signal.SIGTERM)
        _, err = p2.communicate(timeout=WAIT_S)
        assert p2.returncode == 0, err[-2000:]
        assert "resumed from snapshot" in err
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
        push.close()
    settings = load_settings(cfg)
    got = Pipeline(settings, model=PerformanceModel.shipped(), workers=0, mode="live")
    ref = Pipeline(settings, model=PerformanceModel.shipped(), workers=0, mode="live")
    try:
        assert node_state.load(data / "state", got) is not None
        for i, m in enumerate(tiles):
            ref.feed(LogRecord(t=1.0 + i, link="sonar", msg=m))
        ref.drain()
        assert got.stats.tiles_in == 36 and got.stats.tiles_rejected == 0
        assert ref.contacts and got.contacts == ref.contacts
    finally:
        got.close()
        ref.close()
