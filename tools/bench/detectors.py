#!/usr/bin/env python3
"""Benchmark the four detectors (SPEC sections 1-3) on one core.

Reports, on a Rayleigh tile with NaN columns and planted targets:

1. throughput (Mpx/s) of each detector alone and of all four together (``score_maps``),
   against the time of one memory copy of the tile (``tile.copy()``, and ``np.copyto`` into a
   buffer already mapped), best against best and run by run;
2. the same work done by a plain ``scipy.ndimage`` reference (banded ``uniform_filter1d``: one
   pass per distinct window width, since the windows grow with range), its run time and its
   largest difference from ``score_maps``;
3. error against run time of each speed option (``precision = "float32"``, ``decimation``
   2 and 4): the error of the scores and of the detections against the full-precision path.

OpenCV is held to one thread (``cv2.setNumThreads(1)``); numpy and scipy run single-threaded
here. Figures taken on a shared machine vary from run to run: each time is the best of
``--repeat`` runs.

Examples::

    python tools/bench/detectors.py score                 # 2048 x 4096 tile, the figures of docs/detectors.md
    python tools/bench/detectors.py score --quick         # 512 x 1024, one repeat: a smoke run
    python tools/bench/detectors.py score --check         # exit 1 if scipy and score_maps disagree
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
from scipy import ndimage

from atr_node.config import DETECTOR_NAMES, DetectorSettings, TemplateSettings
from atr_node.detectors import (Workspace, column_mean, column_median, find_detections, score_maps,
                                window_geometry)
sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402  (tools/bench/harness.py: repeats, warm-up, statistics, JSON)

GEO = dict(range0_m=10.0, dr_m=0.1, dx_m=0.1, altitude_m=14.0)
TAU = {"mf": 1.0, "lac": 1.5, "smf": 0.25, "z": 2.0}


def make_tile(rows: int, cols: int, seed: int, template: TemplateSettings) -> tuple[np.ndarray, list]:
    """Rayleigh seabed, a nadir gap of NaN, and targets (echo x4, shadow x0.15) on a grid."""
    rng = np.random.default_rng(seed)
    img = rng.rayleigh(size=(rows, cols)).astype(np.float32)
    img[:, : max(1, cols // 64)] = np.nan
    geom = window_geometry(GEO["range0_m"] + GEO["dr_m"] * np.arange(cols), dr_m=GEO["dr_m"],
                           dx_m=GEO["dx_m"], altitude_m=GEO["altitude_m"], template=template)
    w, ln = geom.echo_px, geom.length_px
    truth = []
    for r in range(3 * ln, rows - 3 * ln, 6 * ln):
        for c in range(cols // 16, cols - 2 * int(geom.shadow_px.max()), max(cols // 12, 4 * w + 1)):
            s = int(geom.shadow_px[c])
            img[r - ln // 2:r - ln // 2 + ln, c - w:c] *= 4.0
            img[r - ln // 2:r - ln // 2 + ln, c:c + s] *= 0.15
            truth.append((r, c))
    return img, truth


CLOCK = time.perf_counter
"""Wall clock; ``--cpu`` switches to this process's CPU time (steadier on a shared machine)."""


def best_time(fn: Callable[[], object], repeat: int, name: str = "") -> tuple[float, object]:
    """Best time of ``repeat`` runs (seconds) and the last result; the samples go to the harness
    under ``name`` (median, min and max in ``atr-node bench detectors --json``)."""
    samples, out = [], None
    for _ in range(repeat):
        t0 = CLOCK()
        out = fn()
        samples.append(CLOCK() - t0)
    if name:
        harness.record(name, samples, clock="process" if CLOCK is time.process_time else "wall")
    return max(min(samples), 1e-6), out  # a coarse clock can read 0 for tiny runs


# ----------------------------------------------------------------------------------------
# The plain scipy.ndimage reference: box sums by uniform_filter1d, one band per window width.


def _box(img: np.ndarray, row_off: int, n_rows: int, col_off: int, n_cols: int) -> np.ndarray:
    """Sum of img over rows [i + row_off, +n_rows) x cols [j + col_off, +n_cols), zeros outside."""
    pr, pc = n_rows + abs(row_off), n_cols + abs(col_off)
    s = ndimage.uniform_filter1d(np.pad(img, ((pr, pr), (pc, pc))), n_rows, axis=0, mode="constant") * n_rows
    s = ndimage.uniform_filter1d(s, n_cols, axis=1, mode="constant") * n_cols
    # uniform_filter1d centres its window at -(n // 2): read it where the window starts at the offset.
    r0, c0 = pr + row_off + n_rows // 2, pc + col_off + n_cols // 2
    return s[r0:r0 + img.shape[0], c0:c0 + img.shape[1]]


def scipy_scores(x: np.ndarray, template: TemplateSettings, settings: DetectorSettings) -> dict[str, np.ndarray]:
    """The four detectors with scipy.ndimage box filters, band of equal window width by band."""
    rows, cols = x.shape
    g = window_geometry(GEO["range0_m"] + GEO["dr_m"] * np.arange(cols), dr_m=GEO["dr_m"],
                        dx_m=GEO["dx_m"], altitude_m=GEO["altitude_m"], template=template)
    valid = np.isfinite(x)
    xv = np.where(valid, x, 0.0).astype(np.float64)
    b, m = column_mean(x), column_median(x)
    b = np.where(np.isfinite(b) & (b > 0), b, 1.0)
    i_n = xv / b
    jj = np.where(valid, i_n - np.nan_to_num(m / b, nan=1.0), 0.0)
    seg = np.select([x < 0.3 * m, x < 0.6 * m, x > 4 * m, x > 2 * m], [-1.0, -0.5, 1.0, 0.5], 0.0)
    seg = np.where(valid, seg, 0.0)
    mask = valid.astype(np.float64)
    w, ln, f = g.echo_px, g.length_px, settings.min_valid_fraction
    fz = max(settings.min_valid_fraction_zones, f)  # echo and shadow zones; the SMF context: f
    cl = g.ctx_row1 - g.ctx_row0
    out = {d: np.full((rows, cols), np.nan) for d in DETECTOR_NAMES}
    reach = max(g.reach())
    for s in np.unique(g.shadow_px):
        band = np.flatnonzero(g.shadow_px == s)
        lo, hi = max(0, band[0] - reach), min(cols, band[-1] + reach + 1)
        sl = (slice(None), slice(lo, hi))
        k = band - lo
        cw = int(g.ctx_col1[band[0]] - g.ctx_col0[band[0]])
        cc0 = int(g.ctx_col0[band[0]])

        def sums(img: np.ndarray, col_off: int, n_cols: int, row_off: int = g.row0, n_rows: int = ln) -> np.ndarray:
            return _box(img[sl], row_off, n_rows, col_off, n_cols)[:, k]

        n_e, n_s, n_c = sums(mask, -w, w), sums(mask, 0, s), sums(mask, cc0, cw, g.ctx_row0, cl)
        with np.errstate(all="ignore"):
            ok_e, ok_s, ok_c = n_e >= fz * w * ln - 1e-6, n_s >= fz * s * ln - 1e-6, n_c >= f * cw * cl - 1e-6
            mu_e, mu_s = sums(i_n, -w, w) / n_e, sums(i_n, 0, s) / n_s
            var = np.maximum(sums(i_n * i_n, 0, s) / n_s - mu_s * mu_s, 0.0)
            mf = sums(jj, -w, w) / n_e - sums(jj, 0, s) / n_s
            lac = var / np.maximum(mu_s * mu_s, settings.lacunarity_floor)
            z = (mu_e - mu_s) / np.maximum(np.sqrt(var), settings.sigma_floor)
            smf = (sums(seg, -w, w) / n_e - sums(seg, 0, s) / n_s) / (1.0 + 10.0 * sums(np.abs(seg), cc0, cw, g.ctx_row0, cl) / n_c)
        es = ok_e & ok_s
        out["mf"][:, band] = np.where(es, mf, np.nan)
        out["lac"][:, band] = np.where(ok_s, lac, np.nan)
        out["z"][:, band] = np.where(es, z, np.nan)
        out["smf"][:, band] = np.where(es & ok_c, smf, np.nan)
    return out


# ----------------------------------------------------------------------------------------


def detections(maps: dict[str, np.ndarray], settings: DetectorSettings) -> dict[str, list]:
    return {d: find_detections(g, TAU[d], detector=d, range0_m=GEO["range0_m"], dr_m=GEO["dr_m"],
                               dx_m=GEO["dx_m"], min_extent_m=settings.min_extent_m,
                               max_extent_m=settings.max_extent_m) for d, g in maps.items()}


def compare_detections(ref: list, got: list, radius_px: int = 3) -> tuple[int, int, float]:
    """(missed, extra, mean peak offset px) of ``got`` against ``ref``, greedy within a radius."""
    used, offsets, missed = set(), [], 0
    for a in ref:
        best = None
        for k, b in enumerate(got):
            dist = max(abs(a.row - b.row), abs(a.col - b.col))
            if k not in used and dist <= radius_px and (best is None or dist < best[1]):
                best = (k, dist)
        if best is None:
            missed += 1
        else:
            used.add(best[0])
            offsets.append(best[1])
    return missed, len(got) - len(used), float(np.mean(offsets)) if offsets else 0.0


def score_error(got: np.ndarray, ref: np.ndarray, step: int) -> tuple[float, float]:
    """(max, 99.9th percentile) of |got - ref| / std(ref) over the pixels both score.

    With decimation ``step`` > 1 the maximum is taken at the scored pixels (every step-th row
    and column: the engine's own error) and the percentile over all pixels (the cost of
    repeating each score over its step x step block).
    """
    both = np.isfinite(got) & np.isfinite(ref)
    if not both.any():
        return 0.0, 0.0
    scale = float(np.std(ref[both])) or 1.0
    diff = np.abs(got.astype(np.float64) - ref)
    at = both[::step, ::step]
    worst = float(np.max(diff[::step, ::step][at], initial=0.0)) / scale
    return worst, float(np.percentile(diff[both], 99.9)) / scale


def main_score(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("Examples::")[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rows", type=int, default=2048, help="tile rows (pings), default 2048")
    ap.add_argument("--cols", type=int, default=4096, help="tile columns (range bins), default 4096")
    ap.add_argument("--repeat", type=int, default=5, help="runs per measurement, best kept (default 5)")
    ap.add_argument("--quick", action="store_true", help="512 x 1024 tile, one repeat")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-scipy", action="store_true", help="skip the scipy.ndimage reference")
    ap.add_argument("--check", action="store_true",
                    help="exit 1 if the scipy reference and score_maps differ by more than 1e-6 relative")
    ap.add_argument("--cpu", action="store_true",
                    help="time with this process's CPU time instead of the wall clock (shared machines)")
    args = ap.parse_args(argv)
    global CLOCK
    if args.cpu:
        CLOCK = time.process_time
    if args.quick:
        args.rows, args.cols, args.repeat = min(args.rows, 512), min(args.cols, 1024), 1
    cv2.setNumThreads(1)
    template, base = TemplateSettings(), DetectorSettings()
    x, truth = make_tile(args.rows, args.cols, args.seed, template)
    mpx = x.size / 1e6
    print(f"tile {args.rows} x {args.cols} float32 ({mpx:.1f} Mpx), {len(truth)} planted targets, "
          f"OpenCV threads {cv2.getNumThreads()}, best of {args.repeat}, "
          f"{'CPU time' if args.cpu else 'wall clock'}")

    # Two copies: ``tile.copy()`` (the reference of the "x copy" column: a new tile, as a
    # node receives it, in memory the kernel maps on first touch) and ``np.copyto`` into a
    # buffer already mapped (the bare memory bandwidth, about 2x faster on this VM).
    t_copy, _ = best_time(lambda: x.copy(), max(args.repeat, 3), "tile.copy()")
    dst = np.empty_like(x)
    t_copyto, _ = best_time(lambda: np.copyto(dst, x), max(args.repeat, 3), "np.copyto into a mapped buffer")
    print(f"\n{'what':<36}{'time ms':>10}{'Mpx/s':>10}{'x copy':>9}")
    print(f"{'memory copy of the tile':<36}{t_copy * 1e3:>10.1f}{mpx / t_copy:>10.0f}{1.0:>9.1f}")
    print(f"{'  the same into a mapped buffer':<36}{t_copyto * 1e3:>10.1f}{mpx / t_copyto:>10.0f}"
          f"{t_copyto / t_copy:>9.1f}")
    ws = Workspace()  # buffers reused from tile to tile, as in the node
    runs = [(d, (d,), ws) for d in DETECTOR_NAMES] + [("all four", DETECTOR_NAMES, ws),
                                                       ("all four, no workspace", DETECTOR_NAMES, None)]
    t_all, full = 0.0, {}
    for label, enabled, w in runs:
        t, maps = best_time(lambda: score_maps(x, template=template, detectors=base, enabled=enabled,
                                               workspace=w, **GEO), args.repeat, f"score_maps {label}")
        print(f"{'score_maps ' + label:<36}{t * 1e3:>10.1f}{mpx / t:>10.1f}{t / t_copy:>9.1f}")
        if label == "all four":  # copied: the maps live in the workspace, reused by the next call
            t_all, full = t, {d: m.copy() for d, m in maps.items()}
    # This VM's speed drifts by up to 40 % from minute to minute, so a best copy and a best
    # score_maps taken minutes apart can come from different phases: the ratio is also taken
    # pair by pair (a best-of-3 copy just before each run of all four), median over the pairs.
    ratios, ratios_to = [], []  # pair by pair (kept as ratios, not through the harness's own pairing,
    for _ in range(args.repeat):  # which alternates single runs: here each side is a best of 3)
        tc, _ = best_time(lambda: x.copy(), 3)
        tt, _ = best_time(lambda: np.copyto(dst, x), 3)
        ta, _ = best_time(lambda: score_maps(x, template=template, detectors=base, workspace=ws, **GEO), 1)
        ratios.append(ta / tc)
        ratios_to.append(ta / tt)
    harness.value("all four / tile.copy(), run by run (median)", float(np.median(ratios)))
    print(f"{'all four / copy, run by run':<36}{'':>20}{float(np.median(ratios)):>9.1f}"
          f"   (median of {len(ratios)} pairs, {min(ratios):.1f}-{max(ratios):.1f}; "
          f"{float(np.median(ratios_to)):.1f} against the copy into a mapped buffer)")
    rc = 0
    if not args.no_scipy:
        t_ref, ref = best_time(lambda: scipy_scores(x, template, base), 1, "scipy.ndimage reference, all four")
        worst = 0.0
        for d in DETECTOR_NAMES:
            same_nan = np.array_equal(np.isnan(ref[d]), np.isnan(full[d]))
            ok = np.isfinite(ref[d])
            err = np.abs(full[d][ok] - ref[d][ok]) / np.maximum(np.abs(ref[d][ok]), 1.0)
            worst = max(worst, float(err.max(initial=0.0)) if same_nan else np.inf)
        print(f"{'scipy.ndimage, all four':<36}{t_ref * 1e3:>10.1f}{mpx / t_ref:>10.1f}{t_ref / t_copy:>9.1f}"
              f"   score_maps is {t_ref / t_all:.1f}x faster; max rel. difference {worst:.1e}")
        if args.check and not worst <= 1e-6:
            rc = 1

    print("\nspeed options (all four) against the full-precision path. err: |diff| / std of the"
          "\nfull-precision scores, max at the scored pixels and 99.9th percentile over all pixels;"
          f"\ndetections at tau {TAU} matched within 3 px.")
    ref_det = detections(full, base)
    n_ref = sum(len(v) for v in ref_det.values())
    print(f"{'option':<24}{'time ms':>9}{'Mpx/s':>8}{'speed-up':>9}  {'max err mf/lac/smf/z':<30}"
          f"{'p99.9 err':>10}{'missed':>8}{'extra':>7}{'offset px':>10}   (reference: {n_ref} detections)")
    options = [("float64, decimation 1", base),
               ("float32", dataclasses.replace(base, precision="float32")),
               ("decimation 2", dataclasses.replace(base, decimation=2)),
               ("decimation 4", dataclasses.replace(base, decimation=4)),
               ("float32 + decimation 2", dataclasses.replace(base, precision="float32", decimation=2))]
    for label, opt in options:
        t, maps = best_time(lambda: score_maps(x, template=template, detectors=opt, workspace=ws, **GEO),
                            args.repeat, f"score_maps all four, {label}")
        errs = [score_error(maps[d], full[d], opt.decimation) for d in DETECTOR_NAMES]
        det = detections(maps, base)
        missed = extra = 0
        offs = []
        for d in DETECTOR_NAMES:
            m_, e_, o_ = compare_detections(ref_det[d], det[d])
            missed, extra = missed + m_, extra + e_
            offs.append(o_)
        max_err = "/".join(f"{e[0]:.0e}" for e in errs)
        print(f"{label:<24}{t * 1e3:>9.1f}{mpx / t:>8.1f}{t_all / t:>9.2f}  {max_err:<30}"
              f"{max(e[1] for e in errs):>10.1e}{missed:>8}{extra:>7}{np.mean(offs):>10.2f}")
    return rc




# ================================================================================================
# Part "extract" (was tools/bench/detectors.py extract)
# ================================================================================================

EXTRACT_DOC = """Benchmark detection extraction (``find_detections``, SPEC section 3) on node-sized score maps.

Score maps of a Rayleigh tile with a NaN nadir gap and planted targets
(``make_tile`` of the part above, scored by ``score_maps``), at the detector thresholds of the
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

    python tools/bench/detectors.py extract              # 1024 x 1501 maps (a node tile core), best of 7
    python tools/bench/detectors.py extract --quick      # 512 x 1024, best of 2: a smoke run
    python tools/bench/detectors.py extract --check      # exit 1 if previous and current results differ
    python tools/bench/detectors.py extract --mission    # + the detect jobs of a generated mission (~10 s more)
"""


import contextlib
import tempfile
from pathlib import Path
from typing import Iterator

from atr_node.config import Settings  # noqa: E402
from atr_node.detectors import Detection, score_strip  # noqa: E402
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


def best_time_extract(fn: Callable[[], object], repeat: int, name: str = "") -> tuple[float, object]:
    """Best CPU time of ``repeat`` runs, seconds, and the last result; the samples go to the
    harness under ``name``."""
    samples, out = [], None
    for _ in range(repeat):
        t0 = time.process_time()
        out = fn()
        samples.append(time.process_time() - t0)
    if name:
        harness.record(name, samples, clock="process")
    return max(min(samples), 1e-6), out  # a coarse clock can read 0 for tiny runs


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
        if len(jobs) < max_jobs and job.core[1] - job.core[0] >= 256:  # a whole unit (25.6 m at 0.1 m)
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
            tb, before = best_time_extract(lambda: previous(g, tau, detector=d, **kw), repeat)
            tn, now = best_time_extract(lambda: find_detections(g, tau, detector=d, **kw), repeat)
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
    for label in ("before", "now"):
        harness.record(f"node detect, all {len(jobs)} units, extraction {label}", runs[label], clock="process",
                       work=len(jobs), work_unit="units")
    harness.value("mission find_detections, mean per map: before / now ms", [t_b * 1e3 / n_maps, t_n * 1e3 / n_maps])
    tb, tn = min(runs["before"]) / len(jobs), min(runs["now"]) / len(jobs)
    print(f"{'node detect(job), per unit':<36}{tb * 1e3:>11.1f}{tn * 1e3:>8.1f}{tb / tn:>10.1f}"
          f"   {mpx_map / tb:.1f} -> {mpx_map / tn:.1f} Mpx/s on one core")
    return same


def main_extract(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=EXTRACT_DOC.split("\n\n")[0], epilog=EXTRACT_DOC.split("Examples::")[1],
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
            tb, before = best_time_extract(lambda: previous(g, tau, detector=d, **kw), args.repeat,
                                           f"extract previous, {d} at {f} tau")
            tn, now = best_time_extract(lambda: find_detections(g, tau, detector=d, **kw), args.repeat,
                                        f"find_detections, {d} at {f} tau")
            same = before == now
            same_all &= same
            t_before, t_now = t_before + tb, t_now + tn
            print(f"{d:<5}{tau:>8.3f}{100 * hot.mean():>8.2f}{n_comp:>7}{len(now):>6}{tb * 1e3:>11.2f}{tn * 1e3:>8.2f}"
                  f"{tb * 1e3 / mpx:>15.2f}{tn * 1e3 / mpx:>12.2f}{tb / tn:>10.1f}{'yes' if same else 'NO':>6}")
    n = len(DETECTOR_NAMES) * len(FRACTIONS)
    print(f"{'all':<5}{'':>8}{'':>8}{'':>7}{'':>6}{t_before * 1e3 / n:>11.2f}{t_now * 1e3 / n:>8.2f}"
          f"{t_before * 1e3 / n / mpx:>15.2f}{t_now * 1e3 / n / mpx:>12.2f}{t_before / t_now:>10.1f}"
          f"{'yes' if same_all else 'NO':>6}   (mean per map)")

    t_bits, bits = best_time_extract(lambda: {d: np.packbits(~np.isnan(maps[d])) for d in DETECTOR_NAMES}, args.repeat,
                                       "coverage bits, all four maps")
    distinct = len({bytes(b) for b in bits.values()})
    print(f"\ncoverage bits of node.detect, all four maps: {t_bits * 1e3:.2f} ms "
          f"({t_bits * 1e3 / mpx / len(DETECTOR_NAMES):.2f} ms/Mpx per map); {distinct} distinct of "
          f"{len(DETECTOR_NAMES)} (equal ones are one shared array in the result)")
    if args.mission:
        same_all &= bench_mission(args.repeat, args.mission_units)
    return 1 if args.check and not same_all else 0


PARTS = {"score": main_score, "extract": main_extract}


def main(argv: list[str] | None = None) -> int:  # a part, every part, or the first with options
    return harness.subject_main(__doc__, PARTS, argv)


if __name__ == "__main__":
    raise SystemExit(main())
