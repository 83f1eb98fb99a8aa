"""Late joiners (ICD v1.1, issue 20): a follower, ``atr-node monitor``, ``export --from`` and
``exwpt`` started while a real node runs get every live contact, each message applied once.

The node (``conftest.start_node``) replays the small mission and stops feeding at
``pause_after`` records, after some contacts were published, until the test lets it go on:
the client joins mid-run at a known point instead of at a time that depends on the machine.
Everything goes over real loopback sockets: the node's PUB socket and its snapshot endpoint
on the next port, where the clients look for it.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import threading
import time

import pytest

from atr_node.io.atrlog import read_atrlog
from atr_node.node import wire
from atr_node.node.publisher import Subscriber
from atr_node.node.snapshot_endpoint import derived_snapshot_endpoint
from atr_node.operators.stream import NodeFollower

from .conftest import WAIT_S, StreamLines, follow_until, free_port_pair, stop_client, wait_until


@pytest.fixture(scope="module")
def pause_at(mission):
    """A record 60 % into the mission: 7 of its 11 contact messages are out by then."""
    _, _, files = mission
    return 6 * sum(1 for _ in read_atrlog(files.atrlog)) // 10


def _live(messages):
    """Reference: the live contacts after ``messages``, applied one by one, by id."""
    live = {}
    for m in messages:
        if m["state"] == "withdrawn":
            live.pop(m["id"], None)
        else:
            live[m["id"]] = m
    return live


def _paused(node):
    node.release()
    assert node.paused.wait(WAIT_S), "the node never reached the pause"
    before = list(node.emitted)
    assert _live(before), "contacts should be live before the client joins"
    return before


def test_follower_started_mid_run_gets_every_live_contact_once(live_node, pause_at):
    node = live_node(pause_after=pause_at)
    early = Subscriber(node.endpoint)  # on the wire from the start: what the node sent, in order
    wire_log: list[dict] = []

    def record() -> None:
        got = early.recv(0.1)
        if got is not None:
            wire_log.append(got[1])

    wait_until(lambda: bool(wire_log), step=record)  # up once a heartbeat arrives
    before = _paused(node)
    applied: list[dict] = []
    fol = NodeFollower(node.endpoint, snapshot=derived_snapshot_endpoint(node.endpoint), on_contact=applied.append,
                       snapshot_timeout_s=WAIT_S)
    try:
        follow_until(fol, lambda: fol.stats.snapshot != "waiting")
        assert fol.stats.snapshot == "ok"
        node.resume_feed.set()
        node.join()
        last = len(node.emitted)  # seq of the node's last message
        assert follow_until(fol, lambda: bool(applied) and applied[-1]["seq"] == last)
        wait_until(lambda: any(m.get("seq") == last for m in wire_log), step=record)
    finally:
        fol.close()
        early.close()
    emitted = node.emitted
    seq = fol.stats.snapshot_seq
    # the snapshot: every message published before the join, nothing after
    assert seq == len(before) == before[-1]["seq"] and fol.stats.snapshot_contacts == len(_live(before))
    assert len(emitted) > len(before), "messages should follow the join"
    # on the wire: every contact message once, seq strictly increasing from 1
    contacts_on_wire = [m for m in wire_log if m.get("type") == "contact"]
    assert [m["seq"] for m in contacts_on_wire] == list(range(1, len(emitted) + 1))
    assert all(wire.validate_contact(m, require_seq=True) == [] for m in contacts_on_wire)
    # applied once each: the snapshot's live contacts, then every later message exactly once
    seqs = [m["seq"] for m in applied]
    assert len(seqs) == len(set(seqs))
    assert sorted(seqs[:fol.stats.snapshot_contacts]) == sorted(m["seq"] for m in _live(before).values())
    assert seqs[fol.stats.snapshot_contacts:] == list(range(seq + 1, len(emitted) + 1))
    assert fol.stats.gaps == 0 and fol.stats.seq_resets == 0 and fol.stats.bad == 0
    # the book: the node's final live list, message for message
    final_live = node.service.pipeline.live_contacts()
    assert final_live and {c["id"]: c for c in fol.book.contacts()} == {c["id"]: c for c in final_live}
    assert final_live == sorted(_live(emitted).values(), key=lambda c: c["id"])


def test_monitor_started_mid_run_shows_every_live_contact(live_node, pause_at):
    node = live_node(pause_after=pause_at)
    before = _paused(node)
    proc = subprocess.Popen([sys.executable, "-m", "atr_node", "monitor", "--from", node.endpoint, "--plain",
                             "--refresh", "0.3", "--rows", "50", "--snapshot-timeout", str(WAIT_S)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "COLUMNS": "160"})  # the whole 'received' line
    stdout, stderr = StreamLines(proc.stdout), StreamLines(proc.stderr)
    try:
        stdout.wait_for(lambda t: "live contacts at seq" in t)  # the monitor has the snapshot
        node.resume_feed.set()
        node.join()
        n_after = len(node.emitted) - len(before)
        # a frame that counts every later message: the monitor has them all, and may stop
        stdout.wait_for(lambda t: f" {n_after} contact messages" in t)
        returncode = stop_client(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
    out, err = stdout.close(), stderr.close()
    assert returncode == 0, err
    n_before = len(_live(before))
    assert f"snapshot: {n_before} live contacts at seq {len(before)}" in err, err
    assert f"{len(node.emitted) - len(before)} contact messages" in err
    last = out.strip().split("\n\n")[-1].split("\n")
    rows = [r.split() for r in last[6:] if r[:5].strip().isdigit()]
    shown = {int(r[0]): float(r[1]) for r in rows if r[8] != "GONE"}
    final_live = {c["id"]: c for c in node.service.pipeline.live_contacts()}
    assert final_live and set(shown) == set(final_live)
    for cid, bel in shown.items():
        assert bel == pytest.approx(final_live[cid]["bel"], abs=6e-6)
    # some of them were last published before the monitor started: only the snapshot had them
    assert any(c["seq"] <= len(before) for c in final_live.values())


def test_export_from_started_mid_run_writes_every_live_contact(live_node, pause_at, tmp_path):
    node = live_node(pause_after=pause_at)
    before = _paused(node)
    out = tmp_path / "live.geojson"
    proc = subprocess.Popen([sys.executable, "-m", "atr_node", "export", "--from", node.endpoint,
                             "--until-silent", "0", "--refresh", "0.2", "-o", str(out),
                             "--snapshot-timeout", str(WAIT_S)], stderr=subprocess.PIPE,
                            text=True)
    stderr = StreamLines(proc.stderr)

    def written() -> dict:
        try:
            return {f["id"]: {k: v for k, v in f["properties"].items() if k != "time_utc"}
                    for f in json.loads(out.read_text())["features"]}
        except (OSError, ValueError):
            return {}

    try:
        stderr.wait_for(lambda t: "node up" in t)  # first heartbeat: the snapshot is asked right after it
        wait_until(lambda: node.service.snapshot_server.served > 0)
        node.resume_feed.set()
        node.join()
        want = {c["id"]: c for c in node.service.pipeline.live_contacts()}
        wait_until(lambda: written() == want, poll_s=0.1)  # until the refreshed file holds the final list
        returncode = stop_client(proc)  # and the file is written once more at the stop
    finally:
        if proc.poll() is None:
            proc.kill()
    err = stderr.close()
    assert returncode == 0, err
    assert f"snapshot: {len(_live(before))} live contacts at seq {len(before)}" in err
    got = written()
    assert got and got == want


def test_exwpt_started_mid_run_sends_the_live_contacts_first(live_node, pause_at):
    import tty

    from .test_exwpt import _pty_reader, parse_exwpt

    node = live_node(pause_after=pause_at)
    before = _paused(node)
    master, slave = os.openpty()
    tty.setraw(master)
    lines: list[bytes] = []
    stop = threading.Event()
    reader = threading.Thread(target=_pty_reader, args=(master, lines, stop), daemon=True)
    reader.start()
    proc = subprocess.Popen([sys.executable, "-m", "atr_node", "exwpt", "--from", node.endpoint, "--port",
                             os.ttyname(slave), "--min-move-m", "0", "--min-bel-change", "0",
                             "--snapshot-timeout", str(WAIT_S)],
                            stderr=subprocess.PIPE, text=True)
    stderr = StreamLines(proc.stderr)
    try:
        stderr.wait_for(lambda t: "node up" in t)
        wait_until(lambda: node.service.snapshot_server.served > 0)
        node.resume_feed.set()
        node.join()
        after = [m for m in node.emitted[len(before):] if m["state"] != "withdrawn"]
        want = sorted(_live(before).values(), key=lambda c: c["id"]) + after
        wait_until(lambda: len(lines) >= len(want))  # until every sentence is on the pty
        returncode = stop_client(proc)
    finally:
        stop.set()
        reader.join(2)
        os.close(master)
        os.close(slave)
        if proc.poll() is None:
            proc.kill()
    err = stderr.close()
    assert returncode == 0, err
    got = [parse_exwpt(x) for x in lines]
    # the snapshot's live contacts (by id), then one sentence per later new/update message
    assert [(d["id"], d["state"]) for d in got] == [(m["id"], m["state"]) for m in want]


def test_a_v1_node_without_the_endpoint_is_followed_after_one_warning(live_node, pause_at, caplog):
    node = live_node(pause_after=pause_at, snapshot=False)
    before = _paused(node)
    fol = NodeFollower(node.endpoint, snapshot=derived_snapshot_endpoint(node.endpoint), snapshot_timeout_s=0.5)
    try:
        with caplog.at_level(logging.WARNING, logger="atr_node.operators.stream"):
            follow_until(fol, lambda: fol.stats.snapshot != "waiting")
            # the subscription is up (a heartbeat got through) before the node goes on: what it
            # publishes next must all arrive, however slowly a loaded machine joins
            assert fol.wait_heartbeat(WAIT_S)
            node.resume_feed.set()
            node.join()
            assert follow_until(fol, lambda: fol.stats.contacts >= len(node.emitted) - len(before))
    finally:
        fol.close()
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "snapshot endpoint" in warnings[0].getMessage()
    assert fol.stats.snapshot.startswith("unavailable: no snapshot from")
    # as before v1.1: what was published after joining, and nothing refused
    assert fol.stats.contacts == len(node.emitted) - len(before) > 0 and fol.stats.bad == 0


def test_replay_command_serves_the_snapshot_on_the_port_after_publish(mission, tmp_path):
    _, cfg, files = mission
    port = free_port_pair()
    out = tmp_path / "c.jsonl"
    proc = subprocess.Popen([sys.executable, "-m", "atr_node", "replay", str(files.atrlog), "--config", str(cfg),
                             "--online-calibration", "off", "--workers", "0", "--quiet", "--speed", "50",
                             "--publish", f"tcp://127.0.0.1:{port}", "--contacts-out", str(out)],
                            stderr=subprocess.PIPE, text=True)
    fol = NodeFollower(f"tcp://127.0.0.1:{port}", snapshot=f"tcp://127.0.0.1:{port + 1}", snapshot_timeout_s=WAIT_S)
    stderr = StreamLines(proc.stderr)
    try:
        assert fol.wait_heartbeat(WAIT_S)
        follow_until(fol, lambda: proc.poll() is not None, timeout_s=WAIT_S)  # the replay runs to its end
        returncode = proc.wait(timeout=WAIT_S)
        final = [json.loads(x) for x in out.read_text().splitlines()] if returncode == 0 else []
        live = {c["id"]: c for c in final if c["state"] != "withdrawn"}
        if live:  # until the follower's book holds what the replay wrote (published before it exited)
            follow_until(fol, lambda: {c["id"]: c for c in fol.book.contacts()} == live)
    finally:
        fol.close()
        if proc.poll() is None:
            proc.kill()
    err = stderr.close()
    assert returncode == 0, err
    assert fol.stats.snapshot == "ok" and fol.stats.gaps == 0
    assert all(wire.validate_contact(c, require_seq=True) == [] for c in final)
    assert live and {c["id"]: c for c in fol.book.contacts()} == live


def test_joining_while_messages_stream_applies_each_exactly_once():
    """The clone pattern's race: messages published between the subscription and the snapshot
    are held, and the ones the snapshot already holds are dropped by their seq. The snapshot
    server answers only after the node has published 20 more messages since the request came
    in, so the race happens on every run, not only on a loaded machine."""
    from atr_node.node.publisher import Publisher
    from atr_node.node.snapshot_endpoint import ContactView, SnapshotServer

    asked = threading.Event()
    since_asked = [0]

    class SlowView(ContactView):
        def snapshot(self):
            if threading.current_thread().name == "atr-snapshot" and not asked.is_set():
                asked.set()
                wait_until(lambda: since_asked[0] >= 20, poll_s=0.002)
            return super().snapshot()

    pub = Publisher("tcp://127.0.0.1:*")
    view = SlowView()
    srv = SnapshotServer("tcp://127.0.0.1:*", view)
    messages = []
    for seq in range(1, 1501):
        cid = 1 + (seq * 7) % 30
        state = "withdrawn" if seq % 6 == 0 else ("new" if seq % 6 == 1 else "update")
        messages.append(wire.contact_message(id=cid, state=state, t=1.7e9 + seq, lat_deg=44.0, lon_deg=9.8,
                                             east_m=float(seq), north_m=0.0, sigma_m=1.0, bel=0.9, pl=1.0,
                                             m_theta=0.1, looks=1, detections=1, detectors=["smf"], legs=[0],
                                             seq=seq))
    joined = threading.Event()
    follower: list[NodeFollower] = []

    def node():  # as NodeService._emit: the view, then the PUB socket
        for m in messages:
            if m["seq"] == 300:
                joined.wait(WAIT_S)  # some history before the follower exists
                # heartbeats until the follower's subscription is up (its first message asks
                # for the snapshot), so the stream goes on while the snapshot is served: the
                # race under test, however loaded the machine
                wait_until(lambda: pub.heartbeat(wire.heartbeat_message(
                    t=time.time(), uptime_s=1.0, tiles_in=0, tiles_done=0, tiles_dropped=0, tiles_rejected=0,
                    queue_depth=0, p50_ms=0.0, p99_ms=0.0, mode="nominal")) or follower[0].stats.heartbeats > 0,
                    poll_s=0.005)
                asked.wait(WAIT_S)  # the snapshot is asked for: the 1200 messages to come follow the request
            if m["seq"] == 1500:  # the snapshot is served before the last message, on any machine
                wait_until(lambda: follower[0].stats.snapshot == "ok", poll_s=0.005)
            view.published(m)
            pub.contact(m)
            if asked.is_set():
                since_asked[0] += 1
            time.sleep(0.0005)

    t = threading.Thread(target=node)
    t.start()
    applied: list[dict] = []
    try:
        wait_until(lambda: view.snapshot()[0] >= 299, poll_s=0.005)
        fol = NodeFollower(pub.endpoint, snapshot=srv.endpoint, on_contact=applied.append, snapshot_timeout_s=WAIT_S)
        follower.append(fol)
        joined.set()
        assert follow_until(fol, lambda: bool(applied) and applied[-1]["seq"] == 1500)
        t.join()
    finally:
        fol.close()
        srv.close()
        pub.close()
    s = fol.stats.snapshot_seq
    assert fol.stats.snapshot == "ok" and 299 <= s < 1500
    seqs = [m["seq"] for m in applied]
    n_snap = fol.stats.snapshot_contacts
    assert sorted(seqs[:n_snap]) == sorted(m["seq"] for m in _live(messages[:s]).values())
    assert seqs[n_snap:] == list(range(s + 1, 1501))  # every later message once, in order
    assert fol.stats.gaps == 0 and fol.stats.contacts == 1500 - s
    assert fol.stats.duplicates >= 20  # the race happened: held messages the snapshot already had
    assert {c["id"]: c for c in fol.book.contacts()} == _live(messages)


@pytest.mark.parametrize("command", ["monitor", "export", "exwpt"])
@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "soon"])
def test_snapshot_timeout_must_be_seconds(command, value, capsys):
    """--snapshot-timeout: a usage error naming the option (exit 2), raised while the command
    line is parsed, so before the command runs."""
    from atr_node.cli import main

    with pytest.raises(SystemExit) as end:
        main([command, "--from", "tcp://127.0.0.1:1", "--snapshot-timeout", value])
    assert end.value.code == 2
    err = capsys.readouterr().err
    assert err.splitlines()[-1].endswith(f"argument --snapshot-timeout: must be a finite number of seconds > 0, "
                                         f"got '{value}'")
