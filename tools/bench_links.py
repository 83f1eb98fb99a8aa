#!/usr/bin/env python3
"""Benchmark the link drivers (package ``hw``): codecs, transports, replay and pacing.

Measures, each on real parts (a pty, python-can's virtual bus, ZeroMQ on loopback, real files):

  nmea encode         encode_gga + encode_hdt, sentences/s
  nmea decode (real)  NmeaDecoder on the R/V Palmer logs (openrvdas NBP1406), lines/s
  framer              LineFramer on 4 KiB chunks, MB/s
  can decode          CanNavDecoder on the five DBC frames, frames/s
  pty serial          PtyNmeaOut -> SerialNmeaLink, lines/s
  virtual can         python-can virtual bus -> CanLink, frames/s
  zmq tiles           PUSH -> ZmqTileLink (PULL), tiles/s and MB/s for float32 tiles
  replay max          ReplayLink at speed=max over an .atrlog of tiles + nav, records/s
  pacing error        Paced at a factor: wall-clock lateness of each record (p50, p99, max ms)

Figures depend on the machine and its load; on a shared machine take them as indicative.
Usage: ``python tools/bench_links.py [--quick] [--tile-size N] [--real-data DIR]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import can  # noqa: E402
import msgpack  # noqa: E402
import zmq  # noqa: E402

from atr_node.io.atrlog import AtrLogWriter  # noqa: E402
from atr_node.records.tile import Tile  # noqa: E402
from hw.can_link import CanLink  # noqa: E402
from hw.can_nav import CanNavDecoder, encode_altitude, encode_attitude, encode_leg, encode_position, encode_time  # noqa: E402
from hw.framing import LineFramer  # noqa: E402
from hw.hil import PtyNmeaOut  # noqa: E402
from hw.nmea import NmeaDecoder, encode_gga, encode_hdt  # noqa: E402
from hw.replay import Paced, ReplayLink, StampedNmeaLink  # noqa: E402
from hw.serial_nmea import SerialNmeaLink  # noqa: E402
from hw.zmq_sonar import ZmqTileLink  # noqa: E402

REAL = Path(os.environ.get("ATR_REAL_DATA", Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "real"))
ROWS: list[tuple[str, str, str]] = []


def row(name: str, value: str, note: str = "") -> None:
    ROWS.append((name, value, note))
    print(f"  {name:20s} {value:>22s}  {note}", flush=True)


def bench_codecs(n: int, real: Path) -> None:
    t = time.perf_counter()
    lines = [encode_gga(1.7e9 + 0.1 * k, 44.0 + 1e-6 * k, 9.8) for k in range(n)] + [encode_hdt(k % 360) for k in range(n)]
    row("nmea encode", f"{2 * n / (time.perf_counter() - t):,.0f} /s")
    paths = sorted((real / "nmea").glob("NBP1406_*"))
    if paths:
        recs = [r for p in paths for r in StampedNmeaLink(p)]
        d = NmeaDecoder()
        t = time.perf_counter()
        for r in recs:
            d.feed(r.msg, r.t)
        dt = time.perf_counter() - t
        row("nmea decode (real)", f"{len(recs) / dt:,.0f} lines/s", f"{len(recs)} lines, {d.counts['accepted']} accepted, "
            f"{d.rejected} rejected {dict((k, v) for k, v in d.counts.items() if k != 'accepted')}")
    else:
        row("nmea decode (real)", "skipped", f"no real data under {real}")
    stream = b"".join(lines)
    framer = LineFramer()
    t = time.perf_counter()
    got = sum(len(framer.feed(stream[i:i + 4096])) for i in range(0, len(stream), 4096))
    row("framer", f"{len(stream) / (time.perf_counter() - t) / 1e6:,.1f} MB/s", f"{got} lines")
    frames = [encode_time(1.7e9), encode_position(44.0, 9.8), encode_attitude(90.0), encode_altitude(10.0), encode_leg(1)]
    dec = CanNavDecoder()
    t = time.perf_counter()
    for k in range(n):
        dec.feed(*frames[k % 5], 1.7e9)
    row("can decode", f"{n / (time.perf_counter() - t):,.0f} frames/s")


def bench_pty(n: int) -> None:
    out = PtyNmeaOut()
    link = SerialNmeaLink(out.slave_path)
    sentences = [encode_gga(1.7e9 + 0.1 * k, 44.0, 9.8) for k in range(n)]

    def write():
        from atr_node.io.atrlog import LogRecord
        for s in sentences:
            out.send(LogRecord(0.0, "nmea", s))

    th = threading.Thread(target=write, daemon=True)
    t = time.perf_counter()
    th.start()
    got = 0
    while got < n and link.recv(timeout=5.0) is not None:
        got += 1
    dt = time.perf_counter() - t
    th.join()
    link.shutdown()
    out.close()
    row("pty serial", f"{got / dt:,.0f} lines/s", f"{got}/{n} lines, {sum(map(len, sentences)) / dt / 1e3:,.0f} kB/s")


def bench_can(n: int) -> None:
    ch = f"bench-{uuid.uuid4().hex}"
    frames = [encode_position(44.0, 9.8)] * n
    with CanLink("virtual", ch) as link, can.Bus(interface="virtual", channel=ch) as tx:
        t = time.perf_counter()
        for fid, data, ext in frames:
            tx.send(can.Message(arbitration_id=fid, data=data, is_extended_id=ext))
        got = 0
        while got < n and link.recv(timeout=5.0) is not None:
            got += 1
        dt = time.perf_counter() - t
    row("virtual can", f"{got / dt:,.0f} frames/s", f"{got}/{n} frames, send + receive")


def tile_map(seq: int, size: int, rng: np.random.Generator) -> dict:
    return Tile(mission="bench", leg=1, side="port", seq=seq, pixels=rng.random((size, size), dtype=np.float32),
                kind="intensity", range0_m=5.0, dr_m=0.05, dx_m=0.05, slant=False,
                ping_time=1.7e9 + seq + np.arange(size) * 1e-3).to_map()


def bench_zmq(n: int, size: int, rng: np.random.Generator) -> None:
    ctx = zmq.Context.instance()
    push = ctx.socket(zmq.PUSH)
    push.linger = 0
    port = push.bind_to_random_port("tcp://127.0.0.1")
    payload = msgpack.packb(tile_map(0, size, rng), use_bin_type=True)
    with ZmqTileLink(f"tcp://127.0.0.1:{port}") as link:
        th = threading.Thread(target=lambda: [push.send(payload) for _ in range(n)], daemon=True)
        t = time.perf_counter()
        th.start()
        got = 0
        while got < n and link.recv(timeout=10.0) is not None:
            got += 1
        dt = time.perf_counter() - t
        th.join()
    push.close()
    row("zmq tiles", f"{got / dt:,.1f} tiles/s", f"{size}x{size} float32, {got * len(payload) / dt / 1e6:,.0f} MB/s incl. msgpack decode")


def bench_replay(n: int, size: int, rng: np.random.Generator, tmp: Path) -> None:
    path = tmp / "bench.atrlog"
    with AtrLogWriter(path, flush_every=1000) as w:
        for k in range(n):
            t = 1.7e9 + 0.01 * k
            if k % 100 == 0:
                w.write(t, "sonar", tile_map(k, size, rng))
            else:
                w.write(t, "nmea", encode_hdt(k % 360).rstrip())
    mb = path.stat().st_size / 1e6
    t = time.perf_counter()
    with Paced(ReplayLink(path), None) as link:
        got = sum(1 for _ in link)
    dt = time.perf_counter() - t
    row("replay max", f"{got / dt:,.0f} records/s", f"{got} records ({n // 100} tiles), {mb / dt:,.0f} MB/s of log")
    return path


def bench_pacing(speed: float, n: int, tmp: Path) -> None:
    path = tmp / "pace.atrlog"
    with AtrLogWriter(path, flush_every=1000) as w:
        for k in range(n):
            w.write(1.7e9 + 0.05 * k, "nmea", encode_hdt(k % 360).rstrip())
    late = []
    with Paced(ReplayLink(path), speed) as link:
        for rec in link:
            due = link._wall0 + (rec.t - link._t0) / speed
            late.append(time.monotonic() - due)
    ms = np.array(late) * 1e3
    row("pacing error", f"p50 {np.percentile(ms, 50):.2f} / p99 {np.percentile(ms, 99):.2f} ms",
        f"speed {speed:g}, {n} records 50 ms apart in the log, max {ms.max():.2f} ms late")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="Figures are indicative on a loaded machine; rerun on a quiet one.")
    ap.add_argument("--quick", action="store_true", help="small counts: a smoke run of a few seconds")
    ap.add_argument("--tile-size", type=int, default=1024, help="tile rows = cols for the ZeroMQ and replay runs")
    ap.add_argument("--real-data", type=Path, default=REAL, help="folder of the real recordings")
    args = ap.parse_args(argv)
    q = args.quick
    size = 128 if q else args.tile_size
    rng = np.random.default_rng(0)
    print(f"hw link benchmarks ({'quick' if q else 'full'}; {os.cpu_count()} CPUs; load {os.getloadavg()[0]:.1f})")
    with tempfile.TemporaryDirectory() as tmp:
        bench_codecs(2_000 if q else 50_000, args.real_data)
        bench_pty(500 if q else 20_000)
        bench_can(500 if q else 20_000)
        bench_zmq(10 if q else 200, size, rng)
        bench_replay(500 if q else 20_000, size, rng, Path(tmp))
        bench_pacing(10.0 if q else 5.0, 20 if q else 200, Path(tmp))
    print("\n| benchmark | result | notes |\n|---|---|---|")
    for name, value, note in ROWS:
        print(f"| {name} | {value} | {note} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
