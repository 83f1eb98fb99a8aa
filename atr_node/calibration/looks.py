"""Look-level evidence: the detectors of one pass judged together (SPEC 6.1).

The four detectors read the same pixels of the same pass, so their detections are not
independent pieces of evidence. The injection already measures their *joint* behaviour: every
injected target and every clean template-sized cell gives all four responses at once. From
those joint responses this module builds, per set of enabled detectors:

- a **look score** ``z = sum_d (l_d(gamma_d) + LR_TIE u_d(gamma_d))`` (``look_score = "lr"``,
  the default): ``l_d`` the detector's log likelihood ratio of injected targets against clean
  cells (:func:`lr_table`), negative where targets rarely respond so weakly, and ``u_d(g) =
  -ln S_N,d(g)`` its background tail (how rare ``g`` is on target-free seabed), which here
  only breaks ties; ``look_score = "fisher"`` sums the tails alone (Fisher's way of putting
  p-values on one scale; never below 0, so a detector that stays low tells nothing). A
  detector that did not cover a place adds 0. Any combination would do: the confidence below
  is measured on ``z`` itself, so the detectors' dependence is in the numbers, not assumed away;
- the **look confidence** ``c(z) = P(T | Z >= z, the look fired)``: the look fired where at
  least one detector exceeded its threshold (that is where the node has a detection); built by
  :func:`~atr_node.calibration.stats.confidence_curve` from the fired targets and cells, with
  the model's prior;
- the **look P(y)**: ``Pd_look(r)`` = share of injected targets at range r on which at least one
  detector fired: the miss probability of the look as a whole.

A look then gives a cell one piece of evidence: ``c(z)`` on {T} where it has a detection,
else ``Pd_look(r)`` on {notT} where it covered the cell. Looks combine by Dempster's rule.

Each table is a :class:`~atr_node.calibration.model.DetectorPerformance` (tau, confidence,
P(y)), so the model file checks it as it checks a detector's. Tables exist for every non-empty
subset of the calibrated detectors: a node with a detector disabled uses the table of the
detectors it runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from ..config import DETECTOR_NAMES
from .stats import isotonic_increasing

SCORE_DEFINITION = "z = sum over detectors of -ln S_N,d(gamma_d) (background tail; 0 where not covered)"
LR_BINS = 24
"""Bins of a detector's likelihood-ratio table: half at quantiles of its target responses, half at
quantiles of its background responses (:func:`lr_edges`)."""
LR_CAP = math.log(1000.0)
"""Largest |l_d|: no single detector's response moves the look's odds by more than 1000."""
LR_TIE = 0.01
"""Weight of the background tail ``u_d`` added to ``l_d``: it only breaks the ties of the
likelihood ratio (its bins, isotonic pools and cap), so stronger responses still rank higher."""
LR_SCORE_DEFINITION = (f"z = sum over detectors of l_d(gamma_d) + {LR_TIE:g} u_d(gamma_d), l_d = ln f_T,d / f_N,d "
                       f"(binned, Jeffreys, isotonic non-decreasing, clipped to +-ln {math.exp(LR_CAP):.0f}), "
                       "u_d = -ln S_N,d (ties only); 0 where not covered")
TAIL_POINTS = 48
"""Knots of a detector's tail table u_d."""
TAIL_EXTRA = math.log(10.0)
"""How far u_d goes beyond the largest background response: one decade of survival."""
TAIL_MIN_EXCESS = 10
"""Fewest background responses over the tail threshold to fit the exponential tail."""
MIN_STRATUM_TARGETS = 50
"""Fewest injected targets (and 4 times as many clean cells) on each side of
``calibration.clip_headroom_db`` for the clipped places to get their own likelihood ratios
(:attr:`LookModel.lrs_clipped`); fewer: one table for all."""
MIN_STRATUM_CELLS = 4 * MIN_STRATUM_TARGETS
"""Fewest clean cells on each side of ``calibration.clip_headroom_db`` for the same."""


def _canonical(detectors: Sequence[str]) -> list[str]:
    order = {d: i for i, d in enumerate(DETECTOR_NAMES)}
    return sorted(set(detectors), key=lambda d: (order.get(d, len(order)), d))


def subset_key(detectors: Sequence[str]) -> str:
    """Canonical name of a detector set: its members in :data:`DETECTOR_NAMES` order, joined by
    ``+`` (``"mf+lac+smf+z"``)."""
    return "+".join(_canonical(detectors))


@dataclass(frozen=True, eq=False)
class TailTable:
    """``u(g) = -ln S_N(g)`` of one detector on knots ``gamma`` (increasing), ``u``
    non-decreasing, >= 0; linear between knots, flat below the first; beyond the last knot
    (the largest background response) it goes on with ``slope`` = 1 / the mean excess of the
    upper tail (an exponential tail, peaks over threshold) for at most one decade of survival
    (:data:`TAIL_EXTRA`), so a response beyond anything the seabed gave still ranks above a
    marginal one, but no single detector's extreme carries the look alone."""

    gamma: np.ndarray
    u: np.ndarray
    slope: float = 0.0

    def __call__(self, g: np.ndarray | float) -> np.ndarray:
        g = np.asarray(g, dtype=np.float64)
        x = np.where(np.isnan(g), self.gamma[0], g)
        out = np.interp(x, self.gamma, self.u)
        if self.slope > 0.0:
            # one decade of survival beyond the data at most (TAIL_EXTRA): the fitted tail is
            # not trusted further, so one detector's extreme value (a lacunarity blowing up at
            # the swath's edge) cannot carry the look on its own; +inf stays finite
            beyond = np.minimum(np.clip(x - self.gamma[-1], 0.0, None) * self.slope, TAIL_EXTRA)
            out = out + beyond
        return np.where(np.isnan(g), 0.0, out)


def tail_table(x_n: np.ndarray, *, points: int = TAIL_POINTS) -> TailTable:
    """The background tail of a detector from its non-target responses.

    ``S_N(g) = (#{x_n >= g} + 1/2) / (k + 1)`` (Jeffreys, never 0) at knots placed on the
    upper tail: the quantiles of survival 1, 1/2, ... down to 1/k, geometrically. Without
    responses, a flat table (u = 0: the detector tells nothing).
    """
    x = np.sort(np.asarray(x_n, dtype=np.float64)[np.isfinite(x_n)])
    k = x.size
    if k == 0:
        return TailTable(np.array([0.0, 1.0]), np.zeros(2))
    surv = np.unique(np.geomspace(1.0 / k, 1.0, max(2, points)))
    knots = np.unique(np.concatenate([np.quantile(x, 1.0 - surv), [x[0], x[-1]]]))
    if knots.size < 2:
        knots = np.array([knots[0], knots[0] + max(abs(knots[0]), 1.0) * 1e-6])
    n_ge = k - np.searchsorted(x, knots, side="left")
    u = -np.log((n_ge + 0.5) / (k + 1.0))
    u = np.maximum.accumulate(np.maximum(u, 0.0))
    # exponential tail beyond the data: MLE of the mean excess over the upper 5 % (at least
    # TAIL_MIN_EXCESS responses), slope 1 / mean excess; none with too few responses
    n_top = max(TAIL_MIN_EXCESS, int(0.05 * k))
    slope = 0.0
    if k >= 2 * TAIL_MIN_EXCESS:
        top = x[k - n_top:]
        excess = float(np.mean(top - x[k - n_top - 1]))
        slope = 1.0 / excess if excess > 0 and math.isfinite(excess) else 0.0
    return TailTable(knots, u, slope)


@dataclass(frozen=True, eq=False)
class LrTable:
    """``l(g) = ln f_T(g) / f_N(g)`` of one detector on knots ``gamma`` (increasing), ``l``
    non-decreasing and within +-:data:`LR_CAP`; linear between knots, flat beyond them; NaN
    (not covered) gives 0: no evidence either way."""

    gamma: np.ndarray
    l: np.ndarray  # noqa: E741  (the symbol of the definition)
    tail: TailTable | None = None
    """The detector's background tail: ``LR_TIE u(g)`` is added, to break ties."""

    def __call__(self, g: np.ndarray | float) -> np.ndarray:
        g = np.asarray(g, dtype=np.float64)
        out = np.interp(np.where(np.isnan(g), self.gamma[0], g), self.gamma, self.l)
        if self.tail is not None:
            out = out + LR_TIE * self.tail(g)
        return np.where(np.isnan(g), 0.0, out)


def lr_edges(x_t: np.ndarray, x_n: np.ndarray, *, bins: int = LR_BINS) -> np.ndarray:
    """Bin edges of :func:`lr_table`: ``bins / 2`` quantile bins of the targets' responses and as
    many of the background's, merged, so the ratio is resolved where either kind lies (a few
    dozen injected targets among thousands of clean cells would otherwise share the top bin
    with the background's tail). Finite responses only; sorted, unique."""
    half = max(1, bins // 2)
    q = np.linspace(0.0, 1.0, half + 1)
    return np.unique(np.concatenate([np.quantile(np.asarray(x, dtype=np.float64), q) for x in (x_t, x_n)]))


def lr_table(x_t: np.ndarray, x_n: np.ndarray, *, bins: int = LR_BINS, cap: float = LR_CAP,
             tail: TailTable | None = None) -> LrTable:
    """A detector's log likelihood ratio from its target and background responses.

    Bins from :func:`lr_edges`; per bin the Jeffreys-smoothed frequencies
    ``(k + 1/2) / (n + bins/2)`` of the targets and of the background; ``l`` = the log of their
    ratio, made non-decreasing by a weighted isotonic fit (weights = responses in the bin: a
    stronger response is never less target-like) and clipped to +-``cap``; knots at the bins'
    centres. Unlike Fisher's tail ``u = -ln S_N``, which is never below 0, ``l`` is negative
    where targets rarely respond so weakly: a detector that should have responded and did not
    counts against the look. Without responses of either kind, a flat table (l = 0).
    ``tail``: the detector's background tail, carried for the ties (:attr:`LrTable.tail`).
    """
    t = np.asarray(x_t, dtype=np.float64)
    n = np.asarray(x_n, dtype=np.float64)
    t, n = t[np.isfinite(t)], n[np.isfinite(n)]
    if t.size == 0 or n.size == 0:
        return LrTable(np.array([0.0, 1.0]), np.zeros(2), tail)
    edges = lr_edges(t, n, bins=bins)
    if edges.size < 2:
        return LrTable(np.array([edges[0], edges[0] + max(abs(edges[0]), 1.0) * 1e-6]), np.zeros(2), tail)
    k = edges.size - 1
    ct = np.histogram(np.clip(t, edges[0], edges[-1]), edges)[0].astype(np.float64)
    cn = np.histogram(np.clip(n, edges[0], edges[-1]), edges)[0].astype(np.float64)
    ratio = ((ct + 0.5) / (t.size + 0.5 * k)) / ((cn + 0.5) / (n.size + 0.5 * k))
    l = np.clip(isotonic_increasing(np.log(ratio), ct + cn + 1.0), -cap, cap)  # noqa: E741
    return LrTable(0.5 * (edges[1:] + edges[:-1]) if k > 1 else edges.copy(), l if k > 1 else np.repeat(l, 2), tail)


@dataclass(frozen=True, eq=False)
class LookModel:
    """Tail tables per detector and the look tables per detector set."""

    tails: Mapping[str, TailTable]
    tables: Mapping[str, Any]
    """subset key -> :class:`~atr_node.calibration.model.DetectorPerformance` over z."""
    info: Mapping[str, Any] = field(default_factory=dict)
    lrs: Mapping[str, LrTable] | None = None
    """Per-detector likelihood ratios (``look_score = "lr"``): z sums these, not the tails."""
    lrs_clipped: Mapping[str, LrTable] | None = None
    """The likelihood ratios of places where the recording clips (headroom below
    :attr:`clip_headroom_db`, :func:`clipped`): there a target's echo is cut at the sensor's
    full scale, so the highlight detectors respond less to a target than on darker seabed, and
    the same response says more. None: one table for every place (no place of the calibration
    images clipped, or too few, :data:`MIN_STRATUM_TARGETS`)."""
    clip_headroom_db: float | None = None
    """The headroom below which :attr:`lrs_clipped` applies (``calibration.clip_headroom_db``)."""
    weights: Mapping[str, Mapping[str, float]] | None = None
    """subset key -> detector -> the weight of its term in that set's z (:func:`fit_weights`,
    ``calibration.look_weights = "fit"``); None, or a set without weights: every term 1."""
    weights_clipped: Mapping[str, Mapping[str, float]] | None = None
    """The same for the places where the recording clips (:attr:`lrs_clipped`), fitted on the
    targets and cells there: where the seabed's highlights are cut at full scale the highlight
    detectors read the same saturated pixels, and the shadow carries what is left."""

    @property
    def terms(self) -> Mapping[str, Any]:
        """The per-detector terms z sums: the likelihood ratios where the model has them, else
        the background tails."""
        return self.tails if self.lrs is None else self.lrs

    def terms_at(self, headroom_db: float) -> Mapping[str, Any]:
        """The terms of a place with this headroom: :attr:`lrs_clipped` where it clips, else
        :attr:`terms`."""
        if self.lrs_clipped is not None and clipped(headroom_db, self.clip_headroom_db):
            return self.lrs_clipped
        return self.terms

    def table(self, detectors: Sequence[str]) -> Any | None:
        """The look table of this detector set, None if the model has none for it."""
        return self.tables.get(subset_key(detectors))

    def score(self, responses: Mapping[str, np.ndarray | float], detectors: Sequence[str], *,
              headroom_db: float = math.inf) -> np.ndarray:
        """``z`` of joint responses: ``responses[d]`` per detector of ``detectors`` (NaN = not
        covered, adds 0); detectors without a tail table add 0. ``headroom_db``: of the place
        (:func:`headroom_db`; inf = unknown or far from clipping)."""
        # canonical order: the sum's rounding does not depend on the order detectors are listed
        terms = self.terms_at(headroom_db)
        w = self.weights_of(detectors, clipped=terms is self.lrs_clipped)
        present = [d for d in _canonical(detectors) if d in terms and d in responses]
        if not present:
            return np.zeros(np.shape(next(iter(responses.values()), 0.0)))
        return _combine([terms[d](responses[d]) for d in present], [w.get(d, 1.0) for d in present])

    def weights_of(self, detectors: Sequence[str], *, clipped: bool = False) -> Mapping[str, float]:
        """The weights of a detector set's terms (empty: every term 1), at places that clip or not."""
        w = self.weights_clipped if clipped and self.lrs_clipped is not None else self.weights
        return {} if w is None else w.get(subset_key(detectors), {})


def _combine(us: list[np.ndarray], ws: Sequence[float] | None = None) -> np.ndarray:
    """z from the detectors' terms (tails or likelihood ratios): their sum, each term times its
    weight ``ws`` (None: all 1; :func:`fit_weights`). For the tails the sum was measured on
    development scenes of the held-out generator (seed 201) against their maximum and the sum
    of the two largest: the sum gave the fewest false alarms at equal Pd."""
    ws = [1.0] * len(us) if ws is None else list(ws)
    z = float(ws[0]) * np.asarray(us[0], dtype=np.float64)  # times 1.0 is exact: the plain sum as before
    for u, w in zip(us[1:], ws[1:]):
        z = z + float(w) * np.asarray(u, dtype=np.float64)
    return z


WEIGHT_RIDGE = 1.0
"""Pull of the fitted weights towards 1 (the plain sum), in units of one response of the fit:
it decides only when the fit has few responses (a short file's on-line calibration)."""


def fit_weights(u_t: np.ndarray, u_n: np.ndarray) -> np.ndarray:
    """Weights ``w_d >= 0`` of the detectors' terms in the look score ``z = sum_d w_d u_d``.

    ``u_t`` (m, k), ``u_n`` (n, k): the k detectors' terms (log likelihood ratios, 0 where a
    detector did not cover) of injected targets and of clean cells, those on which the look
    fired. The weights (and an intercept, not kept) maximise the class-balanced logistic
    likelihood of targets against cells, ``sum_i a_i [log(1 + e^{s_i}) - y_i s_i]`` with
    ``s = u w + b`` and ``a`` = 1/2 over each class's count, plus ``WEIGHT_RIDGE / (m + n)
    sum_d (w_d - 1)^2``. Were the detectors independent given the class and their terms the
    true log likelihood ratios, the sum (all 1) would be the optimum; where two detectors read
    the same pixels the same way (the highlight detectors on one echo), their terms repeat one
    piece of evidence and the fit shares one weight between them: the dependence SPEC 6.1 asks
    to model, measured on the joint responses. Non-negative, so a stronger response never
    lowers z. Without targets or cells: all 1.
    """
    from scipy.optimize import minimize
    from scipy.special import expit

    t = np.asarray(u_t, dtype=np.float64)
    n = np.asarray(u_n, dtype=np.float64)
    k = t.shape[1] if t.ndim == 2 else (n.shape[1] if n.ndim == 2 else 0)
    if t.ndim != 2 or n.ndim != 2 or t.shape[0] == 0 or n.shape[0] == 0 or k == 0:
        return np.ones(k)
    x = np.vstack([t, n])
    y = np.concatenate([np.ones(t.shape[0]), np.zeros(n.shape[0])])
    a = np.concatenate([np.full(t.shape[0], 0.5 / t.shape[0]), np.full(n.shape[0], 0.5 / n.shape[0])])
    ridge = WEIGHT_RIDGE / x.shape[0]

    def loss(p: np.ndarray) -> tuple[float, np.ndarray]:
        w, b = p[:k], p[k]
        s = x @ w + b
        f = float(np.sum(a * (np.logaddexp(0.0, s) - y * s))) + ridge * float(np.sum((w - 1.0) ** 2))
        r = a * (expit(s) - y)
        return f, np.concatenate([x.T @ r + 2.0 * ridge * (w - 1.0), [r.sum()]])

    res = minimize(loss, np.concatenate([np.ones(k), [0.0]]), jac=True, method="L-BFGS-B",
                   bounds=[(0.0, None)] * k + [(None, None)])
    w = np.asarray(res.x[:k], dtype=np.float64)
    return w if np.all(np.isfinite(w)) else np.ones(k)


def look_scores(target: Mapping[str, np.ndarray], nontarget: Mapping[str, np.ndarray], taus: Mapping[str, float],
                terms: Mapping[str, Any], detectors: Sequence[str], *,
                clipped_terms: Mapping[str, Any] | None = None,
                clipped_at: tuple[np.ndarray, np.ndarray] | None = None,
                fit: bool = False, fit_targets: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, float], dict[str, float]]:
    """(z_t, fired_t, z_n, fired_n, weights, clipped weights) of a detector set: z NaN where no
    detector covered; ``terms``: the per-detector terms (:attr:`LookModel.terms`);
    ``clipped_terms`` those of the targets and cells where ``clipped_at`` (bool masks of the
    targets, of the cells) is true (:attr:`LookModel.lrs_clipped`). ``fit``: the terms weighted
    by :func:`fit_weights` on the covered targets and cells the set fired on, those where it
    clips apart from the others (returned, detector -> weight; the clipped ones empty without
    ``clipped_terms``); else all 1 (both returned empty). ``fit_targets``: the targets the fit
    reads (bool mask; default all); z is returned for every target."""
    detectors = _canonical(detectors)
    parts = []
    for k, resp in enumerate((target, nontarget)):
        arrs = [np.asarray(resp[d], dtype=np.float64) for d in detectors]
        covered = np.zeros(arrs[0].shape, dtype=bool)
        fired = np.zeros(arrs[0].shape, dtype=bool)
        us = []
        for d, a in zip(detectors, arrs):
            if clipped_terms is not None and clipped_at is not None:
                us.append(np.where(clipped_at[k], clipped_terms[d](a), terms[d](a)))
            else:
                us.append(terms[d](a))
            covered |= np.isfinite(a)
            fired |= np.isfinite(a) & (a > taus[d])
        parts.append((us, covered, fired))
    ones = [1.0] * len(detectors)
    split = clipped_terms is not None and clipped_at is not None
    ws, ws_c = ones, ones
    if fit:
        (us_t, cov_t, fir_t), (us_n, cov_n, fir_n) = parts
        u_t, u_n = np.column_stack(us_t), np.column_stack(us_n)
        use_t, use_n = cov_t & fir_t, cov_n & fir_n
        if fit_targets is not None:
            use_t &= np.asarray(fit_targets, dtype=bool)
        if split:
            c_t, c_n = np.asarray(clipped_at[0], dtype=bool), np.asarray(clipped_at[1], dtype=bool)
            ws = fit_weights(u_t[use_t & ~c_t], u_n[use_n & ~c_n]).tolist()
            ws_c = fit_weights(u_t[use_t & c_t], u_n[use_n & c_n]).tolist()
        else:
            ws = fit_weights(u_t[use_t], u_n[use_n]).tolist()
    out = []
    for k, (us, covered, fired) in enumerate(parts):
        z = _combine(us, ws)
        if split and ws_c != ws:
            z = np.where(clipped_at[k], _combine(us, ws_c), z)
        out += [np.where(covered, z, np.nan), fired]
    return (out[0], out[1], out[2], out[3], dict(zip(detectors, ws)) if fit else {},
            dict(zip(detectors, ws_c)) if fit and split else {})


CONFIDENCE_TIE = 1e-3
"""Size of :func:`ranked_confidence`'s tie-break: at most ``CONFIDENCE_TIE / 4`` on a look's
confidence, far below any difference the calibration resolves."""
CONFIDENCE_TIE_SCALE = 10.0
"""Scale of z in :func:`ranked_confidence` (the lr score spans about -30 to 30)."""


def ranked_confidence(c: np.ndarray | float, z: np.ndarray | float) -> np.ndarray:
    """A look's confidence with the ties of its table broken by its score ``z``:
    ``c + e c (1 - c) s(z)``, ``e`` = :data:`CONFIDENCE_TIE`, ``s(z) = 1/2 + atan(z / 10) / pi``
    in (0, 1).

    The table ``c(z)`` is flat where the calibration cannot tell scores apart: above its
    strongest clean cell (the smoothed background survival stops at half a cell) and across
    its isotonic pools. There every look gets the same confidence, so a contact with one
    overwhelming look and one with a look just past the last clean cell tie at the same Bel,
    and the ROC, which sweeps Bel, takes them in together. The term orders them by z (the
    score the table is measured on, higher = rarer on seabed) without moving any confidence by
    more than ``e / 4``: strictly increasing in ``c`` and, where ``0 < c < 1``, in ``z``; 0 and
    1 stay 0 and 1; NaN stays NaN."""
    c = np.asarray(c, dtype=np.float64)
    s = 0.5 + np.arctan(np.asarray(z, dtype=np.float64) / CONFIDENCE_TIE_SCALE) / math.pi
    return c + CONFIDENCE_TIE * c * (1.0 - c) * s


def headroom_db(full_scale: float | None, background: np.ndarray | float) -> np.ndarray:
    """How far below the recording's full scale (its clip level, intensity) the seabed's mean
    intensity ``background`` lies, in dB: ``10 log10(full_scale / background)``. inf where the
    full scale is unknown (None: float data) or the background is not a positive number (no
    data); 0 or less where the seabed itself is at full scale."""
    b = np.asarray(background, dtype=np.float64)
    if full_scale is None or not math.isfinite(full_scale) or full_scale <= 0:
        return np.full(b.shape, math.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = 10.0 * np.log10(float(full_scale) / b)
    return np.where(np.isfinite(b) & (b > 0), h, math.inf)


def clipped(headroom: np.ndarray | float, limit_db: float | None) -> np.ndarray:
    """Places where the recording clips a target's echo: headroom below ``limit_db``
    (``calibration.clip_headroom_db``); none when it is None."""
    h = np.asarray(headroom, dtype=np.float64)
    if limit_db is None:
        return np.zeros(h.shape, dtype=bool)
    return h < float(limit_db)


def with_prior(curve_c: np.ndarray, old_prior: float, new_prior: float) -> np.ndarray:
    """A confidence table made with prior ``old_prior`` as it reads under ``new_prior``:
    ``c = P(T | data)`` changes by the prior odds ratio, ``odds' = odds * o(new) / o(old)``
    (exact for the Bayes ratio; the isotonic fit, where there was one, is carried along)."""
    c = np.asarray(curve_c, dtype=np.float64)
    k = (new_prior / (1.0 - new_prior)) / (old_prior / (1.0 - old_prior))
    odds = c / (1.0 - c) * k
    return odds / (1.0 + odds)


def area_prior(density_km2: float, cell_area_m2: float) -> float:
    """P(T) per template-sized cell from a target density (Poisson): ``1 - exp(-rho A)``,
    strictly inside (0, 1)."""
    lam = float(density_km2) * float(cell_area_m2) / 1e6
    p = -math.expm1(-lam)
    return min(max(p, 1e-12), 1.0 - 1e-12)


# -- file ------------------------------------------------------------------------------------

def looks_to_dict(looks: LookModel, detector_dict) -> dict[str, Any]:
    """The ``looks`` section of the model file (``detector_dict`` turns a table into the
    per-detector JSON layout)."""
    return {"info": dict(looks.info),
            "tails": {d: {"gamma": t.gamma.tolist(), "u": t.u.tolist(), "slope": float(t.slope)}
                      for d, t in looks.tails.items()},
            "tables": {k: detector_dict(p) for k, p in looks.tables.items()},
            **({} if looks.lrs is None else
               {"lr": _lr_dict(looks.lrs)}),
            **({} if looks.lrs_clipped is None else
               {"lr_clipped": _lr_dict(looks.lrs_clipped), "clip_headroom_db": float(looks.clip_headroom_db)}),
            **({} if not looks.weights else {"weights": _weights_dict(looks.weights)}),
            **({} if not looks.weights_clipped else {"weights_clipped": _weights_dict(looks.weights_clipped)})}


def _weights_dict(weights: Mapping[str, Mapping[str, float]]) -> dict[str, dict[str, float]]:
    return {k: {d: float(v) for d, v in w.items()} for k, w in weights.items()}


def _lr_dict(lrs: Mapping[str, LrTable]) -> dict[str, Any]:
    return {d: {"gamma": t.gamma.tolist(), "l": t.l.tolist()} for d, t in lrs.items()}


def _knots(t: Any, name: str) -> tuple[np.ndarray, np.ndarray, bool]:
    """``t["gamma"]`` and ``t[name]`` of a table in a model file as float64 arrays, and whether
    they are knots: 1-D, the same length >= 2, finite, gamma increasing, the values
    non-decreasing. Raises what ``np.asarray`` or the lookups raise on a malformed table."""
    g = np.asarray(t["gamma"], dtype=np.float64)
    v = np.asarray(t[name], dtype=np.float64)
    ok = (g.ndim == 1 and g.size >= 2 and v.shape == g.shape and bool(np.all(np.isfinite(g)))
          and bool(np.all(np.isfinite(v))) and not np.any(np.diff(g) <= 0) and not np.any(np.diff(v) < 0))
    return g, v, ok


def looks_from_dict(raw: Any, where: str, detector_from) -> LookModel:
    """Read and check the ``looks`` section (errors name the file and key)."""
    from ..errors import ModelFileError

    def err(key: str, msg: str) -> ModelFileError:
        return ModelFileError(f"{where}, key 'looks.{key}': {msg}")

    if not isinstance(raw, dict):
        raise err("", "expected a map")
    tails_raw, tables_raw = raw.get("tails"), raw.get("tables")
    if not isinstance(tails_raw, dict) or not isinstance(tables_raw, dict):
        raise err("tails", "looks needs maps 'tails' and 'tables'")
    tails = {}
    for d, t in tails_raw.items():
        try:
            g, u, ok = _knots(t, "u")
            slope = float(t.get("slope", 0.0))
        except (TypeError, ValueError, KeyError, AttributeError):
            raise err(f"tails.{d}", "needs lists of numbers 'gamma' and 'u' and a number 'slope'") from None
        if not (math.isfinite(slope) and slope >= 0.0):
            raise err(f"tails.{d}.slope", f"must be finite and >= 0, got {slope!r}")
        if not ok or np.any(u < 0):
            raise err(f"tails.{d}", "gamma must be increasing and u finite, >= 0 and non-decreasing, same length >= 2")
        tails[d] = TailTable(g, u, slope)
    def lr_section(name: str) -> dict[str, LrTable] | None:
        if name not in raw:
            return None
        if not isinstance(raw[name], dict):
            raise err(name, "expected a map detector -> {gamma, l}")
        out = {}
        for d, t in raw[name].items():
            try:
                g, lv, ok = _knots(t, "l")
            except (TypeError, ValueError, KeyError, AttributeError):
                raise err(f"{name}.{d}", "needs lists of numbers 'gamma' and 'l'") from None
            if not ok:
                raise err(f"{name}.{d}", "gamma must be increasing and l finite and non-decreasing, same length >= 2")
            if d not in tails:
                raise err(f"{name}.{d}", "a detector without a tail table")
            out[str(d)] = LrTable(g, lv, tails[d])
        return out

    lrs, lrs_clipped = lr_section("lr"), lr_section("lr_clipped")
    clip_db = None
    if lrs_clipped is not None:
        if lrs is None or set(lrs_clipped) != set(lrs):
            raise err("lr_clipped", "needs 'lr' of the same detectors")
        clip_db = raw.get("clip_headroom_db")
        if isinstance(clip_db, bool) or not isinstance(clip_db, (int, float)) or not math.isfinite(clip_db):
            raise err("clip_headroom_db", f"must be a finite number with 'lr_clipped', got {clip_db!r}")
        clip_db = float(clip_db)
    tables = {}
    for k, t in tables_raw.items():
        members = [m for m in str(k).split("+") if m]
        missing = [m for m in members if m not in tails or (lrs is not None and m not in lrs)]
        if not members or missing:
            raise err(f"tables.{k}", f"names detectors without a tail{' or lr' if lrs is not None else ''} table: "
                                     f"{missing or k!r}")
        tables[str(k)] = detector_from(t, where, f"looks.tables.{k}")

    def weights_section(name: str, lr_name: str, of: Any) -> dict[str, dict[str, float]] | None:
        if name not in raw:
            return None
        if not isinstance(raw[name], dict):
            raise err(name, "expected a map detector set -> {detector: weight}")
        if of is None:
            raise err(name, f"weights the likelihood-ratio terms: needs '{lr_name}'")
        out = {}
        for k, w in raw[name].items():
            if str(k) not in tables:
                raise err(f"{name}.{k}", "a detector set without a look table")
            members = set(m for m in str(k).split("+") if m)
            if (not isinstance(w, dict) or set(map(str, w)) != members
                    or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0
                               for v in w.values())):
                raise err(f"{name}.{k}", f"needs a finite weight >= 0 for each of {sorted(members)}, got {w!r}")
            out[str(k)] = {str(d): float(v) for d, v in w.items()}
        return out

    weights = weights_section("weights", "lr", lrs)
    weights_clipped = weights_section("weights_clipped", "lr_clipped", lrs_clipped)
    info = raw.get("info") if isinstance(raw.get("info"), dict) else {}
    return LookModel(tails, tables, info, lrs, lrs_clipped, clip_db, weights, weights_clipped)
