"""Benchmark of the target simulation (SPEC section 4), on one core.

1. Signatures per second: a 2 m target (cylinder, cone, wedge; random heading, 10-90 m range)
   at 10 cm pixels with 2 x 2 sub-rays: the ray trace alone, and the whole signature (trace,
   SAS beam, gray levels, speckle, blend into a tile) as ``inject_targets`` makes it.
2. Error against run time for the sub-ray count: proportion maps at k = 1, 2, 4 against
   k = 8 (mean |p_shadow - p_shadow(8)| over the footprint, relative to the k = 8 shadow area;
   relative error of the echo total), with the time per trace.
3. Mission generation: the default demo mission (``--quick``: a 2-leg mission).

    python tools/bench/simulation.py [--quick] [--seed 0]

OpenCV runs on one thread (``cv2.setNumThreads(1)``); the tracer is numpy element-wise work,
where BLAS threads play no part. Figures taken on a shared machine are indicative only.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time

import cv2
import numpy as np

from atr_node.config import Settings, SimulationSettings
from atr_node.simulation.inject import Placement, inject_targets
from atr_node.simulation.meshes import builtin_mesh, place
from atr_node.simulation.mission import generate_mission
from atr_node.simulation.raytrace import trace
from atr_node.simulation.seabed import seabed_pixels
from pathlib import Path  # noqa: E402
sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402  (tools/bench/harness.py: repeats, warm-up, statistics, JSON)

H, DR, DX = 14.0, 0.1, 0.1
SHAPES = ("cylinder", "cone", "wedge")


def _cases(rng: np.random.Generator, n: int) -> list[tuple[str, float, float]]:
    return [(SHAPES[i % 3], float(rng.uniform(10, 90)), float(rng.uniform(0, 360))) for i in range(n)]


def _clock() -> tuple[float, float]:
    return time.perf_counter(), time.process_time()


def _rate(n: int, t0: tuple[float, float]) -> tuple[float, float]:
    """(per wall second, per CPU second) since t0."""
    w, c = _clock()
    return n / (w - t0[0]), n / max(c - t0[1], 1e-9)


def bench_signatures(rng: np.random.Generator, n: int) -> tuple[tuple[float, float], tuple[float, float]]:
    rows, cols = 64, 1000
    meshes = {s: builtin_mesh(s) for s in SHAPES}
    cases = _cases(rng, n)
    placed = [place(meshes[s], along_m=3.2, range_m=r, heading_deg=h) for s, r, h in cases]
    t0 = _clock()
    for m in placed:
        trace(m, range0_m=0.0, dr_m=DR, dx_m=DX, rows=rows, cols=cols, altitude_m=H, subrays=2)
    r_trace = _rate(n, t0)
    harness.record(f"ray trace, {n} signatures", [n / r_trace[1]], clock="process", work=n, work_unit="signatures")
    host = seabed_pixels(rows=rows, cols=cols, range0_m=0.0, dr_m=DR, altitude_m=H, rng=rng)
    g = np.ones(cols)
    t0 = _clock()
    for s, r, h in cases:
        inject_targets(host, range0_m=0.0, dr_m=DR, dx_m=DX, altitude_m=H, rng=rng, g=g,
                       placements=[Placement(s, row=32.0, range_m=r, heading_deg=h, mesh=meshes[s])])
    r_whole = _rate(n, t0)
    harness.record(f"whole signature (inject_targets), {n}", [n / r_whole[1]], clock="process", work=n,
                   work_unit="signatures")
    return r_trace, r_whole


def bench_subrays(rng: np.random.Generator, n: int, reps: int) -> list[tuple[int, float, float, float]]:
    rows, cols = 64, 1000
    cases = [place(builtin_mesh(s), along_m=3.2, range_m=r, heading_deg=h) for s, r, h in _cases(rng, n)]
    kw = dict(range0_m=0.0, dr_m=DR, dx_m=DX, rows=rows, cols=cols, altitude_m=H)

    def full(sig):
        ps, ec = np.zeros((rows, cols)), np.zeros((rows, cols))
        r0, r1, c0, c1 = sig.footprint
        ps[r0:r1, c0:c1], ec[r0:r1, c0:c1] = sig.p_shadow, sig.echo
        return ps, ec

    ref = [full(trace(m, subrays=8, **kw)) for m in cases]
    out = []
    for k in (1, 2, 4, 8):
        t0 = time.process_time()
        for _ in range(reps):
            sigs = [trace(m, subrays=k, **kw) for m in cases]
        dt = (time.process_time() - t0) / (reps * n)
        harness.record(f"trace, {k} x {k} sub-rays (per signature)", [dt], clock="process")
        e_sh, e_ec = [], []
        for sig, (rps, rec) in zip(sigs, ref):
            ps, ec = full(sig)
            e_sh.append(np.abs(ps - rps).sum() / max(rps.sum(), 1e-9))
            e_ec.append(abs(ec.sum() - rec.sum()) / max(rec.sum(), 1e-9))
        out.append((k, dt * 1e3, float(np.mean(e_sh)), float(np.mean(e_ec))))
    return out


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
    n = 60 if args.quick else 600
    trace_s, full_s = bench_signatures(rng, n)
    print(f"signatures per second, one core, 2 m targets (cylinder/cone/wedge), 10 cm pixels, 2 x 2 sub-rays, n = {n}")
    print(f"  {'stage':<44}{'per wall s':>12}{'per CPU s':>12}")
    print(f"  {'ray trace (proportion maps)':<44}{trace_s[0]:>12.0f}{trace_s[1]:>12.0f}")
    print(f"  {'whole signature (trace+beam+speckle+blend)':<44}{full_s[0]:>12.0f}{full_s[1]:>12.0f}")
    print()
    rows = bench_subrays(rng, 12 if args.quick else 60, 1 if args.quick else 3)
    print("sub-ray count: error of the proportion maps against k = 8, and CPU time per trace")
    print(f"  {'k':>3}{'ms/trace':>10}{'shadow L1 err':>15}{'echo sum err':>14}")
    for k, ms, es, ee in rows:
        print(f"  {k:>3}{ms:>10.2f}{es:>14.1%}{ee:>14.1%}")
    print()
    what, dt, recs = bench_mission(args.quick, args.seed)
    print(f"mission generation: {what}: {dt:.2f} s ({recs} records)")
    return 0



if __name__ == "__main__":
    raise SystemExit(main())
