"""The node end to end (issue 7): HIL replay through real links, determinism, SIGKILL resume,
malformed input mixed into a replay."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from atr_node.calibration.model import PerformanceModel
from atr_node.config import Settings
from atr_node.io.atrlog import AtrLogWriter, read_atrlog
from atr_node.node import wire
from atr_node.node.pipeline import Pipeline
from atr_node.node.service import NodeService

from ..waiting import WAIT_S, wait_until


@pytest.fixture(scope="module")
def mission(small_mission):
    return small_mission


def replay_in_process(settings: Settings, log_path, *, workers: int) -> list[dict]:
    pipe = Pipeline(settings, model=PerformanceModel.shipped(), workers=workers, mode="replay")
    try:
        return pipe.replay(read_atrlog(log_path)).contacts
    finally:
        pipe.close()


def test_replay_is_deterministic_whatever_the_worker_timing(mission):
    settings, _, files = mission
    a = replay_in_process(settings, files.atrlog, workers=0)
    b = replay_in_process(settings, files.atrlog, workers=1)
    assert a, "the small mission should give contacts"
    assert a == b
    for c in a:
        assert wire.validate_contact(c) == []


SUBSCRIBER = r"""
import json, os, sys, time
sys.path.insert(0, sys.argv[3])
from atr_node.node.publisher import Subscriber
sub = Subscriber(sys.argv[1])
out = open(sys.argv[2], "w")
done, ready = sys.argv[4], sys.argv[5]
deadline = time.monotonic() + float(sys.argv[6])  # a guard against a hang (WAIT_S), not a timing assertion
contacts = 0
while time.monotonic() < deadline:
    got = sub.recv(timeout_s=0.5)
    if got is not None:
        topic, msg = got
        out.write(json.dumps({"topic": topic, "msg": msg}) + "\n")
        out.flush()
        contacts += topic == "contact"
        if ready:  # a heartbeat got through: the subscription is up (ZeroMQ's slow joiner)
            open(ready, "w").close()
            ready = ""
    # the test writes how many contacts the node published once it is idle: every one of
    # them received, done (an event, not a guess at how long a loaded machine takes)
    if os.path.exists(done) and contacts >= int(open(done).read()):
        break
else:
    sys.exit(1)  # the published contacts never all arrived
"""


def test_hil_replay_through_pty_can_zmq_into_the_node(mission, tmp_path):
    """The mission played out onto a pty (NMEA), python-can's virtual bus and ZeroMQ; the node
    opens its ordinary links on the other ends; a separate process subscribes."""
    from hw import open_link
    from hw.hil import CanBusOut, HilPlayer, PtyNmeaOut, ZmqTileOut
    from hw.recorder import LinkMux
    from hw.replay import Paced, ReplayLink

    settings, _, files = mission
    # a queue deep enough that the live node never degrades on a loaded test machine: the
    # comparison below is with the full-resolution replay
    settings = settings.replace(node=dataclasses.replace(settings.node, queue_tiles=10_000))
    n_tiles = sum(1 for r in read_atrlog(files.atrlog) if r.link == "sonar")
    nmea_out = PtyNmeaOut()
    can_out = CanBusOut("virtual", "atr-e2e-test")
    tile_out = ZmqTileOut("tcp://127.0.0.1:*", socket="push")
    links = [open_link(nmea_out.slave_path), open_link("can://virtual/atr-e2e-test"),
             open_link(tile_out.endpoint, socket="pull")]
    contacts: list[dict] = []
    service = NodeService(settings, model=PerformanceModel.shipped(), mode="live", workers=1,
                          publish="tcp://127.0.0.1:*", on_contact=contacts.append)
    endpoint = service.publisher.endpoint
    received = tmp_path / "received.jsonl"
    ready = tmp_path / "subscribed"
    done = tmp_path / "published"
    sub = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, endpoint, str(received),
                            str(Path(__file__).resolve().parents[2]), str(done), str(ready), str(WAIT_S)])
    mux = LinkMux(links)
    node = threading.Thread(target=service.run_live, args=(mux,), daemon=True)
    node.start()
    # the subscriber has a heartbeat before the first contact can be published: an event, not a
    # guess at how long a loaded machine takes to start a Python process and subscribe
    wait_until(lambda: ready.exists() or sub.poll() is not None)
    assert ready.exists(), "the subscriber never got a heartbeat"
    player = HilPlayer(Paced(ReplayLink(files.atrlog), speed=40.0), nmea=nmea_out, can=can_out, sonar=tile_out)
    counts = player.run()
    try:
        # every tile in and nothing waiting in the worker (a live node keeps the last leg's last
        # rows until the next leg): no contact comes after this until the node stops
        assert wait_until(lambda: service.pipeline.stats.tiles_in >= n_tiles and service.pipeline.queue_depth == 0,
                          poll_s=0.1), "the node did not process every tile"
        (tmp_path / "published.tmp").write_text(str(len(contacts)))
        os.replace(tmp_path / "published.tmp", done)
        assert sub.wait(timeout=WAIT_S) == 0
    finally:
        service.stop()
        node.join(timeout=WAIT_S)
        mux.shutdown()
        player.close()
        service.close()
    assert counts["sonar_sent"] == n_tiles and counts["nmea_sent"] > 0 and counts["can_sent"] > 0
    st = service.pipeline.stats
    assert st.tiles_in == n_tiles and st.tiles_rejected == 0 and st.units_degraded == 0
    nav = service.pipeline.decoder.stats()
    assert nav["nmea"].get("accepted", 0) > 0 and nav["can"].get("accepted", 0) > 0
    lines = [json.loads(x) for x in received.read_text().splitlines()]
    hbs = [x["msg"] for x in lines if x["topic"] == "heartbeat"]
    got = [x["msg"] for x in lines if x["topic"] == "contact"]
    assert hbs and all(wire.validate_heartbeat(h) == [] for h in hbs)
    assert got and all(wire.validate_contact(c) == [] for c in got)
    # the same mission replayed in-process gives the same contacts (the strips of the last leg
    # are flushed by finish() in a replay; live, they wait for the next leg, so compare the
    # contacts both have published, by id, after flushing the live node too)
    service.pipeline.emit = lambda msg: None  # the service is closed: its publisher's socket too
    service.pipeline.finish()
    live = service.pipeline.contacts
    ref = replay_in_process(settings, files.atrlog, workers=0)
    strip = lambda cs: [{k: v for k, v in c.items() if k != "t"} for c in cs]
    assert strip(live) == strip(ref)


def _replay_cmd(cfg, log, out, state):
    return [sys.executable, "-m", "atr_node", "replay", str(log), "--config", str(cfg), "--online-calibration", "off",
            "--publish", "none", "--contacts-out", str(out), "--state-dir", str(state), "--quiet"]


def test_sigkill_mid_replay_then_restart_gives_the_same_contacts(mission, tmp_path):
    settings, cfg, files = mission
    ref_out = tmp_path / "ref.jsonl"
    r = subprocess.run(_replay_cmd(cfg, files.atrlog, ref_out, tmp_path / "ref_state"), capture_output=True,
                       text=True, timeout=5 * WAIT_S)  # a whole replay: a hang guard
    assert r.returncode == 0, r.stderr
    state = tmp_path / "state"
    out = tmp_path / "out.jsonl"
    kills = 0
    for attempt in range(3):  # kill at a few points, each after at least one new snapshot
        proc = subprocess.Popen(_replay_cmd(cfg, files.atrlog, out, state), stderr=subprocess.PIPE, text=True)
        before = (state / "CURRENT").read_text() if (state / "CURRENT").exists() else None
        def current() -> str | None:
            return (state / "CURRENT").read_text() if (state / "CURRENT").exists() else None

        assert wait_until(lambda: proc.poll() is not None or current() not in (None, before), poll_s=0.02)
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=WAIT_S)
            kills += 1
        else:
            break
    assert kills >= 1, "the replay ended before it could be killed"
    r = subprocess.run(_replay_cmd(cfg, files.atrlog, out, state), capture_output=True, text=True,
                       timeout=5 * WAIT_S)  # a whole replay: a hang guard
    assert r.returncode == 0, r.stderr
    ref = [json.loads(x) for x in ref_out.read_text().splitlines()]
    got = [json.loads(x) for x in out.read_text().splitlines()]
    assert ref and got == ref


def test_malformed_input_mixed_into_a_replay_is_rejected_and_changes_nothing(mission, tmp_path):
    settings, _, files = mission
    dirty = tmp_path / "dirty.atrlog"
    bad_tiles = [
        {"type": "tile", "v": 2},
        "not a map",
        {"type": "tile", "v": 1, "mission": "x", "leg": 0, "side": "left", "seq": 1},
    ]
    n_bad_tiles = n_bad_nmea = n_bad_can = 0
    with AtrLogWriter(dirty) as w:
        for i, rec in enumerate(read_atrlog(files.atrlog)):
            if rec.link == "sonar" and i % 7 == 0:
                m = dict(rec.msg)
                m["data"] = m["data"][:-3]  # wrong length for the shape
                w.write(rec.t, "sonar", m)
                bt = bad_tiles[n_bad_tiles % len(bad_tiles)]
                if isinstance(bt, dict):
                    w.write(rec.t, "sonar", bt)
                n_bad_tiles += 1 + isinstance(bt, dict)
            if rec.link == "nmea" and i % 50 == 0:
                w.write(rec.t, "nmea", b"$GPGGA,garbage*00")
                w.write(rec.t, "nmea", b"\xff\xfe" * 60)
                n_bad_nmea += 2
            if rec.link == "can" and i % 50 == 0:
                w.write(rec.t, "can", {"id": 0x7FF, "data": b"\x00" * 8, "ext": False})
                n_bad_can += 1
            w.write_record(rec)
    pipe = Pipeline(settings, model=PerformanceModel.shipped(), workers=0, mode="replay")
    try:
        for rec in read_atrlog(dirty):
            pipe.feed(rec)
        pipe.finish()
        got = pipe.contacts
        assert pipe.stats.tiles_rejected == n_bad_tiles
        nav = pipe.decoder.stats()
        assert sum(v for k, v in nav["nmea"].items() if k != "accepted") >= n_bad_nmea
        assert sum(v for k, v in nav["can"].items() if k != "accepted") >= n_bad_can
    finally:
        pipe.close()
    assert got == replay_in_process(settings, files.atrlog, workers=0)
