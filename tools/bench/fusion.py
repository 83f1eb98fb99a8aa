#!/usr/bin/env python3
"""Benchmark of the evidence grid (SPEC section 7): update rates and memory per covered cell.

Single process, one core (BLAS/OpenMP threads pinned to 1 before numpy loads), timed in
process CPU time by default (``--wall`` for wall-clock time). Prints:

1. realistic tiles: an 8 Mpx core (0.1 m pixels, 4 detectors) deposited into 0.5 m cells,
   in pixel updates/s (pixel x detector) and cell updates/s ((leg, detector, cell) pieces
   of evidence), the leg commit, and contact extraction;
2. the raw accumulate rate: ``L += d`` over cells (the commit and the merge are this);
3. closed-form evaluation rate (belief read-out);
4. memory per covered cell over a lawnmower mission, persistent and transient.

Run ``python tools/bench/fusion.py grid`` (``--quick`` for a smoke run, ``--help`` for options).
Figures taken on a loaded machine are indicative only.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from atr_node.config import FusionSettings  # noqa: E402
from atr_node.fusion import (ContactTracker, DetectionEvidence, DetectorObservation, EvidenceGrid,  # noqa: E402
                             Observation, closed_form)
from atr_node.geo import MissionFrame, TileGeometry  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402  (tools/bench/harness.py: repeats, statistics, JSON)

DETS = ("mf", "lac", "smf", "z")


def straight_geometry(rows: int, cols: int, *, east0_m: float, north0_m: float, heading_deg: float,
                      dx_m: float = 0.1, dr_m: float = 0.1, range0_m: float = 10.0) -> TileGeometry:
    """A straight track directly in the metric frame (no projection cost in the benchmark)."""
    h = np.radians(heading_deg)
    i = np.arange(rows)
    return TileGeometry(east_m=east0_m + i * dx_m * np.sin(h), north_m=north0_m + i * dx_m * np.cos(h),
                        ue=np.full(rows, np.cos(h)), un=np.full(rows, -np.sin(h)),
                        ranges_m=range0_m + dr_m * np.arange(cols), heading_grid_rad=np.full(rows, h))


def observation(geom: TileGeometry, leg: int, t: float, rng: np.random.Generator) -> Observation:
    rows, cols = geom.east_m.size, geom.ranges_m.size
    pd = np.clip(1.0 - (geom.ranges_m / geom.ranges_m[-1]) ** 4, 0.0, 1.0) * 0.95
    views = []
    for k, d in enumerate(DETS):
        cov = np.ones((rows, cols), bool)
        cov[:, : 5 + 3 * k] = False  # window edges differ per detector
        cov[:, cols - 5 - 3 * k:] = False
        hits = tuple(DetectionEvidence(int(r), int(c), 2.0, float(geom.ranges_m[c]), float(rng.uniform(0.3, 0.9)))
                     for r, c in zip(rng.integers(0, rows, 5), rng.integers(20, cols - 20, 5)))
        views.append(DetectorObservation(d, cov, pd, hits))
    return Observation(leg=leg, t=t, geometry=geom, detectors=tuple(views))


CLOCK = time.process_time
"""CPU time of this process: on a shared machine it excludes the time other jobs hold the core
(``--wall`` switches to wall-clock time)."""


def best_of(fn, repeat: int, name: str = "") -> float:
    """Minimum time of ``fn`` over ``repeat`` runs (no warm-up: each call builds its own state),
    through the harness, which keeps the median and maximum for ``--json``."""
    clock = "wall" if CLOCK is time.perf_counter else "process"
    return harness.measure(name or getattr(fn, "__name__", "call"), fn, repeat=repeat, warmup=0, clock=clock).min_s


def bench_tiles(rows: int, cols: int, repeat: int) -> list[tuple[str, str, str]]:
    rng = np.random.default_rng(0)
    fusion = FusionSettings()
    out = []
    geom = straight_geometry(rows, cols, east0_m=1000.0, north0_m=2000.0, heading_deg=30.0)
    obs = observation(geom, 1, 0.0, rng)
    state = {}

    def deposit():
        g = EvidenceGrid(fusion, gate_m=3.0)
        g.add_observation(obs)
        state["grid"] = g

    t_dep = best_of(deposit, repeat, f"deposit {rows}x{cols} core, 4 detectors")
    g = state["grid"]
    layer = g.open[1]
    cells = int(((layer.chunks.gather() >= 0).any(axis=2)).sum())  # (detector, cell) pieces
    px = rows * cols * len(DETS)
    out.append((f"deposit {rows}x{cols} core, 4 det", f"{t_dep * 1e3:.0f} ms",
                f"{px / t_dep / 1e6:.1f} M pixel-updates/s; {cells / t_dep / 1e6:.1f} M cell-updates/s"))

    def commit():
        g2 = EvidenceGrid(fusion, gate_m=3.0)
        g2.add_observation(obs)
        t0 = CLOCK()
        g2.close_leg(1)
        state["commit"] = CLOCK() - t0
        state["g2"] = g2

    commits_s = []
    for _ in range(repeat):  # the commit alone is timed (inside commit()), not the deposit before it
        commit()
        commits_s.append(state["commit"])
    best = harness.record("commit leg", commits_s, clock="wall" if CLOCK is time.perf_counter else "process").min_s
    out.append(("commit leg (one piece per detector and cell)", f"{best * 1e3:.1f} ms",
                f"{cells / best / 1e6:.1f} M cell-updates/s"))
    frame = MissionFrame("ltp", 44.08, 9.85)
    tr = ContactTracker(fusion, frame, gate_m=3.0)
    t_c = best_of(lambda: ContactTracker(fusion, frame, gate_m=3.0).update(state["g2"], 1.0), repeat,
                  "contact extraction after the tile")
    tr.update(state["g2"], 1.0)
    out.append(("contact extraction after the tile", f"{t_c * 1e3:.1f} ms", f"{len(tr.live)} contacts"))
    return out


def bench_raw(n_cells: int, repeat: int) -> list[tuple[str, str, str]]:
    rng = np.random.default_rng(1)
    acc = np.zeros((2, n_cells))
    d = np.log1p(-rng.uniform(0, 0.9, size=(2, n_cells)))
    t_add = best_of(lambda: np.add(acc, d, out=acc), repeat, f"raw accumulate, {n_cells} cells")
    la, lb = acc[0] - 1e-3, acc[1] - 1e-3
    t_cf = best_of(lambda: closed_form(la, lb), repeat, f"closed form, {n_cells} cells")
    return [("raw accumulate L_T, L_N += d", f"{t_add * 1e3:.1f} ms / {n_cells / 1e6:.0f} M cells",
             f"{n_cells / t_add / 1e6:.0f} M cell-updates/s"),
            ("closed-form evaluation (Bel, Pl, m_theta)", f"{t_cf * 1e3:.1f} ms / {n_cells / 1e6:.0f} M cells",
             f"{n_cells / t_cf / 1e6:.1f} M cells/s")]


def bench_memory(legs: int, length_m: float, chunk_cells: int) -> list[tuple[str, str, str]]:
    """Lawnmower: legs 200 m apart, port and starboard 10-150 m, 0.1 m pixels, 0.5 m cells."""
    rng = np.random.default_rng(2)
    fusion = FusionSettings(chunk_cells=chunk_cells)
    g = EvidenceGrid(fusion, gate_m=3.0)
    rows_tile = 1000
    peak_open = 0
    for leg in range(1, legs + 1):
        heading = 0.0 if leg % 2 else 180.0
        east = 200.0 * leg
        for k in range(int(length_m / (rows_tile * 0.1))):
            north = k * rows_tile * 0.1 if heading == 0.0 else length_m - k * rows_tile * 0.1
            for side in (+1, -1):
                geom = straight_geometry(rows_tile, 1400, east0_m=east, north0_m=north, heading_deg=heading)
                if side < 0:  # port: across-track vector reversed
                    geom = TileGeometry(geom.east_m, geom.north_m, -geom.ue, -geom.un, geom.ranges_m,
                                        geom.heading_grid_rad)
                g.add_observation(observation(geom, leg, float(leg), rng))
            peak_open = max(peak_open, g.nbytes()["open_layers"])
    g.close_all()
    nb = g.nbytes()
    covered = g.covered_cells()
    persistent = nb["accumulators"] + nb["coverage_bitmaps"] + nb["chunk_metadata"]
    harness.value("persistent_bytes_per_covered_cell", persistent / covered)
    return [(f"mission, chunks of {chunk_cells} cells", f"{legs} legs x {length_m:.0f} m", f"{covered / 1e6:.2f} M covered cells, "
             f"{len(g.chunk_keys())} chunks, "
             f"{len(g.detections) / (covered * fusion.cell_m ** 2 / 1e6):.0f} detections/km2"),
            ("accumulators L_T, L_N", f"{nb['accumulators'] / covered:.2f} B/covered cell",
             f"L_N 8 B/allocated cell; L_T in {len(g._lt)} chunks with T evidence"),
            ("coverage bitmaps + chunk metadata", f"{(nb['coverage_bitmaps'] + nb['chunk_metadata']) / covered:.3f} "
             "B/covered cell", "looks, legs, last update"),
            ("persistent total", f"{persistent / covered:.2f} B/covered cell", "target <= 16"),
            ("open-leg layer (transient)", f"{peak_open / 1e6:.0f} MB peak", "4 det x 2 x 8 B per cell of one leg")]


def main_grid(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="small sizes, one repeat (smoke test)")
    p.add_argument("--repeat", type=int, default=3, help="repeats per measurement (best kept)")
    p.add_argument("--legs", type=int, default=6, help="legs of the memory mission")
    p.add_argument("--length-m", type=float, default=1000.0, help="leg length of the memory mission")
    p.add_argument("--chunk-cells", type=int, default=32, help="fusion.chunk_cells for the memory mission")
    p.add_argument("--wall", action="store_true", help="time with the wall clock instead of process CPU time")
    a = p.parse_args(argv)
    global CLOCK
    if a.wall:
        CLOCK = time.perf_counter
    if a.quick:
        rows, cols, n_raw, repeat, legs, length = 500, 400, 1_000_000, 1, 2, 200.0
    else:
        rows, cols, n_raw, repeat, legs, length = 5334, 1500, 20_000_000, a.repeat, a.legs, a.length_m
    table = bench_tiles(rows, cols, repeat) + bench_raw(n_raw, repeat) + bench_memory(legs, length, a.chunk_cells)
    w0 = max(len(r[0]) for r in table)
    w1 = max(len(r[1]) for r in table)
    print(f"{'measurement':<{w0}}  {'value':<{w1}}  note")
    print("-" * (w0 + w1 + 40))
    for name, value, note in table:
        print(f"{name:<{w0}}  {value:<{w1}}  {note}")
    clock = "wall-clock" if a.wall else "process CPU"
    print(f"\nsingle process, 1 thread, {clock} time, best of {repeat}; figures on a shared machine are indicative")
    return 0



# ================================================================================================
# Part "node" (was tools/bench/fusion.py node)
# ================================================================================================

NODE_DOC = """The node's main-process fusion on a realistic mission (issue 7): deposit, contacts, commit.

1. A generated mission (default 4 legs of 200 m, 150 m swath, tiles of 1024 pings: 24 Mpx,
   the profile of issue 7) is replayed once through the node's pipeline in this process
   (``workers = 0``), recording every call the pipeline makes to the evidence grid and the
   contact tracker (observations, contact updates, the final commit).
2. That call sequence is replayed ``--repeat`` times through a fresh grid and tracker, timed
   in process CPU time (best of N), per call kind:
   ``EvidenceGrid.add_observation``, ``ContactTracker.update``, ``EvidenceGrid.close_all``.
3. First touch of fresh memory with and without NumPy's huge-page advice (the VM effect
   ``atr_node.node.warmup`` documents), 200 MB.

Single process, one core. Figures taken on a loaded machine are indicative only.
``--quick``: a small mission and one repetition (a smoke run).
"""



for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import dataclasses  # noqa: E402
import tempfile  # noqa: E402



def mission_settings(args: argparse.Namespace):
    """Settings of the benchmark mission: ``args.legs`` legs of 200 m, ``args.swath_m`` swath,
    tiles of ``args.tile_pings`` pings (``--quick``: 2 short legs of small tiles)."""
    from atr_node.config import Settings

    base = Settings()
    sim = dataclasses.replace(base.simulation, mission_legs=2 if args.quick else args.legs,
                              mission_leg_length_m=60.0 if args.quick else 200.0,
                              mission_swath_m=40.0 if args.quick else args.swath_m,
                              mission_tile_pings=256 if args.quick else args.tile_pings)
    # per-detector evidence: four layers per leg, the heavier deposit (and the form a
    # reference copy of an older fusion package also takes, for bench_fusion_ab)
    return base.replace(simulation=sim, fusion=dataclasses.replace(base.fusion, evidence="paper"))


def record_calls(settings, atrlog: Path) -> tuple[list[tuple], object, int]:
    """Replay ``atrlog`` in process; return the grid / tracker calls, the frame and pixels."""
    from atr_node.calibration.model import PerformanceModel
    from atr_node.io.atrlog import read_atrlog
    from atr_node.node.pipeline import Pipeline

    calls: list[tuple] = []
    pipe = Pipeline(settings, model=PerformanceModel.shipped(), workers=0, mode="replay")
    grid = pipe.grid
    add, close_all = grid.add_observation, grid.close_all

    def rec_add(obs):
        calls.append(("obs", obs))
        return add(obs)

    def rec_close_all():
        calls.append(("close_all",))
        return close_all()

    grid.add_observation, grid.close_all = rec_add, rec_close_all  # instance attributes: this grid only
    orig_update = Pipeline._update_contacts

    def rec_update(self, t):
        if self.tracker is not None:
            calls.append(("update", t))
        return orig_update(self, t)

    pipe._update_contacts = rec_update.__get__(pipe)
    try:
        pipe.replay(read_atrlog(atrlog))
    finally:
        pipe.close()
    return calls, pipe.frame, pipe.stats.pixels


def replay_calls(grid, tracker, calls, after=None) -> tuple[list[float], list[list]]:
    """Replay recorded calls through ``grid`` and ``tracker``: CPU seconds per kind
    (observations, contact updates, closing), the contacts each update returned, and
    ``after(grid)`` called after every call, untimed (a digest of the state, say)."""
    spent, updates = [0.0, 0.0, 0.0], []
    for c in calls:
        t0 = time.process_time()
        if c[0] == "obs":
            grid.add_observation(c[1])
            spent[0] += time.process_time() - t0
        elif c[0] == "update":
            out = tracker.update(grid, c[1])
            spent[1] += time.process_time() - t0
            updates.append(out)
        else:
            grid.close_all()
            spent[2] += time.process_time() - t0
        if after is not None:
            after(grid)
    return spent, updates


def time_calls(settings, gate_m: float, detectors, frame, calls) -> tuple[list[float], int]:
    """One replay of the calls through a fresh grid and tracker: CPU seconds per kind."""
    from atr_node.fusion import ContactTracker, EvidenceGrid

    grid = EvidenceGrid(settings.fusion, gate_m=gate_m, detectors=detectors)
    tracker = ContactTracker(settings.fusion, frame, gate_m=gate_m)
    spent, updates = replay_calls(grid, tracker, calls)
    return spent, sum(len(u) for u in updates)


def first_touch(mb: int, huge: bool) -> float:
    """CPU seconds (user + system) to touch ``mb`` MB of fresh memory."""
    try:
        from numpy._core.multiarray import _set_madvise_hugepage
    except ImportError:
        return float("nan")
    prev = _set_madvise_hugepage(huge)
    try:
        t0 = sum(os.times()[:2])
        a = np.empty(mb * 1_000_000, np.uint8)
        a[::4096] = 1
        spent = sum(os.times()[:2]) - t0
        del a
        return spent
    finally:
        _set_madvise_hugepage(prev)


def main_node(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=NODE_DOC, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small mission, one repetition")
    ap.add_argument("--repeat", type=int, default=5, help="replays of the call sequence (best of N)")
    ap.add_argument("--legs", type=int, default=4)
    ap.add_argument("--swath-m", type=float, default=150.0)
    ap.add_argument("--tile-pings", type=int, default=1024)
    args = ap.parse_args(argv)

    from atr_node.fusion import association_gate_m
    from atr_node.simulation.mission import generate_mission

    s = mission_settings(args)
    with tempfile.TemporaryDirectory() as tmp:
        files = generate_mission(s, Path(tmp) / "m", seed=11)
        calls, frame, pixels = record_calls(s, files.atrlog)
    gate = association_gate_m(s.fusion, s.template)
    dets = tuple(s.detectors.enabled)
    per_kind: list[list[float]] = [[], [], []]
    msgs = 0
    for _ in range(1 if args.quick else max(1, args.repeat)):
        spent, msgs = time_calls(s, gate, dets, frame, calls)
        for k in range(3):
            per_kind[k].append(spent[k])
    best = [min(v) for v in per_kind]
    for k, name in enumerate(("EvidenceGrid.add_observation", "ContactTracker.update", "EvidenceGrid.close_all")):
        harness.record(f"node mission: {name}, all calls", per_kind[k], clock="process")
    n_obs = sum(c[0] == "obs" for c in calls)
    n_upd = sum(c[0] == "update" for c in calls)
    print(f"mission: {pixels / 1e6:.1f} Mpx in {n_obs} tile cores, {n_upd} contact updates, {msgs} contact messages "
          f"(best of {1 if args.quick else args.repeat}, CPU s, one core)")
    print(f"{'stage':34s} {'CPU s':>8s} {'per call ms':>12s} {'Mpx/s':>8s}")
    for name, sec, n in (("EvidenceGrid.add_observation", best[0], n_obs), ("ContactTracker.update", best[1], n_upd),
                         ("EvidenceGrid.close_all", best[2], 1)):
        print(f"{name:34s} {sec:8.3f} {1e3 * sec / max(n, 1):12.2f} {pixels / 1e6 / max(sec, 1e-9):8.1f}")
    mb = 50 if args.quick else 200
    print(f"first touch of {mb} MB: {first_touch(mb, True):.3f} s with huge-page advice, "
          f"{first_touch(mb, False):.3f} s without")
    return 0


PARTS = {"grid": main_grid, "node": main_node}


def main(argv: list[str] | None = None) -> int:  # a part, every part, or the first with options
    return harness.subject_main(__doc__, PARTS, argv)


if __name__ == "__main__":
    raise SystemExit(main())
