"""Statistics of detector responses: survival functions, confidence, P(y), Wilson, thresholds.

Pure functions, arrays in and arrays out (SPEC section 5). Every estimate here is defined for
empty and single-sample inputs (SPEC section 8): smoothed proportions are never exactly 0 or
1, an empty range bin has Pd = 0 with the interval [0, 1], an empty response set gives the
caller's default threshold.

Notation: ``x_T`` are target responses (max gamma over each injected target's template
footprint), ``x_N`` non-target responses (max gamma over each template-sized cell of the
target-free image), NaN = not covered, always dropped first.

References
----------
.. [1] V. Myers, O. Midtgaard, "Fusion of contacts in synthetic aperture sonar imagery using
   performance estimates", eqs. (5)-(7) and section 4.2.
.. [2] E. B. Wilson, "Probable inference, the law of succession, and statistical inference",
   JASA 22 (1927) 209-212.
.. [3] G. Dobeck, "On the power of algorithm fusion", Proc. SPIE 4394 (2001).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

Smoothing = Literal["jeffreys", "laplace"]

_PSEUDO = {"jeffreys": 0.5, "laplace": 1.0}
Z95 = 1.959963984540054
"""Standard normal quantile of 0.975: the two-sided 95 % Wilson interval."""


def _finite(x: np.ndarray | list[float]) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64).ravel()
    return a[np.isfinite(a)]


def smoothed_proportion(k: np.ndarray | float, n: np.ndarray | float, *,
                        smoothing: Smoothing = "jeffreys") -> np.ndarray:
    """Smoothed proportion ``(k + a) / (n + 2a)``; a = 1/2 (Jeffreys) or 1 (Laplace).

    Never exactly 0 or 1, and 1/2 when ``n = 0`` (SPEC section 5: neither survival function is
    ever 0 or 1).
    """
    a = _PSEUDO[smoothing]
    return (np.asarray(k, dtype=np.float64) + a) / (np.asarray(n, dtype=np.float64) + 2.0 * a)


def survival_counts(samples: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Number of finite samples >= each value of ``at`` (shape of ``at``), by one sort."""
    s = np.sort(_finite(samples))
    at = np.asarray(at, dtype=np.float64)
    return s.size - np.searchsorted(s, at, side="left")


def survival(samples: np.ndarray, at: np.ndarray, *, smoothing: Smoothing | None = "jeffreys") -> np.ndarray:
    """Empirical survival function P(X >= t) of the finite samples at ``at``.

    ``smoothing=None`` gives the raw ratio (0/0 -> 0.5); otherwise
    :func:`smoothed_proportion`.
    """
    n = _finite(samples).size
    k = survival_counts(samples, at)
    if smoothing is None:
        return np.where(n > 0, k / max(n, 1), 0.5)
    return smoothed_proportion(k, n, smoothing=smoothing)


def wilson_interval(k: np.ndarray | float, n: np.ndarray | float, *, z: float = Z95) -> tuple[np.ndarray, np.ndarray]:
    """Wilson score interval of a binomial proportion [2]_.

    ``(p + z^2/2n -+ z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n)`` with p = k/n; ``n = 0``
    gives [0, 1]. Returns (low, high), each of the broadcast shape of k and n.
    """
    k = np.asarray(k, dtype=np.float64)
    n = np.asarray(n, dtype=np.float64)
    safe_n = np.where(n > 0, n, 1.0)
    p = np.where(n > 0, k / safe_n, 0.5)
    z2 = z * z
    denom = 1.0 + z2 / safe_n
    centre = (p + z2 / (2.0 * safe_n)) / denom
    half = z * np.sqrt(np.maximum(p * (1.0 - p) / safe_n + z2 / (4.0 * safe_n * safe_n), 0.0)) / denom
    # k = 0 and k = n give exactly 0 and 1 in closed form; do not let rounding move them.
    low = np.where((n > 0) & (k > 0), np.clip(centre - half, 0.0, 1.0), 0.0)
    high = np.where((n > 0) & (k < n), np.clip(centre + half, 0.0, 1.0), 1.0)
    return low, high


def isotonic_increasing(y: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Least-squares non-decreasing fit of ``y`` (pool adjacent violators).

    Parameters
    ----------
    y : (n,) float
    weights : (n,) float > 0, optional (default all 1)

    Returns
    -------
    (n,) float64, non-decreasing; every value is a weighted mean of a run of ``y``, so it stays
    inside [min(y), max(y)].
    """
    y = np.asarray(y, dtype=np.float64)
    w = np.ones_like(y) if weights is None else np.asarray(weights, dtype=np.float64)
    # Blocks as a stack of (mean, weight, length); amortised O(n).
    means: list[float] = []
    wsum: list[float] = []
    length: list[int] = []
    for yi, wi in zip(y.tolist(), w.tolist()):
        means.append(yi)
        wsum.append(wi)
        length.append(1)
        while len(means) > 1 and means[-2] > means[-1]:
            m2, w2, l2 = means.pop(), wsum.pop(), length.pop()
            w1 = wsum[-1]
            means[-1] = (means[-1] * w1 + m2 * w2) / (w1 + w2)
            wsum[-1] = w1 + w2
            length[-1] += l2
    return np.repeat(np.asarray(means), np.asarray(length, dtype=np.intp))


@dataclass(frozen=True)
class ConfidenceCurve:
    """c_d(gamma; tau) tabulated on a gamma grid (SPEC section 5, paper eq. 6).

    ``gamma`` (n,) increasing from ``tau``; ``confidence`` (n,) non-decreasing, strictly in
    (0, 1); ``isotonic_adjusted`` says whether the raw Bayes ratio ``raw`` (n,) dipped and was
    replaced by its isotonic fit, ``max_adjustment`` by how much at most.
    """

    tau: float
    gamma: np.ndarray
    confidence: np.ndarray
    isotonic_adjusted: bool
    max_adjustment: float
    n_target_above: int
    n_nontarget_above: int
    raw: np.ndarray | None = None


def confidence_curve(x_t: np.ndarray, x_n: np.ndarray, tau: float, *, prior_target: float = 0.1,
                     n_points: int = 64, smoothing: Smoothing = "jeffreys",
                     gamma_max: float | None = None) -> ConfidenceCurve:
    """Confidence c(gamma; tau) = P(T | Gamma >= gamma) for detections at threshold tau.

    Built from the responses that exceeded tau only (paper eq. 6-7). With ``pi_tau`` the
    posterior of eq. 6 at the threshold::

        pi_tau   = S_T(tau) P(T) / (S_T(tau) P(T) + S_N(tau) (1 - P(T)))
        S_X(g|tau) = smoothed (#{x > tau, x >= g} / #{x > tau})
        c(g; tau) = pi_tau S_T(g|tau) / (pi_tau S_T(g|tau) + (1 - pi_tau) S_N(g|tau))

    so c(tau; tau) = pi_tau (eq. 6) up to the smoothing and, for many samples, c(g; tau) -> P(T | Gamma >= g) with
    the per-location prior P(T); smoothing makes it depend on tau as in the paper's figure 3.
    Where the ratio dips it is replaced by its isotonic fit (weights = responses per grid
    step), so the table is non-decreasing; smoothing keeps it strictly inside (0, 1).

    Parameters
    ----------
    x_t, x_n : (m,), (k,) float
        Target and non-target responses (NaN dropped).
    tau : float
        Detection threshold.
    prior_target : float in (0, 1)
        P(T) per possible target location.
    n_points : int >= 2
        Grid points from tau to ``gamma_max`` (default: the largest response above tau, or
        tau + 1 when none), placed where the responses are (:func:`_confidence_grid`).
    """
    if not 0.0 < prior_target < 1.0:
        raise ValueError(f"prior_target must be in (0, 1), got {prior_target}")
    if n_points < 2:
        raise ValueError(f"n_points must be >= 2, got {n_points}")
    t = _finite(x_t)
    nt = _finite(x_n)
    t_above = t[t > tau]
    n_above = nt[nt > tau]
    # Eq. 6 at the threshold, both survival functions smoothed.
    s_t = smoothed_proportion(t_above.size, t.size, smoothing=smoothing)
    s_n = smoothed_proportion(n_above.size, nt.size, smoothing=smoothing)
    pi_tau = float(s_t * prior_target / (s_t * prior_target + s_n * (1.0 - prior_target)))
    if gamma_max is None:
        both = np.concatenate([t_above, n_above])
        gamma_max = float(both.max()) if both.size else tau + 1.0
    if not gamma_max > tau:
        gamma_max = tau + max(abs(tau), 1.0) * 1e-6
    grid = _confidence_grid(tau, gamma_max, t_above, n_above, n_points)
    # Conditional survival among exceedances; at grid[0] = tau every exceedance counts.
    k_t = survival_counts(t_above, grid)
    k_n = survival_counts(n_above, grid)
    st = smoothed_proportion(k_t, t_above.size, smoothing=smoothing)
    sn = smoothed_proportion(k_n, n_above.size, smoothing=smoothing)
    raw = pi_tau * st / (pi_tau * st + (1.0 - pi_tau) * sn)
    # Weights: responses falling in each grid step (at least 1, so empty steps still count).
    w = np.ones(grid.size)
    w[:-1] += (k_t[:-1] - k_t[1:]) + (k_n[:-1] - k_n[1:])
    w[-1] += k_t[-1] + k_n[-1]
    dips = bool(np.any(np.diff(raw) < 0.0))
    conf = isotonic_increasing(raw, w) if dips else raw
    return ConfidenceCurve(tau=float(tau), gamma=grid, confidence=conf, isotonic_adjusted=dips,
                           max_adjustment=float(np.max(np.abs(conf - raw))),
                           n_target_above=int(t_above.size), n_nontarget_above=int(n_above.size), raw=raw)


def _confidence_grid(tau: float, gamma_max: float, t_above: np.ndarray, n_above: np.ndarray,
                     n_points: int) -> np.ndarray:
    """About ``n_points`` increasing gamma values from tau to gamma_max: half at quantiles of
    the non-target exceedances, half at quantiles of the target ones (so the table resolves
    the confidence where the data are, whatever the spread of gamma), topped up evenly."""
    k = max((n_points - 2) // 2, 1)
    q = np.linspace(0.0, 1.0, k + 2)[1:-1]
    parts = [np.array([tau, gamma_max])]
    for x in (n_above, t_above):
        x = x[x <= gamma_max]
        if x.size:
            parts.append(np.quantile(x, q))
    grid = np.unique(np.concatenate(parts))
    if grid.size < n_points:
        grid = np.unique(np.concatenate([grid, np.linspace(tau, gamma_max, n_points - grid.size + 2)]))
    return grid


@dataclass(frozen=True)
class PdCurve:
    """P(y) table: Pd per range bin at a threshold (SPEC section 5, paper section 4.2).

    ``edges_m`` (b + 1,), ``injected``, ``detected`` (b,) counts, ``pd`` (b,) smoothed
    estimate (0 where a bin is empty: no evidence), ``low``/``high`` (b,) Wilson 95 %.
    """

    tau: float
    edges_m: np.ndarray
    injected: np.ndarray
    detected: np.ndarray
    pd: np.ndarray
    low: np.ndarray
    high: np.ndarray

    @property
    def centres_m(self) -> np.ndarray:
        return 0.5 * (self.edges_m[:-1] + self.edges_m[1:])


def range_edges(ranges_m: np.ndarray, bin_m: float) -> np.ndarray:
    """Bin edges on multiples of ``bin_m`` covering every finite range (at least one bin)."""
    if not bin_m > 0:
        raise ValueError(f"bin_m must be > 0, got {bin_m}")
    r = _finite(ranges_m)
    if r.size == 0:
        return np.array([0.0, bin_m])
    lo = np.floor(r.min() / bin_m) * bin_m
    hi = np.floor(r.max() / bin_m) * bin_m + bin_m
    return np.arange(round((hi - lo) / bin_m) + 1) * bin_m + lo


def pd_curve(ranges_m: np.ndarray, x_t: np.ndarray, tau: float, *, bin_m: float = 10.0,
             edges_m: np.ndarray | None = None, smoothing: Smoothing = "jeffreys") -> PdCurve:
    """Pd(r; tau) = detected / injected per range bin, smoothed, with its Wilson interval.

    A target counts as detected when its response exceeds tau (SPEC section 3: gamma > tau).
    Targets with a NaN response (not covered) are not counted. Empty bins: Pd = 0, interval
    [0, 1]. Non-empty bins: the smoothed proportion (Jeffreys: (k + 1/2) / (n + 1)).

    Parameters
    ----------
    ranges_m, x_t : (m,) float
        Ground range of each injected target's anchor and its response.
    edges_m : (b + 1,) float, optional
        Bin edges (default :func:`range_edges` of the finite ranges with ``bin_m``).
    """
    r = np.asarray(ranges_m, dtype=np.float64).ravel()
    x = np.asarray(x_t, dtype=np.float64).ravel()
    if r.shape != x.shape:
        raise ValueError(f"ranges_m {r.shape} and x_t {x.shape} differ in length")
    keep = np.isfinite(r) & np.isfinite(x)
    r, x = r[keep], x[keep]
    edges = range_edges(r, bin_m) if edges_m is None else np.asarray(edges_m, dtype=np.float64)
    if edges.ndim != 1 or edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise ValueError("edges_m must be increasing, at least two values")
    nb = edges.size - 1
    idx = np.clip(np.searchsorted(edges, r, side="right") - 1, 0, nb - 1)
    inside = (r >= edges[0]) & (r <= edges[-1])
    n = np.bincount(idx[inside], minlength=nb).astype(np.int64)
    k = np.bincount(idx[inside], weights=(x[inside] > tau).astype(np.float64), minlength=nb).astype(np.int64)
    pd = np.where(n > 0, smoothed_proportion(k, n, smoothing=smoothing), 0.0)
    low, high = wilson_interval(k, n)
    return PdCurve(tau=float(tau), edges_m=edges, injected=n, detected=k, pd=pd, low=low, high=high)


def pd_at(curve_edges_m: np.ndarray, curve_pd: np.ndarray, range_m: np.ndarray | float) -> np.ndarray:
    """Evaluate a P(y) table at ranges: linear between bin centres, flat in the outer
    half-bins, exactly 0 outside [edges[0], edges[-1]] and for NaN ranges."""
    edges = np.asarray(curve_edges_m, dtype=np.float64)
    pd = np.asarray(curve_pd, dtype=np.float64)
    r = np.asarray(range_m, dtype=np.float64)
    centres = 0.5 * (edges[:-1] + edges[1:])
    val = np.interp(np.where(np.isfinite(r), r, edges[0]), centres, pd)
    return np.where(np.isfinite(r) & (r >= edges[0]) & (r <= edges[-1]), val, 0.0)


def dobeck_threshold(x_t: np.ndarray, pd_target: float, *, default: float) -> float:
    """The largest threshold whose Pd on the target responses is at least ``pd_target`` [3]_.

    Pd(tau) = #{x > tau} / m over the finite responses. Among the response values (and just
    below the smallest one) the largest tau with Pd(tau) >= pd_target; no finite response ->
    ``default``.
    """
    if not 0.0 < pd_target <= 1.0:
        raise ValueError(f"pd_target must be in (0, 1], got {pd_target}")
    s = np.sort(_finite(x_t))
    m = s.size
    if m == 0:
        return float(default)
    need = int(np.ceil(pd_target * m - 1e-9))
    if need >= m:
        # Every response must exceed tau: just below the smallest one.
        return float(np.nextafter(s[0], -np.inf))
    # Pd(s[i]) counts values > s[i]; the largest s[i] with count >= need.
    counts_above = m - np.searchsorted(s, s, side="right")
    ok = np.nonzero(counts_above >= need)[0]
    if ok.size == 0:
        # Ties at the smallest value: only a threshold below it reaches the target.
        return float(np.nextafter(s[0], -np.inf))
    return float(s[ok[-1]])
