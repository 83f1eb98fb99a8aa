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
        us = [terms[d](responses[d]) for d in _canonical(detectors) if d in terms and d in responses]
        return np.zeros(np.shape(next(iter(responses.values()), 0.0))) if not us else _combine(us)


def _combine(us: list[np.ndarray]) -> np.ndarray:
    """z from the detectors' terms (tails or likelihood ratios): their sum. For the tails it was
    measured on development scenes of the held-out generator (seed 201) against their maximum
    and the sum of the two largest: the sum gave the fewest false alarms at equal Pd."""
    z = np.array(us[0], dtype=np.float64, copy=True)
    for u in us[1:]:
        z = z + u
    return z


def look_scores(target: Mapping[str, np.ndarray], nontarget: Mapping[str, np.ndarray], taus: Mapping[str, float],
                terms: Mapping[str, Any], detectors: Sequence[str], *,
                clipped_terms: Mapping[str, Any] | None = None,
                clipped_at: tuple[np.ndarray, np.ndarray] | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(z_t, fired_t, z_n, fired_n) of a detector set: z NaN where no detector covered;
    ``terms``: the per-detector terms (:attr:`LookModel.terms`); ``clipped_terms`` those of
    the targets and cells where ``clipped_at`` (bool masks of the targets, of the cells) is
    true (:attr:`LookModel.lrs_clipped`)."""
    out = []
    detectors = _canonical(detectors)
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
        z = _combine(us)
        out += [np.where(covered, z, np.nan), fired]
    return out[0], out[1], out[2], out[3]


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
               {"lr_clipped": _lr_dict(looks.lrs_clipped), "clip_headroom_db": float(looks.clip_headroom_db)})}


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
    info = raw.get("info") if isinstance(raw.get("info"), dict) else {}
    return LookModel(tails, tables, info, lrs, lrs_clipped, clip_db)
