#!/usr/bin/env python3
"""The node's main-process fusion on a realistic mission (issue 7): deposit, contacts, commit.

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

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


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
    ``after(grid)`` called after every call, untimed (``bench_fusion_ab.py`` digests there)."""
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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
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
    best, msgs = None, 0
    for _ in range(1 if args.quick else max(1, args.repeat)):
        spent, msgs = time_calls(s, gate, dets, frame, calls)
        best = spent if best is None else [min(a, b) for a, b in zip(best, spent)]
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


if __name__ == "__main__":
    sys.exit(main())
