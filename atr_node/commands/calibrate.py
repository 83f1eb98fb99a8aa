"""Estimate detector performance by target injection (SPEC section 5) and write the model file.

Synthetic targets are injected into target-free images over many iterations; the responses of
the four detectors give, per detector, the threshold tau (Dobeck, at calibration.pd_target),
the confidence c(gamma; tau) and the P(y) curve Pd(r; tau) with its Wilson interval. The
images come from recordings (.atrlog or .xtf sonar tiles, or 8-bit PNG textures with --pixel-m) or,
by default, from synthetic seabeds. Writes the model (JSON, versioned) and two figures:
confidence against gamma for three thresholds (paper figure 3) and the P(y) curves (figure 4).

Examples:

    atr-node calibrate --out model.json --plots plots/
    atr-node calibrate --input mission.atrlog --max-images 4 --out model.json
    atr-node calibrate --input survey.xtf --iterations 10 --targets 5 --out model.json
    atr-node calibrate --synthetic 2 --rows 1024 --cols 2048 --iterations 20 --targets 40
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..config import load_settings
from ..errors import AtrError
from ._crs import add_crs_argument, add_frequency_argument, resolve_crs, resolve_frequency
from ._inputs import require_sonar_tile
from ._progress import add_progress_argument


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", metavar="FILE", help="TOML settings (default: built-in defaults)")
    parser.add_argument("--input", metavar="PATH", nargs="*", default=[],
                        help=".atrlog or .xtf recordings (their sonar tiles) or .png seabed images; none: synthetic seabeds")
    parser.add_argument("--max-images", type=int, default=4, metavar="N",
                        help="use at most N tiles per recording (default 4)")
    parser.add_argument("--pixel-m", type=float, default=None, metavar="M",
                        help="pixel size of PNG images in metres (default: sensor.dr_m)")
    parser.add_argument("--range0-m", type=float, default=None, metavar="M",
                        help="ground range of the first column of PNG and synthetic images (default: 2 x altitude)")
    parser.add_argument("--synthetic", type=int, default=1, metavar="N",
                        help="number of synthetic seabed images when no --input is given (default 1)")
    parser.add_argument("--seabed", default=None, help="synthetic seabed type (default: simulation.seabed)")
    parser.add_argument("--rows", type=int, default=2048, help="rows of synthetic images (default 2048)")
    parser.add_argument("--cols", type=int, default=1024, help="columns of synthetic images (default 1024)")
    parser.add_argument("--iterations", type=int, default=None, help="default: calibration.iterations")
    parser.add_argument("--targets", type=int, default=None, help="targets per image; default: calibration.targets_per_image")
    parser.add_argument("--seed", type=int, default=None, help="default: calibration.seed")
    parser.add_argument("--out", default="performance_model.json", metavar="FILE", help="model file to write")
    parser.add_argument("--plots", default=None, metavar="DIR",
                        help="write confidence.png and pyr.png there (default: next to --out)")
    parser.add_argument("--no-plots", action="store_true", help="write no figures")
    add_progress_argument(parser, help="no progress bar on stderr")
    add_crs_argument(parser)
    add_frequency_argument(parser)


class ProgressBar:
    """A one-line text progress bar on a stream (stderr), redrawn in place."""

    def __init__(self, label: str, *, stream=None, width: int = 30, enabled: bool = True) -> None:
        self.label = label
        self.stream = stream or sys.stderr
        self.width = width
        self.enabled = enabled
        self.t0 = time.perf_counter()

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        frac = done / total if total else 1.0
        n = int(round(frac * self.width))
        dt = time.perf_counter() - self.t0
        eta = dt / frac - dt if frac > 0 else float("nan")
        self.stream.write(f"\r{self.label} [{'#' * n}{'.' * (self.width - n)}] {done}/{total} "
                          f"{dt:5.1f} s, {eta:5.1f} s left ")
        if done >= total:
            self.stream.write("\n")
        self.stream.flush()


def calibration_counts(args: argparse.Namespace, cal) -> tuple[int, int, int]:
    """(iterations, targets per image, seed): the command line's, else the config's
    ``[calibration]`` values; shared with ``atr-node batch calibrate``."""
    iterations = args.iterations if args.iterations is not None else cal.iterations
    targets = args.targets if args.targets is not None else cal.targets_per_image
    seed = args.seed if args.seed is not None else cal.seed
    if iterations < 1 or targets < 1:
        raise AtrError("--iterations and --targets must be >= 1")
    return iterations, targets, seed


def run(args: argparse.Namespace) -> int:
    from ..calibration.estimate import estimate_model
    from ..calibration.plots import plot_confidence, plot_pyr
    from ..calibration.responses import collect_responses
    from ..calibration.sources import images_from_paths, synthetic_images

    settings = resolve_frequency(getattr(args, "frequency", None), load_settings(args.config))
    cal = settings.calibration
    iterations, targets, seed = calibration_counts(args, cal)
    seabed = args.seabed or settings.simulation.seabed
    if args.input:
        crs = resolve_crs(getattr(args, "crs", None), settings)
        for path in args.input:  # every recording checked before the first injection
            if Path(path).suffix.lower() in (".atrlog", ".xtf", ".jsf"):
                require_sonar_tile(path, crs=crs, frequency=settings.recording.frequency)
        images = images_from_paths(args.input, settings=settings, max_images=args.max_images,
                                   pixel_m=args.pixel_m, range0_m=args.range0_m, crs=crs)
        source = ", ".join(str(p) for p in args.input)
    else:
        images = synthetic_images(args.synthetic, settings=settings, rows=args.rows, cols=args.cols,
                                  seed=seed, seabed=seabed, range0_m=args.range0_m)
        source = f"synthetic seabed ({seabed})"
    print(f"calibrating on {len(images)} image(s) from {source}: {targets} targets x {iterations} iterations "
          f"per image", file=sys.stderr)
    bar = ProgressBar("inject+score", enabled=not args.no_progress)
    t0 = time.perf_counter()
    responses = collect_responses(images, settings=settings, iterations=iterations, targets_per_image=targets,
                                  seed=seed, progress=bar)
    elapsed = time.perf_counter() - t0
    model = estimate_model(responses, calibration=cal, thresholds=settings.detectors.threshold,
                           provenance={"source": source, "seabed": seabed if not args.input else "recorded",
                                       "calibration_s": round(elapsed, 3)})
    out = model.save(args.out)
    print(f"wrote {out} ({responses.n_targets} target signatures, {elapsed:.1f} s)")
    for d, p in model.detectors.items():
        y = p.pyr
        print(f"  {d:4s} tau={p.tau:9.4g} ({p.tau_source}, Pd {p.pd_at_tau:.3f}) "
              f"conf {p.confidence.confidence[0]:.3f}..{p.confidence.confidence[-1]:.3f}"
              f"{' isotonic' if p.confidence.isotonic_adjusted else ''} "
              f"P(y) {y.edges_m[0]:.0f}-{y.edges_m[-1]:.0f} m")
    if not args.no_plots:
        plots = Path(args.plots) if args.plots else Path(args.out).resolve().parent
        f3 = plot_confidence(responses, model, plots / "confidence.png", calibration=cal)
        f4 = plot_pyr(model, plots / "pyr.png")
        print(f"wrote {f3} and {f4}")
    return 0
