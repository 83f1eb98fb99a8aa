"""Per-range column statistics: background b(j), median m(j), and the leg's tracker (SPEC 2).

The detectors normalise by the per-range background ``b(j)`` (NaN-aware mean of column j
over rows) and use the per-range median ``m(j)`` (matched-filter de-median, SMF
segmentation). Both are computed whole-array: the mean from column sums, the median by one
``np.partition`` of the transposed tile, exact and equal to ``np.nanmedian(pixels, axis=0)``.
Non-finite pixels (NaN, inf) are no data.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..errors import AtrError


def _check_pixels(pixels: np.ndarray) -> np.ndarray:
    a = np.asarray(pixels)
    if a.ndim != 2:
        raise AtrError(f"pixels: expected a 2-D (rows, cols) array, got shape {a.shape}")
    if a.dtype != np.float32:
        a = a.astype(np.float32)
    return np.ascontiguousarray(a)


def column_mean(pixels: np.ndarray) -> np.ndarray:
    """NaN-aware mean of each column over rows.

    Parameters
    ----------
    pixels : ndarray, shape (rows, cols)
        Ground-range tile; non-finite = no data.

    Returns
    -------
    ndarray of float64, shape (cols,)
        Mean of the valid pixels of each column; NaN for a column without any.
    """
    a = _check_pixels(pixels)
    rows, cols = a.shape
    n = np.zeros(cols, np.int64)
    total = np.zeros(cols)
    # Rows a block at a time (the block's mask and zero-filled copy stay in cache); OpenCV sums
    # the columns in float64, several times faster than numpy's column reductions.
    step = max(1, _MEDIAN_BLOCK_BYTES // (4 * max(cols, 1)))
    for r0 in range(0, rows if cols else 0, step):
        xb = a[r0:r0 + step]
        vb = np.isfinite(xb)
        n += cv2.reduce(vb.view(np.uint8), 0, cv2.REDUCE_SUM, dtype=cv2.CV_32S).reshape(-1)
        clean = xb if vb.all() else np.where(vb, xb, np.float32(0))
        total += cv2.reduce(clean, 0, cv2.REDUCE_SUM, dtype=cv2.CV_64F).reshape(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, total / np.maximum(n, 1), np.nan)


def column_median(pixels: np.ndarray, *, valid_counts: np.ndarray | None = None) -> np.ndarray:
    """NaN-aware median of each column over rows, exactly ``np.nanmedian(pixels, axis=0)``.

    Parameters
    ----------
    pixels : ndarray, shape (rows, cols)
        Ground-range tile; non-finite = no data.
    valid_counts : ndarray, shape (cols,), optional
        Finite pixels per column, when the caller has them already.

    Returns
    -------
    ndarray of float64, shape (cols,)
        The median of the valid pixels of each column (mean of the two middle ones for an even
        count); NaN for a column without valid pixels.

    Notes
    -----
    In a column with n valid and k missing pixels, the missing ones are replaced by k // 2
    copies of -inf and the rest by +inf, so the valid values keep their ranks shifted by k // 2
    and the median sits at ranks k // 2 + (n - 1) // 2 and k // 2 + n // 2. One partition at
    the middle rank and a max / min of its two halves reach every such rank.
    """
    a = _check_pixels(pixels)
    rows, cols = a.shape
    if rows == 0 or cols == 0:
        return np.full(cols, np.nan)
    finite = np.isfinite(a)
    n = cv2.reduce(finite.view(np.uint8), 0, cv2.REDUCE_SUM, dtype=cv2.CV_32S).reshape(-1) \
        if valid_counts is None else np.asarray(valid_counts)
    n = n.astype(np.int64)
    # Rows without any valid pixel (dropped pings) hold no value of any column: leaving them
    # out changes no median, and spares every column the missing-pixel path below (a few
    # dropped pings would otherwise make every column "partly valid").
    keep = None
    per_row = finite.any(axis=1)
    if not per_row.all() and per_row.any():
        keep = np.flatnonzero(per_row)
        rows = keep.size
    k = rows - n
    mid = (rows - 1) // 2
    lo = k // 2 + (n - 1) // 2
    hi = k // 2 + n // 2
    centre, below, above = np.empty(cols), np.full(cols, np.nan), np.full(cols, np.nan)
    # Columns a block at a time: the block's transposed copy stays in cache and reuses memory
    # (a whole transposed copy of a large tile costs more in page faults than the partition).
    step = max(1, _MEDIAN_BLOCK_BYTES // (4 * a.shape[0]))
    for c0 in range(0, cols, step):
        c1 = min(cols, c0 + step)
        # (block cols, rows), each column contiguous; the valid rows only (a gather of whole
        # row pieces, then the transpose)
        at = cv2.transpose(a[:, c0:c1] if keep is None else a[keep, c0:c1])
        if at.ndim == 1:  # OpenCV gives a 1-D array for a single column
            at = at.reshape(1, rows)
        kb = k[c0:c1]
        partial = np.flatnonzero((kb > 0) & (kb < rows))
        if partial.size:
            # Rank of each missing pixel among its column's missing pixels; the first k // 2 go
            # low. Only partly valid columns need it: empty ones give NaN whatever they hold.
            sub = at[partial]
            miss = ~np.isfinite(sub)
            low = (np.cumsum(miss, axis=1, dtype=np.int32) <= (kb[partial] // 2)[:, None]) & miss
            sub[miss] = np.inf
            sub[low] = -np.inf
            at[partial] = sub
        at.partition(mid, axis=1)  # in place: ``at`` is our own transposed copy
        centre[c0:c1] = at[:, mid]
        # The halves only where a rank lies in them (all-valid columns of an even count need
        # only the upper one; columns without data none).
        has = n[c0:c1] > 0
        ranks = np.concatenate([lo[c0:c1][has], hi[c0:c1][has]])
        if (ranks < mid).any():
            below[c0:c1] = at[:, :mid].max(axis=1, initial=-np.inf)
        if (ranks > mid).any():
            above[c0:c1] = at[:, mid + 1:].min(axis=1, initial=np.inf)

    def pick(rank: np.ndarray) -> np.ndarray:
        return np.where(rank < mid, below, np.where(rank > mid, above, centre))

    with np.errstate(invalid="ignore", over="ignore"):
        med = 0.5 * pick(lo) + 0.5 * pick(hi)
    return np.where(n > 0, med, np.nan)


_MEDIAN_BLOCK_BYTES = 1 << 19
"""Size of the transposed block of columns :func:`column_median` partitions at a time."""


class BackgroundTracker:
    """Per-range column statistic b(j) (or m(j)) tracked over a leg with exponential forgetting.

    Two ways to forget (SPEC section 2):

    - ``memory_m`` (what the node uses): per ping, ``f = exp(-dx_m / memory_m)`` for each ping
      that has data in the column, ``b <- f b + (1 - f) x``, so the past fades with the
      distance travelled, not with the number of tiles. For the mean (:func:`column_mean`,
      the default) the update is exactly per ping: N one-ping tiles give what one N-ping tile
      gives, to rounding. A median has no per-ping recursion: with
      :func:`column_median` a tile's median is folded in with the weight of its pings,
      ``m <- f^n m + (1 - f^n) median_tile`` (n = the column's pings with data); the node
      feeds it the strip's fixed units (``node.unit_length_m``), so it too sees the same
      pings in the same groups whatever the tile cut.
    - ``forgetting`` (kept for direct use): ``b <- f b + (1 - f) b_tile`` per update,
      whatever the tile's size.

    A column the tile does not cover keeps its value, and a column seen for the first time
    takes the tile's value (per ping: its first ping's). Call :meth:`reset` at the start of a
    leg.

    Parameters
    ----------
    forgetting : float, optional
        f in [0, 1): the weight of the past per update. Give this or ``memory_m``.
    memory_m : float, optional
        e-folding length along track, metres (``DetectorSettings.background_memory_m``):
        :meth:`update` then needs the tile's ``dx_m``.
    statistic : callable, optional
        The per-column statistic of a tile: :func:`column_mean` for b(j) (default), or
        :func:`column_median` to track the SMF and matched-filter median m(j) the same way.
    """

    def __init__(self, forgetting: float | None = None, *, memory_m: float | None = None, statistic=None) -> None:
        if (forgetting is None) == (memory_m is None):
            raise AtrError("BackgroundTracker: give one of forgetting and memory_m")
        if forgetting is not None and not 0.0 <= forgetting < 1.0:
            raise AtrError(f"BackgroundTracker: forgetting must be in [0, 1), got {forgetting!r}")
        if memory_m is not None and not (np.isfinite(memory_m) and memory_m > 0):
            raise AtrError(f"BackgroundTracker: memory_m must be finite and > 0, got {memory_m!r}")
        self.forgetting = None if forgetting is None else float(forgetting)
        self.memory_m = None if memory_m is None else float(memory_m)
        self.statistic = column_mean if statistic is None else statistic
        self._b: np.ndarray | None = None
        self._w: np.ndarray | None = None
        """Per column, the total weight of the pings folded in (``memory_m`` mean only)."""

    @property
    def background(self) -> np.ndarray | None:
        """The current b(j), float64 (cols,), or None before the first tile."""
        return None if self._b is None else self._b.copy()

    def reset(self) -> None:
        """Forget everything (a new leg)."""
        self._b = None
        self._w = None

    @property
    def weight(self) -> np.ndarray | None:
        """Per column, the weight of the past (``memory_m`` mean; None otherwise or before the
        first tile): saved with :attr:`background` so that a resumed node goes on exactly."""
        return None if self._w is None else self._w.copy()

    def restore(self, background: np.ndarray | None, weight: np.ndarray | None = None) -> None:
        """Start from a saved b(j) (a node restarting from its snapshot) and its weight; a
        snapshot without the weight resumes as far into a leg (``W = 1 / (1 - f)`` at 0.1 m
        pings)."""
        self._b = None if background is None else np.asarray(background, dtype=np.float64).copy()
        if self._b is None or self.memory_m is None or self.statistic is not column_mean:
            self._w = None
        elif weight is not None and np.asarray(weight).shape == self._b.shape:
            self._w = np.asarray(weight, dtype=np.float64).copy()
        else:
            self._w = np.full(self._b.shape, 1.0 / (1.0 - math.exp(-0.1 / self.memory_m)))

    def update(self, pixels: np.ndarray, *, dx_m: float | None = None) -> np.ndarray:
        """Fold one tile in and return the updated b(j), float64 (cols,).

        Parameters
        ----------
        pixels : ndarray, shape (rows, cols)
            The tile's rows in ping order; non-finite = no data.
        dx_m : float, optional
            Ping spacing, metres; needed with ``memory_m``.

        Raises
        ------
        AtrError
            The tile's column count differs from the previous tiles' (the leg changed
            geometry without a :meth:`reset`), or ``dx_m`` is missing or not > 0 with
            ``memory_m``; the tracker is left unchanged.
        """
        a = _check_pixels(pixels)
        if self._b is not None and self._b.shape != (a.shape[1],):
            raise AtrError(f"BackgroundTracker: tile has {a.shape[1]} columns, the leg so far "
                           f"{self._b.size}; call reset() when the range axis changes")
        if self.memory_m is None:
            return self._update_per_tile(a)
        if dx_m is None or not (np.isfinite(dx_m) and dx_m > 0):
            raise AtrError(f"BackgroundTracker: memory_m needs the tile's dx_m > 0, got {dx_m!r}")
        f = math.exp(-float(dx_m) / self.memory_m)
        if self.statistic is column_mean:
            self._b, self._w = _per_ping_mean(a, self._b, self._w, f)
        else:
            self._b = self._per_tile_weighted(a, f)
        return self._b.copy()

    def _update_per_tile(self, a: np.ndarray) -> np.ndarray:
        b_tile = self.statistic(a)
        if self._b is None:
            self._b = b_tile
            return self._b.copy()
        f = self.forgetting
        have_tile = np.isfinite(b_tile)
        have_past = np.isfinite(self._b)
        mixed = f * self._b + (1.0 - f) * b_tile
        self._b = np.where(have_tile & have_past, mixed, np.where(have_tile, b_tile, self._b))
        return self._b.copy()

    def _per_tile_weighted(self, a: np.ndarray, f: float) -> np.ndarray:
        """``m <- f^n m + (1 - f^n) stat(tile)``, n = the column's pings with data."""
        b_tile = self.statistic(a)
        n = np.isfinite(a).sum(axis=0)
        if self._b is None:
            return b_tile
        keep = f ** n
        have_tile = np.isfinite(b_tile)
        have_past = np.isfinite(self._b)
        mixed = keep * self._b + (1.0 - keep) * b_tile
        return np.where(have_tile & have_past, mixed, np.where(have_tile, b_tile, self._b))


def _per_ping_mean(a: np.ndarray, b: np.ndarray | None, w: np.ndarray | None, f: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The exponentially weighted mean per column, ping by ping, skipping no-data pixels:
    ``b = sum_r f^(age_r) x_r / sum_r f^(age_r)`` over every ping seen so far (age in pings).

    Kept as (b, W) with ``W = sum_r f^(age_r)``: a block of rows with the column's valid pixels
    x_0..x_{n-1} in ping order gives ``W' = f^n W + sum_r f^(n-1-r)`` and
    ``b' = (f^n W b + sum_r f^(n-1-r) x_r) / W'``. The normalisation makes a leg's first pings
    their plain mean (not the first ping's speckle), and the recursion composes exactly: N
    one-ping tiles give what one N-ping tile gives, to rounding. Far into a leg ``W -> 1 /
    (1 - f)`` and this is the usual ``b <- f b + (1 - f) x``. Blocks of rows keep the weight
    arrays small.
    """
    rows, cols = a.shape
    out = np.full(cols, np.nan) if b is None else np.asarray(b, dtype=np.float64).copy()
    wt = np.zeros(cols) if w is None else np.asarray(w, dtype=np.float64).copy()
    wt = np.where(np.isfinite(out), wt, 0.0)
    step = max(1, _MEDIAN_BLOCK_BYTES // (8 * max(cols, 1)))
    for r0 in range(0, rows, step):
        xb = a[r0:r0 + step].astype(np.float64)
        valid = np.isfinite(xb)
        n = valid.sum(axis=0)
        rank = np.cumsum(valid, axis=0) - 1  # the pixel's place among its column's valid ones
        wr = np.where(valid, np.power(f, n - 1 - rank), 0.0)
        s = np.where(valid, xb, 0.0)
        s *= wr
        s = s.sum(axis=0)
        sw = wr.sum(axis=0)
        decay = np.power(f, n)
        w_new = decay * wt + sw
        past = np.where(np.isfinite(out), out, 0.0) * wt * decay
        upd = n > 0
        out = np.where(upd, (past + s) / np.where(upd, w_new, 1.0), out)
        wt = np.where(upd, w_new, wt)
    return out, wt
