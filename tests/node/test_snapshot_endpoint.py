"""Late joiners on the node side (ICD v1.1 section 3): ``seq`` on every contact message, the
snapshot endpoint on real loopback sockets (answers, bad requests, consistency while the
pipeline publishes, CURVE), ``seq`` across a resume, and bind failures in one line."""

from __future__ import annotations

import itertools
import shutil
import socket
import subprocess
import sys
import threading
import time

import msgpack
import pytest
import zmq

from atr_node.calibration.model import PerformanceModel
from atr_node.config import load_settings
from atr_node.errors import AtrError
from atr_node.io.atrlog import read_atrlog
from atr_node.node import wire
from atr_node.node.service import NodeService
from atr_node.node.snapshot_endpoint import (ContactView, SnapshotServer, derived_snapshot_endpoint,
                                             node_snapshot_endpoint, request_snapshot)
from atr_node.security import CurveConfig, generate_keypair, load_keypair, load_public_key


def msg(id, seq, state="update", bel=0.9):
    return wire.contact_message(id=id, state=state, t=1.7e9 + seq, lat_deg=44.0, lon_deg=9.8, east_m=float(id),
                                north_m=2.0, sigma_m=1.0, bel=bel, pl=1.0, m_theta=1.0 - bel, looks=1, detections=1,
                                detectors=["smf"], legs=[0], seq=seq)


def live_after(messages, seq):
    """Reference: the live contacts after the messages up to ``seq``, applied one by one."""
    live = {}
    for m in messages:
        if m["seq"] > seq:
            break
        if m["state"] == "withdrawn":
            live.pop(m["id"], None)
        else:
            live[m["id"]] = m
    return [live[k] for k in sorted(live)]


# ------------------------------------------------------------------------------ wire
def test_contact_seq_is_required_of_v11_and_optional_for_readers():
    m = msg(3, 7)
    assert m["seq"] == 7 and wire.validate_contact(m, require_seq=True) == []
    v1 = {k: v for k, v in m.items() if k != "seq"}
    assert wire.validate_contact(v1) == []  # a v1 node's message is still read
    assert any("missing 'seq'" in p for p in wire.validate_contact(v1, require_seq=True))
    assert any("'seq' should be >= 1" in p for p in wire.validate_contact({**m, "seq": 0}))
    assert any("'seq' should be int" in p for p in wire.validate_contact({**m, "seq": True}))
    assert any("'seq' should be int" in p for p in wire.validate_contact({**m, "seq": 2.0}))
    with pytest.raises(ValueError, match="seq"):
        wire.contact_message(**{k: v for k, v in m.items() if k not in ("type", "v", "seq")}, seq=0)


def test_snapshot_reply_round_trip_and_refusals():
    contacts = [msg(1, 4), msg(2, 5)]
    assert wire.read_snapshot_reply(wire.snapshot_reply(5, contacts)) == (5, contacts)
    assert wire.read_snapshot_reply(wire.snapshot_reply(0, [])) == (0, [])
    with pytest.raises(ValueError, match="refused.*nope"):
        wire.read_snapshot_reply(wire.snapshot_error("nope"))
    for bad in (b"\xc1", msgpack.packb({"seq": -1, "contacts": []}), msgpack.packb({"seq": 1}),
                msgpack.packb({"seq": 1, "contacts": [1]}), msgpack.packb([1, 2]),
                msgpack.packb({"seq": True, "contacts": []})):
        with pytest.raises(ValueError, match="snapshot reply"):
            wire.read_snapshot_reply(bad)


@pytest.mark.parametrize("pub, want", [
    ("tcp://127.0.0.1:5560", "tcp://127.0.0.1:5561"), ("tcp://auv3.local:7000", "tcp://auv3.local:7001"),
    ("tcp://[::1]:5560", "tcp://[::1]:5561"), ("tcp://127.0.0.1:*", None), ("tcp://127.0.0.1:65535", None),
    ("ipc:///tmp/atr", None), ("127.0.0.1:5560", None), ("tcp://:5560", None)])
def test_snapshot_endpoint_derived_from_the_pub_endpoint(pub, want):
    assert derived_snapshot_endpoint(pub) == want


def test_replay_snapshot_endpoint_choice():
    settings = load_settings(None)
    assert node_snapshot_endpoint(settings, publish_arg=None, snapshot_arg=None)[0] == "tcp://127.0.0.1:5561"
    assert node_snapshot_endpoint(settings, publish_arg="tcp://10.0.0.2:6000", snapshot_arg=None)[0] == \
        "tcp://10.0.0.2:6001"
    assert node_snapshot_endpoint(settings, publish_arg="tcp://10.0.0.2:6000", snapshot_arg="tcp://*:7")[0] == \
        "tcp://*:7"
    assert node_snapshot_endpoint(settings, publish_arg=None, snapshot_arg="none")[0] is None


# ------------------------------------------------------------------------------ server
@pytest.fixture
def server():
    view = ContactView()
    srv = SnapshotServer("tcp://127.0.0.1:*", view)
    yield view, srv
    srv.close()


def _exchange(sock, frames, timeout_s=5.0):
    sock.send_multipart(frames)
    assert sock.poll(int(timeout_s * 1000)), "no reply"
    return sock.recv_multipart()


def test_server_answers_the_live_contacts_and_refuses_anything_else(server):
    view, srv = server
    assert request_snapshot(srv.endpoint) == (0, [])  # nothing published yet
    for m in (msg(1, 1, "new"), msg(2, 2, "new"), msg(1, 3), msg(2, 4, "withdrawn"), msg(3, 5, "new")):
        view.published(m)
    assert request_snapshot(srv.endpoint) == (5, [msg(1, 3), msg(3, 5, "new")])
    ctx = zmq.Context.instance()
    dealer = ctx.socket(zmq.DEALER)
    dealer.setsockopt(zmq.LINGER, 0)
    dealer.connect(srv.endpoint)
    try:
        # unknown requests, from a DEALER (no envelope) and a REQ: an error map each, no crash
        for frames in ([b"contact"], [b"contacts", b"extra"], [b"\xff" * 100], [b""]):
            (reply,) = _exchange(dealer, frames)
            assert "error" in msgpack.unpackb(reply) and "'contacts'" in msgpack.unpackb(reply)["error"]
        req = ctx.socket(zmq.REQ)
        req.setsockopt(zmq.LINGER, 0)
        req.connect(srv.endpoint)
        try:
            (reply,) = _exchange(req, [b"CONTACTS"])
        finally:
            req.close()
        with pytest.raises(ValueError, match="refused.*unknown request b'CONTACTS'"):
            wire.read_snapshot_reply(reply)
        (reply,) = _exchange(dealer, [b"contacts"])  # a DEALER's good request is answered too
        assert wire.read_snapshot_reply(reply) == (5, [msg(1, 3), msg(3, 5, "new")])
    finally:
        dealer.close()
    assert srv.refused == 5 and srv.served == 3
    assert request_snapshot(srv.endpoint)[0] == 5  # still serving


def test_every_snapshot_is_a_state_the_stream_passed_through(server):
    """Snapshots taken while another thread publishes: each equals the live set after exactly
    its seq (reference: the messages up to it, applied one by one)."""
    view, srv = server
    messages = []
    for seq in range(1, 3001):  # ids 1..40, born, updated, withdrawn and new again
        cid = 1 + (seq * 7) % 40
        state = "withdrawn" if seq % 5 == 0 else ("new" if seq % 5 == 1 else "update")
        messages.append(msg(cid, seq, state, bel=0.5 + (seq % 100) / 250))
    done = threading.Event()

    def publish():
        for m in messages:
            view.published(m)
            if m["seq"] % 10 == 0:
                time.sleep(0.001)  # long enough for requests to land in between
        done.set()

    t = threading.Thread(target=publish)
    t.start()
    seen = []
    while not done.is_set() or not seen:
        seen.append(request_snapshot(srv.endpoint))
    t.join()
    seen.append(request_snapshot(srv.endpoint))
    assert seen[-1][0] == 3000 and len({s for s, _ in seen}) >= 3
    for seq, contacts in seen:
        assert contacts == live_after(messages, seq), seq


def test_v1_node_without_the_endpoint_times_out_cleanly():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(AtrError, match=f"no snapshot from tcp://127.0.0.1:{port} within 0.3 s"):
        request_snapshot(f"tcp://127.0.0.1:{port}", timeout_s=0.3)


def test_snapshot_endpoint_is_a_curve_server_like_the_pub_socket(tmp_path):
    keys = {name: generate_keypair(tmp_path / "keys", name) for name in ("node", "peer", "intruder")}
    auth = tmp_path / "authorized"
    auth.mkdir()
    shutil.copy(keys["peer"][0], auth / "peer.key")
    cfg = tmp_path / "node.toml"
    cfg.write_text(f'[links]\ncurve_secret_key_file = "{keys["node"][1]}"\ncurve_authorized_dir = "{auth}"\n')
    service = NodeService(load_settings(cfg), model=PerformanceModel.shipped(), workers=0,
                          publish="tcp://127.0.0.1:*", snapshot="tcp://127.0.0.1:*")
    try:
        service._emit(msg(4, 1, "new"))
        ep = service.snapshot_server.endpoint
        node_pub = load_public_key(keys["node"][0])
        peer = CurveConfig(keys=load_keypair(keys["peer"][1]), server_public_key=node_pub)
        intruder = CurveConfig(keys=load_keypair(keys["intruder"][1]), server_public_key=node_pub)
        assert request_snapshot(ep, curve=peer) == (1, [msg(4, 1, "new")])
        with pytest.raises(AtrError, match="no snapshot"):
            request_snapshot(ep, curve=intruder, timeout_s=0.5)
        with pytest.raises(AtrError, match="no snapshot"):
            request_snapshot(ep, timeout_s=0.5)  # plain text to a CURVE server
    finally:
        service.close()


def test_no_publisher_binds_no_snapshot_endpoint(small_mission):
    settings, _, _ = small_mission
    service = NodeService(settings, model=PerformanceModel.shipped(), workers=0, publish=None,
                          snapshot="tcp://127.0.0.1:*")
    try:
        assert service.snapshot_server is None
    finally:
        service.close()


# ------------------------------------------------------------------------------ seq and resume
def _run_node(settings, **kw):
    emitted = []
    service = NodeService(settings, model=PerformanceModel.shipped(), workers=0, on_contact=emitted.append, **kw)
    return service, emitted


def test_seq_counts_every_message_and_survives_a_resume(small_mission, tmp_path):
    settings, _, files = small_mission
    records = list(read_atrlog(files.atrlog))
    ref, ref_msgs = _run_node(settings)
    try:
        ref.run(iter(records))
        ref_final = ref.pipeline.contacts
    finally:
        ref.close()
    assert [m["seq"] for m in ref_msgs] == list(range(1, len(ref_msgs) + 1))
    assert all(wire.validate_contact(m, require_seq=True) == [] for m in ref_msgs)
    # the final state of each contact carries the seq of its last message (--contacts-out)
    last = {m["id"]: m for m in ref_msgs}
    assert ref_final == [last[k] for k in sorted(last)]

    state = tmp_path / "state"
    first, first_msgs = _run_node(settings, state_dir=state, publish="tcp://127.0.0.1:*",
                                  snapshot="tcp://127.0.0.1:*")
    try:  # stop two thirds in (the node's last periodic snapshot is somewhat before)
        first.run(itertools.islice(records, 2 * len(records) // 3), finish=False)
    finally:
        first.close()
    second, second_msgs = _run_node(settings, state_dir=state, publish="tcp://127.0.0.1:*",
                                    snapshot="tcp://127.0.0.1:*")
    try:
        skip = second.resume()
        assert 0 < skip < len(records)
        seq, contacts = request_snapshot(second.snapshot_server.endpoint)
        # the restored state: the seq of the snapshot, the live contacts after exactly it
        assert 0 < seq == second.pipeline.contact_seq <= len(first_msgs)
        assert contacts == live_after(ref_msgs, seq) and contacts
        second.run(itertools.islice(records, skip, None), start=skip)
        assert second.snapshot_server.served == 1
        final = second.pipeline.contacts
        view_seq, view = second.contact_view.snapshot()
    finally:
        second.close()
    # after the resume the count goes on from the snapshot's seq: the same messages, same seqs
    assert [m["seq"] for m in second_msgs] == list(range(seq + 1, len(ref_msgs) + 1))
    assert second_msgs == ref_msgs[seq:]
    assert final == ref_final
    assert view_seq == len(ref_msgs) and view == [c for c in ref_final if c["state"] != "withdrawn"]


# ------------------------------------------------------------------------------ bind failures
def _replay(files, cfg, *extra):
    return subprocess.run([sys.executable, "-m", "atr_node", "replay", str(files.atrlog), "--config", str(cfg),
                           "--online-calibration", "off", "--workers", "0", "--quiet", *extra],
                          capture_output=True, text=True, timeout=120)


def test_a_port_in_use_is_one_clear_line(small_mission):
    _, cfg, files = small_mission
    with socket.socket() as busy, socket.socket() as free:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        free.bind(("127.0.0.1", 0))
        b, f = busy.getsockname()[1], free.getsockname()[1]
        free.close()
        r = _replay(files, cfg, "--publish", f"tcp://127.0.0.1:{f}", "--snapshot", f"tcp://127.0.0.1:{b}")
        assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert (f"cannot bind the snapshot endpoint (ROUTER) to 'tcp://127.0.0.1:{b}': Address already in use"
                in r.stderr and "--snapshot" in r.stderr)
        r = _replay(files, cfg, "--publish", f"tcp://127.0.0.1:{b}")
        assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert f"cannot bind the contact PUB socket to 'tcp://127.0.0.1:{b}'" in r.stderr and "--publish" in r.stderr
