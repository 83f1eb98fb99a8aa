"""The tracer as it was before the batched engine (issue 19): every (plane, segment, ray)
triple tested densely, one target per call. Kept as the reference the signature engine must
reproduce bit for bit; slow, tests only."""

from __future__ import annotations

import numpy as np

from atr_node.simulation.meshes import Mesh
from atr_node.errors import GeometryError
from atr_node.simulation.window import TraceWindow, surfaces
from atr_node.simulation.raytrace import _PARALLEL_EPS, Signature, _clip_above_seabed, _empty, trace_window


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


def dense_trace(mesh: Mesh, *, range0_m: float, dr_m: float, dx_m: float, rows: int, cols: int,
                altitude_m: float, subrays: int = 2, window: TraceWindow | None = None) -> Signature:
    """:func:`atr_node.simulation.raytrace.trace` as it was: every plane x segment x ray
    tested, one target per call. Same parameters and result."""
    k = int(subrays)
    if k < 1:
        raise GeometryError(f"subrays must be >= 1, got {subrays}")
    w = window if window is not None else trace_window(mesh, range0_m=range0_m, dr_m=dr_m, dx_m=dx_m, rows=rows,
                                                        cols=cols, altitude_m=altitude_m)
    if w is None:
        return _empty()
    H = float(altitude_m)
    tri, normals, _, _ = surfaces([w])
    lo = w.lo
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


def l1_error(sigs: list, refs: list) -> tuple[float, float]:
    """Mean L1 error of the shadow and of the echo maps of ``sigs`` against ``refs``, relative to
    the reference's totals (targets whose reference shadow is under one pixel are left out):
    the error the signature benchmark and tests quote."""
    es, ee = [], []
    for s, r in zip(sigs, refs):
        if r.empty or r.p_shadow.sum() < 1.0:
            continue
        es.append(np.abs(s.p_shadow - r.p_shadow).sum() / r.p_shadow.sum())
        ee.append(np.abs(s.echo - r.echo).sum() / max(float(r.echo.sum()), 1e-9))
    return float(np.mean(es)), float(np.mean(ee))
