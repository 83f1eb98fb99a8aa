"""Contacts from the evidence grid: extraction, stable ids, new / update / withdrawn (SPEC section 7).

A contact is an 8-connected region of cells whose Bel(T) is at least ``withdraw_bel``
holding a cell at ``report_bel`` or more (hysteresis: a contact is born at ``report_bel``
and lives until its region falls below ``withdraw_bel``) and at least one detection (the
cell of a detection record lies in it): a region with no detection behind it is never a
contact, neither born nor kept alive (SPEC 7). A region is a union of association gates
around detections, so objects a few metres apart can share one: a region whose detections
form several groups (each within the gate of its strongest detection) is split, each cell
going to the nearest group. A contact's position comes from its detections
(:func:`detection_position`: their confidence-weighted mean; ``sigma_m`` their spread plus
``nav_sigma_m`` in quadrature); ``bel``, ``pl`` and ``m_theta`` are those of its cell of
highest Bel(T) within ``sigma_m`` of that position (not the region's peak, which can lie where
one look's gate reached and another look that covered the object and missed it did not); in
a region split into groups (objects a few metres apart), every group's are those of its cell
nearest to its position; its legs are those of the same cell (:func:`_read_cell`).

Extended objects (a wreck, ``detectors/objects.py``) come from the detect stage in pieces when
they cross units' edges, one per unit, each at its own centre: components whose detections'
object footprints overlap or touch are one contact (:meth:`ContactTracker._merge_objects`),
its position and extent those of the union of the footprints (:func:`contact_position`,
:func:`extent_fields`), so one wreck is one contact wherever the tiles were cut.

Ids stay stable: after each update, regions are matched one-to-one to the live contacts by
nearest position within the association gate; a region without a match becomes a new
contact, a live contact without a region is withdrawn. Only chunks of the grid changed since
the last update are re-evaluated (``EvidenceGrid.changed_since``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..config import FusionSettings
from ..geo import MissionFrame
from .baselines import leader_groups
from .grid import EvidenceGrid
from .observation import DetectionRecord, axis_heading_deg
from .mass import closed_form

STATES = ("new", "update", "withdrawn")
_OFF = np.int64(1 << 30)
_CHUNK_OFF = 1 << 20
"""Offset of chunk coordinates in a chunk code (chunks within +-2^20 of the origin)."""


def _chunk_code(key: tuple[int, int]) -> int:
    """A chunk's code: increasing in (cy, cx) order, as ``sorted`` orders chunk keys."""
    return (key[0] + _CHUNK_OFF) * (2 * _CHUNK_OFF) + (key[1] + _CHUNK_OFF)


@dataclass(eq=False)
class _Component:
    """One contact candidate of a region (the region itself, or one of its split groups)."""

    key: tuple
    """Order of the full extraction: (0, first cell code) for a region, (1, first cell code,
    group) for a split group beyond the first."""
    ce: float
    cn: float
    sigma: float
    bel: float
    mn: float
    mth: float
    iy: int
    ix: int
    """The cell its Bel(T), pl, m_theta and legs are read at (:func:`_read_cell`); its first cell
    if it has no detection (never published)."""
    dets: list[int]
    """Its detections (indices into ``grid.detections``, ascending)."""
    fields: dict | None = None
    seen: "Contact | None" = None
    """The live contact it was last found equal to (or published as): unchanged since, it is
    skipped without comparing."""
    members: "tuple[_Component, ...]" = ()
    """A merged extended object (:meth:`ContactTracker._merge_objects`): the components it
    joins, in order (their cells read give its legs); empty for any other component."""
    ext: Any = None
    """Its extended objects' footprints (:func:`_footprints`), computed on first use."""


@dataclass(eq=False)
class _Region:
    cells: tuple[np.ndarray, ...]
    """(iy, ix, bel, mn, mth, code), in the full extraction's order (``code``: chunk code x
    cells per chunk + index in the chunk's cached cells)."""
    keys: set
    comps: list

    @property
    def code(self) -> np.ndarray:
        return self.cells[5]


@dataclass(frozen=True)
class Contact:
    """One contact, with exactly the fields of the ICD section 3 ``contact`` message."""

    id: int
    state: str
    t: float
    lat_deg: float
    lon_deg: float
    east_m: float
    north_m: float
    sigma_m: float
    bel: float
    pl: float
    m_theta: float
    looks: int
    detections: int
    detectors: tuple[str, ...]
    legs: tuple[int, ...]
    length_m: float | None = None
    """(ICD v1.1, optional) An extended object (a wreck): length of its long axis; None (not
    in the message) for any other contact."""
    width_m: float | None = None
    """(v1.1, optional) Its extent across the long axis."""
    heading_deg: float | None = None
    """(v1.1, optional) True heading of its long axis, in [0, 180)."""

    def __post_init__(self) -> None:
        if self.state not in STATES:
            raise ValueError(f"contact {self.id}: state {self.state!r} is not one of {STATES}")

    def to_message(self) -> dict[str, Any]:
        """The ICD section 3 map (type ``contact``, v 1), plain Python types only."""
        return {"type": "contact", "v": 1, "id": int(self.id), "state": self.state, "t": float(self.t),
                "lat_deg": float(self.lat_deg), "lon_deg": float(self.lon_deg), "east_m": float(self.east_m),
                "north_m": float(self.north_m), "sigma_m": float(self.sigma_m), "bel": float(self.bel),
                "pl": float(self.pl), "m_theta": float(self.m_theta), "looks": int(self.looks),
                "detections": int(self.detections), "detectors": [str(d) for d in self.detectors],
                "legs": [int(x) for x in self.legs],
                **{k: float(getattr(self, k)) for k in EXTENT_FIELDS if getattr(self, k) is not None}}

    @classmethod
    def from_message(cls, m: dict[str, Any]) -> "Contact":
        fields = {f.name for f in dataclasses.fields(cls)}
        kw = {k: v for k, v in m.items() if k in fields}
        kw["detectors"] = tuple(kw["detectors"])
        kw["legs"] = tuple(kw["legs"])
        return cls(**kw)

    def same_content(self, other: "Contact") -> bool:
        """Equal apart from state and time (nothing new to publish)."""
        return all(getattr(self, k) == getattr(other, k) for k in _CONTENT_FIELDS)


_CONTENT_FIELDS = tuple(f.name for f in dataclasses.fields(Contact) if f.name not in ("state", "t"))
EXTENT_FIELDS = ("length_m", "width_m", "heading_deg")
"""The optional extent of a contact (ICD v1.1 section 3), all three or none."""


def extent_fields(detections: Sequence[DetectionRecord], frame: MissionFrame) -> dict[str, float | None]:
    """A contact's extent from its detections: per leg, the oriented box of the union of the
    footprints of its extended objects (:func:`leg_boxes`: a wreck cut by units' edges is seen
    in pieces, one per unit, that together make the wreck); of the legs, the longest box (the
    most complete view), its grid heading turned true (plus the meridian convergence at its
    centre); None when no detection carries an extent (``detectors/objects.py``)."""
    boxes = leg_boxes(detections)
    if not boxes:
        return dict.fromkeys(EXTENT_FIELDS)
    best = boxes[0]
    for b in boxes[1:]:
        if b[2] > best[2]:
            best = b
    lat, lon = frame.to_latlon(best[0], best[1])
    conv, _ = frame.grid_factors(lat, lon)
    return {"length_m": float(best[2]), "width_m": float(best[3]),
            "heading_deg": axis_heading_deg(best[4] + float(conv))}


TOUCH_M = 1.0
"""Footprints of extended objects at most this far apart are one object. Pieces of one wreck
cut by units' edges overlap (neighbouring units see each other's edge rows, their margins);
the allowance covers the gaps a broken hull outline leaves between pieces found apart."""


def _unique_footprints(detections: Sequence[DetectionRecord]) -> list[DetectionRecord]:
    """The extended detections, one per distinct footprint (the detectors of a unit report
    its object with the same centre and extent), in their order."""
    seen: dict[tuple, DetectionRecord] = {}
    for r in detections:
        if r.length_m is not None:
            seen.setdefault((r.leg, r.east_m, r.north_m, r.length_m, r.width_m, r.heading_deg), r)
    return list(seen.values())


def _corners(recs: Sequence[DetectionRecord]) -> np.ndarray:
    """Corners (k, 4, 2) (east, north) of the footprints of extended detections: the centre
    +- half the length along the grid heading, +- half the width across it, in turn."""
    h = np.radians(np.array([r.heading_deg for r in recs], dtype=float))
    u = np.column_stack([np.sin(h), np.cos(h)])  # along the long axis
    v = np.column_stack([np.cos(h), -np.sin(h)])  # across it
    c = np.array([(r.east_m, r.north_m) for r in recs], dtype=float)
    a = 0.5 * np.array([r.length_m for r in recs], dtype=float)[:, None] * u
    b = 0.5 * np.array([r.width_m for r in recs], dtype=float)[:, None] * v
    return np.stack([c + a + b, c + a - b, c - a - b, c - a + b], axis=1)


def _box(points: np.ndarray) -> tuple[float, float, float, float, float]:
    """Oriented bounding box of points (n, 2) (east, north), its long axis the principal axis
    of their second moments: (centre east, centre north, length, width, grid heading of the
    long axis in [0, 180))."""
    m = points.mean(axis=0)
    d = points - m
    see, snn, sen = float((d[:, 0] ** 2).mean()), float((d[:, 1] ** 2).mean()), float((d[:, 0] * d[:, 1]).mean())
    phi = 0.5 * math.atan2(2.0 * sen, snn - see)  # from grid north, clockwise
    u = np.array([math.sin(phi), math.cos(phi)])
    v = np.array([math.cos(phi), -math.sin(phi)])
    along, across = d @ u, d @ v
    a0, a1, c0, c1 = float(along.min()), float(along.max()), float(across.min()), float(across.max())
    centre = m + 0.5 * (a0 + a1) * u + 0.5 * (c0 + c1) * v
    length, width, heading = a1 - a0, c1 - c0, math.degrees(phi)
    if width > length:  # a square-ish union: the longer side is the axis
        length, width, heading = width, length, heading + 90.0
    return float(centre[0]), float(centre[1]), length, width, axis_heading_deg(heading)


def leg_boxes(detections: Sequence[DetectionRecord]) -> list[tuple[float, float, float, float, float, float]]:
    """Per leg (ascending) that saw extended objects among ``detections``, the oriented box of
    the union of their footprints (:func:`_box` of their corners): (east, north, length,
    width, grid heading, weight), the weight the sum of the leg's distinct footprints'
    confidences. The pieces of one wreck seen by neighbouring units of a leg make its full
    extent; different legs are not joined (their navigation differs: the union would grow
    by the offset between them)."""
    by_leg: dict[int, list[DetectionRecord]] = {}
    for r in _unique_footprints(detections):
        by_leg.setdefault(r.leg, []).append(r)
    out = []
    for leg in sorted(by_leg):
        recs = by_leg[leg]
        out.append((*_box(_corners(recs).reshape(-1, 2)), math.fsum(r.confidence for r in recs)))
    return out


def contact_position(detections: Sequence[DetectionRecord], idx: Sequence[int], *, nav_sigma_m: float
                     ) -> tuple[float, float, float]:
    """Position of a contact: (east_m, north_m, sigma_m).

    With extended objects among its detections, the centre of their extent: per leg the
    centre of the box of the union of its footprints (:func:`leg_boxes`), averaged over the
    legs by their weights, ``sigma_m`` the spread of those centres plus ``nav_sigma_m`` in
    quadrature (as :func:`detection_position`). The pieces of a wreck cut by units' edges
    lie either side of its centre, and its other detections on its edges. Otherwise
    :func:`detection_position`.
    """
    boxes = leg_boxes([detections[i] for i in idx])
    if not boxes:
        return detection_position(detections, idx, nav_sigma_m=nav_sigma_m)
    w = [b[5] for b in boxes]
    if not math.fsum(w) > 0.0:
        w = [1.0] * len(boxes)
    sw = math.fsum(w)
    e = math.fsum(wi * b[0] for wi, b in zip(w, boxes)) / sw
    n = math.fsum(wi * b[1] for wi, b in zip(w, boxes)) / sw
    var = math.fsum(wi * ((b[0] - e) ** 2 + (b[1] - n) ** 2) for wi, b in zip(w, boxes)) / sw
    return e, n, math.sqrt(0.5 * var + float(nav_sigma_m) ** 2)


def _footprints(detections: Sequence[DetectionRecord], idx: Sequence[int]) -> tuple | None:
    """Footprints of the extended objects among detections ``idx``: (corners (k, 4, 2), their
    axes (k, 2, 2), bounding circle centre (2,) and radius), None without any."""
    recs = _unique_footprints([detections[i] for i in idx])
    if not recs:
        return None
    corners = _corners(recs)
    axes = np.stack([corners[:, 0] - corners[:, 3], corners[:, 0] - corners[:, 1]], axis=1)
    norm = np.linalg.norm(axes, axis=2, keepdims=True)
    axes = np.divide(axes, norm, out=np.zeros_like(axes), where=norm > 0)
    pts = corners.reshape(-1, 2)
    centre = pts.mean(axis=0)
    return corners, axes, centre, float(np.sqrt(((pts - centre) ** 2).sum(axis=1)).max())


def _touch(a: tuple, b: tuple, tol_m: float) -> bool:
    """Whether some footprint of ``a`` and some of ``b`` (:func:`_footprints`) overlap or lie
    within ``tol_m`` of each other: no separating axis among the rectangles' edge normals
    (separating axis theorem) with a gap over ``tol_m``."""
    ca, aa = a[0], a[1]
    cb, ab = b[0], b[1]
    for i in range(ca.shape[0]):
        for j in range(cb.shape[0]):
            axes = np.concatenate([aa[i], ab[j]])  # (4, 2)
            pa, pb = ca[i] @ axes.T, cb[j] @ axes.T  # (4 corners, 4 axes)
            gap = np.maximum(pb.min(axis=0) - pa.max(axis=0), pa.min(axis=0) - pb.max(axis=0))
            if not (gap > tol_m).any():
                return True
    return False


def _legs(grid: EvidenceGrid, comp: _Component) -> tuple[int, ...]:
    """Legs of a component: those at its cell (``iy``, ``ix``), or at any of its members' (merged)."""
    if not comp.members:
        return tuple(grid.legs_at(comp.iy, comp.ix))
    return tuple(sorted({leg for m in comp.members for leg in grid.legs_at(m.iy, m.ix)}))


def _one_to_one(pairs: list[tuple[float, int, int]]) -> dict[int, int]:
    """Component -> contact id from (distance, contact id, component) pairs: nearest first,
    each contact and each component used once."""
    pairs.sort()
    comp_id: dict[int, int] = {}
    used: set[int] = set()
    for _, cid, j in pairs:
        if cid not in used and j not in comp_id:
            comp_id[j] = cid
            used.add(cid)
    return comp_id


def detection_position(detections: Sequence[DetectionRecord], idx: Sequence[int], *, nav_sigma_m: float
                       ) -> tuple[float, float, float]:
    """Position of a contact from the detections behind it (SPEC 7): (east_m, north_m, sigma_m).

    The position is the confidence-weighted mean of the detections' positions (equal
    weights when every confidence is 0). ``sigma_m`` is the 1-sigma horizontal uncertainty
    (ICD section 3): ``sqrt(s^2 + nav_sigma_m^2)`` with ``s^2 = sum w_i |x_i - x|^2 / (2 sum w_i)``
    the confidence-weighted per-axis variance of the detections about the mean. The
    navigation part is not divided by the number of detections: the detectors of a look
    read the same pixels, and the legs of a mission share the INS drift.

    Sums are ``math.fsum`` (correctly rounded): the result depends on the set of detections
    only, not on their order, so the incremental and full extractions agree bit for bit.

    Parameters
    ----------
    detections : sequence of DetectionRecord
        The grid's detection records (``EvidenceGrid.detections``).
    idx : sequence of int
        Indices into ``detections`` of the contact's detections (at least one).
    nav_sigma_m : float
        1-sigma navigation uncertainty (``fusion.nav_sigma_m``).
    """
    recs = [detections[i] for i in idx]
    w = [r.confidence for r in recs]
    if not math.fsum(w) > 0.0:
        w = [1.0] * len(recs)
    sw = math.fsum(w)
    e = math.fsum(wi * r.east_m for wi, r in zip(w, recs)) / sw
    n = math.fsum(wi * r.north_m for wi, r in zip(w, recs)) / sw
    var = math.fsum(wi * ((r.east_m - e) ** 2 + (r.north_m - n) ** 2) for wi, r in zip(w, recs)) / sw
    return e, n, math.sqrt(0.5 * var + float(nav_sigma_m) ** 2)


def _peak_near(e: np.ndarray, n: np.ndarray, bel: np.ndarray, cells: np.ndarray, ce: float, cn: float,
               radius_m: float) -> int:
    """The cell of ``cells`` (indices, in the extraction's order; ``e, n`` every cell's centre)
    with the highest Bel(T) within ``radius_m`` of (ce, cn), the last such on a tie; the nearest
    cell (the first on a tie) when none is that close, and always with ``radius_m = 0``
    (:func:`_read_cell`)."""
    d2 = (e[cells] - ce) ** 2 + (n[cells] - cn) ** 2
    near = cells[d2 <= radius_m * radius_m] if radius_m > 0 else cells[:0]
    if not near.size:
        return int(cells[int(np.argmin(d2))])
    b = bel[near]
    return int(near[np.flatnonzero(b == b.max())[-1]])


def _read_cell(e: np.ndarray, n: np.ndarray, bel: np.ndarray, reg: np.ndarray, cells: np.ndarray,
               region: int | None, ce: float, cn: float, sigma_m: float) -> int:
    """The cell a component with detections reads its Bel(T), pl, m_theta and legs at, from its
    ``cells`` (indices in the extraction's order, ascending) and position (ce, cn):

    - not split (``region`` None): its highest Bel(T) within ``sigma_m`` of its position, not
      its region's peak: the peak can lie where one look's gate reached and another look, which
      covered the contact's place and missed it, did not (its swath edge or nadir gap 2 m away):
      an object shown on one leg only, covered by the next at Pd 0.9, read 0.79 there and 0.42
      where it is;
    - a group of a split region (``region`` its region's label in ``reg``): the cell nearest
      its position, of the region's cells when the group has none (each cell goes to the
      nearest group's position, so a group squeezed between two others can get no cell). A
      group's cells border its neighbour's, whose gate reaches them with that group's T mass, so
      at its peak a one-detection satellite 4 m from a rock seen on three legs read the rock's
      0.998. It is the cell nearest the position, not ``grid.masses_at(ce, cn)``: a position on a
      cell of another group, or below ``withdraw_bel``, still reads one of its own. Groups closer
      than the gate still share T mass there.

    Both extraction paths read through here, so they agree message for message."""
    if region is None:
        return _peak_near(e, n, bel, cells, ce, cn, sigma_m)
    if not cells.size:
        cells = np.flatnonzero(reg == region)
    return _peak_near(e, n, bel, cells, ce, cn, 0.0)


def _comp_cells(lab: np.ndarray, n_comp: int) -> list[np.ndarray]:
    """Per component label, its cells (indices in the extraction's order, ascending)."""
    order = np.argsort(lab, kind="stable")
    bounds = np.searchsorted(lab[order], np.arange(n_comp + 1))
    return [order[bounds[j]:bounds[j + 1]] for j in range(n_comp)]


_NEAR_K = 8
"""Groups a cell's nearest-group search looks at first (:func:`nearest_group`)."""
_BLOCK = 1 << 20
"""Elements of one block of the exhaustive cells x groups search (8 MB of float64)."""


def nearest_group(e: np.ndarray, n: np.ndarray, ge: np.ndarray, gn: np.ndarray) -> np.ndarray:
    """Index of each cell's nearest group: ``argmin_g (e - ge[g])^2 + (n - gn[g])^2``, the first
    (lowest g) on a tie, bit for bit as that dense (cells x groups) argmin, in O((cells +
    groups) log groups) time and O(cells) memory.

    A k-d tree gives each cell its :data:`_NEAR_K` nearest groups; the exact squared distances
    above are taken on those alone. When the k-th candidate is not clearly farther than the
    first (a tie beyond k: rare, cells equidistant from many groups), that cell falls back to
    the exhaustive search, in blocks of :data:`_BLOCK` elements. Heavy clutter put 2,500
    groups in a region of 185,000 cells: the dense matrix took 3.7 GB (issue 21 item 3).

    Parameters
    ----------
    e, n : ndarray (K,)
        Cell centres, east and north (m).
    ge, gn : ndarray (G,)
        Group positions, east and north (m), G >= 1.
    """
    g = ge.size
    k = min(g, _NEAR_K)
    if g <= k:
        return _nearest_dense(e, n, ge, gn)
    pts = np.column_stack([e, n])
    _, idx = cKDTree(np.column_stack([ge, gn])).query(pts, k=k)
    d2 = (e[:, None] - ge[idx]) ** 2 + (n[:, None] - gn[idx]) ** 2  # the dense argmin's values
    best = d2.min(axis=1)
    # the lowest group index among the candidates at the exact minimum
    out = np.where(d2 == best[:, None], idx, g).min(axis=1)
    # a group outside the k candidates is at least as far as the k-th: it cannot win (nor tie)
    # when the k-th is farther than the best by more than rounding
    unsure = ~(d2.max(axis=1) > best * (1.0 + 1e-9) + 1e-18)
    if unsure.any():
        rows = np.flatnonzero(unsure)
        out[rows] = _nearest_dense(e[rows], n[rows], ge, gn)
    return out


def _nearest_dense(e: np.ndarray, n: np.ndarray, ge: np.ndarray, gn: np.ndarray) -> np.ndarray:
    """:func:`nearest_group` by the exhaustive argmin, in blocks of cells (bounded memory)."""
    out = np.empty(e.size, dtype=np.int64)
    step = max(1, _BLOCK // max(1, ge.size))
    for a in range(0, e.size, step):
        b = a + step
        out[a:b] = np.argmin((e[a:b, None] - ge[None, :]) ** 2 + (n[a:b, None] - gn[None, :]) ** 2, axis=1)
    return out


def label_cells(iy: np.ndarray, ix: np.ndarray) -> tuple[int, np.ndarray]:
    """8-connected components of a sparse set of distinct cells; (n, labels (K,)), labels
    numbered in order of each component's first cell in the given order."""
    k = iy.size
    if k == 0:
        return 0, np.zeros(0, dtype=np.int64)
    limit = max(1 << 22, 64 * k)
    if int(iy.max()) - int(iy.min()) + int(ix.max()) - int(ix.min()) + 2 > limit:
        return label_graph(iy, ix)  # cells spread very far apart (a nav jump)
    # a raster of the cells, labelled in C, with every run of empty rows (columns) cut to one:
    # 8-adjacency (|dy| <= 1 and |dx| <= 1) is unchanged. Components are then numbered by
    # first cell in the given order, as connected_components numbers them (label_graph)
    ry, h = _squeeze(iy)
    rx, w = _squeeze(ix)
    if h * w > limit:
        return label_graph(iy, ix)
    img = np.zeros((h, w), dtype=bool)
    img[ry, rx] = True
    raw, n = ndimage.label(img, structure=np.ones((3, 3), dtype=bool))
    raw = raw[ry, rx]
    found, first = np.unique(raw, return_index=True)
    renum = np.empty(n + 1, dtype=np.int64)
    renum[found[np.argsort(first)]] = np.arange(found.size)
    return int(n), renum[raw]


def _squeeze(v: np.ndarray) -> tuple[np.ndarray, int]:
    """Raster index of each coordinate, runs of unused values cut to one (order kept), and
    the raster size."""
    v0 = int(v.min())
    used = np.zeros(int(v.max()) - v0 + 1, dtype=bool)
    used[v - v0] = True
    keep = used.copy()
    keep[1:] |= used[:-1]  # a used value, or the first unused one after it
    new = np.cumsum(keep) - 1
    return new[v - v0], int(new[-1]) + 1


def label_graph(iy: np.ndarray, ix: np.ndarray) -> tuple[int, np.ndarray]:
    """:func:`label_cells` through a sparse neighbour graph (any spread of cells)."""
    k = iy.size
    if k == 0:
        return 0, np.zeros(0, dtype=np.int64)
    code = (iy + _OFF) * (2 * _OFF) + (ix + _OFF)
    order = np.argsort(code)
    sc = code[order]
    src, dst = [np.arange(k)], [np.arange(k)]
    for dy, dx in ((0, 1), (1, -1), (1, 0), (1, 1)):
        want = code + dy * (2 * _OFF) + dx
        pos = np.minimum(np.searchsorted(sc, want), k - 1)
        hit = sc[pos] == want
        src.append(np.flatnonzero(hit))
        dst.append(order[pos[hit]])
    s, d = np.concatenate(src), np.concatenate(dst)
    graph = coo_matrix((np.ones(s.size, dtype=np.int8), (s, d)), shape=(k, k))
    n, labels = connected_components(graph, directed=False)
    return int(n), labels.astype(np.int64)


class ContactTracker:
    """Extracts contacts from an :class:`EvidenceGrid` and keeps their ids stable."""

    def __init__(self, fusion: FusionSettings, frame: MissionFrame, *, gate_m: float, incremental: bool = True) -> None:
        self.fusion, self.frame, self.gate_m = fusion, frame, float(gate_m)
        self.incremental = bool(incremental)
        """Re-label only the regions near changed chunks (:meth:`update`); False: every region
        at every update (:meth:`_update_full`, the reference the tests compare against)."""
        self.next_id = 1
        self.live: dict[int, Contact] = {}
        self.history: dict[int, Contact] = {}
        """Last message of every contact ever published (final states)."""
        self._stamp = 0
        self._cells: dict[tuple[int, int], tuple[np.ndarray, ...]] = {}
        self._merged: dict[tuple[int, ...], _Component] = {}
        """Merged extended objects of the last update, by their members (``_merge_objects``)."""
        self._groups: dict[bytes, tuple[int, np.ndarray]] = {}
        """Leader grouping of a region's detections, by their positions and confidences (see _split)."""
        self._reset_regions()

    def _reset_regions(self) -> None:
        """Forget the incremental state (regions, components, detection index)."""
        self._regions: dict[int, _Region] = {}
        self._comps: dict[int, _Component] = {}
        self._chunk_regions: dict[tuple[int, int], set[int]] = {}
        self._next_region = 0
        self._det_chunks: dict[tuple[int, int], list[int]] = {}
        """Grid detections by the chunk of their cell (indices into ``grid.detections``)."""
        self._det_cells = np.zeros((0, 2), dtype=np.int64)
        self._n_det = 0

    def _refresh(self, grid: EvidenceGrid) -> list[tuple[int, int]]:
        """Re-evaluate the cells of the chunks changed since the last update; returns those chunks."""
        keys = grid.changed_since(self._stamp)
        changed = keys
        self._stamp = grid.stamp
        # chunks without T evidence have Bel(T) = 0: dropped without evaluating the layer terms
        with_t = grid.has_t_evidence(keys)
        for key in (k for k, w in zip(keys, with_t) if not w):
            self._cells.pop(key, None)
        keys = [k for k, w in zip(keys, with_t) if w]
        if not keys:
            return changed
        acc = grid.chunk_accumulators(keys)
        has_t = (acc[:, 0] < 0.0).any(axis=1)  # else no T evidence: Bel(T) = 0 everywhere
        for key in (k for k, h in zip(keys, has_t) if not h):
            self._cells.pop(key, None)
        rows = np.flatnonzero(has_t)
        if not rows.size:
            return changed
        # one closed_form over every chunk, on contiguous copies: element for element the
        # values of one call per chunk (the same contiguous kernels)
        m = closed_form(np.ascontiguousarray(acc[rows, 0]), np.ascontiguousarray(acc[rows, 1]))
        r, c = np.nonzero(m.m_t >= self.fusion.withdraw_bel)
        bounds = np.searchsorted(r, np.arange(rows.size + 1))
        n = grid.n
        for i, row in enumerate(rows.tolist()):
            key = keys[row]
            a, b = bounds[i], bounds[i + 1]
            if a == b:
                self._cells.pop(key, None)
                continue
            sel = c[a:b]
            self._cells[key] = (key[0] * n + sel // n, key[1] * n + sel % n, m.m_t[i, sel], m.m_n[i, sel],
                                m.m_theta[i, sel])
        return changed

    def update(self, grid: EvidenceGrid, t: float) -> list[Contact]:
        """Re-extract contacts after new evidence; return the messages to publish."""
        if not self.incremental:
            return self._update_full(grid, t)
        changed = self._refresh(grid)
        self._index_detections(grid)
        self._relabel(grid, changed)
        return self._publish(grid, t)

    def _update_full(self, grid: EvidenceGrid, t: float) -> list[Contact]:
        """:meth:`update` re-labelling every region (the reference: what the incremental update
        reproduces message for message)."""
        self._refresh(grid)
        # in chunk order, not cache insertion order: a tracker restored from a snapshot rebuilds
        # its cache in another order, and the sums below must not change in their last bits (nor
        # the label order that numbers new contacts); found by tools/kill_restart.py
        parts = [self._cells[k] for k in sorted(self._cells)]
        if parts:
            iy, ix, bel, mn, mth = (np.concatenate([p[i] for p in parts]) for i in range(5))
        else:
            iy = ix = np.zeros(0, dtype=np.int64)
            bel = mn = mth = np.zeros(0)
        n_reg, reg = label_cells(iy, ix)
        det_reg = self._detection_labels(grid, iy, ix, reg)
        own: dict[int, int] = {}
        e, n = grid.cell_centre(iy, ix)  # once per extraction: the groups' cells and each contact's read
        lab, n_comp, det_lab = self._split(grid, e, n, reg, n_reg, det_reg, own=own)
        # detections of each component: one stable sort, not a scan of all detections per
        # component (same members, same order)
        d_order = np.argsort(det_lab, kind="stable")
        d_bounds = np.searchsorted(det_lab[d_order], np.arange(n_comp + 1))
        members = [d_order[d_bounds[j]:d_bounds[j + 1]].tolist() for j in range(n_comp)]
        # position from the detections behind a component (SPEC 7); one without any is never a
        # contact (SPEC 7)
        comps = []
        cells_of = _comp_cells(lab, n_comp)
        for j, m in enumerate(members):
            if m:
                ce, cn, sigma = contact_position(grid.detections, m, nav_sigma_m=self.fusion.nav_sigma_m)
                p = _read_cell(e, n, bel, reg, cells_of[j], own.get(j), ce, cn, sigma)
                comps.append(_Component(j, ce, cn, sigma, float(bel[p]), float(mn[p]), float(mth[p]), int(iy[p]),
                                        int(ix[p]), m))
        comps = self._merge_objects(grid, comps)
        # one-to-one matching, nearest first, within the gate (one distance matrix, live
        # contacts x components; the same element-wise hypot as one row at a time)
        pairs = []
        if self.live and comps:
            cids = list(self.live)
            ce = np.array([c.ce for c in comps])
            cn = np.array([c.cn for c in comps])
            le = np.array([self.live[c].east_m for c in cids])
            ln = np.array([self.live[c].north_m for c in cids])
            d = np.hypot(ce[None, :] - le[:, None], cn[None, :] - ln[:, None])
            ii, jj = np.nonzero(d <= self.gate_m)
            pairs = list(zip(d[ii, jj].tolist(), [cids[i] for i in ii.tolist()], jj.tolist()))
        comp_id = _one_to_one(pairs + self._member_pairs(comps))
        out: list[Contact] = []
        for j, comp in enumerate(comps):
            if j not in comp_id and comp.bel < self.fusion.report_bel:
                continue
            cid = comp_id.get(j)
            state = "update" if cid is not None else "new"
            legs = _legs(grid, comp)
            dets = [grid.detections[i] for i in comp.dets]
            names = {r.detector for r in dets}
            fields = dict(east_m=comp.ce, north_m=comp.cn, sigma_m=comp.sigma, bel=comp.bel,
                          pl=float(1.0 - comp.mn), m_theta=comp.mth, looks=len(legs), detections=len(dets),
                          detectors=tuple(d for d in grid.detectors if d in names),
                          legs=legs, **extent_fields(dets, self.frame))
            if state == "update":
                old = self.live[cid]
                # lat/lon are a function of (east, north): equal fields mean equal content
                if all(getattr(old, k) == v for k, v in fields.items()):
                    continue
            else:
                cid, self.next_id = self.next_id, self.next_id + 1
            lat, lon = self.frame.to_latlon(comp.ce, comp.cn)
            c = Contact(id=cid, state=state, t=float(t), lat_deg=float(lat), lon_deg=float(lon), **fields)
            self.live[cid] = c
            out.append(c)
        return self._withdraw_rest(grid, t, comp_id, out)

    def _withdraw_rest(self, grid: EvidenceGrid, t: float, comp_id: dict[int, int], out: list[Contact]
                       ) -> list[Contact]:
        """Withdraw the live contacts neither matched nor published in ``out`` (with the belief
        now at their position), record every message, return them all."""
        for cid in sorted(set(self.live) - set(comp_id.values()) - {c.id for c in out}):
            old = self.live.pop(cid)
            m = grid.masses_at(old.east_m, old.north_m)
            out.append(dataclasses.replace(old, state="withdrawn", t=float(t), bel=float(m.m_t),
                                           pl=float(1.0 - m.m_n), m_theta=float(m.m_theta)))
        for c in out:
            self.history[c.id] = c
        return out

    # -- incremental update ------------------------------------------------------------------
    # A region's cells, detections, split and statistics depend on its own cells only, and the
    # cells of a chunk change only when the grid marks the chunk changed (legs, T and notT
    # evidence alike). A region can change only if it has cells in a changed chunk or in one
    # of its 8 neighbours (a new cell there may join it to others): those regions are
    # dissolved and their cells labelled again with the changed chunks' cells; every other
    # region, and its components, is kept as it was. Components are ordered as the full
    # extraction numbers them (by first cell in chunk order, split groups after), and matched
    # to the live contacts over all of them, so the messages are the same, in the same order
    # (``tests/fusion/test_contacts.py`` replays missions both ways).

    def _index_detections(self, grid: EvidenceGrid) -> None:
        """Index the grid's new detections by chunk (``grid.detections`` only grows)."""
        dets = grid.detections
        if len(dets) < self._n_det:  # not the grid this index was built on
            self._det_chunks, self._det_cells, self._n_det = {}, np.zeros((0, 2), dtype=np.int64), 0
        if len(dets) == self._n_det:
            return
        new = dets[self._n_det:]
        dy, dx = grid.cell_of(np.array([r.east_m for r in new]), np.array([r.north_m for r in new]))
        n = grid.n
        for i, key in enumerate(zip((dy // n).tolist(), (dx // n).tolist()), start=self._n_det):
            self._det_chunks.setdefault(key, []).append(i)
        self._det_cells = np.concatenate([self._det_cells, np.column_stack([dy, dx])])
        self._n_det = len(dets)

    def _relabel(self, grid: EvidenceGrid, changed: list[tuple[int, int]]) -> None:
        """Dissolve the regions near ``changed`` chunks and label their cells again."""
        if not changed:
            return
        nn = grid.nn
        changed_set = set(changed)
        dissolve: set[int] = set()
        owners = self._chunk_regions
        if owners:
            near = {(cy + dy, cx + dx) for cy, cx in changed_set for dy in (-1, 0, 1) for dx in (-1, 0, 1)}
            for k in near & owners.keys():
                dissolve |= owners[k]
        stale = np.array(sorted(_chunk_code(k) for k in changed_set), dtype=np.int64)
        parts: list[tuple[np.ndarray, ...]] = []
        keys: set[tuple[int, int]] = set(changed_set)
        for rid in dissolve:
            reg = self._regions.pop(rid)
            for comp in reg.comps:
                self._comps.pop(id(comp), None)
            for k in reg.keys:
                owners = self._chunk_regions[k]
                owners.discard(rid)
                if not owners:
                    del self._chunk_regions[k]
            keys |= reg.keys
            if reg.keys.isdisjoint(changed_set):
                parts.append(reg.cells)
                continue
            cc = reg.code // nn  # cells of changed chunks are taken from the cache below
            keep = stale[np.minimum(np.searchsorted(stale, cc), stale.size - 1)] != cc
            parts.append(tuple(a[keep] for a in reg.cells))
        for k in changed_set:
            c = self._cells.get(k)
            if c is not None and c[0].size:
                parts.append((*c, _chunk_code(k) * nn + np.arange(c[0].size, dtype=np.int64)))
        if not parts:
            return
        iy, ix, bel, mn, mth, code = (np.concatenate([p[i] for p in parts]) for i in range(6))
        if not iy.size:
            return
        order = np.argsort(code)  # chunk order, then the cache's order within a chunk: the full order
        iy, ix, bel, mn, mth, code = iy[order], ix[order], bel[order], mn[order], mth[order], code[order]
        n_reg, reg = label_cells(iy, ix)
        # detections of these cells: those indexed under the chunks involved
        cand = [i for k in keys for i in self._det_chunks.get(k, ())]
        det_idx = np.array(sorted(cand), dtype=np.int64)
        det_reg = np.full(det_idx.size, -1, dtype=np.int64)
        if det_idx.size:
            cell_code = (iy + _OFF) * (2 * _OFF) + (ix + _OFF)
            dc = self._det_cells[det_idx]
            want = (dc[:, 0] + _OFF) * (2 * _OFF) + (dc[:, 1] + _OFF)
            o = np.argsort(cell_code)
            pos = np.minimum(np.searchsorted(cell_code[o], want), cell_code.size - 1)
            hit = cell_code[o][pos] == want
            det_reg = np.where(hit, reg[o[pos]], -1)
            det_idx, det_reg = det_idx[hit], det_reg[hit]
        extras: list[tuple[int, int]] = []
        own: dict[int, int] = {}
        e, n = grid.cell_centre(iy, ix)  # once per extraction: the groups' cells and each contact's read
        lab, n_comp, det_lab = self._split(grid, e, n, reg, n_reg, det_reg, det_idx, extras, own)
        # each component's cells in the full extraction's order (a subset of its cells): the
        # same cells read
        cells_of = _comp_cells(lab, n_comp)
        d_order = np.argsort(det_lab, kind="stable")
        d_bounds = np.searchsorted(det_lab[d_order], np.arange(n_comp + 1)).tolist()
        r_order = np.argsort(reg, kind="stable")
        r_bounds = np.searchsorted(reg[r_order], np.arange(n_reg + 1)).tolist()
        first = code[r_order[r_bounds[:-1]]].tolist() if n_reg else []  # each region's first cell
        comps = []
        for j in range(n_comp):
            if j < n_reg:
                key: tuple = (0, first[j])
            else:
                r, g = extras[j - n_reg]
                key = (1, first[r], g)
            dl = det_idx[d_order[d_bounds[j]:d_bounds[j + 1]]].tolist()
            # position from its detections (SPEC 7); without any it is kept for the region's
            # bookkeeping but never published (_publish)
            ce, cn, sigma = (contact_position(grid.detections, dl, nav_sigma_m=self.fusion.nav_sigma_m) if dl
                             else (math.nan, math.nan, math.nan))
            # (without detections: its first cell, for the bookkeeping only)
            cells = cells_of[j]
            p = (_read_cell(e, n, bel, reg, cells, own.get(j), ce, cn, sigma) if dl
                 else int(cells[0]) if cells.size else 0)
            comps.append(_Component(key, ce, cn, sigma, float(bel[p]), float(mn[p]),
                                    float(mth[p]), int(iy[p]), int(ix[p]), dl))
        by_region: list[list[_Component]] = [[comps[j]] for j in range(n_reg)]
        for c, (r, _g) in enumerate(extras, start=n_reg):
            by_region[r].append(comps[c])
        for j in range(n_reg):
            cells = r_order[r_bounds[j]:r_bounds[j + 1]]
            rid = self._next_region
            self._next_region += 1
            ckeys = {(cc // (2 * _CHUNK_OFF) - _CHUNK_OFF, cc % (2 * _CHUNK_OFF) - _CHUNK_OFF)
                     for cc in np.unique(code[cells] // nn).tolist()}
            mine = by_region[j]
            self._regions[rid] = _Region((iy[cells], ix[cells], bel[cells], mn[cells], mth[cells], code[cells]),
                                         ckeys, mine)
            for k in ckeys:
                self._chunk_regions.setdefault(k, set()).add(rid)
            for comp in mine:
                self._comps[id(comp)] = comp

    def _publish(self, grid: EvidenceGrid, t: float) -> list[Contact]:
        """Match the components to the live contacts and return the messages (as the full
        extraction does, component by component in its order)."""
        # a region with no detection behind it is never a contact, neither born nor kept
        # alive (SPEC 7): a live contact whose region lost its detections is withdrawn
        comps = self._merge_objects(grid, [c for c in sorted(self._comps.values(), key=lambda c: c.key) if c.dets])
        n_comp = len(comps)
        pairs = []
        if self.live and n_comp:
            cids = list(self.live)
            ce = np.array([c.ce for c in comps])
            cn = np.array([c.cn for c in comps])
            le = np.array([self.live[c].east_m for c in cids])
            ln = np.array([self.live[c].north_m for c in cids])
            # the pairs within the gate, without the (live x components) matrix: candidates from
            # a sort by east, then the full extraction's element-wise hypot on them
            by_e = np.argsort(ce, kind="stable")
            se = ce[by_e]
            reach = self.gate_m * (1.0 + 1e-6) + 1e-9  # wider than the gate: rounding cannot lose a pair
            lo = np.searchsorted(se, le - reach, side="left")
            hi = np.searchsorted(se, le + reach, side="right")
            cnt = hi - lo
            ii = np.repeat(np.arange(le.size), cnt)
            jj = by_e[np.repeat(lo - np.cumsum(cnt) + cnt, cnt) + np.arange(int(cnt.sum()))]
            d = np.hypot(ce[jj] - le[ii], cn[jj] - ln[ii])
            ok = d <= self.gate_m
            pairs = list(zip(d[ok].tolist(), [cids[i] for i in ii[ok].tolist()], jj[ok].tolist()))
        comp_id = _one_to_one(pairs + self._member_pairs(comps))
        out: list[Contact] = []
        for j, comp in enumerate(comps):
            cid = comp_id.get(j)
            if cid is not None and comp.seen is not None and self.live.get(cid) is comp.seen:
                continue  # the contact it was compared with last time, and it has not changed since
            comp.seen = None
            if cid is None and comp.bel < self.fusion.report_bel:
                continue
            state = "update" if cid is not None else "new"
            fields = comp.fields
            if fields is None:
                legs = _legs(grid, comp)
                dets = [grid.detections[i] for i in comp.dets]
                names = {r.detector for r in dets}
                fields = comp.fields = dict(
                    east_m=comp.ce, north_m=comp.cn, sigma_m=comp.sigma, bel=comp.bel, pl=float(1.0 - comp.mn),
                    m_theta=comp.mth, looks=len(legs), detections=len(dets),
                    detectors=tuple(d for d in grid.detectors if d in names), legs=legs,
                    **extent_fields(dets, self.frame))
            if state == "update":
                old = self.live[cid]
                if all(getattr(old, k) == v for k, v in fields.items()):
                    comp.seen = old
                    continue
            else:
                cid, self.next_id = self.next_id, self.next_id + 1
            lat, lon = self.frame.to_latlon(comp.ce, comp.cn)
            c = Contact(id=cid, state=state, t=float(t), lat_deg=float(lat), lon_deg=float(lon), **fields)
            self.live[cid] = c
            comp.seen = c
            out.append(c)
        return self._withdraw_rest(grid, t, comp_id, out)

    def _member_pairs(self, comps: list[_Component]) -> list[tuple[float, int, int]]:
        """(distance, contact id, component) pairs within the gate of a merged component's
        members' positions: a piece published alone (as the vehicle passes a wreck, the
        pieces come one unit after another) keeps its id when the next piece joins it, though
        the union's centre moved beyond the gate."""
        merged = [(j, c) for j, c in enumerate(comps) if c.members]
        if not merged or not self.live:
            return []
        cids = list(self.live)
        le = np.array([self.live[c].east_m for c in cids])
        ln = np.array([self.live[c].north_m for c in cids])
        out = []
        for j, c in merged:
            for m in c.members:
                d = np.hypot(m.ce - le, m.cn - ln)
                out.extend((float(d[i]), cids[i], j) for i in np.flatnonzero(d <= self.gate_m).tolist())
        return out

    def _merge_objects(self, grid: EvidenceGrid, comps: list[_Component]) -> list[_Component]:
        """Join the components (in the full extraction's order, each with detections) that hold
        pieces of one extended object: their footprints (:func:`_footprints`) overlap or lie
        within :data:`TOUCH_M`. The detect stage sees one unit, so a wreck crossing units'
        edges comes as one piece per unit, each at its own centre, often metres apart, in
        regions or split groups of their own; one object is one contact (ICD 3), whatever
        the tiles' cuts (SPEC 0). A merged component stands at the first member's place in
        the order, with the union of their detections (position and extent from those,
        :func:`contact_position`, :func:`extent_fields`) and the cell read of the highest
        Bel(T) among them. Components without an extent are untouched. A function of the ordered
        components only, so the incremental and full extractions agree."""
        ext = []
        for j, c in enumerate(comps):
            if c.ext is None:
                c.ext = _footprints(grid.detections, c.dets) or ()
            if c.ext:
                ext.append(j)
        if len(ext) < 2:
            return comps
        centre = np.array([comps[j].ext[2] for j in ext])
        radius = np.array([comps[j].ext[3] for j in ext])
        # candidate pairs from a k-d tree within the widest reach, then the exact test: no
        # (objects x objects) matrix (heavy clutter makes thousands of objects, issue 21 item 3)
        reach = 2.0 * float(radius.max()) + TOUCH_M
        cand = cKDTree(centre).query_pairs(reach * (1.0 + 1e-9) + 1e-9, output_type="ndarray")
        cand = cand[np.lexsort((cand[:, 1], cand[:, 0]))] if cand.size else np.zeros((0, 2), dtype=np.int64)
        ci, cj = cand[:, 0], cand[:, 1]
        d = np.hypot(centre[ci, 0] - centre[cj, 0], centre[ci, 1] - centre[cj, 1])
        near = d <= radius[ci] + radius[cj] + TOUCH_M
        ii, jj = ci[near], cj[near]
        parent = list(range(len(ext)))

        def root(i: int) -> int:
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        for i, j in zip(ii.tolist(), jj.tolist()):
            ri, rj = root(i), root(j)
            if ri != rj and _touch(comps[ext[i]].ext, comps[ext[j]].ext, TOUCH_M):
                parent[max(ri, rj)] = min(ri, rj)
        groups: dict[int, list[int]] = {}
        for i in range(len(ext)):
            groups.setdefault(root(i), []).append(ext[i])
        merged: dict[int, _Component] = {}
        gone: set[int] = set()
        cache: dict[tuple[int, ...], _Component] = {}
        for g in groups.values():
            if len(g) < 2:
                continue
            members = tuple(comps[j] for j in g)
            ident = tuple(id(m) for m in members)
            old = self._merged.get(ident)
            if old is None or any(a is not b for a, b in zip(old.members, members)):
                top = max(members, key=lambda c: c.bel)  # the first of the highest
                dets = sorted({i for m in members for i in m.dets})
                ce, cn, sigma = contact_position(grid.detections, dets, nav_sigma_m=self.fusion.nav_sigma_m)
                old = _Component(members[0].key, ce, cn, sigma, top.bel, top.mn, top.mth, top.iy, top.ix, dets,
                                 members=members, ext=())
            cache[ident] = old  # unchanged members: the same merged component (its publish cache)
            merged[g[0]] = old
            gone.update(g[1:])
        self._merged = cache
        return [merged.get(j, c) for j, c in enumerate(comps) if j not in gone]

    def _split(self, grid: EvidenceGrid, e: np.ndarray, n: np.ndarray, reg: np.ndarray, n_reg: int,
               det_reg: np.ndarray, det_idx: np.ndarray | None = None,
               extras: list[tuple[int, int]] | None = None,
               own: dict[int, int] | None = None) -> tuple[np.ndarray, int, np.ndarray]:
        """Split belief regions that hold several distinct objects.

        A region is a union of association gates around detections, so two objects a few
        metres apart share one. Its detections are grouped by leader clustering within the gate;
        each cell goes to the nearest group (by its confidence-weighted mean position), and
        each group is a contact. Returns (cell labels, number of contacts, detection labels).

        ``det_reg`` labels the grid's detections ``det_idx`` (ascending; None: all of them).
        ``extras``, if given, receives (region, group) of each label beyond ``n_reg``, in order;
        ``own``, if given, maps every label of a split region to its region's label (what
        :func:`_read_cell` reads).
        """
        lab = reg.copy()
        det_lab = det_reg.copy()
        n_comp = n_reg
        if not n_reg or not (det_reg >= 0).any():
            return lab, n_comp, det_lab
        dets = grid.detections if det_idx is None else [grid.detections[i] for i in det_idx.tolist()]
        de = np.array([r.east_m for r in dets])
        dn = np.array([r.north_m for r in dets])
        conf = np.array([max(r.confidence, 1e-12) for r in dets])
        kept: dict[bytes, tuple[int, np.ndarray]] = {}  # the groupings of today's regions only
        # cells and detections of each region from one stable sort each (same members, same
        # ascending order as a scan per region)
        c_order = np.argsort(reg, kind="stable")
        c_bounds = np.searchsorted(reg[c_order], np.arange(n_reg + 1))
        d_order = np.argsort(det_reg, kind="stable")
        d_bounds = np.searchsorted(det_reg[d_order], np.arange(n_reg + 1)).tolist()
        xy_all = np.column_stack([de[d_order], dn[d_order]])  # a region's members: rows a..b
        conf_all = conf[d_order]
        for j in np.unique(det_reg[det_reg >= 0]).tolist():
            a, b = d_bounds[j], d_bounds[j + 1]
            if b - a < 2:
                continue
            members = d_order[a:b]
            # leader_groups is deterministic: a region whose detections did not change (most
            # of them, from one update to the next) reuses its grouping
            xy = xy_all[a:b]
            mkey = xy.tobytes() + conf_all[a:b].tobytes()
            ng, g = kept[mkey] = self._groups.get(mkey) or leader_groups(xy, conf_all[a:b], radius_m=self.gate_m)
            if ng < 2:
                continue
            wsum = np.bincount(g, weights=conf[members], minlength=ng)
            ge = np.bincount(g, weights=conf[members] * de[members], minlength=ng) / wsum
            gn = np.bincount(g, weights=conf[members] * dn[members], minlength=ng) / wsum
            cells = c_order[c_bounds[j]:c_bounds[j + 1]]
            nearest = nearest_group(e[cells], n[cells], ge, gn)
            new_labels = np.r_[j, n_comp + np.arange(ng - 1)]  # group 0 keeps the region's label
            lab[cells] = new_labels[nearest]
            det_lab[members] = new_labels[g]
            n_comp += ng - 1
            if extras is not None:
                extras.extend((j, k) for k in range(1, ng))
            if own is not None:
                own.update((int(label), j) for label in new_labels)
        if det_idx is None:
            self._groups = kept
        else:  # a subset of the regions: keep the others' groupings too (bounded)
            if len(self._groups) > 4 * (len(self._regions) + len(kept)) + 256:
                self._groups = {}
            self._groups.update(kept)
        return lab, n_comp, det_lab

    @staticmethod
    def _detection_labels(grid: EvidenceGrid, iy: np.ndarray, ix: np.ndarray, lab: np.ndarray) -> np.ndarray:
        """Component label of each grid detection's cell (-1: not in any candidate region)."""
        if not grid.detections or iy.size == 0:
            return np.full(len(grid.detections), -1, dtype=np.int64)
        de = np.array([r.east_m for r in grid.detections])
        dn = np.array([r.north_m for r in grid.detections])
        dy, dx = grid.cell_of(de, dn)
        code = (iy + _OFF) * (2 * _OFF) + (ix + _OFF)
        want = (dy + _OFF) * (2 * _OFF) + (dx + _OFF)
        order = np.argsort(code)
        pos = np.minimum(np.searchsorted(code[order], want), code.size - 1)
        hit = code[order][pos] == want
        return np.where(hit, lab[order[pos]], -1)

    # -- state for snapshots --------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        return {"next_id": self.next_id, "live": [c.to_message() for c in self.live.values()],
                "history": [c.to_message() for c in self.history.values()]}

    def restore(self, state: dict[str, Any]) -> None:
        """Restore ids and live contacts; the cell cache is rebuilt from the grid on the next update."""
        self.next_id = int(state["next_id"])
        self.live = {int(m["id"]): Contact.from_message(m) for m in state["live"]}
        self.history = {int(m["id"]): Contact.from_message(m) for m in state["history"]}
        self._stamp, self._cells, self._groups, self._merged = 0, {}, {}, {}
        self._reset_regions()
