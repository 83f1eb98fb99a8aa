"""Do the legs agree? The shift between two legs' views of the same objects (issue 17).

Fusion associates a target's looks within the gate ``gate_sigmas * nav_sigma_m + length_m / 2``
(SPEC section 7) and reads each look's missed-detection evidence where the look did not fire.
If the INS puts two legs farther apart than the gate, a target seen on both becomes two
contacts, each in the other look's miss: both fall. The held-out benchmark measured it: with
per-leg nav errors of about 2 m and the default ``nav_sigma_m`` of 1 m, the node finds 107 of 144
targets instead of 138 (docs/evaluation.md, nav2). Nothing in the node could tell the user so.

The objects on the seabed (targets, rocks, anything the looks detect strongly) are seen by
every leg that passes them, and they do not move: between two legs, the displacements from
one leg's detection to the other's of the same object share one vector, the legs' relative
navigation error (a per-leg offset, the common case for an INS over one straight leg; drift
along the leg spreads it). :func:`leg_shifts` measures that vector for every pair of legs:

1. per leg, the anchors of its point detections with confidence >= ``min_confidence`` (look
   evidence: the confident looks; one anchor per object and look already);
2. pairs: every pair of the two legs' anchors within ``search_m`` (larger than any gate: what
   the gate missed is what we look for), so that a shift as long as the spacing of the objects
   still pairs each object with itself;
3. the shift: the mode of their displacements, a vote on a grid for the densest disc of radius
   ``mode_m`` (pairs of two different objects spread over the search disc; the pairs of one
   object seen twice all land on the shift), refined to the mean of the displacements near it;
   ``support`` is how many objects agree on it, ``chance`` how many unrelated pairs would.

A shift longer than the association gate, agreed by at least ``min_support`` objects (and 3
times the chance agreement), means the looks of one object on those two legs are not
associated: :class:`NavCheck` logs it once per pair of legs with the ``nav_sigma_m`` that would
hold them, and the end-of-run line of ``replay`` and ``run`` says it. The check reads the
detection records only; it changes no evidence and no contact.

Measured against the held-out generator's own nav errors (its ``scene.json`` states every
leg's offset, drift and wander): docs/fusion.md, "Do the legs agree?".
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

log = logging.getLogger(__name__)

SEARCH_M = 10.0
"""How far apart two legs' detections of one object may be found (metres): over 3x the default
gate, as far as a poor INS puts two legs."""
MODE_M = 1.0
"""Displacements within this of each other agree (metres): an anchor's spread between looks."""
MIN_SUPPORT = 5
"""Objects that must agree on a shift before it is believed (and reported)."""
CHANCE_FACTOR = 3.0
"""... and at least this many times the pairs that would agree by chance (:attr:`LegShift.chance`)."""
MAX_LOGGED = 5
"""Flagged pairs logged one by one; the rest are counted (:meth:`NavCheck.summary`)."""
MIN_CONFIDENCE = 0.5
"""Records below this confidence are left out: weak looks are mostly seabed texture, whose
repeated patterns can agree on a wrong shift (chosen on the development seeds' nav2 scenes:
at 0.3 two of 39 flagged pairs, on SASSED, were 4-5 m off the truth; at 0.5 none of 30)."""


@dataclass(frozen=True)
class LegShift:
    """Where leg ``leg_b`` sees the objects that leg ``leg_a`` sees: ``east_m``, ``north_m``
    from a's detection to b's, agreed by ``support`` objects; ``pairs`` of the two legs'
    anchors lay within the search distance."""

    leg_a: int
    leg_b: int
    east_m: float
    north_m: float
    support: int
    pairs: int
    chance: float = 0.0
    """Pairs of unrelated anchors expected to agree by chance: ``pairs`` spread evenly over
    the search disc, the share that falls within ``mode_m`` of one point."""

    @property
    def distance_m(self) -> float:
        return math.hypot(self.east_m, self.north_m)


def believed(support: int, chance: float, *, min_support: int = MIN_SUPPORT) -> bool:
    """Enough objects agree on a shift to believe it: at least ``min_support`` and
    :data:`CHANCE_FACTOR` times the agreement expected by chance (:attr:`LegShift.chance`)."""
    return support >= max(min_support, CHANCE_FACTOR * chance)


def leg_anchors(records: Iterable, *, min_confidence: float = MIN_CONFIDENCE) -> dict[int, np.ndarray]:
    """Leg -> (k, 2) distinct (east, north) anchors of its point detections with confidence >=
    ``min_confidence`` (extended objects, whose anchor is a centre, are left out)."""
    by: dict[int, set[tuple[float, float]]] = {}
    for r in records:
        if r.length_m is None and r.confidence >= min_confidence and math.isfinite(r.east_m) \
                and math.isfinite(r.north_m):
            by.setdefault(int(r.leg), set()).add((float(r.east_m), float(r.north_m)))
    return {leg: np.array(sorted(p), dtype=np.float64).reshape(-1, 2) for leg, p in by.items()}


def near_pairs(pa: np.ndarray, pb: np.ndarray, search_m: float) -> np.ndarray:
    """(n, 2) indices (i into ``pa``, j into ``pb``) of every pair closer than ``search_m``,
    sorted."""
    if not len(pa) or not len(pb):
        return np.zeros((0, 2), dtype=np.intp)
    near = cKDTree(pa).sparse_distance_matrix(cKDTree(pb), search_m, output_type="ndarray")
    ij = np.column_stack([near["i"], near["j"]]).astype(np.intp)
    return ij[np.lexsort((ij[:, 1], ij[:, 0]))]


def shift_mode(d: np.ndarray, search_m: float, mode_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The mode of displacements ``d`` (n, 2), all within ``search_m`` of 0: a vote on a grid of
    ``mode_m / 2`` cells for the densest disc of radius ``mode_m`` (first on ties), the mean of
    the displacements it holds, then twice those within ``mode_m`` of the mean and their mean.
    Returns the centre (the members' mean) and the mask of the members (NaN and none for no
    displacement). Linear in n."""
    d = np.asarray(d, dtype=np.float64).reshape(-1, 2)
    if not len(d):
        return np.full(2, np.nan), np.zeros(0, dtype=bool)
    cell = 0.5 * mode_m
    nb = int(math.ceil(2.0 * search_m / cell)) + 1
    lo = -0.5 * nb * cell
    idx = np.clip(np.floor((d - lo) / cell).astype(np.intp), 0, nb - 1)
    votes = np.zeros((nb, nb), dtype=np.float64)
    np.add.at(votes, (idx[:, 0], idx[:, 1]), 1.0)
    k = int(math.ceil(mode_m / cell))  # the disc of radius mode_m about a cell, as a square of cells
    yy, xx = np.mgrid[-k:k + 1, -k:k + 1]
    disc = ((xx * cell) ** 2 + (yy * cell) ** 2 <= mode_m ** 2).astype(np.float64)
    dens = ndimage.convolve(votes, disc, mode="constant")  # small whole counts: exact
    i, j = np.unravel_index(int(np.argmax(dens)), dens.shape)
    # the votes that disc counted, then twice their mean and the displacements within mode_m
    di, dj = idx[:, 0] - i, idx[:, 1] - j
    members = (np.abs(di) <= k) & (np.abs(dj) <= k)
    members[members] = disc[di[members] + k, dj[members] + k] > 0
    centre = d[members].mean(axis=0)  # the densest disc holds at least one vote
    for _ in range(2):
        near = np.hypot(d[:, 0] - centre[0], d[:, 1] - centre[1]) <= mode_m
        if not near.any():  # votes at opposite edges of the disc, their mean between them
            break
        members, centre = near, d[near].mean(axis=0)
    return centre, members


def leg_shifts(records: Iterable, legs: Sequence[int] | None = None, *, only: int | None = None,
               search_m: float = SEARCH_M, mode_m: float = MODE_M,
               min_confidence: float = MIN_CONFIDENCE) -> list[LegShift]:
    """The shift of every pair of ``legs`` (all legs of ``records`` when None) with at least one
    pair of anchors within ``search_m``, ``leg_a < leg_b`` (see the module docstring); with
    ``only``, the pairs that include that leg."""
    anchors = leg_anchors(records, min_confidence=min_confidence)
    chosen = sorted(anchors if legs is None else (g for g in set(legs) if g in anchors))
    out = []
    for k, a in enumerate(chosen):
        for b in chosen[k + 1:]:
            if only is not None and only not in (a, b):
                continue
            pa, pb = anchors[a], anchors[b]
            ij = near_pairs(pa, pb, search_m)
            if not len(ij):
                continue
            s, m = shift_mode(pb[ij[:, 1]] - pa[ij[:, 0]], search_m, mode_m)
            # objects, not pairs: an anchor agrees once however many others lie near it
            support = min(len(np.unique(ij[m, 0])), len(np.unique(ij[m, 1])))
            out.append(LegShift(a, b, float(s[0]), float(s[1]), int(support), int(len(ij)),
                                float(len(ij) * (mode_m / search_m) ** 2)))
    return out


def sigma_to_hold(distance_m: float, *, gate_sigmas: float, length_m: float, mode_m: float = MODE_M) -> float:
    """The ``nav_sigma_m`` whose gate holds a shift of ``distance_m`` with ``mode_m`` to spare,
    rounded up to 0.5 m."""
    need = (distance_m + mode_m - 0.5 * length_m) / max(gate_sigmas, 1e-9)
    return max(0.5, math.ceil(need * 2.0) / 2.0)


class NavCheck:
    """Checks every pair of closed legs once (:meth:`update`), logs a shift beyond the gate (the
    first :data:`MAX_LOGGED` such pairs).

    ``flagged`` lists those shifts, ``shifts`` every pair's, in the order checked.
    """

    def __init__(self, *, gate_m: float, gate_sigmas: float, nav_sigma_m: float, length_m: float,
                 min_support: int = MIN_SUPPORT) -> None:
        self.gate_m = float(gate_m)
        self.gate_sigmas = float(gate_sigmas)
        self.nav_sigma_m = float(nav_sigma_m)
        self.length_m = float(length_m)
        self.min_support = int(min_support)
        self.checked: set[int] = set()
        self.shifts: list[LegShift] = []
        self.flagged: list[LegShift] = []
        self.log_pairs = True
        """False: flagged pairs are counted, not logged (a second pass over the same recording)."""

    def update(self, records: Sequence, closed_legs: Iterable[int]) -> list[LegShift]:
        """Check each newly closed leg against the legs closed before it; returns the shifts
        newly flagged (logged once each)."""
        new = sorted(set(closed_legs) - self.checked)
        if not new:
            return []
        found = []
        for leg in new:
            if self.checked:
                for s in leg_shifts(records, sorted(self.checked | {leg}), only=leg):
                    self.shifts.append(s)
                    if self.believed(s) and s.distance_m > self.gate_m:
                        self.flagged.append(s)
                        found.append(s)
                        if self.log_pairs and len(self.flagged) <= MAX_LOGGED:
                            log.warning("%s%s", self.message(s), "" if len(self.flagged) < MAX_LOGGED else
                                        " (further pairs are counted in the end-of-run summary, not logged)")
            self.checked.add(leg)
        return found

    def believed(self, s: LegShift) -> bool:
        """:func:`believed` with this check's ``min_support``."""
        return believed(s.support, s.chance, min_support=self.min_support)

    def figures(self) -> list[dict]:
        """Every pair checked, as JSON-ready maps (the end-of-run summary's ``leg_shifts``)."""
        return [{"leg_a": s.leg_a, "leg_b": s.leg_b, "east_m": round(s.east_m, 3), "north_m": round(s.north_m, 3),
                 "distance_m": round(s.distance_m, 3), "support": s.support, "pairs": s.pairs,
                 "chance": round(s.chance, 2), "flagged": s in self.flagged} for s in self.shifts]

    def message(self, s: LegShift) -> str:
        """One line for a flagged shift."""
        return (f"legs {s.leg_a} and {s.leg_b} disagree: {s.support} objects seen on both lie "
                f"{s.distance_m:.1f} m apart (east {s.east_m:+.1f}, north {s.north_m:+.1f}), beyond the "
                f"association gate of {self.gate_m:.1f} m, so their looks of one object are not fused; if "
                f"the INS is that poor, set fusion.nav_sigma_m to about "
                f"{sigma_to_hold(s.distance_m, gate_sigmas=self.gate_sigmas, length_m=self.length_m):g} "
                f"(now {self.nav_sigma_m:g})")

    def report(self) -> str | None:
        """One line either way, for a report (None when no pair of legs was measured): the
        :meth:`summary` when a pair is flagged, else the largest shift believed and the gate."""
        if self.flagged:
            return self.summary()
        believed = [s for s in self.shifts if self.believed(s)]
        if not believed:
            k = len(self.shifts)
            return (f"navigation: {k} pair{'s' if k != 1 else ''} of legs compared, none with {self.min_support} "
                    f"objects seen on both" if self.shifts else None)
        worst = max(believed, key=lambda s: s.distance_m)
        n = len(believed)
        return (f"navigation: the legs agree: {n} pair{'s' if n != 1 else ''} of legs measured on the objects "
                f"both see, the largest shift {worst.distance_m:.1f} m (legs {worst.leg_a} and {worst.leg_b}, "
                f"{worst.support} objects) within the association gate of {self.gate_m:.1f} m")

    def summary(self) -> str | None:
        """One line over the flagged pairs (None when none)."""
        if not self.flagged:
            return None
        worst = max(self.flagged, key=lambda s: s.distance_m)
        need = sigma_to_hold(worst.distance_m, gate_sigmas=self.gate_sigmas, length_m=self.length_m)
        return (f"navigation: {len(self.flagged)} of {len(self.shifts)} pairs of legs see the same objects "
                f"farther apart than the association gate of {self.gate_m:.1f} m (up to {worst.distance_m:.1f} m, "
                f"legs {worst.leg_a} and {worst.leg_b}): fusion.nav_sigma_m = {self.nav_sigma_m:g} is too small "
                f"for this INS; about {need:g} would hold them")
