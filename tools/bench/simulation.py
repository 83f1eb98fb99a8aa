"""Benchmark of the target simulation (SPEC section 4), on one core.

1. The signature engine: signatures per CPU second for 2 m targets (cylinder, cone, wedge;
   random heading, 10-90 m range) at 10 cm pixels, traced 40 at a time as an injection
   traces a tile's targets (``trace_window`` of each placed mesh, then one ``trace_many``):
   each engine (``rays``: k x k sub-rays; ``strips``: k sub-row strips exact along range) at
   k = 1, 2, 4, with the error of its proportion maps against the fine trace (16 x 16
   sub-rays): mean over targets of the L1 error relative to the fine map's total, for the
   shadow and for the echo. Also the old one-target tracer (``dense``, every plane x
   segment x ray tested) at k = 2, the reference the ``rays`` engine matches bit for bit.
2. Whole signatures: ``inject_targets`` of 40 given placements (windows, trace, SAS beam,
   gray levels, speckle, blend into a tile), per CPU second.
3. Mission generation: the default demo mission (``--quick``: a 2-leg mission).

    python tools/bench/simulation.py [--quick] [--seed 0]

OpenCV runs on one thread (``cv2.setNumThreads(1)``); the tracer is numpy element-wise work,
where BLAS threads play no part. Figures taken on a shared machine are indicative only.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import tempfile
import time

import cv2
import numpy as np

from atr_node.config import Settings, SimulationSettings
from atr_node.simulation.inject import Placement, inject_targets
from atr_node.simulation.meshes import builtin_mesh, place
from atr_node.simulation.mission import generate_mission
from atr_node.simulation.raytrace import trace_many, trace_window
from atr_node.simulation.seabed import seabed_pixels
from pathlib import Path  # noqa: E402
sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402  (tools/bench/harness.py: repeats, warm-up, statistics, JSON)
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "simulation"))
from dense_trace import dense_trace, l1_error  # noqa: E402  (the one-target tracer the engine replaced)

H, DR, DX = 14.0, 0.1, 0.1
SHAPES = ("cylinder", "cone", "wedge")


def _cases(rng: np.random.Generator, n: int) -> list[tuple[str, float, float]]:
    return [(SHAPES[i % 3], float(rng.uniform(10, 90)), float(rng.uniform(0, 360))) for i in range(n)]


ROWS, COLS, BATCH = 64, 1000, 40
GEO = dict(range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H)


def _engine(placed: list, k: int, engine: str) -> list:
    """Signatures of the placed meshes, BATCH at a time, windows included."""
    out = []
    for s in range(0, len(placed), BATCH):
        ws = [trace_window(m, rows=ROWS, cols=COLS, **GEO) for m in placed[s:s + BATCH]]
        out += trace_many(ws, subrays=k, engine=engine, **GEO)
    return out


def bench_engine(rng: np.random.Generator, n: int, n_err: int, reps: int) -> list[tuple[str, int, float, float, float]]:
    """(engine, k, signatures per CPU second, shadow error, echo error) per engine and k."""
    meshes = {s: builtin_mesh(s) for s in SHAPES}
    placed = [place(meshes[s], along_m=3.2, range_m=r, heading_deg=h) for s, r, h in _cases(rng, n)]
    fine = [dense_trace(m, rows=ROWS, cols=COLS, subrays=16, **GEO) for m in placed[:n_err]]
    rows = []
    for engine, k in [("dense", 2)] + [(e, k) for e in ("rays", "strips") for k in (1, 2, 4)]:
        if engine == "dense":
            def run(m=placed[:n // 4]):
                return [dense_trace(x, rows=ROWS, cols=COLS, subrays=k, **GEO) for x in m]
            count = n // 4
        else:
            def run(e=engine, kk=k):
                return _engine(placed, kk, e)
            count = n
        best = math.inf
        for _ in range(reps):
            t0 = time.process_time()
            sigs = run()
            best = min(best, time.process_time() - t0)
        rate = count / best
        harness.record(f"signature engine {engine}, k = {k}, {count} signatures", [best], clock="process", work=count,
                       work_unit="signatures")
        es, ee = l1_error(sigs[:n_err], fine)
        harness.value(f"signature engine {engine}, k = {k}: error against 16 x 16 sub-rays (shadow, echo)", [es, ee])
        rows.append((engine, k, rate, es, ee))
    return rows


def bench_whole(rng: np.random.Generator, n: int) -> float:
    """Whole signatures per CPU second: inject_targets of BATCH given placements per call."""
    meshes = {s: builtin_mesh(s) for s in SHAPES}
    host = seabed_pixels(rows=ROWS * 4, cols=COLS, range0_m=0.0, dr_m=DR, altitude_m=H, rng=rng)
    g = np.ones(COLS)
    cases = _cases(rng, n)
    t0 = time.process_time()
    for s in range(0, n, BATCH):
        pl = [Placement(sh, row=16.0 + 6.0 * (i % 40), range_m=r, heading_deg=h, mesh=meshes[sh])
              for i, (sh, r, h) in enumerate(cases[s:s + BATCH])]
        inject_targets(host, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, rng=rng, g=g, placements=pl)
    dt = time.process_time() - t0
    harness.record(f"whole signature (inject_targets, {BATCH} a call), {n}", [dt], clock="process", work=n,
                   work_unit="signatures")
    return n / dt


def bench_mission(quick: bool, seed: int) -> tuple[str, float, int]:
    s = Settings()
    if quick:
        s = s.replace(simulation=dataclasses.replace(SimulationSettings(), mission_legs=2, mission_leg_length_m=100.0))
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        f = generate_mission(s, d, seed=seed)
        dt = time.perf_counter() - t0
    harness.record("mission generation", [dt], clock="wall", work=f.records, work_unit="records")
    sim = s.simulation
    what = (f"{sim.mission_legs} legs x {sim.mission_leg_length_m:.0f} m, swath {sim.mission_swath_m:.0f} m/side, "
            f"{f.targets} targets, {f.clutter_objects} rocks, {f.tiles} tiles")
    return what, dt, f.records


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer signatures, a smaller mission (a smoke run)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    rng = np.random.default_rng(args.seed)
    n = 80 if args.quick else 800
    rows = bench_engine(rng, n, 12 if args.quick else 120, 1 if args.quick else 3)
    print(f"signature engine, one core: 2 m targets (cylinder/cone/wedge, 10-90 m), 10 cm pixels, {BATCH} a batch,")
    print("windows included; error: mean L1 of the maps against 16 x 16 sub-rays, relative to their totals")
    print(f"  {'engine':<8}{'k':>3}{'sig/CPU s':>12}{'shadow err':>12}{'echo err':>10}")
    for engine, k, rate, es, ee in rows:
        print(f"  {engine:<8}{k:>3}{rate:>12.0f}{es:>12.1%}{ee:>10.1%}")
    whole = bench_whole(rng, n)
    print(f"whole signatures (inject_targets, {BATCH} placements a call, rays k = 2): {whole:.0f} per CPU second")
    print()
    what, dt, recs = bench_mission(args.quick, args.seed)
    print(f"mission generation: {what}: {dt:.2f} s ({recs} records)")
    return 0



if __name__ == "__main__":
    raise SystemExit(main())
