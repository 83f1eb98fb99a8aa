"""Dempster-Shafer mass algebra (SPEC section 6): the general rule and the {T, notT} closed form.

Two paths, as in filterpy's Kalman filter: :func:`combine` is Dempster's rule for any frame
and any focal sets, written for clarity (the reference); :func:`closed_form` is the
vectorised evaluation used by the evidence grid for simple support functions on the frame
{T, notT}. The tests check that both agree to 1e-12.

Closed form (SPEC section 6). With ``a = prod(1 - c_k)`` over T-evidence and
``b = prod(1 - q_k)`` over notT-evidence::

    m(T)     = (1 - a) b / (a + b - ab)
    m(notT)  = (1 - b) a / (a + b - ab)
    m(Theta) =      a b / (a + b - ab)

The grid keeps ``L_T = log a = sum log1p(-c_k)`` and ``L_N = log b`` in float64; combining
evidence is then a pure addition of accumulators (exact merge, order-free up to rounding).
Evaluation stays in the log domain (expm1, logaddexp) so that 10^5 pieces of evidence, masses
within 1e-15 of 0 or 1 and accumulators of -inf give exact or finite answers.

References
----------
G. Shafer, *A Mathematical Theory of Evidence*, Princeton University Press, 1976.
V. Myers and O. Midtgaard, "Fusion of contacts in synthetic aperture sonar imagery using
performance estimates", section 5.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Iterable, Mapping
from typing import NamedTuple

import numpy as np

from ..errors import FusionError

T = "T"
NOT_T = "notT"
FRAME_TN: frozenset[str] = frozenset({T, NOT_T})
"""The frame of discernment {T, notT} of SPEC section 6."""

Mass = Mapping[frozenset, float]
"""A basic probability assignment: focal set -> mass (masses sum to 1, no mass on the empty set)."""


# ----------------------------------------------------------------------------------------
# General rule (the reference)


def validate_mass(m: Mass, frame: frozenset, *, tol: float = 1e-9) -> None:
    """Raise :class:`FusionError` unless ``m`` is a mass function on ``frame``."""
    total = 0.0
    for focal, value in m.items():
        if not isinstance(focal, frozenset) or not focal:
            raise FusionError(f"focal set {focal!r} must be a non-empty frozenset")
        if not focal <= frame:
            raise FusionError(f"focal set {sorted(map(str, focal))} is not a subset of the frame {sorted(map(str, frame))}")
        if not (0.0 <= value <= 1.0):
            raise FusionError(f"mass {value!r} on {sorted(map(str, focal))} is outside [0, 1]")
        total += value
    if abs(total - 1.0) > tol:
        raise FusionError(f"masses sum to {total!r}, expected 1")


def combine(m1: Mass, m2: Mass) -> tuple[dict[frozenset, float], float]:
    """Dempster's rule of combination ``m1 (+) m2`` for any frame and focal sets.

    ``m(C) = sum_{A & B = C} m1(A) m2(B) / (1 - K)``, ``K = sum_{A & B = {}} m1(A) m2(B)``.

    Returns
    -------
    (m, K)
        The combined mass (zero masses dropped) and the conflict K.

    Raises
    ------
    FusionError
        Total conflict (K = 1): the two bodies of evidence contradict each other completely.
    """
    out: dict[frozenset, float] = {}
    conflict = 0.0
    for a, ma in m1.items():
        for b, mb in m2.items():
            c = a & b
            if c:
                out[c] = out.get(c, 0.0) + ma * mb
            else:
                conflict += ma * mb
    # 1 - K computed as the sum of the non-conflicting products: the same number, without
    # the cancellation of 1 - K when K is close to 1 (long chains of combinations)
    norm = sum(out.values())
    if not norm > 0.0:
        raise FusionError(f"total conflict (K = {conflict!r}): Dempster's rule is undefined")
    return {c: v / norm for c, v in out.items() if v > 0.0}, conflict


def combine_all(masses: Iterable[Mass]) -> dict[frozenset, float]:
    """``m1 (+) m2 (+) ... (+) mk``: Dempster's rule applied in turn, as :func:`combine`, on
    the logs of the masses.

    Products of masses are sums of logs and each normalisation subtracts a log-sum-exp, so a
    focal set's mass relative to another may fall far below float64's range (10^4 pieces at
    1 - 1e-12 put m(Theta) near 1e-120000) without becoming 0. In linear masses it underflows,
    the rest of the chain then sees a categorical mass, and the answer depends on the order
    of the pieces: (1, 0), (0, 1) or (1/2, 1/2) for the same evidence (issue 21 item 8).

    Raises
    ------
    FusionError
        No mass function, or total conflict between the evidence combined so far and the next.
    """
    it = iter(masses)
    try:
        first = next(it)
    except StopIteration:
        raise FusionError("combine_all needs at least one mass function") from None
    acc = {c: math.log(v) for c, v in first.items() if v > 0.0}
    for m in it:
        terms: dict[frozenset, list[float]] = {}
        for a, la in acc.items():
            for b, mb in m.items():
                c = a & b
                if c and mb > 0.0:
                    terms.setdefault(c, []).append(la + math.log(mb))
        if not terms:
            raise FusionError("total conflict (K = 1.0): Dempster's rule is undefined")
        acc = {c: _logsumexp(v) for c, v in terms.items()}
        norm = _logsumexp(list(acc.values()))  # log(1 - K)
        acc = {c: v - norm for c, v in acc.items()}
    out = {c: math.exp(v) for c, v in acc.items()}
    return {c: v for c, v in out.items() if v > 0.0}


def _logsumexp(logs: list[float]) -> float:
    """``log(sum(exp(x)))`` without overflow or underflow (the largest term factored out)."""
    top = max(logs)
    if top == -math.inf:
        return top
    return top + math.log(math.fsum(math.exp(x - top) for x in logs))


def belief(m: Mass, hypothesis: frozenset) -> float:
    """Bel(A) = sum of m(B) over non-empty B subset of A."""
    return sum(v for b, v in m.items() if b <= hypothesis)


def plausibility(m: Mass, hypothesis: frozenset) -> float:
    """Pl(A) = sum of m(B) over B meeting A."""
    return sum(v for b, v in m.items() if b & hypothesis)


def simple_support(focal: Hashable | frozenset, mass: float, frame: frozenset = FRAME_TN) -> dict[frozenset, float]:
    """The simple support function ``m(focal) = mass``, the rest on the frame."""
    f = focal if isinstance(focal, frozenset) else frozenset({focal})
    if f == frame:
        return {frame: 1.0}
    out = {frame: 1.0 - mass}
    if mass > 0.0:
        out[f] = mass
    return {k: v for k, v in out.items() if v > 0.0}


# ----------------------------------------------------------------------------------------
# Closed form on {T, notT} with log accumulators


class Clamped(NamedTuple):
    """Masses clamped to ``[0, 1 - eps]`` and the number that were moved."""

    mass: np.ndarray
    n_clamped: int


def clamp_mass(mass: np.ndarray | float, eps: float) -> Clamped:
    """Clamp masses to ``[0, 1 - eps]`` so total conflict cannot occur (SPEC section 6).

    Raises
    ------
    FusionError
        A mass is NaN or outside [0, 1]: that is bad input, not something to clamp.
    """
    m = np.asarray(mass, dtype=np.float64)
    bad = ~((m >= 0.0) & (m <= 1.0))
    if bad.any():
        first = m[bad].flat[0]
        raise FusionError(f"{int(bad.sum())} mass(es) outside [0, 1] or NaN (first: {first!r})")
    over = m > 1.0 - eps
    n = int(over.sum())
    return Clamped(np.where(over, 1.0 - eps, m) if n else m, n)


def log_complement(mass: np.ndarray | float) -> np.ndarray:
    """``log(1 - m)`` accurate near 0 and 1: the term a mass adds to L_T or L_N."""
    return np.log1p(-np.asarray(mass, dtype=np.float64))


class TNMasses(NamedTuple):
    """Combined masses on {T, notT} per location; each array has the accumulators' shape."""

    m_t: np.ndarray
    """m({T}) = Bel(T)."""
    m_n: np.ndarray
    """m({notT}); Pl(T) = 1 - m_n."""
    m_theta: np.ndarray
    """m(Theta): ignorance."""
    conflict: np.ndarray
    """bool: both accumulators -inf (total conflict; masses set to 1/2, 1/2, 0)."""

    @property
    def bel(self) -> np.ndarray:
        return self.m_t

    @property
    def pl(self) -> np.ndarray:
        return 1.0 - self.m_n


def closed_form(log_a: np.ndarray | float, log_b: np.ndarray | float) -> TNMasses:
    """Combined {T, notT} masses from the accumulators ``L_T = log a`` and ``L_N = log b``.

    Parameters
    ----------
    log_a, log_b : array_like, any (broadcastable) shape, float64, each <= 0 or -inf
        ``L_T = sum log1p(-c_k)`` and ``L_N = sum log1p(-q_k)``.

    Notes
    -----
    With ``u = 1 - a = -expm1(L_T)``, ``w = 1 - b = -expm1(L_N)`` and the normaliser
    ``D = a + b - ab = a + u b`` (``log D = logaddexp(L_T, L_N + log u)``)::

        m(T) = u b / D,   m(notT) = w a / D,   m(Theta) = a b / D

    each evaluated as ``exp`` of a sum of logs, so no product under- or overflows and no
    ``1 - x`` cancels. ``L_T = L_N = -inf`` (total conflict, impossible with clamped inputs)
    gives 1/2, 1/2, 0 and is flagged in ``conflict``.
    """
    la = np.asarray(log_a, dtype=np.float64)
    lb = np.asarray(log_b, dtype=np.float64)
    if np.any(la > 0.0) or np.any(lb > 0.0) or np.isnan(la).any() or np.isnan(lb).any():
        raise FusionError("log accumulators must be <= 0 (or -inf) and not NaN")
    with np.errstate(divide="ignore", invalid="ignore"):
        log_u = np.log(-np.expm1(la))  # log(1 - a); -inf when a = 1 (no T evidence)
        log_w = np.log(-np.expm1(lb))
        # Everything relative to the larger accumulator M: the masses depend on a and b only
        # through u, w and b / a = exp(L_N - L_T). At |L| >= 2^53 log D = M + log(D / M)
        # rounds back to M (log 2 is lost), so m(T) = m(notT) = 1 (Bel > Pl); at 10^6
        # pieces the lost bits made the masses sum to 1 + 1.8e-9 (issue 21 item 8).
        top = np.maximum(la, lb)
        conflict = np.isneginf(top)  # a = b = 0: total conflict
        top = np.where(conflict, 0.0, top)
        ra = la - top  # log(a / M) <= 0; one of ra, rb is exactly 0
        rb = lb - top
        log_d = np.logaddexp(ra, rb + log_u)  # log((a + (1 - a) b) / M), in [-log 2, log 2]
        m_t = np.exp(log_u + rb - log_d)
        m_n = np.exp(log_w + ra - log_d)
        m_theta = np.exp(np.minimum(la, lb) - log_d)  # a b / D = min(a, b) / (D / M)
    if conflict.any():
        m_t = np.where(conflict, 0.5, m_t)
        m_n = np.where(conflict, 0.5, m_n)
        m_theta = np.where(conflict, 0.0, m_theta)
    return TNMasses(m_t, m_n, m_theta, conflict)


def accumulate(c_t: Iterable[float] | np.ndarray, q_n: Iterable[float] | np.ndarray, *,
               eps: float = 1e-9) -> tuple[float, float, int]:
    """``(L_T, L_N, n_clamped)`` of one location from its T masses ``c_t`` and notT masses ``q_n``.

    The masses are clamped to ``[0, 1 - eps]``, then their log terms summed (``np.sum``).
    """
    ct = clamp_mass(np.asarray(list(c_t) if not isinstance(c_t, np.ndarray) else c_t, dtype=np.float64), eps)
    qn = clamp_mass(np.asarray(list(q_n) if not isinstance(q_n, np.ndarray) else q_n, dtype=np.float64), eps)
    return (float(np.sum(log_complement(ct.mass))), float(np.sum(log_complement(qn.mass))),
            ct.n_clamped + qn.n_clamped)


def to_mass(m: TNMasses, index: int | tuple[int, ...] = ()) -> dict[frozenset, float]:
    """One location of a :class:`TNMasses` as a general mass function on {T, notT}."""
    return {frozenset({T}): float(np.asarray(m.m_t)[index]), frozenset({NOT_T}): float(np.asarray(m.m_n)[index]),
            FRAME_TN: float(np.asarray(m.m_theta)[index])}
