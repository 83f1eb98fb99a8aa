#!/usr/bin/env python3
"""Soak: a long generated mission replayed at full speed through the node, memory and queues sampled.

The mission (``--legs`` legs of ``--leg-length-m`` metres) is generated once, then replayed as
fast as possible through :class:`atr_node.node.service.NodeService` (the pipeline, the
detection worker process, snapshots every ``node.snapshot_every_tiles`` tiles and a PUB socket,
as aboard). A sampler thread records every ``--sample-s`` seconds: the resident memory of the
node process and of its worker process (VmRSS), the queue depth (units in the worker plus
tiles held for nav), tiles in, the evidence grid's bytes and the INS fixes held.

Bounded means: the queue depth never exceeds its bound (``node.queue_tiles`` units in the
worker plus the nav merger's 64 held tiles), and over the second half of the run the memory
that is not the evidence grid (which grows with the area surveyed, by design) grows by less
than ``--max-growth-mb``; the INS fixes held are reported too (they must not grow with the
mission's duration).

Examples::

    python tools/soak/soak.py --quick                          # 2 short legs, seconds
    python tools/soak/soak.py                                  # 24 legs of 300 m, about 1000 tiles
    python tools/soak/soak.py --legs 80 --leg-length-m 500 --json soak.json
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

PAGE_KB = 1


def rss_kb(pid: int | str = "self") -> int:
    """Resident set size of a process, kB (0 when it is gone)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def children(pid: int) -> list[int]:
    """Child processes of ``pid`` (every thread's children)."""
    out: list[int] = []
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            try:
                out += [int(x) for x in open(f"/proc/{pid}/task/{task}/children").read().split()]
            except OSError:
                pass
    except OSError:
        pass
    return out


@dataclass(frozen=True)
class Sample:
    t_s: float
    tiles_in: int
    rss_node_mb: float
    rss_children_mb: float
    queue_depth: int
    held: int
    grid_mb: float
    nav_fixes_held: int

    @property
    def rss_total_mb(self) -> float:
        return self.rss_node_mb + self.rss_children_mb


def _nav_held(track) -> int:
    return int(track._pos.n + track._hdg.n + track._alt.n)


def soak(log: Path, settings, work: Path, *, sample_s: float = 0.5, workers: int = 1) -> tuple[list[Sample], dict]:
    """Replay ``log`` at full speed through a NodeService; return the samples and its summary."""
    from atr_node.calibration.model import PerformanceModel
    from atr_node.io.atrlog import read_atrlog
    from atr_node.node.service import NodeService

    service = NodeService(settings, model=PerformanceModel.shipped(), mode="replay", workers=workers,
                          publish="tcp://127.0.0.1:*", state_dir=work / "state", source_name=str(log))
    samples: list[Sample] = []
    stop = threading.Event()
    t0 = time.monotonic()
    pid = os.getpid()

    def take() -> None:
        p = service.pipeline
        grid = sum(p.grid.nbytes().values()) / 2**20
        samples.append(Sample(time.monotonic() - t0, p.stats.tiles_in, rss_kb() / 1024,
                              sum(rss_kb(c) for c in children(pid)) / 1024, p.queue_depth, p.merger.held, grid,
                              _nav_held(p.track)))

    def sampler() -> None:
        while not stop.wait(sample_s):
            try:
                take()
            except (RuntimeError, ValueError):  # a structure resized while read: skip this sample
                pass

    th = threading.Thread(target=sampler, name="soak-sampler", daemon=True)
    take()  # the first and the last sample do not depend on how fast the replay runs
    th.start()
    try:
        service.run(read_atrlog(log))
        take()
        summary = service.summary()
    finally:
        stop.set()
        th.join(timeout=5)
        service.close()
    summary["wall_s"] = time.monotonic() - t0
    return samples, summary


def verdict(samples: list[Sample], settings, *, max_growth_mb: float) -> dict:
    """Bounds and growth over the run (second half against the middle)."""
    a = {k: np.array([getattr(s, k) for s in samples], dtype=float)
         for k in ("t_s", "tiles_in", "rss_node_mb", "rss_children_mb", "queue_depth", "grid_mb", "nav_fixes_held")}
    total = a["rss_node_mb"] + a["rss_children_mb"]
    non_grid = total - a["grid_mb"]
    mid = len(samples) // 2
    q_bound = settings.node.queue_tiles + 1 + 64
    growth = float(non_grid[-1] - non_grid[mid]) if samples else 0.0
    return {
        "samples": len(samples), "tiles": int(a["tiles_in"][-1]) if samples else 0,
        "rss_total_mb": (float(total.min()), float(total.max()), float(total[-1])) if samples else (0, 0, 0),
        "rss_node_mb": (float(a["rss_node_mb"].min()), float(a["rss_node_mb"].max()), float(a["rss_node_mb"][-1])),
        "rss_worker_mb": (float(a["rss_children_mb"].min()), float(a["rss_children_mb"].max()),
                          float(a["rss_children_mb"][-1])),
        "grid_mb": (float(a["grid_mb"].min()), float(a["grid_mb"].max()), float(a["grid_mb"][-1])),
        "non_grid_growth_second_half_mb": growth,
        "queue_depth": (int(a["queue_depth"].min()), int(a["queue_depth"].max()), int(a["queue_depth"][-1])),
        "queue_bound": q_bound,
        "nav_fixes_held": (int(a["nav_fixes_held"].min()), int(a["nav_fixes_held"].max()),
                           int(a["nav_fixes_held"][-1])),
        "nav_fixes_held_mid": int(a["nav_fixes_held"][mid]) if samples else 0,
        "queue_bounded": bool(a["queue_depth"].max() <= q_bound) if samples else True,
        "memory_bounded": growth < max_growth_mb,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--legs", type=int, default=24, help="mission legs (default 24)")
    ap.add_argument("--leg-length-m", type=float, default=300.0, help="leg length (default 300 m)")
    ap.add_argument("--swath-m", type=float, default=40.0, help="swath per side (default 40 m)")
    ap.add_argument("--quick", action="store_true", help="2 legs of 70 m (a smoke run)")
    ap.add_argument("--sample-s", type=float, default=0.5, help="sampling period (default 0.5 s)")
    ap.add_argument("--workers", type=int, choices=(0, 1), default=1)
    ap.add_argument("--max-growth-mb", type=float, default=25.0,
                    help="largest growth of the non-grid memory over the second half (default 25 MB)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--workdir", type=Path, help="keep the mission and state here (default: a temporary folder)")
    ap.add_argument("--json", metavar="FILE", help="write the verdict and every sample as JSON")
    args = ap.parse_args(argv)
    if args.quick:
        args.legs, args.leg_length_m, args.swath_m, args.sample_s = 2, 70.0, 30.0, min(args.sample_s, 0.2)
    import dataclasses
    import logging

    from atr_node.config import Settings
    from atr_node.simulation.mission import generate_mission

    node_log = logging.getLogger("atr_node")
    level = node_log.level
    node_log.setLevel(logging.ERROR)  # the node's warnings would drown the table
    base = Settings()
    settings = base.replace(simulation=dataclasses.replace(base.simulation, mission_legs=args.legs,
                                                           mission_leg_length_m=args.leg_length_m,
                                                           mission_swath_m=args.swath_m, mission_targets=4 * args.legs,
                                                           mission_tile_pings=128),
                            node=dataclasses.replace(base.node, snapshot_every_tiles=50))
    work = args.workdir or Path(tempfile.mkdtemp(prefix="atr-soak-"))
    try:
        t0 = time.monotonic()
        files = generate_mission(settings, work / "mission", seed=args.seed)
        gen_s = time.monotonic() - t0
        samples, summary = soak(files.atrlog, settings, work, sample_s=args.sample_s, workers=args.workers)
    finally:
        node_log.setLevel(level)
        if args.workdir is None:
            shutil.rmtree(work, ignore_errors=True)
    v = verdict(samples, settings, max_growth_mb=args.max_growth_mb)
    print(f"soak: {args.legs} legs x {args.leg_length_m:g} m, {files.tiles} tiles, {files.records} records "
          f"({files.duration_s / 60:.0f} min of mission), generated in {gen_s:.0f} s, replayed in "
          f"{summary['wall_s']:.0f} s at max speed; workers {args.workers}; machine load {os.getloadavg()[0]:.1f} "
          f"(2 cores, shared)")
    print(f"| {'quantity':<34} | {'min':>9} | {'max':>9} | {'final':>9} |\n|{'-' * 36}|{'-' * 11}|{'-' * 11}|{'-' * 11}|")
    for name, key in [("RSS node + worker (MB)", "rss_total_mb"), ("RSS node (MB)", "rss_node_mb"),
                      ("RSS worker (MB)", "rss_worker_mb"), ("evidence grid (MB)", "grid_mb"),
                      ("queue depth (units + held tiles)", "queue_depth"), ("INS fixes held", "nav_fixes_held")]:
        lo, hi, fin = v[key]
        print(f"| {name:<34} | {lo:>9.1f} | {hi:>9.1f} | {fin:>9.1f} |")
    print(f"samples {v['samples']}; queue bound {v['queue_bound']}: "
          f"{'bounded' if v['queue_bounded'] else 'EXCEEDED'}; non-grid memory growth over the second half "
          f"{v['non_grid_growth_second_half_mb']:+.1f} MB (limit {args.max_growth_mb:g}): "
          f"{'bounded' if v['memory_bounded'] else 'GROWING'}; INS fixes held at mid-run {v['nav_fixes_held_mid']}, "
          f"at the end {v['nav_fixes_held'][2]}")
    print(f"tiles in {summary['tiles_in']}, done {summary['tiles_done']}, rejected {summary['tiles_rejected']}, "
          f"snapshots {summary['snapshots']}, contacts {summary['contacts']}")
    if args.json:
        Path(args.json).write_text(json.dumps({"verdict": v, "summary": summary,
                                               "samples": [dataclasses.asdict(s) for s in samples]}, indent=1,
                                              default=str))
    return 0 if v["queue_bounded"] and v["memory_bounded"] else 1


if __name__ == "__main__":
    sys.exit(main())
