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
Usage: ``python tools/bench_ingest.py [--quick] [--repeat N] [--legs N]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

ROWS: list[tuple[str, int, float]] = []


def best_cpu(fn: Callable[[], Any], repeat: int) -> float:
    """Smallest CPU time (s) of ``repeat`` calls of ``fn``."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return max(best, 1e-9)


def report(name: str, n: int, cpu_s: float) -> None:
    ROWS.append((name, n, cpu_s))
    print(f"  {name:20s} {n:8d} {cpu_s * 1e3:9.2f} {n / cpu_s:14,.0f} {cpu_s / n * 1e6:9.2f}", flush=True)


def main(argv: list[str] | None = None) -> int:
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
    from hw.nmea import NmeaDecoder

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

        report("atrlog read (nav)", len(nav), best_cpu(read(nav_path), repeat))
        report("atrlog read (all)", len(records), best_cpu(read(Path(files.atrlog)), repeat))

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

        report("nmea decode", len(nmea), best_cpu(nmea_run, repeat))
        report("can decode", len(can), best_cpu(can_run, repeat))
        report("nav decode", len(nav), best_cpu(nav_run, repeat))
        report("read + nav decode", len(nav), best_cpu(read_decode_run, repeat))
        fixes = [ev for ev in nav_run(keep=True) if isinstance(ev, NavFix)]

        def track_run() -> None:
            tr = NavTrack()
            for f in fixes:
                tr.add(f)

        report("navtrack add", len(fixes), best_cpu(track_run, repeat))
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

        best = float("inf")
        for _ in range(repeat):  # Pipeline construction is not ingest: time the feed loop only
            pipe_run()
            best = min(best, pipe_run.cpu)  # type: ignore[attr-defined]
        report("pipeline feed (nav)", len(timed), max(best, 1e-9))
    return 0


if __name__ == "__main__":
    sys.exit(main())
