"""Look-level evidence: the detectors of one pass judged together (SPEC 6.1).

The four detectors read the same pixels of the same pass, so their detections are not
independent pieces of evidence. The injection already measures their *joint* behaviour: every
injected target and every clean template-sized cell gives all four responses at once. From
those joint responses this module builds, per set of enabled detectors:

- a **look score** ``z = sum_d u_d(gamma_d)``, with ``u_d(g) = -ln S_N,d(g)`` the detector's
  background tail (how rare ``g`` is on target-free seabed; Fisher's way of putting p-values
  on one scale). A detector that did not cover a place adds 0. Any monotone combination would
  do: the confidence below is measured on ``z`` itself, so the detectors' dependence is in the
  numbers, not assumed away;
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

SCORE_DEFINITION = "z = sum over detectors of -ln S_N,d(gamma_d) (background tail; 0 where not covered)"
TAIL_POINTS = 48
"""Knots of a detector's tail table u_d."""
TAIL_EXTRA = math.log(10.0)
"""How far u_d goes beyond the largest background response: one decade of survival."""
TAIL_MIN_EXCESS = 10
"""Fewest background responses over the tail threshold to fit the exponential tail."""


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
class LookModel:
    """Tail tables per detector and the look tables per detector set."""

    tails: Mapping[str, TailTable]
    tables: Mapping[str, Any]
    """subset key -> :class:`~atr_node.calibration.model.DetectorPerformance` over z."""
    info: Mapping[str, Any] = field(default_factory=dict)

    def table(self, detectors: Sequence[str]) -> Any | None:
        """The look table of this detector set, None if the model has none for it."""
        return self.tables.get(subset_key(detectors))

    def score(self, responses: Mapping[str, np.ndarray | float], detectors: Sequence[str]) -> np.ndarray:
        """``z`` of joint responses: ``responses[d]`` per detector of ``detectors`` (NaN = not
        covered, adds 0); detectors without a tail table add 0."""
        # canonical order: the sum's rounding does not depend on the order detectors are listed
        us = [self.tails[d](responses[d]) for d in _canonical(detectors) if d in self.tails and d in responses]
        return np.zeros(np.shape(next(iter(responses.values()), 0.0))) if not us else _combine(us)


def _combine(us: list[np.ndarray]) -> np.ndarray:
    """z from the detectors' tails: their sum (Fisher). Measured on development scenes of the
    held-out generator (seed 201) against their maximum and the sum of the two largest: the sum
    gave the fewest false alarms at equal Pd (docs/fusion.md)."""
    z = np.array(us[0], dtype=np.float64, copy=True)
    for u in us[1:]:
        z = z + u
    return z


def look_scores(target: Mapping[str, np.ndarray], nontarget: Mapping[str, np.ndarray], taus: Mapping[str, float],
                tails: Mapping[str, TailTable], detectors: Sequence[str]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(z_t, fired_t, z_n, fired_n) of a detector set: z NaN where no detector covered."""
    out = []
    detectors = _canonical(detectors)
    for resp in (target, nontarget):
        arrs = [np.asarray(resp[d], dtype=np.float64) for d in detectors]
        covered = np.zeros(arrs[0].shape, dtype=bool)
        fired = np.zeros(arrs[0].shape, dtype=bool)
        us = []
        for d, a in zip(detectors, arrs):
            us.append(tails[d](a))
            covered |= np.isfinite(a)
            fired |= np.isfinite(a) & (a > taus[d])
        z = _combine(us)
        out += [np.where(covered, z, np.nan), fired]
    return out[0], out[1], out[2], out[3]


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
            "tables": {k: detector_dict(p) for k, p in looks.tables.items()}}


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
            g = np.asarray(t["gamma"], dtype=np.float64)
            u = np.asarray(t["u"], dtype=np.float64)
            slope = float(t.get("slope", 0.0))
        except (TypeError, ValueError, KeyError, AttributeError):
            raise err(f"tails.{d}", "needs lists of numbers 'gamma' and 'u' and a number 'slope'") from None
        if not (math.isfinite(slope) and slope >= 0.0):
            raise err(f"tails.{d}.slope", f"must be finite and >= 0, got {slope!r}")
        if (g.ndim != 1 or g.size < 2 or u.shape != g.shape or not np.all(np.isfinite(g)) or not np.all(np.isfinite(u))
                or np.any(np.diff(g) <= 0) or np.any(np.diff(u) < 0) or np.any(u < 0)):
            raise err(f"tails.{d}", "gamma must be increasing and u finite, >= 0 and non-decreasing, same length >= 2")
        tails[d] = TailTable(g, u, slope)
    tables = {}
    for k, t in tables_raw.items():
        members = [m for m in str(k).split("+") if m]
        missing = [m for m in members if m not in tails]
        if not members or missing:
            raise err(f"tables.{k}", f"names detectors without a tail table: {missing or k!r}")
        tables[str(k)] = detector_from(t, where, f"looks.tables.{k}")
    info = raw.get("info") if isinstance(raw.get("info"), dict) else {}
    return LookModel(tails, tables, info)
