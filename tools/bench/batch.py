#!/usr/bin/env python3
"""Benchmark of ``atr-node batch`` (issue 11): N generated missions, local Dask cluster vs serial.

Generates ``--missions`` missions (``generate_mission``, seeds 1..N, same field), then runs
the command twice through the real CLI (a fresh process each, start-up included):

1. ``atr-node batch ... --scheduler serial`` (one process: the same code path, no Dask);
2. ``atr-node batch ... --workers W`` (a ``LocalCluster`` of W processes x 1 thread, started
   and stopped inside the timed command).

and prints a table of wall time, map and reduce time, tiles, deltas and contacts, and checks
that the two runs wrote identical contacts. The figures of a shared machine are indicative
only: rerun on a quiet one.

    python tools/bench/batch.py                 # 8 missions, 2 workers
    python tools/bench/batch.py --quick         # 2 tiny missions (smoke run)
    python tools/bench/batch.py --missions 16 --workers 4 --keep /tmp/missions
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402  (tools/bench/harness.py: repeats, warm-up, statistics, JSON)

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # one core per worker: no hidden BLAS threads

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

MISSION = """
[simulation]
mission_legs = {legs}
mission_leg_length_m = {length}
mission_swath_m = 30.0
mission_targets = 5
mission_tile_pings = 128
mission_clutter_per_km2 = 1000.0
"""


def generate(folder: Path, n: int, legs: int, length_m: float) -> tuple[Path, list[Path]]:
    from atr_node.config import load_settings
    from atr_node.simulation.mission import generate_mission

    cfg = folder / "bench.toml"
    cfg.write_text(MISSION.format(legs=legs, length=length_m))
    settings = load_settings(cfg)
    return cfg, [generate_mission(settings, folder / f"m{s:02d}", seed=s).atrlog for s in range(1, n + 1)]


def run_batch(cfg: Path, logs: list[Path], out: Path, extra: list[str]) -> dict:
    summary = out.with_suffix(".json")
    cmd = [sys.executable, "-m", "atr_node", "batch", *map(str, logs), "--config", str(cfg), "--quiet",
           "--contacts-out", str(out), "--summary", str(summary), *extra]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    harness.record(f"atr-node batch {' '.join(extra)}, {len(logs)} missions (one process)", [wall], clock="wall",
                   work=len(logs), work_unit="missions")
    if r.returncode != 0:
        raise SystemExit(f"batch failed ({' '.join(cmd)}):\n{r.stderr}")
    s = json.loads(summary.read_text())
    s["process_wall_s"] = wall
    return s


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--missions", type=int, default=8, help="generated missions (default 8)")
    ap.add_argument("--legs", type=int, default=3, help="legs per mission (default 3)")
    ap.add_argument("--length-m", type=float, default=70.0, help="leg length (default 70 m)")
    ap.add_argument("--workers", type=int, default=2, help="local cluster workers (default 2)")
    ap.add_argument("--keep", metavar="DIR", help="generate into DIR and keep it (default: a temporary folder)")
    ap.add_argument("--quick", action="store_true", help="2 missions of 2 x 40 m legs (smoke run)")
    args = ap.parse_args(argv)
    if args.quick:
        args.missions, args.legs, args.length_m = 2, 2, 40.0
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        folder = Path(args.keep) if args.keep else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        cfg, logs = generate(folder, args.missions, args.legs, args.length_m)
        gen_s = time.perf_counter() - t0
        load = os.getloadavg()
        serial = run_batch(cfg, logs, folder / "serial.jsonl", ["--scheduler", "serial"])
        dask = run_batch(cfg, logs, folder / "dask.jsonl", ["--workers", str(args.workers)])
        same = (folder / "serial.jsonl").read_text() == (folder / "dask.jsonl").read_text()
        load_after = os.getloadavg()
    print(f"{args.missions} missions x {args.legs} legs x {args.length_m:.0f} m generated in {gen_s:.1f} s; "
          f"{serial['tiles_in']} tiles, {serial['pixels'] / 1e6:.1f} Mpx, {serial['deltas']} deltas")
    print(f"load average before {load[0]:.2f}, after {load_after[0]:.2f} (on {os.cpu_count()} cores; "
          f"a shared machine gives indicative figures only)")
    print()
    print("| run | wall (process) s | map s | reduce s | sum of task wall s | sum of task CPU s | contacts |")
    print("|---|---|---|---|---|---|---|")
    for name, s in (("serial (one process)", serial), (f"local Dask, {args.workers} workers", dask)):
        print(f"| {name} | {s['process_wall_s']:.1f} | {s['map_s']:.1f} | {s['reduce_s']:.2f} | {s['task_s']:.1f} "
              f"| {s['task_cpu_s']:.1f} | {s['contacts']} |")
    print()
    print(f"speed-up (process wall): {serial['process_wall_s'] / dask['process_wall_s']:.2f} x; "
          f"map phase: {serial['map_s'] / max(dask['map_s'], 1e-9):.2f} x")
    print(f"identical contacts: {'yes' if same else 'NO'}")
    return 0 if same else 1



if __name__ == "__main__":
    raise SystemExit(main())
