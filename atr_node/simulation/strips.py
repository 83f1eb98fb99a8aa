"""The strips signature engine (``simulation.engine = "strips"``, issue 19): each of the k
sub-row planes of a pixel row integrated exactly along range, instead of sampled by k rays.

Called by :func:`~.raytrace.trace_many` with the front segments of a batch of targets (cut by
the planes, clipped to the water column, projected onto the seabed): :func:`strip_targets`
says which targets the strips can integrate exactly, :func:`strip_shadow` and
:func:`strip_echo` add their maps. :func:`expand_ranges` is the index expansion both engines
use.
"""

from __future__ import annotations

import numpy as np


def expand_ranges(lo: np.ndarray, hi: np.ndarray, n_max: np.ndarray, *bases: np.ndarray
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


def strip_targets(st: np.ndarray, gp: np.ndarray, lo_p: np.ndarray, hi_p: np.ndarray, facing: np.ndarray,
                  J: int, *, tol: float) -> np.ndarray:
    """Targets the strips can trace exactly: a closed mesh below the sensor whose front
    segments' shadow intervals do not overlap within any plane (a convex cross-section, as
    every built-in shape has, tilted, scaled or buried). Visibility is then the identity:
    every front segment is seen whole. The others are traced by rays."""
    ok = facing != 0
    bad = ~np.isfinite(hi_p)                                   # reaches the sensor's height
    # Segments of (almost) no length hide nothing and return nothing: a triangle touching a
    # plane at a vertex or along an edge.
    with np.errstate(invalid="ignore"):
        long_ = np.flatnonzero(hi_p - lo_p > tol)
    order = long_[np.lexsort((lo_p[long_], gp[long_]))]
    g, lo, hi = gp[order], lo_p[order], hi_p[order]
    same = g[1:] == g[:-1]
    bad_pair = same & (lo[1:] < hi[:-1] - tol)
    bad_t = np.zeros(J, dtype=bool)
    bad_t[st[bad]] = True
    bad_t[st[order[1:][bad_pair]]] = True
    return ok & ~bad_t


def strip_shadow(hid: np.ndarray, diff: np.ndarray, base: np.ndarray, lo: np.ndarray, hi: np.ndarray, *,
                 edge0: float, dr_m: float, k: int, col_end: np.ndarray) -> None:
    """Add each strip's hidden length per pixel (in sub-rays: the fraction times k) to
    ``hid`` (partial pixels) and ``diff`` (runs of whole pixels, differenced)."""
    ul, uh = (lo - edge0) / dr_m, (hi - edge0) / dr_m
    s = np.flatnonzero(uh > ul)
    base, ul, uh, col_end = base[s], ul[s], uh[s], col_end[s]
    jl = np.floor(ul).astype(np.int64)
    jh = np.minimum(np.floor(uh).astype(np.int64), col_end - 1)
    one = jl == jh
    hid += np.bincount(base + jl, weights=np.where(one, uh - ul, jl + 1 - ul) * k, minlength=hid.size)
    two = ~one
    hid += np.bincount(base[two] + jh[two], weights=(uh[two] - jh[two]) * k, minlength=hid.size)
    run = np.flatnonzero(jh > jl + 1)
    diff += np.bincount(base[run] + jl[run] + 1, minlength=diff.size) - np.bincount(base[run] + jh[run],
                                                                                     minlength=diff.size)


def strip_echo(echo: np.ndarray, base: np.ndarray, a: np.ndarray, b: np.ndarray, nrm: np.ndarray,
               pa: np.ndarray, pb: np.ndarray, lo_w: np.ndarray, hi_w: np.ndarray, c0: np.ndarray, c1: np.ndarray, *,
               H: float, edge0: float, dr_m: float, k: int) -> None:
    """Add each front segment's echo, integrated exactly over the rays that meet it, to the
    ground-range bins of its hits (in sub-ray units: times k^2).

    A ray to seabed point p returns ``|n . d| = |n_y p - n_z H| / sqrt(p^2 + H^2)``; the k
    planes of a row hold ``k / dr`` rays per metre of seabed each, of weight ``1 / k^2``:
    a piece of segment whose rays reach seabed points p1 .. p2 adds
    ``(k / dr) |I(p2) - I(p1)|`` with ``I(p) = n_y sqrt(p^2 + H^2) - n_z H asinh(p / H)``
    (the sign of n . d is the segment's). The hit P(u) = A + u (B - A) has ground range
    ``sqrt(G(u))``, ``G = g0 + g1 u + g2 u^2`` (slant^2 - H^2): the segment is cut where G
    turns and where the ground range crosses a bin edge (the root of G(u) = g^2 on that side).
    """
    ay, az = a[:, 0], a[:, 1]
    ey, ez = b[:, 0] - ay, b[:, 1] - az
    hz = H - az

    def p_of(u: np.ndarray, s: np.ndarray) -> np.ndarray:
        return (ay[s] + u * ey[s]) * H / (hz[s] - u * ez[s])

    def u_of(p: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return (p * hz - H * ay) / (H * ey + p * ez)

    def integral(p1: np.ndarray, p2: np.ndarray, s: np.ndarray) -> np.ndarray:
        return np.abs(nrm[s, 1] * (np.hypot(p2, H) - np.hypot(p1, H))
                      - (nrm[s, 2] * H) * (np.arcsinh(p2 / H) - np.arcsinh(p1 / H))) * (k / dr_m)

    g2 = ey * ey + ez * ez
    g1 = 2.0 * (ay * ey + (az - H) * ez)
    g0 = ay * ay + az * (az - 2.0 * H)
    # Most segments are short: their rays all lie in the window, the closest point to the
    # sensor is not inside them, and both ends' hits fall in one bin. Those are added whole.
    inside_w = (pa >= lo_w) & (pa <= hi_w) & (pb >= lo_w) & (pb <= hi_w)
    with np.errstate(divide="ignore", invalid="ignore"):
        turn_u = np.where(g2 > 0, -g1 / (2.0 * g2), 0.0)
    w_a = np.floor((np.sqrt(np.maximum(g0, 0.0)) - edge0) / dr_m).astype(np.int64)
    w_b = np.floor((np.sqrt(np.maximum(g0 + g1 + g2, 0.0)) - edge0) / dr_m).astype(np.int64)
    whole = inside_w & ((turn_u <= 0.0) | (turn_u >= 1.0)) & (w_a == w_b)
    s = np.flatnonzero(whole & (w_a >= c0) & (w_a < c1))
    echo += np.bincount(base[s] + w_a[s], weights=integral(pa[s], pb[s], s), minlength=echo.size)
    rest = np.flatnonzero(~whole)
    if rest.size == 0:
        return
    # The others: the part of the segment whose rays the window holds (p is monotone along a
    # segment), cut at the turn of G and at the bin edges.
    pa, pb, ay, ey, hz, ez = pa[rest], pb[rest], ay[rest], ey[rest], hz[rest], ez[rest]
    g2, g1, g0, lo_w, hi_w, c0, c1, base, nrm = (g2[rest], g1[rest], g0[rest], lo_w[rest], hi_w[rest], c0[rest],
                                                   c1[rest], base[rest], nrm[rest])
    all_ = np.arange(rest.size)
    ua = np.where((pa >= lo_w) & (pa <= hi_w), 0.0, np.clip(u_of(np.clip(pa, lo_w, hi_w)), 0.0, 1.0))
    ub = np.where((pb >= lo_w) & (pb <= hi_w), 1.0, np.clip(u_of(np.clip(pb, lo_w, hi_w)), 0.0, 1.0))
    ua, ub = np.minimum(ua, ub), np.maximum(ua, ub)
    turn = np.clip(turn_u[rest], ua, ub)
    # Two pieces per segment: [ua, turn] (G falls) and [turn, ub] (G rises).
    seg = np.concatenate([all_, all_])
    u_lo = np.concatenate([ua, turn])
    u_hi = np.concatenate([turn, ub])
    rising = np.repeat([False, True], len(ay))
    keep = np.flatnonzero((u_hi > u_lo) & (g2[seg] > 0))
    seg, u_lo, u_hi, rising = seg[keep], u_lo[keep], u_hi[keep], rising[keep]

    def ground(u: np.ndarray, s: np.ndarray) -> np.ndarray:
        return np.sqrt(np.maximum(g0[s] + u * (g1[s] + u * g2[s]), 0.0))

    w_lo = np.floor((ground(u_lo, seg) - edge0) / dr_m).astype(np.int64)
    w_hi = np.floor((ground(u_hi, seg) - edge0) / dr_m).astype(np.int64)
    bins_lo = np.maximum(np.minimum(w_lo, w_hi), c0[seg])
    bins_hi = np.minimum(np.maximum(w_lo, w_hi), c1[seg] - 1)
    unbounded = np.full(len(seg), np.iinfo(np.int64).max)
    piece, col = expand_ranges(bins_lo, bins_hi, unbounded, np.zeros(len(seg), np.int64))
    s = seg[piece]
    C2, C1 = g2[s], g1[s]
    up = rising[piece]

    def root(g: np.ndarray) -> np.ndarray:
        """u where G(u) = g^2 on the piece's side of the turn (stable quadratic roots)."""
        C = g0[s] - np.maximum(g, 0.0) ** 2
        D = C1 * C1 - 4.0 * C2 * C
        sq = np.sqrt(np.maximum(D, 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            plus = np.where(C1 >= 0, -2.0 * C / (C1 + sq), (-C1 + sq) / (2.0 * C2))
            minus = np.where(C1 >= 0, -(C1 + sq) / (2.0 * C2), 2.0 * C / (-C1 + sq))
        r = np.where(up, plus, minus)
        r = np.where(np.isfinite(r), r, -C1 / (2.0 * C2))
        # No root: G stays above g^2, the edge lies before a rising piece, after a falling one.
        return np.where(D < 0.0, np.where(up, -np.inf, np.inf), r)

    lo_u, hi_u = u_lo[piece], u_hi[piece]
    e1 = np.clip(root(edge0 + col * dr_m), lo_u, hi_u)
    e2 = np.clip(root(edge0 + (col + 1) * dr_m), lo_u, hi_u)
    echo += np.bincount(base[s] + col, weights=integral(p_of(e1, s), p_of(e2, s), s), minlength=echo.size)
