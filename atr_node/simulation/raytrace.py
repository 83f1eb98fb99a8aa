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

from dataclasses import dataclass

import numpy as np

from ..errors import GeometryError
from .meshes import Mesh
from .strips import expand_ranges, strip_echo, strip_shadow, strip_targets
from .window import TraceWindow, surfaces, trace_window

__all__ = ["ENGINES", "Signature", "TraceWindow", "trace", "trace_many", "trace_window"]

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


def trace(mesh: Mesh, *, range0_m: float, dr_m: float, dx_m: float, rows: int, cols: int,
          altitude_m: float, subrays: int = 2, window: TraceWindow | None = None, engine: str = "rays") -> Signature:
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
    engine
        ``"rays"`` or ``"strips"`` (:data:`ENGINES`, :func:`trace_many`).

    Returns
    -------
    Signature
        Empty when the target is outside the tile or entirely buried.
    """
    if int(subrays) < 1:
        raise GeometryError(f"subrays must be >= 1, got {subrays}")
    w = window if window is not None else trace_window(mesh, range0_m=range0_m, dr_m=dr_m, dx_m=dx_m, rows=rows,
                                                        cols=cols, altitude_m=altitude_m)
    return trace_many([w], range0_m=range0_m, dr_m=dr_m, dx_m=dx_m, altitude_m=altitude_m, subrays=subrays,
                      engine=engine)[0]


ENGINES = ("rays", "strips")
"""Signature engines: ``"rays"``, k x k sampled sub-rays per pixel (the tracer of
:func:`trace`); ``"strips"``, k sub-row planes per pixel row, each integrated exactly along
range (:func:`~.strips.strip_shadow`, :func:`~.strips.strip_echo`)."""


def trace_many(windows: "list[TraceWindow | None]", *, range0_m: float, dr_m: float, dx_m: float,
               altitude_m: float, subrays: int = 2, engine: str = "rays") -> list[Signature]:
    """Trace many placed targets of one tile at once: the signature engine (issue 19).

    The rays and every test on them are those of :func:`trace`, written as whole-array
    operations over all targets' planes, segments and rays, and restricted to the pairs that
    can meet:

    * a triangle is sliced only by the planes within its along-track extent;
    * a segment meets only the rays whose seabed point lies in its shadow interval: an index
      range (the rays are evenly spaced), made exact against the rays' own y, not a test of
      every ray;
    * the ray-segment parameter ``t = N / (y E_z + H E_y)`` has its numerator per segment,
      and the parallel case is looked for only where the denominator can reach 0;
    * a ray met by one segment only has its first hit; elsewhere the first hit is a
      scatter-minimum of ``t`` (ties: the segment :func:`trace` meets first), not a sort;
    * on a closed, consistently wound mesh, segments facing away from the sensor are
      dropped: a ray from outside meets a front face first (its normal is constant along a
      segment, and so is the sign of ``n . (A - S)``). A ray through a silhouette edge, where
      front and back meet at the same ``t``, may then take the front face's normal; that is
      the only difference from testing every segment (none was seen on 360 varied targets:
      ``tests/simulation/test_signature_engine.py``).

    With ``engine="strips"`` the k planes of a row are not sampled by rays along range: the
    shadow of each plane is the exact length of its front segments' seabed intervals in each
    pixel, and the echo the exact integral of ``|n . d|`` over the rays that meet each front
    segment, binned by the ground range of the hit. Closer to the fine trace than rays at the
    same k, and its cost grows with the segments, not with the shadow's length; it needs a
    closed mesh below the sensor whose front segments do not overlap in any plane (a convex
    cross-section); other targets are traced by rays.

    Parameters
    ----------
    windows
        :func:`trace_window` of each placed target in the tile (None: an empty signature).
    range0_m, dr_m, dx_m, altitude_m, subrays
        As :func:`trace`.
    engine
        ``"rays"`` or ``"strips"``.

    Returns
    -------
    list of Signature
        One per window, in order.
    """
    k = int(subrays)
    if k < 1:
        raise GeometryError(f"subrays must be >= 1, got {subrays}")
    if engine not in ENGINES:
        raise GeometryError(f"engine must be one of {ENGINES}, got {engine!r}")
    H = float(altitude_m)
    out: list[Signature] = [_empty()] * len(windows)
    ws = [(n, w) for n, w in enumerate(windows) if w is not None]
    if not ws:
        return out
    J = len(ws)
    frac = (np.arange(k) + 0.5) / k - 0.5
    edge0 = range0_m - dr_m / 2
    tri, nrm_all, m_n, facing = surfaces([w for _, w in ws])
    geo = np.array([(w.i0, w.i1, w.c0, w.c1, w.cs0, w.cs1, w.lo[2] < 0.0) for _, w in ws], dtype=np.int64)
    i0, i1, c0, c1, cs0, cs1, buried = geo.T
    nr, nc = i1 - i0, c1 - c0
    s_n, q_n = nr * k, (cs1 - cs0) * k                       # planes, and rays per plane, per target
    s_off = np.cumsum(s_n) - s_n
    y_off = np.cumsum(q_n) - q_n
    px_off = np.cumsum(nr * nc) - nr * nc                     # each target's maps in one flat array
    ray_off = np.cumsum(s_n * q_n) - s_n * q_n                # each target's rays, plane-major
    zeros = np.zeros(J, dtype=np.int64)

    # Planes: the x of every sub-row, as trace() has them.
    pt, pl = expand_ranges(zeros, s_n - 1, s_n, zeros)
    xs = (i0[pt] + pl // k + frac[pl % k]) * dx_m

    # Segments: each triangle cut by the planes within its along-track extent (one plane of
    # slack for rounding, then the exact test: a vertex on the plane counts as positive).
    # Triangle-major: within a plane the segments keep the triangles' order, which is all the
    # ties depend on.
    tt = np.repeat(np.arange(J), m_n)                         # target of each triangle
    tx = tri[:, :, 0]
    step = dx_m / k
    x_first = (i0 - 0.5 + 0.5 / k) * dx_m                     # about the x of a target's plane 0
    x_lo = np.minimum(np.minimum(tx[:, 0], tx[:, 1]), tx[:, 2])
    x_hi = np.maximum(np.maximum(tx[:, 0], tx[:, 1]), tx[:, 2])
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
        back = ((f_tri != 0) & (f_tri * (f0 - nrm_all[:, 0] * x_lo) > span)
                & (f_tri * (f0 - nrm_all[:, 0] * x_hi) > span))
        p_hi = np.where(back, -1, p_hi)
    ti, gp = expand_ranges(p_lo, p_hi, s_n[tt], s_off[tt])          # (triangle, global plane)
    d = tx[ti] - xs[gp][:, None]                               # signed distances of the 3 vertices
    pos = d >= 0.0                                             # a vertex on the plane counts as positive
    p0, p1, p2 = pos[:, 0], pos[:, 1], pos[:, 2]
    cross = np.flatnonzero(~((p0 == p1) & (p1 == p2)))        # 1 or 2 vertices on the positive side
    ti, gp, d, p0, p1, p2 = ti[cross], gp[cross], d[cross], p0[cross], p1[cross], p2[cross]
    hid_px = np.zeros(int((nr * nc).sum()), dtype=np.float64)
    echo = np.zeros_like(hid_px)
    diff = np.zeros(hid_px.size + 1)                           # the strips' fully hidden pixels, differenced
    if ti.size:
        # The lone vertex, on its own side of the plane: its two edges are the crossing ones.
        lone = np.where(p0 == p1, 2, np.where(p0 == p2, 1, 0))
        o1, o2 = (lone + 1) % 3, (lone + 2) % 3
        flat_v, flat_d = tri.reshape(-1, 3), d.reshape(-1)
        base3, row3 = ti * 3, np.arange(ti.size) * 3
        vl, dl = flat_v[base3 + lone, 1:], flat_d[row3 + lone]
        a = vl + (dl / (dl - flat_d[row3 + o1]))[:, None] * (flat_v[base3 + o1, 1:] - vl)
        b = vl + (dl / (dl - flat_d[row3 + o2]))[:, None] * (flat_v[base3 + o2, 1:] - vl)
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
        if not valid.all():
            keep = np.flatnonzero(valid)
            st, nrm, a, b, pa, pb, gp = st[keep], nrm[keep], a[keep], b[keep], pa[keep], pb[keep], gp[keep]
        lo_p, hi_p = np.minimum(pa, pb), np.maximum(pa, pb)
        if engine == "strips":
            strip = strip_targets(st, gp, lo_p, hi_p, facing, J, tol=1e-6 * dr_m)[st]
            if strip.any():
                s = np.flatnonzero(strip)
                base = px_off[st[s]] + ((gp[s] - s_off[st[s]]) // k) * nc[st[s]] - c0[st[s]]
                lo_w = edge0 + cs0[st[s]] * dr_m                  # the seabed the window's rays reach
                hi_w = edge0 + cs1[st[s]] * dr_m
                strip_shadow(hid_px, diff, base, np.maximum(lo_p[s], lo_w), np.minimum(hi_p[s], hi_w),
                             edge0=edge0, dr_m=dr_m, k=k, col_end=cs1[st[s]])
                strip_echo(echo, base, a[s], b[s], nrm[s], pa[s], pb[s], lo_w, hi_w, c0[st[s]], c1[st[s]], H=H,
                           edge0=edge0, dr_m=dr_m, k=k)
                rest = np.flatnonzero(~strip)
                st, nrm, a, b, gp, lo_p, hi_p = st[rest], nrm[rest], a[rest], b[rest], gp[rest], lo_p[rest], hi_p[rest]
    if ti.size and st.size:
        # The seabed points of the rays (y of every sub-column), as trace() has them.
        yt, yq = expand_ranges(zeros, q_n - 1, q_n, zeros)
        y_all = range0_m + (cs0[yt] + yq // k + frac[yq % k]) * dr_m
        dlen_all = np.hypot(y_all, H)
        y_col = cs0[yt] + yq // k                             # tile column of each seabed point
        dmax = np.maximum.reduceat(dlen_all, y_off)          # longest |P - S| per target
        # Rays whose seabed point lies in the segment's shadow interval [lo_p, hi_p] (the
        # tracer's test): an index range from the rays' even spacing, made exact against the
        # rays' own y (a step or two of rounding), so no pair needs the test.
        ystep = dr_m / k
        y_first = range0_m + (cs0 - 0.5 + 0.5 / k) * dr_m
        qs = q_n[st]
        y0 = y_off[st]

        def y_at(r: np.ndarray) -> np.ndarray:
            return y_all[y0 + np.clip(r, 0, qs - 1)]

        with np.errstate(invalid="ignore", over="ignore"):
            r_lo = np.ceil(np.clip((lo_p - y_first[st]) / ystep, -1.0, qs)).astype(np.int64)
            r_hi = np.floor(np.clip((hi_p - y_first[st]) / ystep, -1.0, qs)).astype(np.int64)
        r_lo, r_hi = np.clip(r_lo, 0, qs), np.clip(r_hi, -1, qs - 1)
        for _ in range(2):
            r_lo -= (r_lo > 0) & (y_at(r_lo - 1) >= lo_p)
            r_hi += (r_hi + 1 < qs) & (y_at(r_hi + 1) <= hi_p)
        for _ in range(2):
            r_lo += (r_lo < qs) & (y_at(r_lo) < lo_p)
            r_hi -= (r_hi >= 0) & (y_at(r_hi) > hi_p)
        # Per segment: the ray-segment intersection t = ((A - S) x E) / (D x E), D = (y, -H),
        # as trace() writes it: t = num / (y E_z - (-H) E_y).
        ay, az = a[:, 0], a[:, 1] - H
        ey, ez = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
        num = ay * ez - az * ey
        hey = -H * ey
        si, yi = expand_ranges(r_lo, r_hi, qs, y0)
        ys = y_all[yi]
        denom = ys * ez[si] - hey[si]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = num[si] / denom
        # Parallel (|denom| <= eps |D| |E|: a segment along the ray) is possible only where
        # denom, linear in y, comes near 0 over the segment's rays: checked per segment with
        # the target's longest |D| (and a factor 2 for rounding), then per pair there.
        seg_len = np.hypot(ey, ez)
        d_lo, d_hi = y_at(r_lo) * ez - hey, y_at(r_hi) * ez - hey
        near_zero = np.minimum(np.abs(d_lo), np.abs(d_hi)) <= 2.0 * _PARALLEL_EPS * dmax[st] * seg_len
        maybe = (r_hi >= r_lo) & ((np.sign(d_lo) != np.sign(d_hi)) | near_zero)
        if maybe.any():
            cand = np.flatnonzero(maybe[si])
            par = cand[np.abs(denom[cand]) <= _PARALLEL_EPS * dlen_all[yi[cand]] * seg_len[si[cand]]]
            if par.size:
                # A segment along the ray (grazing, parallel facet) is met at its nearer end.
                near = np.minimum(np.hypot(ay, az), np.hypot(b[:, 0], b[:, 1] - H))
                t[par] = near[si[par]] / dlen_all[yi[par]]
        # Hit before the seabed point (t = 1: a facet lying on the seabed hides nothing).
        good = (t > 0.0) & (t < 1.0 - 1e-9)
        if not good.all():
            hit = np.flatnonzero(good)
            si, yi, t, ys = si[hit], yi[hit], t[hit], ys[hit]
        # First hit per ray: the smallest t; among equal t, the segment trace() meets first.
        # Rays met by one segment only (every ray, on a convex cross-section) need neither.
        gray = (ray_off[st] + (gp - s_off[st]) * qs - y0)[si] + yi
        n_rays = int((s_n * q_n).sum())
        seen = np.zeros(n_rays, dtype=bool)
        seen[gray] = True
        if np.count_nonzero(seen) != gray.size:
            tmin = np.full(n_rays, np.inf)
            np.minimum.at(tmin, gray, t)
            sel = np.flatnonzero(t == tmin[gray])
            if sel.size > np.count_nonzero(tmin < np.inf):    # ties: the lowest segment wins
                smin = np.full(n_rays, np.iinfo(np.int64).max)
                np.minimum.at(smin, gray[sel], si[sel])
                sel = sel[si[sel] == smin[gray[sel]]]
            si, yi, t, ys = si[sel], yi[sel], t[sel], ys[sel]
        dlen = dlen_all[yi]
        base = (px_off[st] + ((gp - s_off[st]) // k) * nc[st] - c0[st])[si]   # pixel of column 0 of the row
        # Shadow: hidden sub-rays per pixel.
        hid_px += np.bincount(base + y_col[yi], minlength=hid_px.size)
        # Echo: |n . d| at the slant range of the hit, binned on the ground-range axis (layover adds).
        sin_g = np.abs(nrm[:, 1][si] * ys - (nrm[:, 2] * H)[si]) / dlen
        slant = t * dlen
        ground = np.sqrt(np.maximum(slant * slant - H * H, 0.0))
        col = np.floor((ground - edge0) / dr_m).astype(np.int64)
        inside = (col >= c0[st][si]) & (col < c1[st][si])
        if inside.all():
            echo += np.bincount(base + col, weights=sin_g, minlength=echo.size)
        else:
            echo += np.bincount((base + col)[inside], weights=sin_g[inside], minlength=echo.size)
    if engine == "strips":
        hid_px += np.cumsum(diff[:-1]) * k
    shadow32 = (hid_px / (k * k)).astype(np.float32)
    echo32 = (echo / (k * k)).astype(np.float32)
    for j, (n, w) in enumerate(ws):
        o, shape = int(px_off[j]), (int(nr[j]), int(nc[j]))
        sz = shape[0] * shape[1]
        out[n] = Signature(w.i0, w.c0, shadow32[o:o + sz].reshape(shape), echo32[o:o + sz].reshape(shape))
    return out
