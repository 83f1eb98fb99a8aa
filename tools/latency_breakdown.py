#!/usr/bin/env python3
"""Where the node's tile latency goes (issue 7): the latency run of ``tools/bench_node.py``,
with each unit's stage times (``atr_node.node.timing``).

A one-leg mission of large tiles (default 4096 pings x 2001 bins, about 8 Mpx) replayed paced
in live mode, the worker started and warmed up first, as ``bench_node.py`` does. Prints, per
unit, the seconds spent in each stage from the arrival of the tile that released it to its
evidence being published, then the median and maximum per stage:

    ingest      tile decode, nav merge, strip assembly (main process)
    submit      background trackers, job built and handed to the worker
    worker      transfer, queueing behind the other side's unit, detection (det_s of it)
    wait_main   result ready, main process busy elsewhere (fusing the other side)
    deposit     EvidenceGrid.add_observation
    contacts    contact extraction and publishing
    other_fuse  the rest of fusion (coverage unpacked, confidence, georeferencing)

Figures on a loaded machine are indicative only. ``--quick``: small tiles (a smoke run).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small tiles (a smoke run)")
    ap.add_argument("--tile-pings", type=int, default=4096, help="pings per tile")
    ap.add_argument("--swath-m", type=float, default=200.0, help="swath per side (m)")
    ap.add_argument("--interval-s", type=float, default=4.0, help="seconds between tiles")
    ap.add_argument("--warm-up-s", type=float, default=2.0, help="seconds between node start and first tile")
    ap.add_argument("--json", metavar="FILE", help="write the per-unit stage times as JSON")
    args = ap.parse_args(argv)

    from atr_node.calibration.model import PerformanceModel
    from atr_node.config import Settings
    from atr_node.io.atrlog import read_atrlog
    from atr_node.node.service import NodeService
    from atr_node.node.timing import STAGES, breakdown
    from atr_node.simulation.mission import generate_mission
    from hw.replay import IterLink, Paced

    base = Settings()
    pings = 512 if args.quick else args.tile_pings
    swath = 40.0 if args.quick else args.swath_m
    sim = dataclasses.replace(base.simulation, mission_legs=1, mission_leg_length_m=2.2 * pings * base.sensor.dx_m,
                              mission_swath_m=swath, mission_tile_pings=pings, mission_targets=4)
    s = base.replace(simulation=sim)
    with tempfile.TemporaryDirectory() as tmp:
        files = generate_mission(s, Path(tmp) / "m", seed=12, links=False)
        recs = list(read_atrlog(files.atrlog))
    speed = pings * base.sensor.dx_m / sim.mission_speed_m_s / args.interval_s
    svc = NodeService(s, model=PerformanceModel.shipped(), mode="live", workers=1)
    try:
        t0 = time.monotonic()
        time.sleep(args.warm_up_s)  # the worker starts and warms up before the first tile, as aboard
        warm = svc.pipeline.warming
        warm_s = "done" if warm.done() else f"done after more than {args.warm_up_s:g} s"
        svc.pipeline.wait_ready(timeout=300)  # as tools/bench_node.py: a node starts before the survey's first tile
        svc.run_live(Paced(IterLink(iter(recs)), speed), finish_at_end=True)
        stages = list(svc.pipeline.stats.stages)
        p50, p99 = svc.pipeline.stats.latency_ms()
    finally:
        svc.close()
    print(f"{len(recs)} tiles of {pings} x {round(swath / base.sensor.dr_m) + 1} px, one every {args.interval_s:g} s; "
          f"worker warm-up {warm_s} ({time.monotonic() - t0:.0f} s run)")
    head = f"{'unit':>12s} {'rows':>5s} " + " ".join(f"{k:>10s}" for k in STAGES) + f" {'det_s':>7s}"
    print(head)
    for u in stages:
        iv = u.intervals()
        print(f"{u.side + ' ' + str(u.seq):>12s} {u.rows:5d} " + " ".join(f"{iv[k]:10.3f}" for k in STAGES)
              + f" {u.detect_s:7.3f}")
    bd = breakdown(stages)
    print(f"{'median':>12s} {'':5s} " + " ".join(f"{bd[k][0]:10.3f}" for k in STAGES))
    print(f"{'max':>12s} {'':5s} " + " ".join(f"{bd[k][1]:10.3f}" for k in STAGES))
    print(f"heartbeat latency: p50 {p50:.0f} ms, p99 {p99:.0f} ms (target p99 < 1000 ms)")
    if args.json:
        Path(args.json).write_text(json.dumps([{**dataclasses.asdict(u), **u.intervals()} for u in stages], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
