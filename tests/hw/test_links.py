"""Live link drivers on real transports: loop://, a pty, a TCP serial server, ZeroMQ, and the table."""

from __future__ import annotations

import os
import socket
import threading
import time
import uuid

import msgpack
import pytest
import zmq

import hw
from atr_node.config import LinkSettings
from hw.base import Link
from hw.errors import LinkClosedError, LinkError, LinkSpecError
from hw.nmea import encode_dpt, encode_gga, encode_hdt
from hw.nmea_decoder import NmeaDecoder
from hw.serial_nmea import SerialNmeaLink
from hw.zmq_sonar import ZmqTileLink


def drain(link: Link, n: int, timeout: float = 5.0) -> list:
    out = []
    while len(out) < n:
        rec = link.recv(timeout=timeout)
        assert rec is not None, f"only {len(out)} of {n} records arrived"
        out.append(rec)
    return out


def test_loop_url_delivers_every_line_including_garbage():
    sentences = [encode_gga(1.7e9, 44.1, 9.8), encode_hdt(271.0), encode_dpt(8.5)]
    with hw.open_link("loop://") as link:
        link.write(b"\xff\xfenoise\r\n" + b"".join(sentences))
        recs = drain(link, 4)
        assert link.recv(timeout=0.05) is None
    assert [r.msg for r in recs] == [b"\xff\xfenoise"] + [s.rstrip() for s in sentences]
    assert all(r.link == "nmea" for r in recs)
    d = NmeaDecoder()
    fixes = [f for r in recs for f in d.feed(r.msg, r.t)]
    assert len(fixes) == 3 and d.counts["garbage"] == 1


def test_pty_split_writes_reassemble():
    master, slave = os.openpty()
    try:
        with SerialNmeaLink(os.ttyname(slave)) as link:
            line = encode_hdt(12.25)
            for i in range(0, len(line), 3):  # dribble the bytes in
                os.write(master, line[i:i + 3])
            (rec,) = drain(link, 1)
    finally:
        os.close(master)
        os.close(slave)
    assert rec.msg == line.rstrip()


def test_socket_url_reconnects_after_the_server_drops():
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    sessions = [[encode_hdt(1.0), encode_hdt(2.0)], [encode_hdt(3.0)]]

    def serve():
        for lines in sessions:
            conn, _ = server.accept()
            time.sleep(0.3)  # pyserial's socket:// open() discards what is already received
            conn.sendall(b"".join(lines))
            time.sleep(0.3)
            conn.close()  # the link sees EOF and must come back

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    try:
        with SerialNmeaLink(f"socket://127.0.0.1:{port}", reconnect=True, backoff_s=0.05, max_backoff_s=0.1) as link:
            recs = drain(link, 3, timeout=10.0)
            assert link.counts["disconnects"] >= 1
    finally:
        th.join(timeout=5)
        server.close()
    assert [r.msg for r in recs] == [l.rstrip() for s in sessions for l in s]


def test_without_reconnect_a_dead_port_is_a_clear_error():
    with pytest.raises(LinkError, match="/dev/does-not-exist"):
        SerialNmeaLink("/dev/does-not-exist")
    link = SerialNmeaLink("/dev/does-not-exist", reconnect=True, backoff_s=0.01, max_backoff_s=0.02)
    assert not link.connected and link.recv(timeout=0.05) is None
    link.shutdown()


def test_shutdown_is_idempotent_and_recv_after_it_raises():
    link = hw.open_link("nmea", url="loop://")
    link.shutdown()
    link.shutdown()
    with pytest.raises(LinkClosedError):
        link.recv(timeout=0)


def test_zmq_pull_delivers_maps_unvalidated_and_drops_undecodable():
    ctx = zmq.Context.instance()
    push = ctx.socket(zmq.PUSH)
    push.linger = 0
    port = push.bind_to_random_port("tcp://127.0.0.1")
    tile = {"type": "tile", "v": 1, "seq": 7, "data": b"\x00\x01", "shape": [1, 1]}
    try:
        with hw.open_link(f"tcp://127.0.0.1:{port}") as link:
            push.send(b"\xc1\xc1")  # never-used msgpack byte
            push.send(msgpack.packb([1, 2], use_bin_type=True))
            push.send(msgpack.packb({"type": "tile", "v": 99}, use_bin_type=True))  # bad, but a map: delivered
            push.send(msgpack.packb(tile, use_bin_type=True))
            recs = drain(link, 2)
            assert link.recv(timeout=0.05) is None
            assert link.counts["undecodable"] == 2 and "list" in link.last_reject
    finally:
        push.close()
    assert recs[0].msg == {"type": "tile", "v": 99} and recs[1].msg == tile and recs[1].link == "sonar"


def test_zmq_sub_takes_the_last_frame_and_filters_topic():
    ctx = zmq.Context.instance()
    pub = ctx.socket(zmq.PUB)
    pub.linger = 0
    port = pub.bind_to_random_port("tcp://127.0.0.1")
    try:
        with hw.open_link(f"tcp://127.0.0.1:{port}?socket=sub&topic=tile") as link:
            deadline = time.monotonic() + 30  # a guard only: it ends at the first record
            rec = None
            while rec is None and time.monotonic() < deadline:  # slow joiner: resend until subscribed
                pub.send_multipart([b"other", msgpack.packb({"x": 0})])
                pub.send_multipart([b"tile", msgpack.packb({"seq": 1})])
                rec = link.recv(timeout=0.1)
    finally:
        pub.close()
    assert rec is not None and rec.msg == {"seq": 1}


def test_zmq_bind_mode_reports_its_endpoint():
    endpoint = f"inproc://tiles-{uuid.uuid4().hex}"
    with ZmqTileLink(endpoint, bind=True) as link:
        push = zmq.Context.instance().socket(zmq.PUSH)
        push.linger = 0
        push.connect(link.bound_endpoint)
        push.send(msgpack.packb({"seq": 3}))
        assert drain(link, 1)[0].msg == {"seq": 3}
        push.close()


@pytest.mark.parametrize("spec, fragment", [
    ("ftp://x", "unknown scheme"), ("can://virtual", "can://<interface>/<channel>"),
    ("tcp://127.0.0.1:1?sockets=pull", "unknown option"), ("", "expected a link name"),
    ("tcp://127.0.0.1:1?socket=req", "expected 'pull' or 'sub'"), ("can://nope/x", "unknown interface"),
    ("replay:/nonexistent.atrlog", "no such file"), ("tcp://bad endpoint", "cannot connect"),
])
def test_open_link_errors_show_the_expected_form(spec, fragment):
    with pytest.raises(LinkSpecError, match=fragment):
        hw.open_link(spec)


def test_open_links_from_settings_opens_what_is_configured():
    channel = f"cfg-{uuid.uuid4().hex}"
    settings = LinkSettings(sonar_endpoint="tcp://127.0.0.1:5999", nmea_url="loop://", can_interface="virtual",
                            can_channel=channel)
    links = hw.open_links(settings)
    try:
        assert {k: type(v).__name__ for k, v in links.items()} == {
            "sonar": "ZmqTileLink", "nmea": "SerialNmeaLink", "can": "CanLink"}
        assert links["nmea"].reconnect is True and links["can"].name == f"virtual:{channel}"
    finally:
        for link in links.values():
            link.shutdown()
    assert hw.open_links(LinkSettings(sonar_endpoint="")) == {}
