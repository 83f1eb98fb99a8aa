"""Target and non-target detector responses, collected by injection (SPEC section 5).

- Non-target responses: on the target-free image, the maximum of gamma_d over each
  non-overlapping template-sized cell (L rows by W + S(j) columns), so that the prior P(T)
  is per possible target location.
- Target responses: per injected target, the maximum of gamma_d over its template window
  around its anchor (rows ``[i - L//2, i - L//2 + L)``, columns ``[j - W, j + S(j))``).

Only what is needed is scored: the clean image once, then, per iteration, a crop around each
injected target (its windows plus the detectors' margin), normalised with the clean image's
per-range statistics so a crop scores as the whole image would (see :func:`collect_image`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
import logging
import math
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..detectors.windows import window_bounds
from ..errors import AtrError
from .stats import dobeck_threshold, wilson_interval

log = logging.getLogger(__name__)

TRAITS: tuple[str, ...] = ("nominal", "reflectivity_db", "height_m", "headroom_db", "whole")
"""Per-target traits that :func:`collect_image` records: of the injected population, the
headroom of the seabed where it lies (:func:`~atr_node.calibration.looks.headroom_db`), and
``whole`` (0/1): 1 where its footprint lies clear of the swath's end, 0 where the sonar cut its
shadow there (docs/calibration.md, "P(y) at the swath's end")."""


@dataclass(frozen=True)
class Responses:
    """Responses of several detectors to the same injected targets and clean cells.

    ``target[d]`` (m,) and ``target_range_m`` (m,), ``target_shape`` (m,) describe the
    injected targets in injection order; ``nontarget[d]`` (k_d,) the clean cells. NaN = the
    detector did not cover it. ``target_traits`` holds per-target arrays (m,) of the injected
    population (:data:`TRAITS`: ``nominal`` as 0/1, ``reflectivity_db``, ``height_m`` above the
    seabed, ``headroom_db`` of the seabed there); empty when not recorded.
    ``nontarget_headroom_db`` (k,): the headroom of each clean cell (its first column's), when
    every detector has the same cells; None when not recorded.
    """

    detectors: tuple[str, ...]
    target: Mapping[str, np.ndarray]
    nontarget: Mapping[str, np.ndarray]
    target_range_m: np.ndarray
    target_shape: tuple[str, ...] = ()
    provenance: Mapping[str, Any] = field(default_factory=dict)
    target_traits: Mapping[str, np.ndarray] = field(default_factory=dict)
    nontarget_headroom_db: np.ndarray | None = None

    def __post_init__(self) -> None:
        m = np.asarray(self.target_range_m).size
        for k, v in self.target_traits.items():
            if np.asarray(v).shape != (m,):
                raise ValueError(f"target trait {k!r}: expected shape ({m},), got {np.shape(v)}")
        for d in self.detectors:
            if np.asarray(self.target[d]).shape != (m,):
                raise ValueError(f"target responses of {d!r}: expected shape ({m},), got {np.shape(self.target[d])}")
            if np.asarray(self.nontarget[d]).ndim != 1:
                raise ValueError(f"non-target responses of {d!r} must be 1-D")

    @property
    def n_targets(self) -> int:
        return int(np.asarray(self.target_range_m).size)

    def head(self, n_targets: int) -> "Responses":
        """The first ``n_targets`` injected targets (all non-target cells): the responses a
        shorter calibration of the same images would have given."""
        n = max(0, int(n_targets))
        return Responses(self.detectors, {d: self.target[d][:n] for d in self.detectors}, dict(self.nontarget),
                         np.asarray(self.target_range_m)[:n], tuple(self.target_shape[:n]), dict(self.provenance),
                         {k: np.asarray(v)[:n] for k, v in self.target_traits.items()}, self.nontarget_headroom_db)

    @property
    def nominal(self) -> np.ndarray:
        """(m,) bool: the targets of the nominal population (all of them when not recorded)."""
        v = self.target_traits.get("nominal")
        return np.ones(self.n_targets, dtype=bool) if v is None else np.asarray(v) > 0

    @property
    def whole(self) -> np.ndarray:
        """(m,) bool: the targets whose footprint lies clear of the swath's end (all of them
        when not recorded). The thresholds, confidence curves and look scores read these only;
        P(y) reads every target (docs/calibration.md, "P(y) at the swath's end")."""
        v = self.target_traits.get("whole")
        return np.ones(self.n_targets, dtype=bool) if v is None else np.asarray(v) > 0

    @staticmethod
    def concat(parts: Sequence["Responses"]) -> "Responses":
        """Pool the responses of several images (same detectors)."""
        if not parts:
            raise ValueError("no responses to concatenate")
        dets = parts[0].detectors
        for p in parts:
            if p.detectors != dets:
                raise ValueError(f"responses of different detectors: {p.detectors} vs {dets}")
        prov = dict(parts[0].provenance)
        prov["n_images"] = sum(int(p.provenance.get("n_images", 1)) for p in parts)
        if any("iterations_done" in p.provenance for p in parts):  # per image, in order
            prov["iterations_done"] = [i for p in parts for i in p.provenance.get("iterations_done", ())]
        areas = [(p.provenance.get("cell_area_m2"), max(1, int(p.provenance.get("n_cells", 1)))) for p in parts]
        areas = [(a, w) for a, w in areas if isinstance(a, (int, float)) and a > 0]
        if areas:  # weighted by the cells of each image
            prov["cell_area_m2"] = sum(a * w for a, w in areas) / sum(w for _, w in areas)
        # A trait pools only when every part recorded it.
        keys = [k for k in parts[0].target_traits if all(k in p.target_traits for p in parts)]
        traits = {k: np.concatenate([np.asarray(p.target_traits[k], dtype=np.float64) for p in parts]) for k in keys}
        heads = [p.nontarget_headroom_db for p in parts]
        return Responses(
            dets,
            {d: np.concatenate([np.asarray(p.target[d], dtype=np.float64) for p in parts]) for d in dets},
            {d: np.concatenate([np.asarray(p.nontarget[d], dtype=np.float64) for p in parts]) for d in dets},
            np.concatenate([np.asarray(p.target_range_m, dtype=np.float64) for p in parts]),
            tuple(s for p in parts for s in p.target_shape), prov, traits,
            None if any(h is None for h in heads) else np.concatenate([np.asarray(h, dtype=np.float64) for h in heads]))


# ----------------------------------------------------------------------------------------
# Windows on a score map


def cell_edges(shadow_px: np.ndarray, echo_px: int) -> np.ndarray:
    """Column edges of non-overlapping template-wide cells: a cell starting at column c is
    ``echo_px + shadow_px[c]`` wide (the last one may be narrower). (n_cells + 1,) int."""
    cols = int(np.asarray(shadow_px).size)
    edges = [0]
    while edges[-1] < cols:
        c = edges[-1]
        edges.append(min(cols, c + int(echo_px) + int(shadow_px[c])))
    return np.asarray(edges, dtype=np.intp)


def cell_maxima(score: np.ndarray, *, length_px: int, echo_px: int, shadow_px: np.ndarray) -> np.ndarray:
    """Maximum of ``score`` over each non-overlapping template-sized cell (SPEC section 5).

    Parameters
    ----------
    score : (rows, cols) float, NaN = not covered
    length_px, echo_px : int
        L and W of the template in pixels.
    shadow_px : (cols,) int
        S(j) per column.

    Returns
    -------
    (n_cells,) float64: cells of ``length_px`` rows (the last rows that do not fill a cell are
    left out) and :func:`cell_edges` columns; NaN where a cell has no finite score.
    """
    s = np.asarray(score, dtype=np.float64)
    rows, cols = s.shape
    nr = rows // max(1, int(length_px))
    if nr == 0 or cols == 0:
        return np.empty(0)
    s = s[: nr * length_px]
    # fmax ignores NaN unless every value is NaN: an all-NaN cell stays NaN (not covered).
    by_rows = np.fmax.reduce(s.reshape(nr, length_px, cols), axis=1)
    edges = cell_edges(shadow_px, echo_px)
    cells = np.fmax.reduceat(by_rows, edges[:-1], axis=1)
    return cells.ravel()


def window_max(score: np.ndarray, row: int, col: int, *, row0: int, length_px: int, echo_px: int,
               shadow_px: int) -> float:
    """Maximum finite score over the template window of anchor (row, col), clipped to the map;
    NaN when the window holds no finite score."""
    r0, r1, c0, c1 = window_bounds(score.shape, row, col, row0=row0, length_px=length_px, echo_px=echo_px,
                                   shadow_px=shadow_px)
    if r0 >= r1 or c0 >= c1:
        return float("nan")
    w = score[r0:r1, c0:c1]
    return float(np.fmax.reduce(w.ravel())) if w.size else float("nan")


ProgressFn = Callable[[int, int], None]
"""progress(done, total) called after each iteration."""


@dataclass(frozen=True)
class CalibrationImage:
    """A target-free ground-range image to inject into: pixels (rows, cols) float32, NaN = no
    data, with its axes."""

    pixels: np.ndarray
    range0_m: float
    dr_m: float
    dx_m: float
    altitude_m: float
    name: str = "image"
    full_scale: float | None = None
    """The recording's saturation in intensity (:attr:`~atr_node.records.tile.Tile.saturation`):
    injected pixels are clipped to it, as the sensor would have clipped the target's echo.
    None: unknown (float data), nothing clipped."""

    @property
    def ranges_m(self) -> np.ndarray:
        return self.range0_m + self.dr_m * np.arange(self.pixels.shape[1], dtype=np.float64)

    @classmethod
    def from_tile(cls, tile: Any, *, altitude_m: float) -> "CalibrationImage":
        """From a :class:`~atr_node.records.tile.Tile` (slant tiles converted to ground range at
        the tile's nav altitude, or ``altitude_m`` when it has no nav; then amplitude squared into
        intensity, in the node's order: ground range in the nav merger, squared in
        ``Pipeline._on_tile``, :meth:`~atr_node.records.tile.Tile.as_intensity`)."""
        alt = float(np.nanmean(tile.nav.altitude_m)) if tile.nav is not None else float(altitude_m)
        g = (tile.ground_range(None if tile.nav is not None else alt) if tile.slant else tile).as_intensity()
        return cls(np.ascontiguousarray(g.pixels, dtype=np.float32), float(g.range0_m), float(g.dr_m),
                   float(g.dx_m), alt, name=tile.ident, full_scale=g.saturation)


def _settings_provenance(settings: Any) -> dict[str, Any]:
    import dataclasses

    return {"sensor": dataclasses.asdict(settings.sensor), "template": dataclasses.asdict(settings.template),
            "simulation": dataclasses.asdict(settings.simulation),
            "population": dataclasses.asdict(_population(settings))}


def _population(settings: Any) -> Any:
    """The injected population of ``settings`` (the default one for settings without a
    ``calibration`` section)."""
    from ..config import PopulationSettings

    cal = getattr(settings, "calibration", None)
    return getattr(cal, "population", None) or PopulationSettings()


MIN_NOMINAL = 20
"""Fewest nominal target responses Dobeck's rule reads with ``threshold_on = "nominal"``;
with fewer it reads the whole population (and the provenance says so)."""


def thresholds_on_nominal(calibration: Any, nominal: np.ndarray) -> bool:
    """Whether Dobeck's thresholds read the nominal targets only (``population.threshold_on =
    "nominal"`` and at least :data:`MIN_NOMINAL` of them) or the whole population."""
    return calibration.population.threshold_on == "nominal" and int(np.sum(nominal)) >= MIN_NOMINAL


class Convergence:
    """When one image's iterations may stop (issue 19): after each iteration from the second,
    for every detector,

    - its Dobeck threshold on the image's targets so far (the nominal ones when there are
      enough of them, as :func:`~.estimate.estimate_model` sets it) moved by at most
      ``converge_tau`` x the interquartile range of its target responses since the last
      iteration, and
    - the 95 % Wilson half-width of its Pd at that threshold (detected / injected targets of
      the image), divided by sqrt(``pooled``) (the images pooled into the model), is at most
      ``converge_pd``.

    Each image judges its own responses only, so the rule gives the same iterations whatever
    process collects which image, and the same model for the same tiles, settings and seed."""

    def __init__(self, calibration: Any, pooled: int) -> None:
        self.calibration = calibration
        self.tau_tol, self.pd_tol = float(calibration.converge_tau), float(calibration.converge_pd)
        self.scale = math.sqrt(max(1, int(pooled)))
        self.last: dict[str, float] = {}

    @property
    def enabled(self) -> bool:
        return self.tau_tol > 0.0 and self.pd_tol > 0.0

    def done(self, target: Mapping[str, list[float]], nominal: list[float],
             whole: list[float] | None = None) -> bool:
        """Whether the responses so far (each detector's, in injection order) have converged;
        call once after each iteration. ``whole``: as the trait (the thresholds read those
        targets only, as :func:`~.estimate.estimate_model`'s); default all."""
        keep = np.ones(len(nominal), dtype=bool) if whole is None else np.asarray(whole, dtype=float) > 0
        nom = (np.asarray(nominal, dtype=float) > 0) & keep
        use_nominal = thresholds_on_nominal(self.calibration, nom)
        ok, first = True, not self.last
        for d, values in target.items():
            x = np.asarray(values, dtype=np.float64)
            sel = x[nom] if use_nominal else x[keep]
            sel = sel[np.isfinite(sel)]
            if sel.size == 0:
                return False
            tau = dobeck_threshold(sel, self.calibration.pd_target, default=0.0)
            finite = x[np.isfinite(x)]
            q1, q3 = np.percentile(finite, [25.0, 75.0])
            moved = abs(tau - self.last.get(d, math.inf))
            self.last[d] = tau
            lo, hi = wilson_interval(float(np.sum(finite > tau)), float(x.size))
            if first or moved > self.tau_tol * (q3 - q1) or (float(hi) - float(lo)) / 2.0 / self.scale > self.pd_tol:
                ok = False
        return ok and not first


def collect_image(image: CalibrationImage, *, settings: Any, iterations: int, targets_per_image: int,
                  rng: np.random.Generator, enabled: Sequence[str] | None = None,
                  progress: Callable[[], None] | None = None, scoring: str = "auto",
                  pooled: int | None = None) -> Responses:
    """Responses of one image: non-target cells of the clean image, then up to ``iterations``
    rounds of ``targets_per_image`` injected targets: fewer when ``pooled`` (the number of
    images pooled into the model) is given and the image's responses converge first
    (:class:`Convergence`, ``calibration.converge_tau`` and ``converge_pd``).

    Lazy scoring: the clean image is scored once. Each injected target is scored on a crop
    (or, where the crops together cover more than the image, the injected image once):
    its template window of anchors grown by the windows' reach, with the clean image's
    per-range background b(j) and median m(j). Every window of every anchor in that template
    window then reads exactly the pixels it reads in the whole image, so the response equals
    ``score_maps(injected, background=b, median=m)`` there (a test checks it), at a small
    fraction of the cost. Using the clean image's b and m is the node's steady state: its
    tracked background is not moved by one target.

    Parameters
    ----------
    image : CalibrationImage
    settings : atr_node.config.Settings
        ``template``, ``detectors`` (enabled, floors), ``sensor`` and ``simulation``.
    rng : numpy.random.Generator
        Draws every placement and the speckle of the signatures.
    progress : callable, optional
        Called once after each iteration (and once for each iteration a convergence spared).
    scoring : {"auto", "crops", "whole"}
        How the injected targets are scored: ``"crops"`` each on its crop; ``"whole"`` the
        whole injected image once an iteration; ``"auto"`` the whole image when the crops
        together cover at least its area (the same responses to rounding, for less work; with
        ``detectors.decimation`` > 1 the sampled pixels align to the image instead of to each
        crop, as they align to the unit in the node).
    """
    if scoring not in ("auto", "crops", "whole"):
        raise ValueError(f"scoring must be 'auto', 'crops' or 'whole', got {scoring!r}")
    from ..detectors.background import column_mean, column_median
    from ..detectors.engine import score_maps
    from ..detectors.windows import window_geometry
    from ..simulation.inject import inject_targets
    from ..simulation.signature import background_curve
    from .looks import headroom_db

    dets = tuple(settings.detectors.enabled if enabled is None else enabled)
    px = np.ascontiguousarray(image.pixels, dtype=np.float32)
    rows, cols = px.shape
    geo = dict(dr_m=image.dr_m, dx_m=image.dx_m, altitude_m=image.altitude_m)
    common = dict(template=settings.template, detectors=settings.detectors, enabled=dets)
    geom = window_geometry(image.ranges_m, template=settings.template, **geo)
    b, m = column_mean(px), column_median(px)
    clean = score_maps(px, range0_m=image.range0_m, background=b, median=m, **geo, **common)
    nontarget = {d: cell_maxima(clean[d], length_px=geom.length_px, echo_px=geom.echo_px,
                                shadow_px=geom.shadow_px) for d in dets}
    del clean
    # the seabed's headroom under the recording's full scale, per column: a clean cell's is
    # its first column's, an injected target's its anchor column's
    head = headroom_db(image.full_scale, b)
    edges = cell_edges(geom.shadow_px, geom.echo_px)
    nontarget_head = np.tile(head[edges[:-1]], rows // max(1, geom.length_px))
    up, down, left, right = geom.reach()
    g = background_curve(px)  # the injector's gray-level curve g(r), once for all iterations
    target: dict[str, list[float]] = {d: [] for d in dets}
    ranges: list[float] = []
    shapes: list[str] = []
    traits: dict[str, list[float]] = {k: [] for k in TRAITS}
    population = _population(settings)
    conv = Convergence(settings.calibration, pooled) if pooled is not None else None
    conv = conv if conv is not None and conv.enabled else None
    done = 0
    for _ in range(iterations):
        injected, placed = inject_targets(px, range0_m=image.range0_m, n_targets=targets_per_image, rng=rng,
                                          sensor=settings.sensor, simulation=settings.simulation,
                                          template=settings.template, g=g, population=population,
                                          swath_end=True, **geo)
        if image.full_scale is not None:  # the sensor clips the target's echo as it clips the seabed's
            np.minimum(injected, np.float32(image.full_scale), out=injected)
        crops = []
        for t in placed:
            i, j = int(t.row), int(t.col)
            s_j = int(geom.shadow_px[min(max(j, 0), cols - 1)])
            # Anchors of the template window, then every pixel their windows read.
            a_r0, a_r1 = i + geom.row0, i + geom.row1
            a_c0, a_c1 = j - geom.echo_px, j + s_j
            r0, r1 = max(0, a_r0 - up), min(rows, a_r1 + down)
            c0, c1 = max(0, a_c0 - left), min(cols, a_c1 + right)
            crops.append((t, i, j, s_j, r0, r1, c0, c1))
        # The crops together cover more than the image (a short tile full of targets: the
        # node's on-line calibration): one scoring of the whole image costs less, and gives
        # what each crop gives, to rounding (the crops read exactly their windows' pixels).
        whole = None
        if scoring == "whole" or (scoring == "auto" and sum((r1 - r0) * (c1 - c0) for *_, r0, r1, c0, c1 in crops)
                                  >= rows * cols):
            whole = score_maps(injected, range0_m=image.range0_m, background=b, median=m, **geo, **common)
        for t, i, j, s_j, r0, r1, c0, c1 in crops:
            if whole is not None:
                sc, r0, c0 = whole, 0, 0
            else:
                sc = score_maps(injected[r0:r1, c0:c1], range0_m=image.range0_m + c0 * image.dr_m,
                                background=b[c0:c1], median=m[c0:c1], **geo, **common)
            for d in dets:
                target[d].append(window_max(sc[d], i - r0, j - c0, row0=geom.row0, length_px=geom.length_px,
                                            echo_px=geom.echo_px, shadow_px=s_j))
            ranges.append(float(t.range_m))
            shapes.append(str(t.shape))
            traits["nominal"].append(float(t.nominal))
            traits["reflectivity_db"].append(float(t.reflectivity_db))
            traits["height_m"].append(float(t.height_m))
            traits["headroom_db"].append(float(head[min(max(j, 0), cols - 1)]))
            traits["whole"].append(float(not t.cut))
        done += 1
        if progress is not None:
            progress()
        if conv is not None and done < iterations and conv.done(target, traits["nominal"], traits["whole"]):
            if progress is not None:
                for _ in range(iterations - done):
                    progress()
            break
    n_cells = int(np.isfinite(np.column_stack([nontarget[d] for d in dets])).any(axis=1).sum()) if dets else 0
    # the mean area of the clean cells scored: the cell the prior P(T) is per (SPEC 6.1)
    area = (rows // max(1, geom.length_px)) * geom.length_px * image.dx_m * cols * image.dr_m
    prov = {"n_images": 1, "images": [image.name], "image_shape": [rows, cols], "iterations": iterations,
            "targets_per_image": targets_per_image, "iterations_done": [done],
            "cell_area_m2": area / max(1, next(iter(nontarget.values())).size) if dets else None,
            "n_cells": n_cells}
    return Responses(dets, {d: np.asarray(v, dtype=np.float64) for d, v in target.items()}, nontarget,
                     np.asarray(ranges, dtype=np.float64), tuple(shapes), prov,
                     {k: np.asarray(v, dtype=np.float64) for k, v in traits.items()}, nontarget_head)


def _room_for_targets(image: CalibrationImage, settings: Any) -> bool:
    """At least two SMF context windows (SPEC 2.3) along-track and one across: the injector
    keeps targets that far from the edges."""
    rows, cols = image.pixels.shape
    t = settings.template
    ctx_rows = t.context_factor * t.length_m / image.dx_m
    ctx_cols = t.context_factor * (t.echo_width_m + t.shadow_max_m) / image.dr_m
    return rows >= 2 * ctx_rows and cols >= ctx_cols and bool(np.isfinite(image.pixels).any())


def usable_images(images: Sequence[CalibrationImage], *, settings: Any) -> tuple[list[CalibrationImage], list[str]]:
    """(the images with room for a target and its context window, the names of the others);
    the others are logged, and none usable raises :class:`AtrError`."""
    if not images:
        raise ValueError("collect_responses: no image to calibrate on")
    usable = [im for im in images if _room_for_targets(im, settings)]
    skipped = [im.name for im in images if not _room_for_targets(im, settings)]
    if skipped:
        log.warning("calibration: %d image(s) too small for one target and its context window, skipped: %s",
                    len(skipped), ", ".join(skipped))
    if not usable:
        raise AtrError(f"calibration: no image has room for a target and its context window "
                       f"({len(images)} image(s), e.g. {images[0].name} {images[0].pixels.shape})")
    return usable, skipped


def collect_parts(usable: Sequence[CalibrationImage], *, settings: Any, iterations: int, targets_per_image: int,
                  seed: int, which: Sequence[int] | None = None, enabled: Sequence[str] | None = None,
                  progress: Callable[[], None] | None = None) -> dict[int, Responses]:
    """The responses of usable images ``which`` (indices into ``usable``; all by default),
    image k drawing from the random stream ``(seed, k)``: any split of the images between
    processes gives the parts one process gives. ``progress()`` after each iteration."""
    ks = range(len(usable)) if which is None else which
    return {k: collect_one(usable[k], k, len(usable), settings=settings, iterations=iterations,
                           targets_per_image=targets_per_image, seed=seed, enabled=enabled, progress=progress)
            for k in ks}


def collect_one(image: CalibrationImage, k: int, n_usable: int, *, settings: Any, iterations: int,
                targets_per_image: int, seed: int, enabled: Sequence[str] | None = None,
                progress: Callable[[], None] | None = None) -> Responses:
    """The responses of usable image ``k`` of ``n_usable``: its random stream ``(seed, k)``, and
    the early stop at convergence reading the pooled count (what every caller must pass alike:
    :func:`collect_parts`, the batch Monte Carlo's tasks)."""
    return collect_image(image, settings=settings, iterations=iterations, targets_per_image=targets_per_image,
                         rng=np.random.default_rng([seed, k]), enabled=enabled, progress=progress, pooled=n_usable)


def pool_parts(parts: Mapping[int, Responses], *, n_usable: int, skipped: Sequence[str], settings: Any,
               iterations: int, targets_per_image: int, seed: int) -> Responses:
    """The pooled responses of every usable image's part (:func:`collect_parts`), in image
    order, with the calibration's provenance: what :func:`collect_responses` returns."""
    if sorted(parts) != list(range(n_usable)):
        raise ValueError(f"pool_parts: parts of images {sorted(parts)}, expected 0..{n_usable - 1}")
    ordered = [parts[k] for k in range(n_usable)]
    out = Responses.concat(ordered)
    prov = dict(out.provenance)
    prov.update({"images": [n for p in ordered for n in p.provenance["images"]], "iterations": iterations,
                 "targets_per_image": targets_per_image, "seed": seed, "skipped_images": list(skipped)})
    prov.update(_settings_provenance(settings))
    prov["population"]["n_nominal"] = int(out.nominal.sum())
    return dataclasses.replace(out, provenance=prov)


def collect_responses(images: Sequence[CalibrationImage], *, settings: Any, iterations: int,
                      targets_per_image: int, seed: int, enabled: Sequence[str] | None = None,
                      progress: ProgressFn | None = None) -> Responses:
    """Responses of several images pooled (SPEC section 5); image k draws from the random
    stream ``(seed, k)``, so the result depends only on the images, settings and seed."""
    usable, skipped = usable_images(images, settings=settings)
    total = iterations * len(usable)
    done = [0]

    def tick() -> None:
        done[0] += 1
        if progress is not None:
            progress(done[0], total)

    parts = collect_parts(usable, settings=settings, iterations=iterations, targets_per_image=targets_per_image,
                          seed=seed, enabled=enabled, progress=tick)
    return pool_parts(parts, n_usable=len(usable), skipped=skipped, settings=settings, iterations=iterations,
                      targets_per_image=targets_per_image, seed=seed)
