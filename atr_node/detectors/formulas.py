"""The four detector statistics, from window sums (SPEC section 2).

Each detector is a pure function of the box sums of its windows around the anchor (echo zone
E, shadow zone S, SMF context window C; see :mod:`.windows`), for a block of anchors at once.
The engine (:mod:`.engine`, :mod:`.reader`) computes exactly the sums the enabled detectors
list in :data:`NEEDS`; a window with fewer valid pixels than ``min_valid_fraction`` of its
area has a NaN reciprocal count, so every score using it is NaN (the windows a detector uses
are listed in :data:`WINDOWS`).

Sums available (``n_*`` valid-pixel counts, ``a_*`` nominal window areas in pixels)::

    p_E, p_S    sums of p = I_n - 1 over the valid pixels (I_n = I / b(j), centred on its
                expected mean 1 so the tables stay small and keep their digits)
    p2_S        sum of p^2 over the valid pixels of S
    j_E, j_S    sums of J = I_n - median_j(I_n) (matched filter)
    g_E, g_S    sums of 2 * segment code (integers; SMF)
    ag_C        sum of |2 * segment code| over C (integers; SMF)

References
----------
.. [1] J. Myers and O. Midtgaard, "Fusion of contacts in synthetic aperture sonar imagery
   using performance estimates", section 2.
"""

from __future__ import annotations

from typing import Callable, Mapping

import cv2
import numpy as np

from ..config import DetectorSettings

Sums = Mapping[str, np.ndarray]


class WindowMeans:
    """Means over the windows of a block of anchors, each computed once, on first use.

    Parameters
    ----------
    sums : mapping of str to ndarray, each shape (block rows, anchor cols)
        Box sums named ``<table>_<window>`` (see the module docstring).
    recip : mapping of str to ndarray
        Per window ("E", "S", "C"): 1 / valid count, NaN where the window has fewer valid
        pixels than ``min_valid_fraction`` of its area, so every statistic of that window, and
        every score that uses it, comes out NaN with no further masking.
    derived : mapping of str to (str, ndarray), optional
        Means obtained from another table's plus a per-column offset, e.g. the matched
        filter's J = I_n - median(I_n) from p = I_n - 1 when no data fills whole columns.
    """

    def __init__(self, sums: Sums, recip: Mapping[str, np.ndarray],
                 derived: Mapping[str, tuple[str, np.ndarray]] | None = None) -> None:
        self.sums = sums
        self.recip = recip
        self.derived = derived or {}
        self._cache: dict[str, np.ndarray] = {}

    def mean(self, table: str, window: str) -> np.ndarray:
        """Mean of ``table`` over ``window``: a box sum times 1 / count, or, for a key in
        ``derived`` = {key: (other table, offset)}, the other table's mean plus the offset."""
        key = f"{table}_{window}"
        if key not in self._cache:
            if key in self.derived:
                other, offset = self.derived[key]
                self._cache[key] = self.mean(other, window) + offset
            else:
                self._cache[key] = self.sums[key] * self.recip[window]
        return self._cache[key]

    def const(self, value: float) -> np.ndarray:
        """A broadcast row of ``value``: numpy's maximum runs about twice as fast against an
        array as against a scalar."""
        key = f"const_{value!r}"
        if key not in self._cache:
            cols = next(iter(self.sums.values())).shape[1] if self.sums else 1
            self._cache[key] = np.full((1, cols), value)
        return self._cache[key]

    def contrast(self, table: str, out: np.ndarray | None = None) -> np.ndarray:
        """mean(table, E) - mean(table, S), computed once (or written into ``out``, uncached).

        A derived table reuses its source's contrast plus the difference of the two offsets:
        one operation instead of three.
        """
        key = f"contrast_{table}"
        if key in self._cache:
            if out is None:
                return self._cache[key]
            np.copyto(out, self._cache[key])
            return out
        src_e, src_s = self.derived.get(f"{table}_E"), self.derived.get(f"{table}_S")
        if src_e is not None and src_s is not None and src_e[0] == src_s[0]:
            value = np.add(self.contrast(src_e[0]), src_e[1] - src_s[1], out=out)
        else:
            value = np.subtract(self.mean(table, "E"), self.mean(table, "S"), out=out)
        if out is None:
            self._cache[key] = value
        return value

    def shadow_variance(self) -> np.ndarray:
        """Population variance of I_n over S: E[p^2] - E[p]^2 (shift-invariant), floored at 0."""
        if "var_S" not in self._cache:
            mean_p = self.mean("p", "S")
            var = self.mean("p2", "S") - mean_p * mean_p
            self._cache["var_S"] = np.maximum(var, self.const(0.0), out=var)
        return self._cache["var_S"]


def matched_filter(w: WindowMeans, settings: DetectorSettings, out: np.ndarray | None = None) -> np.ndarray:
    """SPEC 2.1: gamma = mean(J, E) - mean(J, S), J = I_n - median(I_n) per column.

    The +1/-1 mask, area-normalised: echo brighter than the per-range median scores positive,
    a shadow darker than it adds to the score.
    """
    return w.contrast("j", out=out)


def lacunarity(w: WindowMeans, settings: DetectorSettings, out: np.ndarray | None = None) -> np.ndarray:
    """SPEC 2.2: gamma = var(I_n, S) / max(mean(I_n, S)^2, floor).

    The floor is ``lacunarity_floor`` times the squared background, which is 1 in I_n units,
    so a window of exact zeros gives 0 / floor = 0 instead of 0 / 0.
    """
    mean = w.mean("p", "S") + 1.0
    mean *= mean
    return np.divide(w.shadow_variance(), np.maximum(mean, w.const(settings.lacunarity_floor), out=mean), out=out)


def segmented_matched_filter(w: WindowMeans, settings: DetectorSettings,
                             out: np.ndarray | None = None) -> np.ndarray:
    """SPEC 2.3: gamma = (mean(seg, E) - mean(seg, S)) / (1 + 10 mean(|seg|, C)).

    Segment codes are held doubled (integers -2..2): the doubled contrast over
    2 + 10 mean(|2 seg|) is the same ratio. The denominator is >= 1 (>= 2 doubled) because it
    averages |seg| (SPEC 2.3 explains why not the signed mean).
    """
    den = w.sums["ag_C"] * (10.0 * w.recip["C"])
    den += 2.0
    return np.divide(w.contrast("g"), den, out=out)


def mean_test(w: WindowMeans, settings: DetectorSettings, out: np.ndarray | None = None) -> np.ndarray:
    """SPEC 2.4: z = (mu1 - mu2) / max(sigma2, floor) on I_n; mu1 over E, mu2 and sigma2 over S.

    The floor is ``sigma_floor`` times the background (1 in I_n units): a shadow window of
    exact zeros gives a large but finite z.
    """
    var = w.shadow_variance()
    sigma = cv2.sqrt(var) if var.dtype == np.float64 else np.sqrt(var)  # cv2's is vectorised
    return np.divide(w.contrast("p"), np.maximum(sigma, w.const(settings.sigma_floor), out=sigma), out=out)


FORMULAS: dict[str, Callable[..., np.ndarray]] = {
    "mf": matched_filter,
    "lac": lacunarity,
    "smf": segmented_matched_filter,
    "z": mean_test,
}
"""Detector name -> statistic ``f(means, settings, out=None)``, in the order of
``atr_node.config.DETECTOR_NAMES``; ``out`` receives the scores when given."""

NEEDS: dict[str, tuple[str, ...]] = {
    "mf": ("n_E", "n_S", "j_E", "j_S"),
    "lac": ("n_S", "p_S", "p2_S"),
    "smf": ("n_E", "n_S", "n_C", "g_E", "g_S", "ag_C"),
    "z": ("n_E", "n_S", "p_E", "p_S", "p2_S"),
}
"""The window sums each detector reads; nothing else is computed for it."""

WINDOWS: dict[str, tuple[str, ...]] = {
    "mf": ("E", "S"),
    "lac": ("S",),
    "smf": ("E", "S", "C"),
    "z": ("E", "S"),
}
"""The windows whose valid fraction decides whether a detector scores or gives NaN."""
