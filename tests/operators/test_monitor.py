"""The monitor: its screen from messages sent over a real PUB socket, bad messages counted,
``atr-node monitor`` against a real node with a PNG, and the belief raster against the grid."""

from __future__ import annotations

import io
import subprocess
import sys
import threading
import time

import matplotlib.image as mpimg
import msgpack
import numpy as np
import pytest
import zmq

from atr_node.node import wire
from atr_node.node.publisher import Publisher
from atr_node.operators.beliefmap import draw_belief_map, grid_raster, load_state_grid
from atr_node.operators.monitor import CLEAR_EOS, HOME, Monitor, render_screen
from atr_node.operators.stream import NodeFollower

from .conftest import WAIT_S, StreamLines, follow_until, stop_client, wait_until


def contact(id, *, state="update", bel=0.9, t=1.7e9):
    return wire.contact_message(id=id, state=state, t=t, lat_deg=-12.5, lon_deg=130.25, east_m=100.0 * id,
                                north_m=50.0, sigma_m=1.25, bel=bel, pl=1.0, m_theta=1.0 - bel, looks=3,
                                detections=4, detectors=["mf", "z"], legs=[1, 2])


def heartbeat(tiles_in=12, mode="nominal"):
    return wire.heartbeat_message(t=time.time(), uptime_s=42.0, tiles_in=tiles_in, tiles_done=10, tiles_dropped=1,
                                  tiles_rejected=2, queue_depth=3, p50_ms=8.4, p99_ms=31.2, mode=mode)


@pytest.fixture
def pub_and_follower():
    pub = Publisher("tcp://127.0.0.1:*")
    fol = NodeFollower(pub.endpoint)
    def beat() -> None:  # slow joiner: until one arrives
        pub.heartbeat(heartbeat(tiles_in=0))
        fol.poll(0.05)

    assert wait_until(lambda: fol.heartbeat is not None, step=beat)
    yield pub, fol
    fol.close()
    pub.close()


def test_screen_shows_heartbeat_and_contacts_by_belief(pub_and_follower):
    pub, fol = pub_and_follower
    for m in (contact(1, bel=0.7, state="new"), contact(2, bel=0.99, state="new"), contact(3, bel=0.8, state="new"),
              contact(3, bel=0.3, state="withdrawn")):
        pub.contact(m)
    pub.heartbeat(heartbeat(tiles_in=12, mode="degraded"))
    # one socket keeps the order: the contacts are in once the degraded heartbeat is (waiting
    # for a count of messages stopped early when the fixture's joining left a heartbeat queued)
    assert follow_until(fol, lambda: fol.heartbeat["mode"] == "degraded")
    screen = render_screen(fol, now=fol.stats.last_heartbeat_at + 0.5, wall=1.7e9 + 30, width=120, max_rows=10)
    lines = screen.split("\n")
    assert "DEGRADED" in lines[1] and "heartbeat 0.5 s ago" in lines[1] and "up 42.0 s" in lines[1]
    assert lines[2].split() == "tiles in 12 done 10 dropped 1 rejected 2 queue 3 latency p50 8 ms p99 31 ms".split()
    assert "2 live, 1 withdrawn" in lines[4]
    rows = [ln.split() for ln in lines[6:]]
    assert [r[0] for r in rows] == ["2", "1", "3"]  # by belief, the withdrawn one flagged
    assert rows[0][1:5] == ["0.99000", "1.00000", "12.500000S", "130.250000E"]
    assert rows[2][8] == "GONE" and rows[0][-1] == time.strftime("%H:%M:%S", time.gmtime(1.7e9))
    stale = render_screen(fol, now=fol.stats.last_heartbeat_at + 7.2, wall=1.7e9, width=120)
    assert "NO HEARTBEAT for 7 s (last: degraded)" in stale
    assert all(len(x) <= 60 for x in render_screen(fol, now=time.monotonic(), width=60).split("\n"))
    short = render_screen(fol, now=time.monotonic(), width=120, max_rows=1).split("\n")
    assert short[-1].strip() == "... and 2 more"


def test_bad_messages_are_counted_and_change_nothing(pub_and_follower):
    pub, fol = pub_and_follower
    pub.contact(contact(5))
    assert follow_until(fol, lambda: fol.book.get(5) is not None)
    before = fol.book.contacts(include_withdrawn=True)
    raw = zmq.Context.instance().socket(zmq.PUB)
    raw.setsockopt(zmq.LINGER, 0)
    port = raw.bind_to_random_port("tcp://127.0.0.1")
    fol._sub._sock.connect(f"tcp://127.0.0.1:{port}")  # a second, misbehaving publisher on the same SUB
    broken = dict(contact(5, bel=0.95), pl=0.5)
    bad = [[b"contact", b"\xc1"], [b"weird", msgpack.packb({})], [b"contact", b"x", b"y"],
           [b"contact", msgpack.packb(broken)], [b"heartbeat", msgpack.packb({"type": "heartbeat"})]]

    def probe() -> None:  # a valid heartbeat from the raw publisher until the SUB has joined it
        raw.send_multipart(wire.encode(wire.TOPIC_HEARTBEAT, heartbeat(tiles_in=0, mode="degraded")))
        fol.poll(0.05)

    assert wait_until(lambda: fol.heartbeat["mode"] == "degraded", step=probe)
    for frames in bad:  # joined: each bad message arrives once
        raw.send_multipart(frames)
    follow_until(fol, lambda: fol.stats.bad >= len(bad))
    raw.close()
    assert fol.stats.bad == len(bad)
    assert fol.book.contacts(include_withdrawn=True) == before and fol.book.rejected == 1
    assert fol.heartbeat["type"] == "heartbeat" and fol.heartbeat["tiles_in"] == 0


def test_monitor_redraws_in_place(pub_and_follower):
    pub, fol = pub_and_follower
    out = io.StringIO()
    mon = Monitor(fol, out=out, refresh_s=0.05, ansi=True, max_rows=5)
    pub.contact(contact(9, state="new"))
    stop = threading.Event()

    def stop_after_three_frames() -> None:  # by frames drawn, not by time: a loaded machine draws fewer per second
        while not (mon.frames >= 3 and fol.book.get(9) is not None) and not stop.wait(0.01):
            pass
        stop.set()

    threading.Thread(target=stop_after_three_frames, daemon=True).start()
    why = mon.run(duration_s=120.0, stop=stop)  # the duration is a guard against hanging only
    text = out.getvalue()
    assert why == "stop" and mon.frames >= 4  # three redraws, then the last frame
    assert text.count(HOME) == mon.frames and text.count(CLEAR_EOS) == mon.frames
    assert "\x1b[2J" in text[:10]  # cleared once, then overwritten in place
    assert "    9 " in text.split(HOME)[-1]


def test_monitor_stops_after_its_duration(pub_and_follower):
    _pub, fol = pub_and_follower
    mon = Monitor(fol, out=io.StringIO(), refresh_s=0.05, ansi=True, max_rows=5)
    # the reason is what this checks; frames >= 1 always holds (run draws a last frame)
    assert mon.run(duration_s=0.3) == "duration" and mon.frames >= 1


def test_monitor_command_against_a_live_node_with_png(live_node, tmp_path):
    state = tmp_path / "state"
    node = live_node(state_dir=state)
    png = tmp_path / "belief.png"
    proc = subprocess.Popen([sys.executable, "-m", "atr_node", "monitor", "--from", node.endpoint, "--plain",
                             "--refresh", "0.3", "--png", str(png), "--png-every", "1",
                             "--state-dir", str(state), "--rows", "50"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stdout, stderr = StreamLines(proc.stdout), StreamLines(proc.stderr)
    try:
        # the first frame with a heartbeat received (its node line says "heartbeat N s ago"; the
        # "received  0 heartbeats" line of earlier frames does not count): the monitor is subscribed
        stdout.wait_for(lambda t: any(x.startswith("node") and "heartbeat" in x and " ago" in x
                                      for x in t.splitlines()))
        node.release()
        node.join()
        n_tiles = node.service.pipeline.stats.tiles_in

        def has_everything(text: str) -> bool:  # a frame with the last heartbeat and every message
            frame = text.strip().split("\n\n")[-1]
            return (f"tiles     in {n_tiles}  done {n_tiles}" in frame
                    and f" {len(node.emitted)} contact messages" in frame)

        stdout.wait_for(has_everything)
        returncode = stop_client(proc)  # a last frame and PNG, then the end-of-run line
    finally:
        if proc.poll() is None:
            proc.kill()
    out, err = stdout.close(), stderr.close()
    assert returncode == 0, err
    last = out.strip().split("\n\n")[-1].split("\n")
    assert f"tiles     in {n_tiles}  done {n_tiles}" in last[2]
    final = {}
    for m in node.emitted:
        final[m["id"]] = m
    assert final
    rows = {int(r.split()[0]): r.split() for r in last[6:] if r[:5].strip().isdigit()}
    assert set(rows) == set(final)
    for cid, r in rows.items():
        assert float(r[1]) == pytest.approx(final[cid]["bel"], abs=6e-6)
    img = mpimg.imread(png)
    assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 200
    assert "PNG(s) written" in err and "PNG problem" not in err


def test_belief_raster_matches_the_grid(live_node, tmp_path):
    state = tmp_path / "state"
    node = live_node(state_dir=state)
    node.release()
    node.join()
    grid = load_state_grid(state)
    r = grid_raster(grid)
    rows, cols = r.bel.shape
    iy0, ix0 = round(r.north0_m / r.cell_m), round(r.east0_m / r.cell_m)
    rng = np.random.default_rng(3)
    sample = [(int(i), int(j)) for i, j in zip(rng.integers(0, rows, 400), rng.integers(0, cols, 400))]
    peak = np.unravel_index(np.nanargmax(r.bel), r.bel.shape)
    sample.append((int(peak[0]), int(peak[1])))
    for i, j in sample:  # independent read-out: the grid's own per-cell accessors
        covered = bool(grid.legs_at(iy0 + i, ix0 + j))
        assert covered == (not np.isnan(r.bel[i, j]))
        if covered:
            e, n = grid.cell_centre(iy0 + i, ix0 + j)
            assert r.bel[i, j] == pytest.approx(float(grid.masses_at(e, n).bel), abs=1e-12)
    assert np.nanmax(r.bel) > 0.9  # the contacts are there
    small = grid_raster(grid, max_cells=rows * cols // 10)
    f = round(small.cell_m / r.cell_m)
    assert f in (2, 4, 8) and small.east0_m == r.east0_m and small.north0_m == r.north0_m
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            ref = np.nanmax(r.bel.reshape(rows // f, f, cols // f, f), axis=(1, 3))
    np.testing.assert_array_equal(small.bel, ref)
    contacts = [dict(m) for m in node.emitted]
    draw_belief_map(tmp_path / "a.png", contacts, raster=r)
    draw_belief_map(tmp_path / "b.png", contacts)
    draw_belief_map(tmp_path / "c.png", [])
    for name in ("a", "b", "c"):
        assert mpimg.imread(tmp_path / f"{name}.png").shape[2] in (3, 4)


def test_bench_tool_quick_smoke():
    from pathlib import Path

    tool = Path(__file__).resolve().parents[2] / "tools" / "bench" / "operators.py"
    r = subprocess.run([sys.executable, str(tool), "--quick", "--sizes", "20"], capture_output=True, text=True,
                       timeout=WAIT_S)
    assert r.returncode == 0, r.stderr
    row = r.stdout.splitlines()[1].split()
    assert row[0] == "20" and all(float(x) > 0 for x in row[1:])


def test_following_a_curve_secured_node(tmp_path):
    """A node whose PUB socket is a CURVE server admitting one client key: the follower with
    that key gets the contacts, one without keys gets nothing."""
    import argparse

    from atr_node.commands._follow import curve_from_args
    from atr_node.errors import AtrError
    from atr_node.security import CurveConfig, generate_keypair, load_keypair, load_public_key

    node_pub, node_sec = generate_keypair(tmp_path, "node")
    tool_pub, tool_sec = generate_keypair(tmp_path, "tool")
    pub = Publisher("tcp://127.0.0.1:*", curve=CurveConfig(keys=load_keypair(node_sec),
                                                          authorized=frozenset({load_public_key(tool_pub)})))
    args = argparse.Namespace(curve_key=str(tool_sec), node_key=str(node_pub))
    good = NodeFollower(pub.endpoint, curve=curve_from_args(args))
    plain = NodeFollower(pub.endpoint)
    try:
        def beat() -> None:
            pub.heartbeat(heartbeat())
            good.poll(0.05)
            plain.poll(0.01)

        assert wait_until(lambda: good.heartbeat is not None, step=beat)
        pub.contact(contact(4, state="new"))
        assert follow_until(good, lambda: good.book.get(4) is not None)
        for _ in range(5):
            plain.poll(0.05)
        assert [c["id"] for c in good.book.contacts()] == [4]
        assert plain.stats.heartbeats == 0 and len(plain.book) == 0
    finally:
        good.close()
        plain.close()
        pub.close()
    with pytest.raises(AtrError, match="go together"):
        curve_from_args(argparse.Namespace(curve_key=str(tool_sec), node_key=None))


def test_png_before_the_nodes_first_snapshot_draws_the_contacts_and_says_why(pub_and_follower, tmp_path):
    pub, fol = pub_and_follower
    pub.contact(contact(5, state="new"))
    assert follow_until(fol, lambda: fol.book.get(5) is not None)
    empty = tmp_path / "state"
    empty.mkdir()  # a node's --state-dir before its first snapshot
    out = io.StringIO()
    mon = Monitor(fol, out=out, ansi=False, png=tmp_path / "b.png", png_every_s=0.1, state_dir=empty)
    mon.run(duration_s=0.3)
    assert mon.pngs >= 1 and mon.png_error == "" and mpimg.imread(tmp_path / "b.png").ndim == 3
    assert "contacts only, no belief map" in mon.png_note and "no snapshot yet" in mon.png_note
    assert "contacts only, no belief map" in out.getvalue().split("\n\n")[-2]
