"""Process many recordings on Dask and merge their evidence exactly; or run the calibration
Monte Carlo on the same engine.

Recordings (.atrlog or .xtf): each one is replayed through the node's pipeline in a task (a
fixed performance model, no on-line calibration), its committed legs become evidence deltas,
the deltas of every recording are added in the canonical order (mission, leg, node, part),
and contacts are extracted from the merged grid. The result does not depend on the number of
workers or the order tasks finish in: --scheduler serial gives the same contacts.

Calibration (--calibrate): target injection per image as tasks, pooled, the model written
to --out; the same model as `atr-node calibrate` with the same images and seed.

Engine: a local Dask cluster of --workers processes by default; --scheduler ADDRESS for a
running scheduler (every worker must read the recordings at the same path); --scheduler
serial for one process. A failed task is retried (--retries) and every failure is reported;
the exit status is 1 if any recording failed after its retries (the others are still merged).

Examples:

    atr-node batch missions/*/mission.atrlog --contacts-out contacts.jsonl
    atr-node batch a.atrlog b.xtf --scheduler tcp://10.0.0.5:8786 --summary run.json
    atr-node batch --calibrate --synthetic 8 --iterations 10 --targets 20 --out model.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from ..config import load_settings
from ..errors import AtrError
from ..io.atomic import atomic_open
from ._crs import add_crs_argument, add_frequency_argument, with_recording_options
from ._progress import add_progress_argument

EXIT_DETAIL = "batch: 1 also when a recording failed after its retries (the others are still merged)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recordings", nargs="*", metavar="RECORDING", help=".atrlog or .xtf recordings")
    parser.add_argument("--config", metavar="FILE", help="TOML settings (default: built-in defaults)")
    parser.add_argument("--model", metavar="FILE", help="performance model (default: the one shipped)")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="Dask scheduler address, or 'serial' for one process (default: a local cluster)")
    parser.add_argument("--workers", type=int, default=2, help="local cluster worker processes (default 2)")
    parser.add_argument("--retries", type=int, default=2, help="resubmissions of a failed task (default 2)")
    parser.add_argument("--contacts-out", metavar="FILE", help="write the contacts as JSON lines")
    parser.add_argument("--grid-out", metavar="FILE", help="write the merged evidence grid (.npz snapshot)")
    parser.add_argument("--summary", metavar="FILE", help="write timings, counters and failures as JSON")
    add_progress_argument(parser)
    add_crs_argument(parser)
    add_frequency_argument(parser)
    cal = parser.add_argument_group("calibration Monte Carlo (--calibrate)")
    cal.add_argument("--calibrate", action="store_true", help="run the calibration Monte Carlo instead")
    cal.add_argument("--input", nargs="*", default=[], metavar="PATH",
                     help="images: recordings' tiles or PNG seabeds (default: synthetic seabeds)")
    cal.add_argument("--max-images", type=int, default=4, help="tiles per recording (default 4)")
    cal.add_argument("--synthetic", type=int, default=4, help="synthetic seabed images (default 4)")
    cal.add_argument("--rows", type=int, default=1024)
    cal.add_argument("--cols", type=int, default=1024)
    cal.add_argument("--iterations", type=int, default=None, help="default: calibration.iterations")
    cal.add_argument("--targets", type=int, default=None, help="default: calibration.targets_per_image")
    cal.add_argument("--seed", type=int, default=None, help="default: calibration.seed")
    cal.add_argument("--out", default="performance_model.json", metavar="FILE", help="model file to write")


class _Progress:
    def __init__(self, label: str, quiet: bool) -> None:
        self.label, self.quiet, self.t0 = label, quiet, time.perf_counter()

    def __call__(self, done: int, total: int, failed: int) -> None:
        if self.quiet:
            return
        dt = time.perf_counter() - self.t0
        sys.stderr.write(f"\r{self.label}: {done}/{total} done, {failed} failed, {dt:6.1f} s ")
        if done >= total:
            sys.stderr.write("\n")
        sys.stderr.flush()


def _report(outcomes) -> int:
    bad = 0
    for o in outcomes:
        if not o.ok:
            bad += 1
            print(f"FAILED {o.name} after {o.attempts} attempts:", file=sys.stderr)
            for i, e in enumerate(o.errors, 1):
                print(f"  attempt {i}: {e}", file=sys.stderr)
        elif o.attempts > 1:
            print(f"retried {o.name}: succeeded on attempt {o.attempts} after: {'; '.join(o.errors)}",
                  file=sys.stderr)
    return bad


def run(args: argparse.Namespace) -> int:
    import logging

    from ..batch import Engine
    from ..batch.engine import dask_log_level

    # Dask logs every worker start and stop at INFO: keep them for -v and -vv
    dask_log_level(logging.INFO if getattr(args, "verbose", 0) else logging.ERROR)
    settings = with_recording_options(args, load_settings(args.config))  # the tasks read them from the settings
    if args.calibrate:
        return _calibrate(args, settings)
    if not args.recordings:
        raise AtrError("batch: give recordings (.atrlog, .xtf) or --calibrate")
    if args.scheduler in (None, "serial"):  # read here: a missing file is bad input, not a failed task
        from pathlib import Path

        for path in args.recordings:
            if not Path(path).is_file():
                raise AtrError(f"{path}: cannot open: No such file or directory; expected a recording "
                               f"(.atrlog, .xtf or .jsf)")
    from ..batch.grids import check_positions, run_recordings
    from ..calibration.model import PerformanceModel
    from ..node.service import write_contacts

    from .replay import dropped_text

    # files this host sees that need --crs or lack the --frequency asked: one line, before any worker starts
    check_positions(args.recordings, settings.recording.crs, settings.recording.frequency)
    model = PerformanceModel.load(args.model) if args.model else PerformanceModel.shipped()
    t0 = time.perf_counter()
    with Engine(args.scheduler, args.workers, args.retries) as eng:
        print(f"atr-node batch: {len(args.recordings)} recording(s) on {eng.describe()}", file=sys.stderr)
        res = run_recordings(args.recordings, settings, model, eng,
                             progress=_Progress("recordings", args.no_progress or not sys.stderr.isatty()))
    wall = time.perf_counter() - t0
    bad = _report(res.outcomes)
    if args.contacts_out:
        write_contacts(args.contacts_out, res.contacts)
    if args.grid_out and res.grid is not None:
        from ..fusion import snapshot

        snapshot.save(args.grid_out, res.grid)
    summary = {"wall_s": round(wall, 3), "map_s": round(res.map_s, 3), "reduce_s": round(res.reduce_s, 3),
               "recordings": len(args.recordings), "failed": bad, "retried": len(res.retried), "deltas": res.deltas,
               "duplicate_deltas": res.duplicates, "contacts": len(res.contacts),
               "covered_cells": res.grid.covered_cells() if res.grid is not None else 0, **res.info,
               "outcomes": [{"name": o.name, "ok": o.ok, "attempts": o.attempts, "errors": list(o.errors),
                             "seconds": round(o.seconds, 3)} for o in res.outcomes]}
    if args.summary:
        with atomic_open(args.summary, "w") as fh:
            json.dump(summary, fh, indent=2)
    print(f"atr-node batch: {len(args.recordings) - bad}/{len(args.recordings)} recordings, {res.deltas} deltas, "
          f"{summary['tiles_in']} tiles ({dropped_text(summary)}), {len(res.contacts)} contacts; "
          f"map {res.map_s:.1f} s, "
          f"reduce {res.reduce_s:.2f} s, wall {wall:.1f} s", file=sys.stderr)
    return 1 if bad else 0


def _calibrate(args: argparse.Namespace, settings) -> int:
    from ..batch import Engine
    from ..batch.montecarlo import run_calibration
    from ..calibration.estimate import estimate_model
    from ..calibration.sources import images_from_paths, synthetic_images
    from .calibrate import calibration_counts

    cal = settings.calibration
    iterations, targets, seed = calibration_counts(args, cal)
    if args.input:
        images = images_from_paths(args.input, settings=settings, max_images=args.max_images, pixel_m=None,
                                   range0_m=None, crs=settings.recording.crs)
    else:
        images = synthetic_images(args.synthetic, settings=settings, rows=args.rows, cols=args.cols, seed=seed,
                                  seabed=settings.simulation.seabed)
    t0 = time.perf_counter()
    with Engine(args.scheduler, args.workers, args.retries) as eng:
        print(f"atr-node batch --calibrate: {len(images)} image(s) x {iterations} iterations x {targets} targets "
              f"on {eng.describe()}", file=sys.stderr)
        responses, outcomes = run_calibration(images, settings, eng, iterations=iterations, targets_per_image=targets,
                                              seed=seed, progress=_Progress("images", args.no_progress or not sys.stderr.isatty()))
    _report(outcomes)
    wall = time.perf_counter() - t0
    model = estimate_model(responses, calibration=cal, thresholds=settings.detectors.threshold,
                           provenance={"calibration_s": round(wall, 3)})
    out = model.save(args.out)
    print(f"wrote {out} ({responses.n_targets} target signatures, {wall:.1f} s)")
    return 0
