"""Detections of one detector: threshold, 8-connected components, size filter, peak (SPEC 3).

``gamma_d > tau_d`` -> 8-connected components (``cv2.connectedComponentsWithStats``) -> drop
components whose extent in range or along-track (metres) is outside ``[min, max]`` -> one
detection per remaining component at its pixel of maximum gamma. NaN scores never detect.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import AtrError


@dataclass(frozen=True)
class Detection:
    """One detection of one detector: a thresholded component, at its peak (SPEC section 3)."""

    detector: str
    row: int
    """Row (ping) of the component's maximum gamma, in the score map."""
    col: int
    """Column of the component's maximum gamma: the anchor (echo/shadow boundary)."""
    gamma: float
    """The component's maximum score."""
    range_m: float
    """Ground range of ``col``."""
    extent_range_m: float
    """Component bounding-box width across-track, metres."""
    extent_along_m: float
    """Component bounding-box length along-track, metres."""
    n_pixels: int
    """Pixels in the component."""


def find_detections(score: np.ndarray, tau: float, *, detector: str, range0_m: float, dr_m: float,
                    dx_m: float, min_extent_m: float, max_extent_m: float) -> list[Detection]:
    """Detections of one score map (SPEC section 3).

    Parameters
    ----------
    score : ndarray, shape (rows, cols)
        gamma_d, NaN where not scored.
    tau : float
        Threshold: pixels with ``gamma > tau`` are candidates.
    detector : str
        Name written into each detection.
    range0_m, dr_m, dx_m : float
        Ground range of column 0, column and row spacing, metres.
    min_extent_m, max_extent_m : float
        A component is kept when its extent in range (columns x dr) and along-track
        (rows x dx) both lie in ``[min_extent_m, max_extent_m]``.

    Returns
    -------
    list of Detection
        Ordered by row, then column, of the peak; ties for the peak go to the first pixel in
        row-major order.

    Raises
    ------
    AtrError
        A score that is not 2-D, or a non-finite threshold.
    """
    g = np.asarray(score)
    if g.ndim != 2:
        raise AtrError(f"find_detections({detector}): score must be 2-D (rows, cols), got shape {g.shape}")
    if not math.isfinite(tau):
        raise AtrError(f"find_detections({detector}): threshold tau must be finite, got {tau!r}")
    with np.errstate(invalid="ignore"):
        hot = g > tau
    if g.size == 0 or not hot.any():
        return []
    n, labels, stats, _ = cv2.connectedComponentsWithStats(hot.view(np.uint8), connectivity=8,
                                                           ltype=cv2.CV_32S)
    width_m = stats[:, cv2.CC_STAT_WIDTH] * dr_m
    height_m = stats[:, cv2.CC_STAT_HEIGHT] * dx_m
    # A relative slack keeps a component of exactly min or max metres (k * dr in floating point).
    tol = 1e-9 * max_extent_m
    keep = ((width_m >= min_extent_m - tol) & (width_m <= max_extent_m + tol)
            & (height_m >= min_extent_m - tol) & (height_m <= max_extent_m + tol))
    keep[0] = False  # label 0 is the background
    if not keep.any():
        return []
    flat = np.flatnonzero(keep[labels.reshape(-1)])
    lab = labels.reshape(-1)[flat]
    val = g.reshape(-1)[flat].astype(np.float64)
    # Peak per component: sort by label, then by decreasing gamma, then by pixel index.
    order = np.lexsort((flat, -val, lab))
    first = order[np.unique(lab[order], return_index=True)[1]]
    peaks = flat[first]
    rows, cols = np.divmod(peaks, g.shape[1])
    out = [Detection(detector=detector, row=int(r), col=int(c), gamma=float(v), range_m=float(range0_m + c * dr_m),
                     extent_range_m=float(width_m[k]), extent_along_m=float(height_m[k]),
                     n_pixels=int(stats[k, cv2.CC_STAT_AREA]))
           for r, c, v, k in zip(rows, cols, val[first], lab[first])]
    out.sort(key=lambda d: (d.row, d.col))
    return out
