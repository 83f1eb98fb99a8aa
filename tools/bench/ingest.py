#!/usr/bin/env python3
"""Benchmark the node's ingest path: ``.atrlog`` reading, NMEA and CAN decoding, ``NavTrack.add``.

Stages, each on the records of a generated mission (real files, the shipped DBC):

  atrlog read (nav)    AtrLogReader over a file of the mission's NMEA and CAN records, records/s
  atrlog read (all)    AtrLogReader over the whole mission file (tiles too), records/s
  nmea decode          NmeaDecoder.feed on the mission's NMEA records, records/s
  can decode           CanNavDecoder.feed on the mission's CAN records, records/s
  nav decode           NavDecoder.feed (the pipeline's entry) on NMEA + CAN records, records/s
  read + nav decode    AtrLogReader of the nav file into NavDecoder.feed: the ingest path, records/s
  navtrack add         NavTrack.add of the decoded fixes, fixes/s
  pipeline feed (nav)  Pipeline.feed (workers=0) of the NMEA + CAN records (no tiles), records/s,
                       after the first position fix (which builds the mission frame once)

Every figure is the best of ``--repeat`` runs in CPU time (``time.process_time``), so a busy
neighbour on a shared machine disturbs it little; still take it as indicative.
Usage: ``python tools/bench/ingest.py nav [--quick] [--repeat N] [--legs N]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable
sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402  (tools/bench/harness.py: repeats, warm-up, statistics, JSON)

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

ROWS: list[tuple[str, int, float]] = []


def best_cpu(fn: Callable[[], Any], repeat: int, name: str = "call", n: int | None = None) -> float:
    """Smallest CPU time (s) of ``repeat`` calls of ``fn`` (no warm-up: the first call's cost is
    part of reading a log once), through the harness under ``name`` with ``n`` records of work."""
    t = harness.measure(name, fn, repeat=repeat, warmup=0, clock="process", work=n, work_unit="records")
    return max(t.min_s, 1e-9)


def report(name: str, n: int, cpu_s: float) -> None:
    ROWS.append((name, n, cpu_s))
    print(f"  {name:20s} {n:8d} {cpu_s * 1e3:9.2f} {n / cpu_s:14,.0f} {cpu_s / n * 1e6:9.2f}", flush=True)


def main_nav(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="Figures are CPU-time best-of-N; on a shared machine indicative only.")
    ap.add_argument("--quick", action="store_true", help="small mission, 2 repeats (a smoke run)")
    ap.add_argument("--repeat", type=int, default=None, help="runs per stage, best kept (default 7, quick 2)")
    ap.add_argument("--legs", type=int, default=None, help="mission legs (default 4, quick 1)")
    args = ap.parse_args(argv)
    repeat = args.repeat or (2 if args.quick else 7)
    legs = args.legs or (1 if args.quick else 4)

    from atr_node.calibration.model import PerformanceModel
    from atr_node.config import Settings
    from atr_node.io.atrlog import AtrLogReader, AtrLogWriter
    from atr_node.node.pipeline import Pipeline
    from atr_node.records.nav import NavFix, NavTrack
    from atr_node.simulation.mission import generate_mission
    from hw.can_nav import CanNavDecoder
    from hw.decode import NavDecoder
    from hw.nmea_decoder import NmeaDecoder

    base = Settings()
    sim = dataclasses.replace(base.simulation, mission_legs=legs, mission_leg_length_m=100.0 if args.quick else 200.0,
                              mission_swath_m=20, mission_tile_pings=1024)
    settings = base.replace(simulation=sim)
    with tempfile.TemporaryDirectory(prefix="bench_ingest_") as tmp:
        files = generate_mission(settings, Path(tmp) / "m", seed=11)
        records = list(AtrLogReader(files.atrlog))
        nav = [r for r in records if r.link != "sonar"]
        nmea = [r for r in nav if r.link == "nmea"]
        can = [r for r in nav if r.link == "can"]
        nav_path = Path(tmp) / "nav.atrlog"
        with AtrLogWriter(nav_path, flush_every=1 << 20) as w:
            for r in nav:
                w.write(r.t, r.link, r.msg)
        print(f"mission: {len(records)} records ({len(nmea)} nmea, {len(can)} can, "
              f"{len(records) - len(nav)} tiles); best of {repeat} runs, CPU time")
        print(f"  {'stage':20s} {'records':>8s} {'cpu ms':>9s} {'records/s':>14s} {'us/rec':>9s}")

        def read(path: Path) -> Callable[[], int]:
            return lambda: sum(1 for _ in AtrLogReader(path))

        report("atrlog read (nav)", len(nav), best_cpu(read(nav_path), repeat, "atrlog read (nav)", len(nav)))
        report("atrlog read (all)", len(records), best_cpu(read(Path(files.atrlog)), repeat, "atrlog read (all)", len(records)))

        def nmea_run() -> None:
            d = NmeaDecoder()
            for r in nmea:
                d.feed(r.msg, r.t)

        def can_run() -> None:
            d = CanNavDecoder()
            for r in can:
                m = r.msg
                d.feed(m["id"], m["data"], m["ext"], r.t)

        def nav_run(keep: bool = False) -> list[Any]:
            # events are not kept while timed: holding 15k objects would time the GC, not the decoder
            d, out = NavDecoder(), []
            for r in nav:
                ev = d.feed(r)
                if keep:
                    out.extend(ev)
            return out

        def read_decode_run() -> None:
            d = NavDecoder()
            for r in AtrLogReader(nav_path):
                d.feed(r)

        report("nmea decode", len(nmea), best_cpu(nmea_run, repeat, "nmea decode", len(nmea)))
        report("can decode", len(can), best_cpu(can_run, repeat, "can decode", len(can)))
        report("nav decode", len(nav), best_cpu(nav_run, repeat, "nav decode", len(nav)))
        report("read + nav decode", len(nav), best_cpu(read_decode_run, repeat, "read + nav decode", len(nav)))
        fixes = [ev for ev in nav_run(keep=True) if isinstance(ev, NavFix)]

        def track_run() -> None:
            tr = NavTrack()
            for f in fixes:
                tr.add(f)

        report("navtrack add", len(fixes), best_cpu(track_run, repeat, "navtrack add", len(fixes)))
        model = PerformanceModel.shipped()

        # the first position fix builds the mission frame (pyproj, tens of ms once per run):
        # fed before the clock starts, so the figure is the steady per-record cost
        dec = NavDecoder()
        warm = next(i for i, r in enumerate(nav)
                    if any(isinstance(ev, NavFix) and ev.lat_deg is not None for ev in dec.feed(r)))
        timed = nav[warm + 1:]

        def pipe_run() -> None:
            p = Pipeline(settings, model=model, workers=0)
            try:
                for r in nav[:warm + 1]:
                    p.feed(r)
                t0 = time.process_time()
                for r in timed:
                    p.feed(r)
                pipe_run.cpu = time.process_time() - t0  # type: ignore[attr-defined]
            finally:
                p.close()

        feeds_s = []
        for _ in range(repeat):  # Pipeline construction is not ingest: time the feed loop only
            pipe_run()
            feeds_s.append(pipe_run.cpu)  # type: ignore[attr-defined]
        best = harness.record("pipeline feed (nav)", feeds_s, clock="process", work=len(timed),
                              work_unit="records").min_s
        report("pipeline feed (nav)", len(timed), max(best, 1e-9))
    return 0




# ================================================================================================
# Part "links" (was tools/bench/ingest.py links)
# ================================================================================================

LINKS_DOC = """Benchmark the link drivers (package ``hw``): codecs, transports, replay and pacing.

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
Usage: ``python tools/bench/ingest.py links [--quick] [--tile-size N] [--real-data DIR]``.
"""


import os
import threading
import uuid

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import can  # noqa: E402
import msgpack  # noqa: E402
import zmq  # noqa: E402

from atr_node.io.atrlog import AtrLogWriter  # noqa: E402
from atr_node.records.tile import Tile  # noqa: E402
from hw.can_link import CanLink  # noqa: E402
from hw.can_nav import CanNavDecoder, encode_altitude, encode_attitude, encode_leg, encode_position, encode_time  # noqa: E402
from hw.framing import LineFramer  # noqa: E402
from hw.hil import PtyNmeaOut  # noqa: E402
from hw.nmea import encode_gga, encode_hdt  # noqa: E402
from hw.nmea_decoder import NmeaDecoder  # noqa: E402
from hw.replay import Paced, ReplayLink, StampedNmeaLink  # noqa: E402
from hw.serial_nmea import SerialNmeaLink  # noqa: E402
from hw.zmq_sonar import ZmqTileLink  # noqa: E402

REAL = Path(os.environ.get("ATR_REAL_DATA", Path(__file__).resolve().parents[3] / "shared" / "data" / "real"))
ROWS_LINKS: list[tuple[str, str, str]] = []


def row(name: str, value: str, note: str = "") -> None:
    ROWS_LINKS.append((name, value, note))
    print(f"  {name:20s} {value:>22s}  {note}", flush=True)


def bench_codecs(n: int, real: Path) -> None:
    t = time.perf_counter()
    lines = [encode_gga(1.7e9 + 0.1 * k, 44.0 + 1e-6 * k, 9.8) for k in range(n)] + [encode_hdt(k % 360) for k in range(n)]
    dt = time.perf_counter() - t
    harness.record("links: nmea encode", [dt], work=2 * n, work_unit="sentences")
    row("nmea encode", f"{2 * n / dt:,.0f} /s")
    paths = sorted((real / "nmea").glob("NBP1406_*"))
    if paths:
        recs = [r for p in paths for r in StampedNmeaLink(p)]
        d = NmeaDecoder()
        t = time.perf_counter()
        for r in recs:
            d.feed(r.msg, r.t)
        dt = time.perf_counter() - t
        harness.record("links: nmea decode (real)", [dt], work=len(recs), work_unit="lines")
        row("nmea decode (real)", f"{len(recs) / dt:,.0f} lines/s", f"{len(recs)} lines, {d.counts['accepted']} accepted, "
            f"{d.rejected} rejected {dict((k, v) for k, v in d.counts.items() if k != 'accepted')}")
    else:
        row("nmea decode (real)", "skipped", f"no real data under {real}")
    stream = b"".join(lines)
    framer = LineFramer()
    t = time.perf_counter()
    got = sum(len(framer.feed(stream[i:i + 4096])) for i in range(0, len(stream), 4096))
    dt = time.perf_counter() - t
    harness.record("links: framer", [dt], work=len(stream), work_unit="bytes")
    row("framer", f"{len(stream) / dt / 1e6:,.1f} MB/s", f"{got} lines")
    frames = [encode_time(1.7e9), encode_position(44.0, 9.8), encode_attitude(90.0), encode_altitude(10.0), encode_leg(1)]
    dec = CanNavDecoder()
    t = time.perf_counter()
    for k in range(n):
        dec.feed(*frames[k % 5], 1.7e9)
    dt = time.perf_counter() - t
    harness.record("links: can decode", [dt], work=n, work_unit="frames")
    row("can decode", f"{n / dt:,.0f} frames/s")


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
    harness.record("links: pty serial", [dt], work=got, work_unit="lines")
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
    harness.record("links: virtual can", [dt], work=got, work_unit="frames")
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
    harness.record("links: zmq tiles", [dt], work=got, work_unit="tiles")
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
    harness.record("links: replay max", [dt], work=got, work_unit="records")
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


def main_links(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=LINKS_DOC.split("\n\n")[0],
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
    for name, value, note in ROWS_LINKS:
        print(f"| {name} | {value} | {note} |")
    return 0




# ================================================================================================
# Part "xtf" (was tools/bench/ingest.py xtf)
# ================================================================================================

XTF_DOC = """Throughput of the XTF reader, writer and conversions on a recording (default: the Iver2 file).

Prints one row per stage: best wall time over the repetitions, pings per second and MB/s of
XTF. Stages: read (XTF -> records, tiles packed as ICD maps), read+sonar-altitude (with bottom
tracking), write (tiles -> XTF), xtf->atrlog and atrlog->xtf (files on disk, as
``atr-node convert``), ground (slant -> ground range of every tile).

    python tools/bench/ingest.py xtf                # 5 repetitions
    python tools/bench/ingest.py xtf --quick        # 1 repetition
"""



sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from atr_node.commands.convert import atrlog_to_xtf, xtf_to_atrlog  # noqa: E402
from atr_node.io.xtf import XtfReader  # noqa: E402
from atr_node.io.xtf_write import XtfWriter  # noqa: E402

DEFAULT = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "xtf" / "scotsman-iver2.xtf"


def best_of(fn, repeat: int, name: str = "call", pings: int | None = None) -> float:
    """Best wall time of ``repeat`` runs (no warm-up: a file read once is what a user sees),
    through the harness under ``name``."""
    return harness.measure(name, fn, repeat=repeat, warmup=0, clock="wall", work=pings, work_unit="pings").min_s


def main_xtf(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=XTF_DOC, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("xtf", nargs="?", default=str(DEFAULT), help=f"XTF file (default {DEFAULT.name})")
    ap.add_argument("--repeat", type=int, default=5, help="repetitions per stage (best is kept)")
    ap.add_argument("--quick", action="store_true", help="one repetition")
    args = ap.parse_args(argv)
    repeat = 1 if args.quick else max(args.repeat, 1)
    path = Path(args.xtf)
    mb = path.stat().st_size / 1e6
    reader = XtfReader(path)
    tiles = [Tile.from_map(r.msg) for r in reader if r.link == "sonar"]
    pings = reader.stats.pings
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)

        def write() -> None:
            with XtfWriter(tmp / "w.xtf") as w:
                for t in tiles:
                    w.write_tile(t)

        xtf_to_atrlog(path, tmp / "c.atrlog", tile_pings=256, mission=None, leg=None)
        stages = [
            ("read", lambda: list(XtfReader(path))),
            ("read+sonar-altitude", lambda: list(XtfReader(path, altitude="sonar"))),
            ("write", write),
            ("xtf->atrlog", lambda: xtf_to_atrlog(path, tmp / "a.atrlog", tile_pings=256, mission=None, leg=None)),
            ("atrlog->xtf", lambda: atrlog_to_xtf(tmp / "c.atrlog", tmp / "b.xtf")),
            ("ground", lambda: [t.ground_range() for t in tiles if t.nav is not None]),
        ]
        print(f"{path.name}: {pings} pings, {len(tiles)} tiles, {mb:.2f} MB; best of {repeat}")
        print(f"{'stage':<22}{'time ms':>10}{'pings/s':>12}{'MB/s':>8}")
        for name, fn in stages:
            t = best_of(fn, repeat, f"xtf {name}", pings)
            print(f"{name:<22}{t * 1e3:>10.1f}{pings / t:>12.0f}{mb / t:>8.1f}")
    return 0


PARTS = {"nav": main_nav, "links": main_links, "xtf": main_xtf}


def main(argv: list[str] | None = None) -> int:  # a part, every part, or the first with options
    return harness.subject_main(__doc__, PARTS, argv)


if __name__ == "__main__":
    raise SystemExit(main())
