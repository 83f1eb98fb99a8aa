"""What the node gives the evidence grid per tile core and leg (SPEC section 7), validated.

One :class:`Observation` = one tile core of one leg: its georeferencing (a
:class:`~atr_node.geo.TileGeometry` for the core rows) and, per enabled detector, a
:class:`DetectorObservation`: the covered pixels (score not NaN), Pd at each column from the
performance model, and the detections in the core with their confidence. Everything is
checked here, before the grid changes, so a bad observation is rejected whole with a message
that says which detector and which field, and loses nothing already accepted.

Also here: the association gate (:func:`association_gate_m`, :func:`gate_cells`), the
pixel -> cell mapping (:func:`pixel_cells`) and :class:`DetectionRecord`, a detection as the
grid keeps it (georeferenced) for contacts and the AND/OR baselines.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import FusionSettings, TemplateSettings
from ..errors import FusionError
from ..geo import TileGeometry


@dataclass(frozen=True)
class DetectionEvidence:
    """One detection of one detector in a tile core, with its confidence (SPEC sections 3, 5)."""

    row: int
    """Core row (ping) of the anchor pixel."""
    col: int
    """Column (range bin) of the anchor pixel."""
    gamma: float
    """Cluster maximum of the score."""
    range_m: float
    """Ground range of the anchor."""
    confidence: float
    """c_d(gamma; tau_d) in [0, 1]: the mass it puts on {T}."""
    length_m: float | None = None
    """An extended object's (``detectors/objects.py``) long-axis length; None otherwise."""
    width_m: float | None = None
    """Its extent across the long axis."""
    axis_deg: float | None = None
    """Its long axis in the tile: 0 along-track (increasing rows), +90 towards increasing range."""
    source: str | None = None
    """The detector that made it, where it differs from the evidence layer it feeds (a look's
    layer, SPEC 6.1, holds the detections of every detector); None = the layer's name."""

    def __post_init__(self) -> None:
        if not (0.0 <= self.confidence <= 1.0):
            raise FusionError(f"detection at row {self.row}, col {self.col}: confidence {self.confidence!r} "
                              "is outside [0, 1]")
        extent = (self.length_m, self.width_m, self.axis_deg)
        if any(v is not None for v in extent) and not (
                all(v is not None and math.isfinite(v) for v in extent) and 0.0 <= self.width_m <= self.length_m):
            raise FusionError(f"detection at row {self.row}, col {self.col}: extent (length_m, width_m, axis_deg) "
                              f"= {extent!r}: expected all three finite, 0 <= width_m <= length_m, or none")

    @classmethod
    def from_detection(cls, detection: Any, confidence: float, *, source: str | None = None) -> "DetectionEvidence":
        """From an ``atr_node.detectors.Detection`` (row, col, gamma, range_m, and an extended
        object's length_m, width_m, axis_deg when it has them) and its confidence."""
        extent = {k: float(v) for k in ("length_m", "width_m", "axis_deg")
                  if (v := getattr(detection, k, None)) is not None}
        return cls(row=int(detection.row), col=int(detection.col), gamma=float(detection.gamma),
                   range_m=float(detection.range_m), confidence=float(confidence), source=source, **extent)


@dataclass(frozen=True, eq=False)
class DetectorObservation:
    """One detector's view of a tile core."""

    detector: str
    covered: np.ndarray
    """bool (rows, cols): the score is not NaN (valid window)."""
    pd: np.ndarray
    """float64 (cols,): Pd_d(r_j) from the performance model, in [0, 1] (0 outside its span)."""
    detections: tuple[DetectionEvidence, ...] = ()

    def __post_init__(self) -> None:
        cov = np.asarray(self.covered)
        if cov.ndim != 2 or cov.dtype != np.bool_:
            raise FusionError(f"detector {self.detector!r}: covered must be a 2-D bool array, "
                              f"got {cov.dtype} {cov.shape}")
        pd = np.ascontiguousarray(self.pd, dtype=np.float64)
        if pd.shape != (cov.shape[1],):
            raise FusionError(f"detector {self.detector!r}: pd has shape {pd.shape}, expected ({cov.shape[1]},) "
                              "= one value per column")
        if not np.all((pd >= 0.0) & (pd <= 1.0)):
            raise FusionError(f"detector {self.detector!r}: pd must be in [0, 1] at every column "
                              f"(found {pd[~((pd >= 0.0) & (pd <= 1.0))][:3].tolist()})")
        for d in self.detections:
            if not (0 <= d.row < cov.shape[0] and 0 <= d.col < cov.shape[1]):
                raise FusionError(f"detector {self.detector!r}: detection at row {d.row}, col {d.col} is outside "
                                  f"the core {cov.shape}")
        object.__setattr__(self, "covered", cov)
        object.__setattr__(self, "pd", pd)
        object.__setattr__(self, "detections", tuple(self.detections))


@dataclass(frozen=True, eq=False)
class Observation:
    """One tile core of one leg, as evidence for the grid (SPEC sections 6-7)."""

    leg: int
    """Survey leg: one leg = one observation (ICD section 1)."""
    t: float
    """UNIX seconds of the evidence (e.g. the core's last ping)."""
    geometry: TileGeometry
    """Georeferencing of the core rows."""
    detectors: tuple[DetectorObservation, ...]

    def __post_init__(self) -> None:
        if not math.isfinite(self.t):
            raise FusionError(f"leg {self.leg}: observation time {self.t!r} is not finite")
        rows, cols = self.geometry.east_m.size, self.geometry.ranges_m.size
        g = self.geometry
        for name in ("east_m", "north_m", "ue", "un", "ranges_m"):
            if not np.all(np.isfinite(getattr(g, name))):
                raise FusionError(f"leg {self.leg}: geometry.{name} is not finite everywhere (nav gap?)")
        names = [d.detector for d in self.detectors]
        if len(set(names)) != len(names):
            raise FusionError(f"leg {self.leg}: a detector appears twice in one observation: {names}")
        for d in self.detectors:
            if d.covered.shape != (rows, cols):
                raise FusionError(f"leg {self.leg}, detector {d.detector!r}: covered is {d.covered.shape}, "
                                  f"the geometry is ({rows}, {cols})")
        object.__setattr__(self, "detectors", tuple(self.detectors))

    @property
    def shape(self) -> tuple[int, int]:
        return self.geometry.east_m.size, self.geometry.ranges_m.size


def association_gate_m(fusion: FusionSettings, template: TemplateSettings) -> float:
    """Association gate radius: ``gate_sigmas * nav_sigma_m + length_m / 2`` (SPEC section 7:
    navigation uncertainty plus template size)."""
    return fusion.gate_sigmas * fusion.nav_sigma_m + 0.5 * template.length_m


@dataclass(frozen=True)
class DetectionRecord:
    """A detection as deposited in the grid (kept for contacts and the AND/OR baselines)."""

    leg: int
    detector: str
    east_m: float
    north_m: float
    t: float
    confidence: float
    gamma: float
    length_m: float | None = None
    """An extended object (a wreck): length of its long axis, metres; None for other detections."""
    width_m: float | None = None
    """Its extent across the long axis, metres."""
    heading_deg: float | None = None
    """Grid heading (clockwise from the mission frame's grid north) of its long axis, in [0, 180)."""


def record_extent(geometry: TileGeometry, det: DetectionEvidence) -> dict[str, float]:
    """The extent fields of a :class:`DetectionRecord` for ``det`` (empty without an extent).

    The long axis, ``axis_deg`` from the track towards increasing range in the tile, turns
    into the mission frame with the ping's grid heading: ``v = cos(a) f + sin(a) u``, ``f``
    the forward unit vector ``(sin h, cos h)`` (east, north) and ``u`` the across-track one
    (towards increasing range on either side); its heading ``atan2(v_e, v_n)`` modulo 180.
    """
    if det.length_m is None:
        return {}
    h = float(geometry.heading_grid_rad[det.row])
    ue, un = float(geometry.ue[det.row]), float(geometry.un[det.row])
    norm = math.hypot(ue, un)
    a = math.radians(det.axis_deg)
    ve = math.cos(a) * math.sin(h) + math.sin(a) * ue / norm
    vn = math.cos(a) * math.cos(h) + math.sin(a) * un / norm
    return {"length_m": float(det.length_m), "width_m": float(det.width_m),
            "heading_deg": axis_heading_deg(math.degrees(math.atan2(ve, vn)))}


def axis_heading_deg(deg: float) -> float:
    """An axis's direction (either way along it) as a heading in [0, 180)."""
    h = deg % 180.0
    return 0.0 if h >= 180.0 else h  # -1e-17 % 180 rounds to 180


def gate_cells(east_m: float, north_m: float, *, gate_m: float, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Global cell indices (iy, ix) whose centres lie within ``gate_m`` of a point.

    The cell holding the point is always included, so a gate smaller than a cell still
    deposits its evidence.
    """
    cy, cx = math.floor(north_m / cell_m), math.floor(east_m / cell_m)
    k = int(math.ceil(gate_m / cell_m)) + 1
    oy, ox = np.mgrid[-k:k + 1, -k:k + 1]
    iy, ix = (cy + oy).ravel(), (cx + ox).ravel()
    de = (ix + 0.5) * cell_m - east_m
    dn = (iy + 0.5) * cell_m - north_m
    keep = (de * de + dn * dn <= gate_m * gate_m) | ((iy == cy) & (ix == cx))
    return iy[keep].astype(np.int64), ix[keep].astype(np.int64)


def pixel_cells(geometry: TileGeometry, rows: slice, *, cell_m: float,
                cols: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
    """Global cell indices (iy, ix) of the pixels of some core rows and columns, each
    (n_rows, n_cols) int64.

    ``world(i, j) = p_i + r_j u_i`` (``atr_node.geo.georef``), then ``floor(x / cell_m)``.
    """
    # in place, one temporary per axis: r * u + p is the same float as p + r * u (IEEE
    # addition commutes), so the cells are bit for bit those of the direct expression
    r = geometry.ranges_m[None, cols]
    out = []
    for pos, u in ((geometry.north_m, geometry.un), (geometry.east_m, geometry.ue)):
        x = r * u[rows, None]
        x += pos[rows, None]
        x /= cell_m
        np.floor(x, out=x)
        out.append(x.astype(np.int64))
    return out[0], out[1]
