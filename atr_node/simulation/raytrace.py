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
from functools import lru_cache

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


def _facet_normals(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Unit normals (m, 3), a keep-mask of non-degenerate triangles, and six times the signed
    volume the triangles enclose (> 0: normals outward, for a closed mesh)."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.column_stack([e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1],
                         e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2],
                         e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]])
    norm = np.sqrt((n * n).sum(axis=1))
    keep = 0.5 * norm > _AREA_EPS
    return n[keep] / norm[keep, None], keep, float((n * tri[:, 0]).sum())


@lru_cache(maxsize=256)
def _closed(faces: bytes) -> bool:
    """Whether triangles (int64 (m, 3) as bytes) close a surface with consistent winding:
    every directed edge once, and its reverse once."""
    f = np.frombuffer(faces, dtype=np.int64).reshape(-1, 3)
    if f.size == 0:
        return False
    a, b = f.reshape(-1), np.roll(f, -1, axis=1).reshape(-1)
    n = int(f.max()) + 1
    edge = np.sort(a * n + b)
    if np.any(edge[1:] == edge[:-1]):
        return False
    return bool(np.isin(b * n + a, edge, assume_unique=True).all())


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
    facing: int = 0
    """+1 (-1): a closed mesh with normals outward (inward), whose faces turned away from the
    sensor can be left out; 0: an open mesh, every face is traced."""

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
    normals, keep, vol6 = _facet_normals(tri_all)
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
    facing = int(np.sign(vol6)) if vol6 != 0.0 and _closed(mesh.faces.tobytes()) else 0
    return TraceWindow(tri, normals, lo, float(zmax), i0, i1, c0, c1, cs0, cs1, facing)


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
    if int(subrays) < 1:
        raise GeometryError(f"subrays must be >= 1, got {subrays}")
    w = window if window is not None else trace_window(mesh, range0_m=range0_m, dr_m=dr_m, dx_m=dx_m, rows=rows,
                                                        cols=cols, altitude_m=altitude_m)
    return trace_many([w], range0_m=range0_m, dr_m=dr_m, dx_m=dx_m, altitude_m=altitude_m, subrays=subrays)[0]


def _expand(lo: np.ndarray, hi: np.ndarray, n_max: np.ndarray, *bases: np.ndarray
            ) -> tuple[np.ndarray, ...]:
    """Index ranges ``lo .. hi`` (inclusive, clipped to ``0 .. n_max - 1``), one per owner,
    expanded owner-major into (owner, base_1 + index, base_2 + index, ...) per element."""
    lo = np.maximum(lo, 0)
    cnt = np.maximum(np.minimum(hi, n_max - 1) - lo + 1, 0)
    total = int(cnt.sum())
    owner = np.repeat(np.arange(cnt.size), cnt)
    shift = np.cumsum(cnt) - cnt - lo                         # element e of owner o has index e - shift[o]
    ramp = np.arange(total)
    return (owner,) + tuple(ramp - (shift - base)[owner] for base in bases)


def trace_many(windows: "list[TraceWindow | None]", *, range0_m: float, dr_m: float, dx_m: float,
               altitude_m: float, subrays: int = 2) -> list[Signature]:
    """Trace many placed targets of one tile at once: the signature engine (issue 19).

    The rays and every test on them are those of :func:`trace`, written as whole-array
    operations over all targets' planes, segments and rays, and restricted to the pairs that
    can meet:

    * a triangle is sliced only by the planes within its along-track extent;
    * a segment is tested only against the rays whose seabed point lies in its shadow
      interval (an index range: the rays are evenly spaced), not against every ray;
    * the ray-segment parameter ``t = N / (y E_z + H E_y)`` has its numerator per segment;
    * the first hit of a ray is a scatter-minimum of ``t`` (ties: the segment :func:`trace`
      meets first), not a sort;
    * on a closed, consistently wound mesh, segments facing away from the sensor are
      dropped: a ray from outside meets a front face first (its normal is constant along a
      segment, and so is the sign of ``n . (A - S)``). A ray through a silhouette edge, where
      front and back meet at the same ``t``, may then take the front face's normal; that is
      the only difference from testing every segment (measured by
      ``atr-node bench simulation``).

    Parameters
    ----------
    windows
        :func:`trace_window` of each placed target in the tile (None: an empty signature).
    range0_m, dr_m, dx_m, altitude_m, subrays
        As :func:`trace`.

    Returns
    -------
    list of Signature
        One per window, in order.
    """
    k = int(subrays)
    if k < 1:
        raise GeometryError(f"subrays must be >= 1, got {subrays}")
    H = float(altitude_m)
    out: list[Signature] = [_empty()] * len(windows)
    ws = [(n, w) for n, w in enumerate(windows) if w is not None]
    if not ws:
        return out
    J = len(ws)
    frac = (np.arange(k) + 0.5) / k - 0.5
    edge0 = range0_m - dr_m / 2
    geo = np.array([(w.i0, w.i1, w.c0, w.c1, w.cs0, w.cs1, len(w.tri), w.lo[2] < 0.0, w.facing)
                    for _, w in ws], dtype=np.int64)
    i0, i1, c0, c1, cs0, cs1, m_n, buried, facing = geo.T
    nr, nc = i1 - i0, c1 - c0
    s_n, q_n = nr * k, (cs1 - cs0) * k                       # planes, and rays per plane, per target
    s_off = np.cumsum(s_n) - s_n
    y_off = np.cumsum(q_n) - q_n
    px_off = np.cumsum(nr * nc) - nr * nc                     # each target's maps in one flat array
    ray_off = np.cumsum(s_n * q_n) - s_n * q_n                # each target's rays, plane-major
    zeros = np.zeros(J, dtype=np.int64)

    # Planes (x of every sub-row) and seabed points (y of every sub-column), as trace() has them.
    pt, pl = _expand(zeros, s_n - 1, s_n, zeros)
    xs = (i0[pt] + pl // k + frac[pl % k]) * dx_m
    yt, yq = _expand(zeros, q_n - 1, q_n, zeros)
    y_all = range0_m + (cs0[yt] + yq // k + frac[yq % k]) * dr_m
    dlen_all = np.hypot(y_all, H)
    y_col = cs0[yt] + yq // k                                 # tile column of each seabed point
    dmax = np.maximum.reduceat(dlen_all, y_off) if dlen_all.size else zeros    # longest |P - S| per target

    # Segments: each triangle cut by the planes within its along-track extent (one plane of
    # slack for rounding, then the exact test of slice_mesh). Triangle-major: within a plane,
    # the segments keep slice_mesh's triangle order, which is all the ties depend on.
    tri = np.concatenate([w.tri for _, w in ws])
    nrm_all = np.concatenate([w.normals for _, w in ws])
    tt = np.repeat(np.arange(J), m_n)                         # target of each triangle
    tx = tri[:, :, 0]
    step = dx_m / k
    x_first = (i0 - 0.5 + 0.5 / k) * dx_m                     # about the x of a target's plane 0
    x_lo, x_hi = tx.min(axis=1), tx.max(axis=1)
    p_lo = np.floor((x_lo - x_first[tt]) / step).astype(np.int64) - 1
    p_hi = np.ceil((x_hi - x_first[tt]) / step).astype(np.int64) + 1
    f_tri = facing[tt]
    if f_tri.any():
        # Triangles of a closed mesh turned away from the sensor in every plane they cross
        # (n . (V - S) is linear in the plane's x: its two ends decide) are never met first.
        # A conservative pre-filter: the exact test is on each segment below.
        v0 = tri[:, 0]
        f0 = nrm_all[:, 1] * v0[:, 1] + nrm_all[:, 2] * (v0[:, 2] - H) + nrm_all[:, 0] * v0[:, 0]
        span = np.abs(nrm_all[:, 0]) * step
        back = (f_tri != 0) & (f_tri * (f0 - nrm_all[:, 0] * x_lo) > span) & (f_tri * (f0 - nrm_all[:, 0] * x_hi) > span)
        p_hi = np.where(back, -1, p_hi)
    ti, gp = _expand(p_lo, p_hi, s_n[tt], s_off[tt])          # (triangle, global plane)
    d = tx[ti] - xs[gp][:, None]                               # signed distances of the 3 vertices
    pos = d >= 0.0                                             # a vertex on the plane counts as positive
    npos = pos.sum(axis=1)
    cross = np.flatnonzero((npos == 1) | (npos == 2))
    ti, gp, d, pos, npos = ti[cross], gp[cross], d[cross], pos[cross], npos[cross]
    hid_px = np.zeros(int((nr * nc).sum()), dtype=np.float64)
    echo = np.zeros_like(hid_px)
    if ti.size:
        # The lone vertex, on its own side of the plane: its two edges are the crossing ones.
        lone = np.where(npos == 1, np.argmax(pos, axis=1), np.argmin(pos, axis=1))
        P = np.arange(ti.size)
        o1, o2 = (lone + 1) % 3, (lone + 2) % 3
        v = tri[ti]
        vl, dl = v[P, lone, 1:], d[P, lone]
        a = vl + (dl / (dl - d[P, o1]))[:, None] * (v[P, o1, 1:] - vl)
        b = vl + (dl / (dl - d[P, o2]))[:, None] * (v[P, o2, 1:] - vl)
        st = tt[ti]                                            # target of each segment
        nrm = nrm_all[ti]
        # A closed mesh's faces turned away from the sensor never take a first hit.
        fs = facing[st]
        front = (fs == 0) | (fs * (nrm[:, 1] * a[:, 0] + nrm[:, 2] * (a[:, 1] - H)) <= 0.0)
        valid = front
        cut = np.flatnonzero(buried[st].astype(bool))
        if cut.size:
            # Clip segments to the water column above the seabed: rays never go below z = 0.
            a[cut], b[cut], valid[cut] = _clip_above_seabed(a[cut], b[cut], valid[cut])
        with np.errstate(divide="ignore", invalid="ignore"):
            pa = np.where(a[:, 1] < H, a[:, 0] * H / (H - a[:, 1]), np.inf)
            pb = np.where(b[:, 1] < H, b[:, 0] * H / (H - b[:, 1]), np.inf)
        keep = np.flatnonzero(valid)
        st, nrm, a, b, pa, pb, gp = st[keep], nrm[keep], a[keep], b[keep], pa[keep], pb[keep], gp[keep]
        lo_p, hi_p = np.minimum(pa, pb), np.maximum(pa, pb)
        # Rays whose seabed point lies in the segment's shadow interval [lo_p, hi_p]: an index
        # range from the rays' even spacing (one ray of slack), then the exact test.
        ystep = dr_m / k
        y_first = range0_m + (cs0 - 0.5 + 0.5 / k) * dr_m
        qs = q_n[st]
        with np.errstate(invalid="ignore", over="ignore"):
            r_lo = np.ceil(np.clip((lo_p - y_first[st]) / ystep, -2.0, qs + 2.0)).astype(np.int64) - 1
            r_hi = np.floor(np.clip((hi_p - y_first[st]) / ystep, -2.0, qs + 2.0)).astype(np.int64) + 1
        # Per segment: the ray-segment intersection t = ((A - S) x E) / (D x E), D = (y, -H),
        # as trace() writes it: t = num / (y E_z - (-H) E_y).
        ay, az = a[:, 0], a[:, 1] - H
        ey, ez = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
        num = ay * ez - az * ey
        hey = -H * ey
        # Global id of a ray = gbase (of its segment) + its index in y_all.
        gbase = ray_off[st] + (gp - s_off[st]) * qs - y_off[st]
        si, yi = _expand(r_lo, r_hi, qs, y_off[st])
        ys = y_all[yi]
        denom = ys * ez[si] - hey[si]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = num[si] / denom
        # Parallel: |denom| <= eps |D| |E|; first against the target's longest |D|, then exactly.
        eps_len = _PARALLEL_EPS * np.hypot(ey, ez)
        par = np.flatnonzero(np.abs(denom) <= (eps_len * dmax[st])[si])
        par = par[np.abs(denom[par]) <= _PARALLEL_EPS * dlen_all[yi[par]] * np.hypot(ey, ez)[si[par]]]
        if par.size:
            # A segment along the ray (grazing, parallel facet) is met at its nearer end.
            near = np.minimum(np.hypot(ay, az), np.hypot(b[:, 0], b[:, 1] - H))
            t[par] = near[si[par]] / dlen_all[yi[par]]
        # In the segment's shadow interval, and hit before the seabed point (t = 1: a facet
        # lying on the seabed hides nothing).
        hit = np.flatnonzero((ys >= lo_p[si]) & (ys <= hi_p[si]) & (t > 0.0) & (t < 1.0 - 1e-9))
        si, yi, t = si[hit], yi[hit], t[hit]
        # First hit per ray: the smallest t; among equal t, the segment trace() meets first.
        gray = gbase[si] + yi
        tmin = np.full(int((s_n * q_n).sum()), np.inf)
        np.minimum.at(tmin, gray, t)
        sel = np.flatnonzero(t == tmin[gray])
        if sel.size > np.count_nonzero(tmin < np.inf):        # ties: the lowest segment wins
            smin = np.full(tmin.size, np.iinfo(np.int64).max)
            np.minimum.at(smin, gray[sel], si[sel])
            sel = sel[si[sel] == smin[gray[sel]]]
        si, yi, t = si[sel], yi[sel], t[sel]
        ht = st[si]
        ys, dlen = y_all[yi], dlen_all[yi]
        base = (px_off[st] + ((gp - s_off[st]) // k) * nc[st] - c0[st])[si]   # pixel of column 0 of the row
        # Shadow: hidden sub-rays per pixel.
        hid_px += np.bincount(base + y_col[yi], minlength=hid_px.size)
        # Echo: |n . d| at the slant range of the hit, binned on the ground-range axis (layover adds).
        sin_g = np.abs(nrm[:, 1][si] * ys - (nrm[:, 2] * H)[si]) / dlen
        slant = t * dlen
        ground = np.sqrt(np.maximum(slant ** 2 - H ** 2, 0.0))
        col = np.floor((ground - edge0) / dr_m).astype(np.int64)
        inside = (col >= c0[ht]) & (col < c1[ht])
        echo += np.bincount((base + col)[inside], weights=sin_g[inside], minlength=echo.size)
    for j, (n, w) in enumerate(ws):
        o, shape = int(px_off[j]), (int(nr[j]), int(nc[j]))
        sz = shape[0] * shape[1]
        out[n] = Signature(w.i0, w.c0, (hid_px[o:o + sz] / (k * k)).reshape(shape).astype(np.float32),
                           (echo[o:o + sz] / (k * k)).reshape(shape).astype(np.float32))
    return out
