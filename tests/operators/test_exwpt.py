"""$EXWPT over serial: the sentence decoded by an independent parser, the adapter's filter and
queue on real pyserial ports (loop://, a pty), and a real node on loopback feeding
``atr-node exwpt`` into a pty."""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import threading
import time
from datetime import datetime, timezone
from decimal import ROUND_HALF_EVEN, Decimal
from functools import reduce

import pytest
import serial
from hypothesis import given, settings as hsettings, strategies as st

from atr_node.errors import AtrError
from atr_node.node import wire
from atr_node.operators.exwpt import ExwptOutput, format_exwpt

from .conftest import WAIT_S, StreamLines, stop_client, wait_until

# Independent decoder: the layout of Chesapeake Times vol. 14 (July 2023), IEC 61162-1 framing.
SENTENCE = re.compile(rb"^\$(EXWPT),([^*]*)\*([0-9A-F]{2})\r\n$")


def parse_exwpt(line: bytes) -> dict:
    m = SENTENCE.match(line)
    assert m, f"not an $EXWPT sentence: {line!r}"
    body = line[1:line.index(b"*")]
    assert reduce(lambda a, b: a ^ b, body, 0) == int(m.group(3), 16), "checksum"
    assert len(line) <= 82
    cat, tod, lon, lat, depth, unit, desc = m.group(2).decode("ascii").split(",")
    ident = re.fullmatch(r"ATR (\d+) (new|update|withdrawn) bel (\d\.\d{3})", desc)
    if ident is None:  # the shorter forms, for long positions and ids
        short = re.fullmatch(r"ATR (\d+)(?: ([NUW]) (\d\.\d{2}))?", desc)
        assert short, desc
        states = {"N": "new", "U": "update", "W": "withdrawn", None: None}
        return {**fields(cat, tod, lon, lat, depth, unit), "id": int(short[1]), "state": states[short[2]],
                "bel": None if short[3] is None else float(short[3])}
    return {**fields(cat, tod, lon, lat, depth, unit), "id": int(ident[1]), "state": ident[2],
            "bel": float(ident[3])}


def fields(cat, tod, lon, lat, depth, unit):
    h, mi, s = tod.split(":")
    return {"category": int(cat), "seconds_of_day": int(h) * 3600 + int(mi) * 60 + float(s), "lon": float(lon),
            "lat": float(lat), "depth": None if depth == "" else float(depth), "unit": unit}


def contact(id=1, *, state="new", lat=44.08, lon=9.85, bel=0.9, t=1.7e9, east=0.0, north=0.0):
    return wire.contact_message(id=id, state=state, t=t, lat_deg=lat, lon_deg=lon, east_m=east, north_m=north,
                                sigma_m=1.0, bel=bel, pl=1.0, m_theta=1.0 - bel, looks=1, detections=1,
                                detectors=["mf"], legs=[0])


def expected_seconds(t: float) -> float:
    ms = Decimal(repr(t)).quantize(Decimal("0.001"), rounding=ROUND_HALF_EVEN)
    return float(ms % 86400)


def _full_sentence_length(cat: int, lon: float, lat: float, cid: int, state: str, bel: float) -> int:
    """Characters of the sentence with the full description and no depth, counted by hand:
    '$', the fields between commas, '*' and two checksum digits, CR LF (IEC 61162-1: at most 82)."""
    fields = ["EXWPT", str(cat), "hh:mm:ss.sss", f"{lon:.7f}", f"{lat:.7f}", "", "M", f"ATR {cid} {state} bel {bel:.3f}"]
    return 1 + len(",".join(fields)) + 3 + 2


def test_the_full_description_gives_way_only_when_it_would_not_fit():
    """A 4-digit id, 'withdrawn' and a 3-digit longitude make 83 characters in full: the short
    form (hypothesis found this case; the test used to expect the full form for every id
    below 10^4)."""
    c = contact(1000, state="withdrawn", lat=-10.0, lon=-100.0, bel=0.125, t=0.0)
    assert _full_sentence_length(0, -100.0, -10.0, 1000, "withdrawn", 0.125) == 83
    d = parse_exwpt(format_exwpt(c, category=0))
    assert (d["id"], d["state"]) == (1000, "withdrawn") and abs(d["bel"] - 0.125) <= 5e-3 + 1e-12  # 2 decimals
    assert len(format_exwpt(contact(1000, state="update", lat=-10.0, lon=-100.0, bel=0.125, t=0.0),
                            category=0)) == _full_sentence_length(0, -100.0, -10.0, 1000, "update", 0.125) == 80
    assert parse_exwpt(format_exwpt(contact(1000, state="update", lat=-10.0, lon=-100.0, bel=0.125, t=0.0),
                                    category=0))["bel"] == 0.125


def test_sentence_fields():
    c = contact(12, lat=50.334671400393564, lon=-4.1486191821828067, bel=0.87345,
                t=datetime(2023, 7, 1, 15, 30, 30, tzinfo=timezone.utc).timestamp())
    line = format_exwpt(c, depth_m=23.0)
    d = parse_exwpt(line)
    assert d == {"category": 3, "seconds_of_day": 15 * 3600 + 30 * 60 + 30.0, "lon": -4.1486192, "lat": 50.3346714,
                 "depth": -23.0, "unit": "M", "id": 12, "state": "new", "bel": 0.873}
    assert line.startswith(b"$EXWPT,3,15:30:30.000,-4.1486192,50.3346714,-23.0,M,ATR 12 new bel 0.873*")
    assert parse_exwpt(format_exwpt(c, category=4))["depth"] is None


@hsettings(max_examples=200, deadline=None)
@given(lat=st.floats(-90, 90), lon=st.floats(-180, 180), bel=st.floats(0, 1), t=st.floats(0, 4.1e9),
       cid=st.integers(0, 10**9), state=st.sampled_from(["new", "update", "withdrawn"]),
       depth=st.none() | st.floats(0, 11_999), cat=st.integers(0, 4))
def test_any_contact_gives_a_valid_sentence(lat, lon, bel, t, cid, state, depth, cat):
    d = parse_exwpt(format_exwpt(contact(cid, state=state, lat=lat, lon=lon, bel=bel, t=t), category=cat,
                                 depth_m=depth))
    assert abs(d["lat"] - lat) <= 0.5e-7 + 1e-12 and abs(d["lon"] - lon) <= 0.5e-7 + 1e-12
    assert d["id"] == cid and d["category"] == cat
    assert d["state"] in (state, None) and (d["bel"] is None or abs(d["bel"] - bel) <= 5e-3 + 1e-12)
    if depth is None and _full_sentence_length(cat, lon, lat, cid, state, bel) <= 82:  # the full description whenever it fits
        assert d["state"] == state and abs(d["bel"] - bel) <= 5e-4 + 1e-12  # a half rounds either way
    assert d["seconds_of_day"] == pytest.approx(expected_seconds(t), abs=1e-9)
    assert d["depth"] is None if depth is None else abs(d["depth"] + depth) <= 0.05 + 1e-9  # a half rounds either way


def test_midnight_rounding_and_bad_options():
    t = datetime(2026, 1, 1, tzinfo=timezone.utc).timestamp() - 0.0004  # 23:59:59.9996 -> next day 00:00:00.000
    assert b",00:00:00.000," in format_exwpt(contact(t=t))
    with pytest.raises(AtrError, match="category 7"):
        format_exwpt(contact(), category=7)
    with pytest.raises(AtrError, match="depth"):
        format_exwpt(contact(), depth_m=-3.0)
    with pytest.raises(AtrError, match="cannot open"):
        ExwptOutput("/dev/does-not-exist-atr")


def read_all(port: serial.SerialBase) -> list[bytes]:
    data = port.read(port.in_waiting or 1)
    return [x + b"\n" for x in data.split(b"\n") if x]


def test_filter_small_updates_and_withdrawn_on_loop_port():
    out = ExwptOutput("loop://", min_move_m=0.5, min_bel_change=0.02, port=serial.serial_for_url("loop://", timeout=0.2))
    out.offer(contact(1, state="new", bel=0.6))
    out.offer(contact(1, state="update", bel=0.61, east=0.3))  # small: not sent
    out.offer(contact(1, state="update", bel=0.61, east=0.6))  # moved 0.6 m since the last sent
    out.offer(contact(1, state="update", bel=0.64, east=0.6))  # belief +0.04
    out.offer(contact(1, state="withdrawn", bel=0.3))  # not sent by default
    out.offer(contact(1, state="update", bel=0.7))  # back after a withdrawal: sent
    got = [parse_exwpt(x) for x in read_all(out.port)]
    assert [(d["state"], d["bel"]) for d in got] == [("new", 0.6), ("update", 0.61), ("update", 0.64),
                                                      ("update", 0.7)]
    assert out.stats.skipped_small == 1 and out.stats.skipped_withdrawn == 1 and out.stats.sent == 4
    out.close()


def test_a_failed_port_loses_nothing_and_is_reopened():
    """The port dies, stays down (connection refused) while contacts arrive, then comes back:
    every contact goes out once, in its newest state, over a real TCP socket:// port."""
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port_no = probe.getsockname()[1]
    probe.close()  # nothing listens there now: opening socket://127.0.0.1:<port_no> is refused
    dead = serial.serial_for_url("loop://")
    dead.close()  # the open port goes away: the next write raises
    out = ExwptOutput(f"socket://127.0.0.1:{port_no}", port=dead)
    assert out.offer(contact(1)) == 0 and out.offer(contact(2)) == 0
    assert out.offer(contact(1, state="update", bel=0.95)) == 0
    assert out.stats.write_errors == 1 and out.pending == 2
    server = socket.socket()
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", port_no))
    server.listen(1)
    try:
        assert out.flush() == 2  # reopened
        conn, _ = server.accept()
        conn.settimeout(WAIT_S)  # a wait for the bytes already sent, not a timing assertion
        data = b""
        while data.count(b"\n") < 2 and (chunk := conn.recv(4096)):  # b"": the sender closed
            data += chunk
        conn.close()
    finally:
        server.close()
        out.close()
    got = [parse_exwpt(x + b"\n") for x in data.split(b"\n") if x]
    assert [(d["id"], d["state"], d["bel"]) for d in got] == [(2, "new", 0.9), (1, "update", 0.95)]


def _pty_reader(master: int, sink: list[bytes], stop: threading.Event) -> None:
    buf = b""
    os.set_blocking(master, False)
    while not stop.is_set():
        try:
            chunk = os.read(master, 4096)
        except BlockingIOError:
            time.sleep(0.02)
            continue
        except OSError:
            break
        buf += chunk
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            sink.append(line + b"\n")


def test_exwpt_command_from_a_live_node_into_a_pty(live_node):
    import tty

    node = live_node()
    master, slave = os.openpty()
    tty.setraw(master)
    lines: list[bytes] = []
    stop = threading.Event()
    reader = threading.Thread(target=_pty_reader, args=(master, lines, stop), daemon=True)
    reader.start()
    proc = subprocess.Popen([sys.executable, "-m", "atr_node", "exwpt", "--from", node.endpoint, "--port",
                             os.ttyname(slave), "--min-move-m", "0", "--min-bel-change", "0"],
                            stderr=subprocess.PIPE, text=True)
    stderr = StreamLines(proc.stderr)
    try:
        stderr.wait_for(lambda t: "node up" in t)
        node.release()
        node.join()
        expected = [m for m in node.emitted if m["state"] != "withdrawn"]
        wait_until(lambda: len(lines) >= len(expected))  # until every sentence is on the pty
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
    assert expected, "the small mission should give contacts"
    got = [parse_exwpt(x) for x in lines]
    # with no filter, one sentence per published new/update message, in publishing order
    assert [(d["id"], d["state"]) for d in got] == [(m["id"], m["state"]) for m in expected]
    for d, m in zip(got, expected):
        assert d["category"] == 3 and d["depth"] is None
        assert abs(d["lat"] - m["lat_deg"]) <= 0.5e-7 + 1e-12 and abs(d["lon"] - m["lon_deg"]) <= 0.5e-7 + 1e-12
        assert d["seconds_of_day"] == pytest.approx(expected_seconds(m["t"]), abs=1e-9)
    assert "0 write errors, 0 still queued" in err


def test_a_contact_no_sentence_can_carry_is_dropped_not_fatal():
    out = ExwptOutput("loop://", port=serial.serial_for_url("loop://", timeout=0.2))
    huge = contact(10**30, lat=-89.1234567, lon=-179.1234567)  # id of 31 digits: 82 characters cannot hold it
    with pytest.raises(AtrError, match="too long"):
        format_exwpt(huge, depth_m=11_000.0)
    out.depth_m = 11_000.0
    assert out.offer(huge) == 0 and out.offer(contact(2)) == 1
    assert out.stats.unformattable == 1 and out.pending == 0
    assert [parse_exwpt(x)["id"] for x in read_all(out.port)] == [2]
    out.close()


def test_exwpt_command_errors_are_clear():
    r = subprocess.run([sys.executable, "-m", "atr_node", "exwpt", "--from", "tcp://127.0.0.1:1", "--port",
                        "/dev/nonexistent-tty"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and "cannot open it" in r.stderr and "/dev/nonexistent-tty" in r.stderr
    r = subprocess.run([sys.executable, "-m", "atr_node", "exwpt", "--from", "localhost:5560", "--port", "loop://",
                        "--duration", "0.1"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and "--from 'localhost:5560': no transport" in r.stderr
