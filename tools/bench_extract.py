#!/usr/bin/env python3
"""Benchmark detection extraction (``find_detections``, SPEC section 3) on node-sized score maps.

Score maps of a Rayleigh tile with a NaN nadir gap and planted targets
(``bench_detectors.make_tile``, scored by ``score_maps``), at the detector thresholds of the
bench (few components) and at fractions of them (many components). For each map and threshold:
the time of the previous implementation (``cv2.connectedComponentsWithStats`` on the whole map,
a whole-map gather of the kept labels and a lexsort; kept here as :func:`previous`), the time of
``find_detections`` now, both in ms per Mpx, and whether the two give the same detections.
Then the cost of the coverage bits of ``node.detect`` (``np.packbits(~np.isnan(score))``).
With ``--mission``, also the node's own case: the detect jobs of a generated mission (two legs,
150 m swath, tiles of 1024 pings, shipped model thresholds), recorded during an in-process
replay; extraction before / now on their score maps, and ``node.detect.detect(job)`` whole
with the previous and the current extraction.

Each time is the best of ``--repeat`` runs of this process's CPU time (``time.process_time``;
OpenCV held to one thread), so a busy neighbour on a shared machine disturbs it less; figures
still vary from run to run there.

Examples::

    python tools/bench_extract.py              # 1024 x 1501 maps (a node tile core), best of 7
    python tools/bench_extract.py --quick      # 512 x 1024, best of 2: a smoke run
    python tools/bench_extract.py --check      # exit 1 if previous and current results differ
    python tools/bench_extract.py --mission    # + the detect jobs of a generated mission (~10 s more)
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_detectors import GEO, TAU, make_tile  # noqa: E402

from atr_node.config import DETECTOR_NAMES, DetectorSettings, Settings, TemplateSettings  # noqa: E402
from atr_node.detectors import Detection, find_detections, score_maps, score_strip  # noqa: E402
from atr_node.node import detect as node_detect  # noqa: E402
from atr_node.node import pipeline as node_pipeline  # noqa: E402

FRACTIONS = (1.0, 0.5, 0.25)
"""Thresholds as fractions of the bench thresholds: 1 gives few components, 0.25 many."""


def previous(score: np.ndarray, tau: float, *, detector: str, range0_m: float, dr_m: float, dx_m: float,
             min_extent_m: float, max_extent_m: float) -> list[Detection]:
    """``find_detections`` as it was before the sparse path (the "before" of the table)."""
    g = np.asarray(score)
    with np.errstate(invalid="ignore"):
        hot = g > tau
    if g.size == 0 or not hot.any():
        return []
    n, labels, stats, _ = cv2.connectedComponentsWithStats(hot.view(np.uint8), connectivity=8, ltype=cv2.CV_32S)
    width_m = stats[:, cv2.CC_STAT_WIDTH] * dr_m
    height_m = stats[:, cv2.CC_STAT_HEIGHT] * dx_m
    tol = 1e-9 * max_extent_m
    keep = ((width_m >= min_extent_m - tol) & (width_m <= max_extent_m + tol)
            & (height_m >= min_extent_m - tol) & (height_m <= max_extent_m + tol))
    keep[0] = False
    if not keep.any():
        return []
    flat = np.flatnonzero(keep[labels.reshape(-1)])
    lab = labels.reshape(-1)[flat]
    val = g.reshape(-1)[flat].astype(np.float64)
    order = np.lexsort((flat, -val, lab))
    first = order[np.unique(lab[order], return_index=True)[1]]
    rows, cols = np.divmod(flat[first], g.shape[1])
    out = [Detection(detector, int(r), int(c), float(v), float(range0_m + c * dr_m), float(width_m[k]),
                     float(height_m[k]), int(stats[k, cv2.CC_STAT_AREA]))
           for r, c, v, k in zip(rows, cols, val[first], lab[first])]
    out.sort(key=lambda d: (d.row, d.col))
    return out


def best_time(fn: Callable[[], object], repeat: int) -> tuple[float, object]:
    """Best CPU time of ``repeat`` runs, seconds, and the last result."""
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.process_time()
        out = fn()
        best = min(best, time.process_time() - t0)
    return max(best, 1e-6), out  # a coarse clock can read 0 for tiny runs


@contextlib.contextmanager
def swapped(module: object, name: str, value: object) -> Iterator[None]:
    """``module.name = value`` for the block (to record jobs, or to run detect with ``previous``)."""
    old = getattr(module, name)
    setattr(module, name, value)
    try:
        yield
    finally:
        setattr(module, name, old)


def mission_jobs(max_jobs: int) -> list[node_detect.DetectJob]:
    """The detect jobs (full-size units only) of an in-process replay of a generated mission."""
    from atr_node.calibration.model import PerformanceModel
    from atr_node.io.atrlog import read_atrlog
    from atr_node.node.service import NodeService
    from atr_node.simulation.mission import generate_mission

    base = Settings()
    sim = dataclasses.replace(base.simulation, mission_legs=2, mission_leg_length_m=200.0, mission_swath_m=150.0,
                              mission_tile_pings=1024)
    settings = base.replace(simulation=sim)
    jobs: list[node_detect.DetectJob] = []

    def record(job: node_detect.DetectJob) -> node_detect.DetectResult:
        if len(jobs) < max_jobs and job.core[1] - job.core[0] >= 512:
            jobs.append(job)
        return node_detect.detect(job)

    with tempfile.TemporaryDirectory() as tmp, swapped(node_pipeline, "detect", record):
        files = generate_mission(settings, Path(tmp) / "m", seed=11)
        svc = NodeService(settings, model=PerformanceModel.shipped(), mode="replay", workers=0)
        try:
            svc.run(read_atrlog(files.atrlog))
        finally:
            svc.close()
    return jobs


def bench_mission(repeat: int, max_jobs: int) -> bool:
    """Print the mission figures; True when previous and current detections agree."""
    jobs = mission_jobs(max_jobs)
    t_b = t_n = 0.0
    n_maps, px, hot_frac, same = 0, 0, [], True
    for job in jobs:
        maps = score_strip(job.pixels, core_rows=job.core, range0_m=job.range0_m, dr_m=job.dr_m, dx_m=job.dx_m,
                           altitude_m=job.altitude_m, template=job.template, detectors=job.detectors,
                           enabled=job.enabled, background=job.background, median=job.median)
        kw = dict(range0_m=job.range0_m, dr_m=job.dr_m, dx_m=job.dx_m, min_extent_m=job.detectors.min_extent_m,
                  max_extent_m=job.detectors.max_extent_m)
        for d, g in maps.items():
            tau = job.taus[d]
            tb, before = best_time(lambda: previous(g, tau, detector=d, **kw), repeat)
            tn, now = best_time(lambda: find_detections(g, tau, detector=d, **kw), repeat)
            same &= before == now
            t_b, t_n, n_maps, px = t_b + tb, t_n + tn, n_maps + 1, px + g.size
            with np.errstate(invalid="ignore"):
                hot_frac.append(float(np.mean(g > tau)))
    mpx_map = px / n_maps / 1e6
    print(f"\ngenerated mission (150 m swath, 1024-ping tiles, shipped model thresholds): {len(jobs)} units, "
          f"{n_maps} maps of {mpx_map:.2f} Mpx, {100 * min(hot_frac):.3f}-{100 * max(hot_frac):.2f} % of pixels hot")
    print(f"{'what':<36}{'before ms':>11}{'now ms':>8}{'speed-up':>10}")
    print(f"{'find_detections, mean per map':<36}{t_b * 1e3 / n_maps:>11.2f}{t_n * 1e3 / n_maps:>8.2f}"
          f"{t_b / t_n:>10.1f}   same: {'yes' if same else 'NO'}")
    node_detect.detect(jobs[0])  # first call: workspace and tables
    runs: dict[str, list[float]] = {"before": [], "now": []}
    for _ in range(max(repeat // 2, 1)):  # interleaved, so a busy neighbour hits both alike
        for label, fn in (("before", previous), ("now", find_detections)):
            with swapped(node_detect, "find_detections", fn):
                t0 = time.process_time()
                for job in jobs:
                    node_detect.detect(job)
                runs[label].append(time.process_time() - t0)
    tb, tn = min(runs["before"]) / len(jobs), min(runs["now"]) / len(jobs)
    print(f"{'node detect(job), per unit':<36}{tb * 1e3:>11.1f}{tn * 1e3:>8.1f}{tb / tn:>10.1f}"
          f"   {mpx_map / tb:.1f} -> {mpx_map / tn:.1f} Mpx/s on one core")
    return same


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("Examples::")[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rows", type=int, default=1024, help="map rows (pings), default 1024")
    ap.add_argument("--cols", type=int, default=1501, help="map columns (range bins), default 1501")
    ap.add_argument("--repeat", type=int, default=7, help="runs per measurement, best kept (default 7)")
    ap.add_argument("--quick", action="store_true", help="512 x 1024 maps, best of 2")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--check", action="store_true", help="exit 1 if previous and current detections differ")
    ap.add_argument("--mission", action="store_true", help="also the detect jobs of a generated mission")
    ap.add_argument("--mission-units", type=int, default=6, help="units of the mission to time (default 6)")
    args = ap.parse_args(argv)
    if args.quick:
        args.rows, args.cols, args.repeat = min(args.rows, 512), min(args.cols, 1024), 2
    cv2.setNumThreads(1)
    template, settings = TemplateSettings(), DetectorSettings()
    img, truth = make_tile(args.rows, args.cols, args.seed, template)
    maps = score_maps(img, template=template, detectors=settings, **GEO)
    mpx = img.size / 1e6
    kw = dict(range0_m=GEO["range0_m"], dr_m=GEO["dr_m"], dx_m=GEO["dx_m"], min_extent_m=settings.min_extent_m,
              max_extent_m=settings.max_extent_m)
    print(f"score maps {args.rows} x {args.cols} float64 ({mpx:.2f} Mpx), {len(truth)} planted targets, "
          f"NaN {np.mean(np.isnan(maps['mf'])):.1%}; best of {args.repeat}, CPU time, OpenCV threads "
          f"{cv2.getNumThreads()}")
    print(f"\n{'map':<5}{'tau':>8}{'hot %':>8}{'comps':>7}{'kept':>6}{'before ms':>11}{'now ms':>8}"
          f"{'before ms/Mpx':>15}{'now ms/Mpx':>12}{'speed-up':>10}{'same':>6}")
    same_all, t_before, t_now = True, 0.0, 0.0
    for d in DETECTOR_NAMES:
        g = maps[d]
        for f in FRACTIONS:
            tau = TAU[d] * f
            with np.errstate(invalid="ignore"):
                hot = g > tau
            n_comp = cv2.connectedComponents(hot.view(np.uint8), connectivity=8)[0] - 1
            tb, before = best_time(lambda: previous(g, tau, detector=d, **kw), args.repeat)
            tn, now = best_time(lambda: find_detections(g, tau, detector=d, **kw), args.repeat)
            same = before == now
            same_all &= same
            t_before, t_now = t_before + tb, t_now + tn
            print(f"{d:<5}{tau:>8.3f}{100 * hot.mean():>8.2f}{n_comp:>7}{len(now):>6}{tb * 1e3:>11.2f}{tn * 1e3:>8.2f}"
                  f"{tb * 1e3 / mpx:>15.2f}{tn * 1e3 / mpx:>12.2f}{tb / tn:>10.1f}{'yes' if same else 'NO':>6}")
    n = len(DETECTOR_NAMES) * len(FRACTIONS)
    print(f"{'all':<5}{'':>8}{'':>8}{'':>7}{'':>6}{t_before * 1e3 / n:>11.2f}{t_now * 1e3 / n:>8.2f}"
          f"{t_before * 1e3 / n / mpx:>15.2f}{t_now * 1e3 / n / mpx:>12.2f}{t_before / t_now:>10.1f}"
          f"{'yes' if same_all else 'NO':>6}   (mean per map)")

    t_bits, bits = best_time(lambda: {d: np.packbits(~np.isnan(maps[d])) for d in DETECTOR_NAMES}, args.repeat)
    distinct = len({bytes(b) for b in bits.values()})
    print(f"\ncoverage bits of node.detect, all four maps: {t_bits * 1e3:.2f} ms "
          f"({t_bits * 1e3 / mpx / len(DETECTOR_NAMES):.2f} ms/Mpx per map); {distinct} distinct of "
          f"{len(DETECTOR_NAMES)} (equal ones are one shared array in the result)")
    if args.mission:
        same_all &= bench_mission(args.repeat, args.mission_units)
    return 1 if args.check and not same_all else 0


if __name__ == "__main__":
    sys.exit(main())
