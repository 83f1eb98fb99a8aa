"""Per-range column statistics: background b(j), median m(j), and the leg's tracker (SPEC 2).

The detectors normalise by the per-range background ``b(j)`` (NaN-aware mean of column j
over rows) and use the per-range median ``m(j)`` (matched-filter de-median, SMF
segmentation). Both are computed whole-array: the mean from column sums, the median by one
``np.partition`` of the transposed tile, exact and equal to ``np.nanmedian(pixels, axis=0)``.
Non-finite pixels (NaN, inf) are no data.
"""

from __future__ import annotations

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
    """Per-range background b(j) tracked over a leg's tiles with exponential forgetting.

    ``b <- f b + (1 - f) b_tile`` column by column (SPEC section 2), where ``b_tile`` is the
    NaN-aware column mean of the new tile; a column the tile does not cover keeps its value,
    and a column seen for the first time takes the tile's value. Call :meth:`reset` at the
    start of a leg.

    Parameters
    ----------
    forgetting : float
        f in [0, 1): the weight of the past (``DetectorSettings.background_forgetting``).
    statistic : callable, optional
        The per-column statistic of a tile: :func:`column_mean` for b(j) (default), or
        :func:`column_median` to track the SMF and matched-filter median m(j) the same way.
    """

    def __init__(self, forgetting: float, *, statistic=None) -> None:
        if not 0.0 <= forgetting < 1.0:
            raise AtrError(f"BackgroundTracker: forgetting must be in [0, 1), got {forgetting!r}")
        self.forgetting = float(forgetting)
        self.statistic = column_mean if statistic is None else statistic
        self._b: np.ndarray | None = None

    @property
    def background(self) -> np.ndarray | None:
        """The current b(j), float64 (cols,), or None before the first tile."""
        return None if self._b is None else self._b.copy()

    def reset(self) -> None:
        """Forget everything (a new leg)."""
        self._b = None

    def restore(self, background: np.ndarray | None) -> None:
        """Start from a saved b(j) (a node restarting from its snapshot)."""
        self._b = None if background is None else np.asarray(background, dtype=np.float64).copy()

    def update(self, pixels: np.ndarray) -> np.ndarray:
        """Fold one tile in and return the updated b(j), float64 (cols,).

        Raises
        ------
        AtrError
            The tile's column count differs from the previous tiles' (the leg changed
            geometry without a :meth:`reset`); the tracker is left unchanged.
        """
        b_tile = self.statistic(pixels)
        if self._b is None:
            self._b = b_tile
            return self._b.copy()
        if self._b.shape != b_tile.shape:
            raise AtrError(f"BackgroundTracker: tile has {b_tile.size} columns, the leg so far "
                           f"{self._b.size}; call reset() when the range axis changes")
        f = self.forgetting
        have_tile = np.isfinite(b_tile)
        have_past = np.isfinite(self._b)
        mixed = f * self._b + (1.0 - f) * b_tile
        self._b = np.where(have_tile & have_past, mixed, np.where(have_tile, b_tile, self._b))
        return self._b.copy()
