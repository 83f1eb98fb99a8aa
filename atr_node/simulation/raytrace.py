"""Geometric-optics ray tracer of a target on a flat seabed (SPEC section 4).

Frame of a tile (ground range): ``x`` along-track (row ``i`` centred on ``x = i * dx_m``),
``y`` ground range away from the sonar (column ``j`` centred on ``y = range0_m + j * dr_m``),
``z`` up from the seabed. The sensor moves along ``x`` at ``y = 0``, altitude ``H``. Pixel
(i, j) is sampled by k x k sub-rays aimed from the sensor at seabed points spread over the
pixel; every ray lies in the plane ``x = const`` of its ping (zero-Doppler geometry).

Each ray goes from ``S = (0, H)`` to its seabed point ``P = (y_s, 0)`` in that plane. Because
the plane is fixed per ray, the mesh is sliced once per sub-row into 2-D segments and the
rays are intersected with the segments of their slice: exact, and far cheaper than a 3-D
Moeller-Trumbore over all triangles. A ray whose first hit is at parameter ``t < 1`` (before
the seabed) leaves its seabed point in shadow and returns ``|n . d|`` (the sine of its grazing
angle on the facet, normal ``n``, direction ``d``; the absolute value makes the winding
irrelevant) at slant range ``R = t |P - S|``, mapped to the ground-range axis with
``r = sqrt(R^2 - H^2)``. Returns landing in one pixel add up (layover).

Only pixels the target can reach are traced: rows of its along-track extent, seabed points
from its nearest ground range to the end of its longest shadow ``y_max H / (H - z_max)``,
echo bins from the smallest slant range its bounding box allows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import GeometryError
from .meshes import Mesh

_AREA_EPS = 1e-12   # m^2: smaller triangles are degenerate and skipped
_PARALLEL_EPS = 1e-9  # |sin| between a ray and a segment below which they are parallel


@dataclass(frozen=True, eq=False)
class Signature:
    """Proportion maps of one target over the window of the tile it can reach.

    The maps cover rows ``row0 .. row0 + rows`` and columns ``col0 .. col0 + cols`` of the
    tile; outside that window the target changes nothing.

    Attributes
    ----------
    p_shadow : ndarray, shape (rows, cols), float32
        Fraction of each pixel's sub-rays whose seabed point is hidden by the target.
    echo : ndarray, shape (rows, cols), float32
        Echo strength e: sum over the sub-rays returning into the pixel of
        ``sin(grazing on the facet)``, divided by k^2 (a facet seen at normal incidence
        that fills the pixel gives 1).
    """

    row0: int
    col0: int
    p_shadow: np.ndarray
    echo: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.p_shadow.shape  # type: ignore[return-value]

    @property
    def p_seabed(self) -> np.ndarray:
        return 1.0 - self.p_shadow

    @property
    def empty(self) -> bool:
        return self.p_shadow.size == 0

    @property
    def footprint(self) -> tuple[int, int, int, int]:
        """(row0, row1, col0, col1), half-open, of the window."""
        r, c = self.shape
        return self.row0, self.row0 + r, self.col0, self.col0 + c


def _empty() -> Signature:
    z = np.zeros((0, 0), dtype=np.float32)
    return Signature(0, 0, z, z)


def _facet_normals(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (m, 3) and a keep-mask of non-degenerate triangles."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.column_stack([e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1],
                         e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2],
                         e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]])
    norm = np.sqrt((n * n).sum(axis=1))
    keep = 0.5 * norm > _AREA_EPS
    return n[keep] / norm[keep, None], keep


def slice_mesh(tri: np.ndarray, x_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cut triangles by the planes ``x = x_m``, packing each plane's segments to the left.

    Parameters
    ----------
    tri : ndarray, shape (m, 3, 3)
        Triangle vertices.
    x_m : ndarray, shape (s,)
        Plane positions.

    Returns
    -------
    a, b : ndarray, shape (s, m', 2)
        Segment end points (y, z) in each plane; m' = the most segments any plane has.
    index : ndarray, shape (s, m'), int
        Triangle of each segment.
    valid : ndarray, shape (s, m'), bool
        False for padding.
    """
    s = x_m.size
    d = tri[None, :, :, 0] - x_m[:, None, None]            # (s, m, 3) signed distances
    pos = d >= 0.0                                          # a vertex on the plane counts as positive
    npos = pos.sum(axis=2)
    si, ti = np.nonzero((npos == 1) | (npos == 2))          # (plane, triangle) pairs that cross; si sorted
    if si.size == 0:
        z = np.zeros((s, 0, 2))
        return z, z, np.zeros((s, 0), dtype=np.int64), np.zeros((s, 0), dtype=bool)
    pp, dp = pos[si, ti], d[si, ti]                         # (P, 3)
    # The lone vertex, on its own side of the plane: its two edges are the crossing ones.
    lone = np.where(npos[si, ti] == 1, np.argmax(pp, axis=1), np.argmin(pp, axis=1))
    P = np.arange(si.size)
    o1, o2 = (lone + 1) % 3, (lone + 2) % 3
    v = tri[ti]                                             # (P, 3, 3)
    vl, dl = v[P, lone, 1:], dp[P, lone]
    a = vl + (dl / (dl - dp[P, o1]))[:, None] * (v[P, o1, 1:] - vl)
    b = vl + (dl / (dl - dp[P, o2]))[:, None] * (v[P, o2, 1:] - vl)
    counts = np.bincount(si, minlength=s)
    rank = P - (np.cumsum(counts) - counts)[si]
    m_used = int(counts.max())
    A = np.zeros((s, m_used, 2))
    B = np.zeros((s, m_used, 2))
    index = np.zeros((s, m_used), dtype=np.int64)
    valid = np.zeros((s, m_used), dtype=bool)
    A[si, rank], B[si, rank], index[si, rank], valid[si, rank] = a, b, ti, True
    return A, B, index, valid


def _clip_above_seabed(a: np.ndarray, b: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Clip 2-D segments (..., 2) = (y, z) to z >= 0; segments entirely below become invalid."""
    za, zb = a[..., 1], b[..., 1]
    valid = valid & ((za > 0.0) | (zb > 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.clip(za / (za - zb), 0.0, 1.0)[..., None]
    cut = a + w * (b - a)
    a = np.where((za < 0.0)[..., None], cut, a)
    b = np.where((zb < 0.0)[..., None], cut, b)
    return a, b, valid


@dataclass(frozen=True, eq=False)
class TraceWindow:
    """What :func:`trace` needs of a placed target before it traces a ray: its usable
    triangles and their normals, and the window of the tile it can reach (rows ``i0 .. i1``,
    columns ``c0 .. c1``; seabed points ``cs0 .. cs1``). Cheap (the mesh's bounding box): a
    caller can reject a placement on the window before paying for the trace."""

    tri: np.ndarray
    normals: np.ndarray
    lo: np.ndarray
    zmax: float
    i0: int
    i1: int
    c0: int
    c1: int
    cs0: int
    cs1: int

    @property
    def footprint(self) -> tuple[int, int, int, int]:
        """(row0, row1, col0, col1), half-open: the traced :class:`Signature`'s footprint."""
        return self.i0, self.i1, self.c0, self.c1


def trace_window(mesh: Mesh, *, range0_m: float, dr_m: float, dx_m: float, rows: int, cols: int,
                 altitude_m: float) -> TraceWindow | None:
    """The window :func:`trace` traces a placed target into, or None when the trace is empty
    (outside the tile, entirely buried, on the other side of the track). Parameters as
    :func:`trace`."""
    if not (altitude_m > 0 and math.isfinite(altitude_m)):
        raise GeometryError(f"altitude must be finite and > 0, got {altitude_m!r}")
    if dr_m <= 0 or dx_m <= 0:
        raise GeometryError(f"pixel spacing must be > 0, got dr={dr_m}, dx={dx_m}")
    H = float(altitude_m)
    tri_all = mesh.triangles_m
    normals, keep = _facet_normals(tri_all)
    tri = tri_all[keep]
    if len(tri) == 0:
        return None
    lo, hi = tri.reshape(-1, 3).min(axis=0), tri.reshape(-1, 3).max(axis=0)
    zmax = min(hi[2], H)
    if zmax <= 0.0 or hi[1] <= 0.0:
        return None  # entirely buried, or on the other side of the track
    # Rows the target spans (pixel i covers x in [(i - 1/2) dx, (i + 1/2) dx)).
    i0 = max(int(math.floor(lo[0] / dx_m + 0.5)), 0)
    i1 = min(int(math.floor(hi[0] / dx_m + 0.5)) + 1, rows)
    # Seabed points that can be hidden: from the nearest ground range to the end of the shadow.
    y_near = max(lo[1], 0.0)
    y_far = hi[1] * H / (H - zmax) if zmax < H else math.inf
    edge0 = range0_m - dr_m / 2
    cs0 = max(int(math.floor((y_near - edge0) / dr_m)), 0)
    cs1 = min(int(math.floor((y_far - edge0) / dr_m)) + 1, cols) if math.isfinite(y_far) else cols
    # Echo bins: the smallest slant range any point of the bounding box can have.
    r_min = math.sqrt(y_near ** 2 + (H - zmax) ** 2)
    g_min = math.sqrt(max(r_min ** 2 - H ** 2, 0.0))
    ce0 = max(int(math.floor((g_min - edge0) / dr_m)), 0)
    c0, c1 = min(cs0, ce0), cs1
    if i1 <= i0 or c1 <= c0 or cs1 <= cs0:
        return None
    return TraceWindow(tri, normals, lo, float(zmax), i0, i1, c0, c1, cs0, cs1)


def trace(mesh: Mesh, *, range0_m: float, dr_m: float, dx_m: float, rows: int, cols: int,
          altitude_m: float, subrays: int = 2, window: TraceWindow | None = None) -> Signature:
    """Trace a placed target (tile frame, see :func:`~.meshes.place`) into proportion maps.

    Parameters
    ----------
    mesh
        The target in the tile frame (metres).
    range0_m, dr_m, dx_m
        Ground range of column 0, range-bin and ping spacing.
    rows, cols
        Tile size; the returned window is clipped to it.
    altitude_m
        Sensor altitude H above the seabed.
    subrays
        k: k x k sub-rays per pixel.
    window
        :func:`trace_window` of the same mesh and geometry, when the caller has it already.

    Returns
    -------
    Signature
        Empty when the target is outside the tile or entirely buried.
    """
    k = int(subrays)
    if k < 1:
        raise GeometryError(f"subrays must be >= 1, got {subrays}")
    w = window if window is not None else trace_window(mesh, range0_m=range0_m, dr_m=dr_m, dx_m=dx_m, rows=rows,
                                                        cols=cols, altitude_m=altitude_m)
    if w is None:
        return _empty()
    H = float(altitude_m)
    tri, normals, lo = w.tri, w.normals, w.lo
    i0, i1, c0, c1, cs0, cs1 = w.i0, w.i1, w.c0, w.c1, w.cs0, w.cs1
    edge0 = range0_m - dr_m / 2
    nr, nc = i1 - i0, c1 - c0

    # Sub-ray planes (s,) and seabed points (q,).
    frac = (np.arange(k) + 0.5) / k - 0.5
    xs = ((np.arange(i0, i1)[:, None] + frac[None, :]) * dx_m).reshape(-1)
    ys = (range0_m + (np.arange(cs0, cs1)[:, None] + frac[None, :]) * dr_m).reshape(-1)
    a, b, index, valid = slice_mesh(tri, xs)
    p_shadow = np.zeros((nr, nc), dtype=np.float64)
    echo = np.zeros((nr, nc), dtype=np.float64)
    if valid.shape[1] == 0:
        return Signature(i0, c0, p_shadow.astype(np.float32), echo.astype(np.float32))
    nrm = normals[index]                                     # (s, m', 3)
    if lo[2] < 0.0:
        # Clip segments to the water column above the seabed: rays never go below z = 0.
        a, b, valid = _clip_above_seabed(a, b, valid)
    # A ray from S = (0, H) to the seabed point (y, 0) crosses segment AB iff y lies between
    # the seabed projections of A and B from S: y' H / (H - z') (similar triangles).
    with np.errstate(divide="ignore", invalid="ignore"):
        pa = np.where(a[..., 1] < H, a[..., 0] * H / (H - a[..., 1]), np.inf)
        pb = np.where(b[..., 1] < H, b[..., 0] * H / (H - b[..., 1]), np.inf)
    lo_p = np.where(valid, np.minimum(pa, pb), np.inf)      # (s, m')
    hi_p = np.where(valid, np.maximum(pa, pb), -np.inf)
    cand = (ys[None, :, None] >= lo_p[:, None, :]) & (ys[None, :, None] <= hi_p[:, None, :])  # (s, q, m')
    si, qi, mi = np.nonzero(cand)
    hid = np.zeros((len(xs), len(ys)), dtype=bool)
    if si.size:
        # Ray S + t (P - S), segment A + u (B - A): t = ((A - S) x E) / (D x E).
        dy, dz = ys[qi], -H
        A, B = a[si, mi], b[si, mi]
        ey, ez = B[:, 0] - A[:, 0], B[:, 1] - A[:, 1]
        ay, az = A[:, 0], A[:, 1] - H
        denom = dy * ez - dz * ey
        dlen = np.hypot(dy, H)
        par = np.abs(denom) <= _PARALLEL_EPS * dlen * np.hypot(ey, ez)
        # A segment along the ray (grazing, parallel facet) is met at its nearer end.
        near = np.minimum(np.hypot(ay, az), np.hypot(B[:, 0], B[:, 1] - H)) / dlen
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(par, near, (ay * ez - az * ey) / np.where(par, 1.0, denom))
        # A hit at the seabed point itself (t = 1, a facet lying on the seabed) hides nothing.
        good = (t > 0.0) & (t < 1.0 - 1e-9)
        si, qi, mi, t, dlen = si[good], qi[good], mi[good], t[good], dlen[good]
        # First hit per ray: sort by (ray, t) and keep the first of each ray.
        ray = si * len(ys) + qi
        order = np.lexsort((t, ray))
        keep = np.ones(order.size, dtype=bool)
        keep[1:] = ray[order][1:] != ray[order][:-1]
        sel = order[keep]
        si, qi, mi, t, dlen = si[sel], qi[sel], mi[sel], t[sel], dlen[sel]
        hid[si, qi] = True
        # Echo: |n . d| at the slant range of the hit, binned on the ground-range axis (layover adds).
        n_hit = nrm[si, mi]
        sin_g = np.abs(n_hit[:, 1] * ys[qi] - n_hit[:, 2] * H) / dlen
        slant = t * dlen
        ground = np.sqrt(np.maximum(slant ** 2 - H ** 2, 0.0))
        col = np.floor((ground - edge0) / dr_m).astype(np.int64) - c0
        row = si // k
        inside = (col >= 0) & (col < nc)
        flat = row[inside] * nc + col[inside]
        echo += np.bincount(flat, weights=sin_g[inside], minlength=nr * nc).reshape(nr, nc) / (k * k)
    # Shadow: fraction of hidden sub-rays per pixel.
    p_shadow[:, cs0 - c0:cs1 - c0] = hid.reshape(nr, k, cs1 - cs0, k).mean(axis=(1, 3))
    return Signature(i0, c0, p_shadow.astype(np.float32), echo.astype(np.float32))
