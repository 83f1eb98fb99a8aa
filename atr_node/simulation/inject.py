"""Injection of simulated targets into any ground-range tile, with their exact truth.

:func:`inject_targets` is the shared simulation API (the engineers' contracts): it places targets (given
or random, apart from each other and from the edges, on valid pixels), traces them
(:mod:`.raytrace`), applies the along-track beam and blends them into a copy of the pixels
(:mod:`.signature`) with the contrast of the sonar model (:mod:`.performance`).

Truth anchor (shared convention, SPEC section 1): ``row`` = the row of the target's
along-track centre; ``col`` = the first column of its shadow, i.e. the boundary between the
echo zone and the shadow zone: along the anchor row, the first column past the brightest one
where the model's mean gray level falls below half the background (:func:`anchor_column`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from ..config import PopulationSettings, SensorSettings, SimulationSettings, TemplateSettings
from ..errors import GeometryError
from .meshes import Mesh, builtin_mesh, place
from .performance import SonarModel
from .raytrace import Signature, TraceWindow, trace_many, trace_window
from .signature import (along_track_kernel, background_curve, blur_along_track, blurred_footprint, draw_speckle,
                        render)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Placement:
    """Where and how to put one target in a tile.

    ``row`` may be fractional (along-track centre in rows); ``heading_deg`` is the angle of
    the target's axis from the along-track axis towards increasing range.
    """

    shape: str
    row: float
    range_m: float
    heading_deg: float = 0.0
    burial_m: float = 0.0
    mesh: Mesh | None = field(default=None, compare=False)
    """A custom mesh (local frame, see :mod:`.meshes`); None: the built-in ``shape``."""
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Factors on the mesh's length, width and height (local x, y, z)."""
    roll_deg: float = 0.0
    """Tilt about the target's own axis, then ``pitch_deg`` about its width; the tilted
    target rests on its lowest point (:meth:`.Mesh.tilted`)."""
    pitch_deg: float = 0.0
    reflectivity_db: float = 0.0
    """Echo level relative to the sonar model's: the echo intensity is multiplied by
    ``10 ** (reflectivity_db / 10)``."""
    nominal: bool = True
    """Drawn from the nominal population (built-in size, level, proud, 0 dB); see
    :func:`draw_placement`."""


@dataclass(frozen=True)
class InjectedTarget:
    """Truth of one injected target."""

    shape: str
    row: int
    """Anchor row: the target's along-track centre (outside 0..rows-1 for a target cut by
    the tile's edge, which a mission renders in both tiles)."""
    col: int
    """Anchor column: the first column of its shadow (echo/shadow boundary)."""
    range_m: float
    """Ground range of the target's centre."""
    heading_deg: float
    burial_m: float
    footprint: tuple[int, int, int, int]
    """(row0, row1, col0, col1), half-open: every modified pixel is inside."""
    echo_sum: float
    """Sum of the echo strength e over the footprint."""
    shadow_px: float
    """Sum of p_shadow over the footprint (hidden pixels)."""
    rho_shadow: float
    """Model shadow-to-background intensity ratio at ``range_m``."""
    rho_echo: float
    """Model echo-to-background intensity ratio at ``range_m`` (before ``reflectivity_db``)."""
    reflectivity_db: float = 0.0
    """Echo level relative to the model's (rendered echo = rho_echo 10^(dB/10) e g)."""
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    height_m: float = float("nan")
    """Height of the (scaled, tilted) target above the seabed once buried: what the sonar sees."""
    nominal: bool = True
    cut: bool = False
    """Placed by ``swath_end``: its signature runs past the tile's last column, the shadow cut
    there (:func:`inject_targets`)."""


def anchor_column(sig: Signature, row: int, rho_shadow: np.ndarray, rho_echo: np.ndarray) -> int:
    """Tile column of the echo/shadow boundary of a signature along ``row`` (see module doc).

    The model's mean gray level relative to the background,
    ``m = p_seabed + p_shadow rho_shadow + e rho_echo`` (per tile column for the rho arrays),
    is followed from its brightest column outwards; the anchor is the first column where it
    falls below 1/2 (the start of the dark shadow), or, without any, the column past the echo.
    """
    i = min(max(row - sig.row0, 0), sig.shape[0] - 1)
    c0, c1 = sig.col0, sig.col0 + sig.shape[1]
    e = sig.echo[i].astype(np.float64)
    p = sig.p_shadow[i].astype(np.float64)
    m = (1.0 - p) + p * rho_shadow[c0:c1] + e * rho_echo[c0:c1]
    peak = int(np.argmax(m))
    dark = (np.arange(m.size) > peak) & (m < 0.5)
    if dark.any():
        return c0 + int(np.argmax(dark))
    first_dark = np.flatnonzero(m < 0.5)  # no highlight before the shadow (weak echo near nadir)
    if first_dark.size:
        return c0 + int(first_dark[0])
    lit = np.flatnonzero(e > 0)
    return c0 + (min(int(lit[-1]) + 1, m.size - 1) if lit.size else m.size // 2)


@lru_cache(maxsize=4096)
def _kernel(range_m: float, dx_m: float, sensor: SensorSettings) -> np.ndarray:
    """The along-track beam at a range rounded to 10 cm (cached: it changes slowly)."""
    k = along_track_kernel(range_m, dx_m=dx_m, sensor=sensor)
    k.setflags(write=False)
    return k


@lru_cache(maxsize=64)
def _ratios(model: SonarModel, range0_m: float, dr_m: float, cols: int,
            altitude_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(rho_shadow, rho_echo) per tile column; cached, as calibration calls with one geometry."""
    rs, re = model.ratios(range0_m + dr_m * np.arange(cols), altitude_m)
    rs.setflags(write=False)
    re.setflags(write=False)
    return rs, re


@lru_cache(maxsize=32)
def _builtin(shape: str) -> Mesh:
    """Built-in meshes are immutable values: build each once."""
    return builtin_mesh(shape)


def _mesh_for(p: Placement) -> Mesh:
    """The placement's mesh in its local frame: scaled, then tilted and set back down."""
    m = p.mesh if p.mesh is not None else _builtin(p.shape)
    if p.scale != (1.0, 1.0, 1.0):
        m = m.scaled(*p.scale)
    if p.roll_deg or p.pitch_deg:
        m = m.tilted(roll_deg=p.roll_deg, pitch_deg=p.pitch_deg)
    return m


def draw_placement(rng: np.random.Generator, *, row_span: tuple[float, float], range_span_m: tuple[float, float],
                   population: PopulationSettings | None = None,
                   shapes: tuple[str, ...] = ("cylinder", "cone", "wedge", "sphere"),
                   max_burial_m: float = 0.0) -> Placement:
    """One random target: shape, along-track row, ground range and heading (the nominal
    population), and with ``population.mode = "varied"`` its size, height, tilt, burial and
    reflectivity (issue 17 item 5; :class:`~atr_node.config.PopulationSettings`).

    Without ``population`` (or with ``mode = "fixed"``) the draws are exactly those of the
    nominal population, so a seed gives the same targets as before the population existed.
    A varied draw first decides (probability ``nominal_fraction``) whether the target is
    nominal; the rest of its draws always come in the same order, so a seed fixes them all.
    The burial depth is a fraction of the height of the scaled, tilted mesh.
    """
    if population is not None:
        shapes = population.shapes
    varied = population is not None and population.mode == "varied"
    nominal = not varied or bool(rng.uniform() < population.nominal_fraction)
    # the draw of rng.choice(shapes), without its array conversion (6 us a call; a test checks
    # the two agree)
    shape = str(shapes[int(rng.integers(0, len(shapes)))])
    row = float(rng.uniform(*row_span))
    range_m = float(rng.uniform(*range_span_m))
    heading = float(rng.uniform(0.0, 360.0))
    if not varied:
        burial = float(rng.uniform(0.0, max_burial_m)) if max_burial_m > 0 else 0.0
        return Placement(shape=shape, row=row, range_m=range_m, heading_deg=heading, burial_m=burial)
    pop = population
    size = rng.uniform(*pop.size_scale)
    scale = (float(size * rng.uniform(*pop.axis_scale)), float(size * rng.uniform(*pop.axis_scale)),
             float(size * rng.uniform(*pop.height_scale)))
    roll, pitch = (float(a) for a in rng.uniform(-pop.tilt_deg, pop.tilt_deg, 2))
    burial_fraction = float(rng.uniform(*pop.burial_fraction))
    reflectivity_db = float(rng.uniform(*pop.reflectivity_db))
    if nominal:
        return Placement(shape=shape, row=row, range_m=range_m, heading_deg=heading, nominal=True)
    p = Placement(shape=shape, row=row, range_m=range_m, heading_deg=heading, scale=scale, roll_deg=roll,
                  pitch_deg=pitch, reflectivity_db=reflectivity_db, nominal=False)
    burial_m = burial_fraction * _mesh_for(p).height_m
    return Placement(shape=shape, row=row, range_m=range_m, heading_deg=heading, burial_m=burial_m, scale=scale,
                     roll_deg=roll, pitch_deg=pitch, reflectivity_db=reflectivity_db, nominal=False)


def _altitude(altitude_m: float | np.ndarray) -> float:
    a = np.asarray(altitude_m, dtype=np.float64)
    alt = float(np.nanmean(a)) if a.size else float("nan")
    if not (math.isfinite(alt) and alt > 0):
        raise GeometryError(f"altitude must be finite and > 0, got {altitude_m!r}")
    return alt


BATCH = True
"""Trace the random placements of one call in one :func:`~.raytrace.trace_many` batch (with
:data:`PRECHECK`), with the same placements, draws and pixels as tracing them one by one
(False, the reference the tests compare with). Explicit placements are always traced in one
batch."""

PRECHECK = True
"""Check a random placement before tracing it (:func:`_anchor_taken`, then the footprint the
trace window gives): the same placements and draws as checking the traced signature (False,
the reference the tests compare with), at a small part of the cost where the tile is full
(issue 19: 97 % of the traces of an on-line calibration were refused afterwards)."""


@dataclass
class _Ready:
    """A placement with its window, checked and ready to trace; ``speckle`` is drawn at
    placement when the tile's targets are traced in one batch."""

    p: Placement
    local: Mesh
    window: TraceWindow
    kernel: np.ndarray
    fp: tuple[int, int, int, int]
    """The blurred signature's footprint, known from the window."""
    speckle: tuple[np.ndarray, np.ndarray] | None = None


def _anchor_taken(p: Placement, taken: list[tuple[int, int, int, int]], gap: tuple[int, int], *, range0_m: float,
                  dr_m: float) -> bool:
    """Whether the pixel of ``p``'s centre (row ``p.row``, range ``p.range_m``) lies in a placed
    footprint grown by ``gap``. A target's trace window holds the pixel of its centre (the
    mesh's bounding box holds the centre of every built-in shape, whatever its heading), so
    then :func:`_overlaps` would refuse its footprint: the same refusal, without placing the
    mesh or tracing it."""
    ra = int(math.floor(p.row + 0.5))
    ca = int(math.floor((p.range_m - (range0_m - dr_m / 2)) / dr_m))
    for q0, q1, d0, d1 in taken:
        if q0 - gap[0] <= ra < q1 + gap[0] and d0 - gap[1] <= ca < d1 + gap[1]:
            return True
    return False


def _overlaps(fp: tuple[int, int, int, int], taken: list[tuple[int, int, int, int]], gap: tuple[int, int]) -> bool:
    r0, r1, c0, c1 = fp
    for q0, q1, d0, d1 in taken:
        if r0 < q1 + gap[0] and q0 < r1 + gap[0] and c0 < d1 + gap[1] and d0 < c1 + gap[1]:
            return True
    return False


def inject_targets(pixels: np.ndarray, *, range0_m: float, dr_m: float, dx_m: float,
                   altitude_m: float | np.ndarray, n_targets: int | None = None,
                   placements: list[Placement] | None = None, rng: np.random.Generator,
                   sensor: SensorSettings | None = None, simulation: SimulationSettings | None = None,
                   template: TemplateSettings | None = None, kind: str = "intensity",
                   shapes: tuple[str, ...] = ("cylinder", "cone", "wedge", "sphere"),
                   range_span_m: tuple[float, float] | None = None, max_burial_m: float = 0.0,
                   population: PopulationSettings | None = None, g: np.ndarray | None = None,
                   max_tries: int = 30, swath_end: bool = False) -> tuple[np.ndarray, list[InjectedTarget]]:
    """Inject simulated targets into a copy of a ground-range tile.

    Parameters
    ----------
    pixels : ndarray, shape (rows, cols)
        Host pixels (linear intensity or amplitude, NaN = no data); not modified.
    range0_m, dr_m, dx_m
        Ground range of column 0, range-bin and ping spacing.
    altitude_m
        Sensor altitude (a scalar, or per-row values whose mean is used).
    n_targets
        Number of random targets (ignored when ``placements`` is given).
    placements
        Exact placements; a target whose signature falls outside the tile is skipped.
    rng
        Random generator (placement and speckle).
    sensor, simulation, template
        Settings (defaults when None); ``template`` sets the spacing between random targets
        and from the edges (the SMF context window of SPEC section 2.3).
    kind
        ``"intensity"`` or ``"amplitude"``.
    shapes
        Built-in shapes drawn for random targets.
    range_span_m
        Ground ranges allowed for random targets (default: the whole tile).
    max_burial_m
        Random burial depth is uniform in [0, max_burial_m] (without ``population``).
    population
        The random targets' population (:func:`draw_placement`; it replaces ``shapes`` and
        ``max_burial_m``); None: the nominal population.
    g : ndarray, shape (cols,), optional
        Background intensity curve g(r); default: measured on this tile.
    max_tries
        Random draws per requested target before giving up on it.
    swath_end
        The tile's last column is where the sonar stops recording (a whole ground-range tile,
        as the calibration injects into). The ``n_targets`` random targets are placed as
        without it (the same draws of ``rng``: every one clear of the far edge); then the draws
        they refused only because their signature ran past the last column are placed too,
        as targets whose shadow the swath's end cuts, where they overlap nothing, with their
        speckle from a generator spawned from ``rng`` (whose stream stays the one without
        ``swath_end``). Together the targets are the population a uniform draw over the
        swath gives (docs/calibration.md, "P(y) at the swath's end"). False: only the first.

    Returns
    -------
    new_pixels : ndarray, shape (rows, cols), float32
    targets : list of InjectedTarget
        In placement order; fewer than ``n_targets`` when the tile has no room (logged).
    """
    sensor = sensor or SensorSettings()
    simulation = simulation or SimulationSettings()
    template = template or TemplateSettings()
    if kind not in ("intensity", "amplitude"):
        raise GeometryError(f"kind must be 'intensity' or 'amplitude', got {kind!r}")
    host = np.array(pixels, dtype=np.float32, copy=True)
    if host.ndim != 2:
        raise GeometryError(f"pixels must be 2-D (rows, cols), got shape {host.shape}")
    rows, cols = host.shape
    H = _altitude(altitude_m)
    ranges = range0_m + dr_m * np.arange(cols)
    if g is None:
        inten = host.astype(np.float64) ** 2 if kind == "amplitude" else host
        g = background_curve(inten)
    g = np.asarray(g, dtype=np.float64)
    if g.shape != (cols,):
        raise GeometryError(f"g must hold one background intensity per column ({cols},), got shape {g.shape}")
    rho_s, rho_e = _ratios(SonarModel.from_settings(sensor, simulation), float(range0_m), float(dr_m), cols, H)
    k = simulation.subrays
    targets: list[InjectedTarget] = []
    taken: list[tuple[int, int, int, int]] = []

    cut: list[Placement] = []  # swath_end: draws refused only for running past the last column

    def refused(fp: tuple[int, int, int, int], p: Placement | None = None, far_edge: bool = True) -> bool:
        """The checks of a random placement's footprint: edges (the far one with
        ``far_edge``), other targets, no data. A draw ``p`` refused only at the far edge is
        kept in ``cut`` with ``swath_end``."""
        if fp[0] < gap[0] or fp[1] > rows - gap[0] or fp[2] < 1:
            return True
        if _overlaps(fp, taken, gap):
            return True
        win = host[fp[0]:fp[1], fp[2]:fp[3]]
        if np.isnan(win).mean() > 0.05 or not np.all(np.isfinite(g[fp[2]:fp[3]])):
            return True
        if far_edge and fp[3] > cols - 1:
            if swath_end and p is not None:
                cut.append(p)
            return True
        return False

    engine = simulation.engine

    def prepare(p: Placement, check: bool) -> _Ready | None:
        early = check and PRECHECK
        if early and taken and _anchor_taken(p, taken, gap, range0_m=range0_m, dr_m=dr_m):
            return None  # its window holds its anchor, which a placed target's area holds: refused
        local = _mesh_for(p)
        mesh = place(local, along_m=p.row * dx_m, range_m=p.range_m, heading_deg=p.heading_deg,
                     burial_m=p.burial_m)
        # The window first (the mesh's bounding box): a placement the checks refuse costs no
        # trace. The blurred signature's footprint is known from it, so the checks are the
        # ones on the traced signature, exactly, and the draws of ``rng`` are the same.
        window = trace_window(mesh, range0_m=range0_m, dr_m=dr_m, dx_m=dx_m, rows=rows, cols=cols, altitude_m=H)
        if window is None:
            return None
        kernel = _kernel(round(p.range_m, 1), dx_m, sensor)
        fp = blurred_footprint(window.footprint, kernel, rows)
        if early and refused(fp, p):
            return None
        return _Ready(p, local, window, kernel, fp)

    def usable(sig: Signature) -> bool:
        return not (sig.empty or (sig.echo.max() <= 0 and sig.p_shadow.max() <= 0))

    def finish(r: _Ready, sig: Signature, check: bool, gen: np.random.Generator | None = None, *,
               cut: bool = False) -> tuple[int, int, int, int] | None:
        """Blend a traced placement into the host and record it: its footprint, or None when
        the checks on the traced signature refuse it (``check`` without :data:`PRECHECK`).
        ``gen``: the generator of its speckle (default ``rng``); ``cut``: a swath-end target
        (:func:`place_cut`), recorded so."""
        p = r.p
        sig = blur_along_track(sig, r.kernel, rows)
        fp = sig.footprint
        if check and not PRECHECK and refused(fp, p):
            return None
        # Reflectivity scales the echo intensity only: the shadow is the seabed's business.
        rho_e_t = rho_e if p.reflectivity_db == 0.0 else rho_e * 10.0 ** (p.reflectivity_db / 10.0)
        render(host, sig, g=g, rho_shadow=rho_s, rho_echo=rho_e_t, rng=rng if gen is None else gen, kind=kind,
               speckle=r.speckle)
        row = int(round(p.row))
        col = anchor_column(sig, row, rho_s, rho_e_t)
        jc = min(max(int(round((p.range_m - range0_m) / dr_m)), 0), cols - 1)
        targets.append(InjectedTarget(shape=p.shape, row=row, col=col, range_m=float(p.range_m),
                                      heading_deg=float(p.heading_deg) % 360.0, burial_m=float(p.burial_m),
                                      footprint=fp, echo_sum=float(sig.echo.sum()),
                                      shadow_px=float(sig.p_shadow.sum()), rho_shadow=float(rho_s[jc]),
                                      rho_echo=float(rho_e[jc]), reflectivity_db=float(p.reflectivity_db),
                                      scale=tuple(float(f) for f in p.scale), roll_deg=float(p.roll_deg),
                                      pitch_deg=float(p.pitch_deg),
                                      height_m=max(r.local.height_m - float(p.burial_m), 0.0),
                                      nominal=bool(p.nominal), cut=cut))
        return fp

    def trace_all(ready: list[_Ready]) -> list[Signature]:
        return trace_many([r.window for r in ready], range0_m=range0_m, dr_m=dr_m, dx_m=dx_m, altitude_m=H,
                          subrays=k, engine=engine)

    def do(p: Placement) -> bool:
        """One random placement, traced at once (the reference order: see :data:`BATCH`)."""
        r = prepare(p, True)
        if r is None:
            return False
        sig = trace_all([r])[0]
        if not usable(sig):
            return False
        fp = finish(r, sig, True)
        if fp is None:
            return False
        taken.append(fp)
        return True

    def place_cut(draws: list[Placement]) -> None:
        """swath_end: the draws refused only at the far edge, in order, where they overlap
        nothing placed (the targets, the ones before); their speckle from a generator spawned
        from ``rng``, whose own stream stays untouched."""
        gen = rng.spawn(1)[0]
        ready = []
        for p in draws:
            r = prepare(p, False)
            if r is None or refused(r.fp, far_edge=False):
                continue
            r.speckle = draw_speckle(gen, (r.fp[1] - r.fp[0], r.fp[3] - r.fp[2]))
            taken.append(r.fp)
            ready.append(r)
        for r, sig in zip(ready, trace_all(ready)):
            if usable(sig):
                finish(r, sig, False, gen, cut=True)

    # Random targets keep the SMF context window (SPEC 2.3) of each other and of the edges.
    gap = (int(math.ceil(template.context_factor * template.length_m / dx_m / 2)),
           int(math.ceil(template.context_factor * template.echo_width_m / dr_m)))
    if placements is not None:
        # No draw depends on a trace here: every placement is traced in one batch, then
        # rendered in order.
        ready = [prepare(p, False) for p in placements]
        live = [r for r in ready if r is not None]
        sigs = iter(trace_all(live))
        for p, r in zip(placements, ready):
            sig = next(sigs) if r is not None else None
            if sig is not None and usable(sig):
                finish(r, sig, False)
            else:
                log.info("target %s at row %.1f, range %.1f m is outside the tile: skipped", p.shape, p.row, p.range_m)
        return host, targets
    n = int(n_targets or 0)
    lo, hi = range_span_m if range_span_m is not None else (ranges[0], ranges[-1])
    lo, hi = max(lo, ranges[0]), min(hi, ranges[-1])
    if n <= 0 or hi <= lo:
        return host, targets

    def draw() -> Placement:
        return draw_placement(rng, row_span=(gap[0], rows - gap[0]), range_span_m=(lo, hi), population=population,
                              shapes=shapes, max_burial_m=max_burial_m)

    def one_by_one() -> None:
        for _ in range(n):
            for _try in range(max_tries):
                if do(draw()):
                    break

    if BATCH and PRECHECK:
        # Place every target first, drawing each one's speckle as the sequential order does
        # right after its placement (its footprint, and so the speckle's shape, is known from
        # the window); then trace them all in one batch and render them in order.
        start = rng.bit_generator.state
        ready: list[_Ready] = []
        for _ in range(n):
            for _try in range(max_tries):
                r = prepare(draw(), True)
                if r is not None:
                    fp = r.fp
                    r.speckle = draw_speckle(rng, (fp[1] - fp[0], fp[3] - fp[2]))
                    taken.append(fp)
                    ready.append(r)
                    break
        sigs = trace_all(ready)
        if all(usable(sig) for sig in sigs):
            for r, sig in zip(ready, sigs):
                finish(r, sig, True)
        else:
            # A window with nothing in it (a sliver above the seabed): the sequential order
            # would have drawn again there. Replay that order from the same generator state.
            rng.bit_generator.state = start
            taken.clear()
            cut.clear()
            one_by_one()
    else:
        one_by_one()
    if len(targets) < n:
        log.info("placed %d of %d targets: the tile has no room for more", len(targets), n)
    if cut:
        place_cut(cut)
    return host, targets
