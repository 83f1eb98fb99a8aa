"""Detections of one detector: threshold, 8-connected components, size filter, peak (SPEC 3).

``gamma_d > tau_d`` -> 8-connected components -> drop components whose extent in range or
along-track (metres) is outside ``[min, max]`` -> one detection per remaining component at its
pixel of maximum gamma (ties: the first pixel in row-major order). NaN scores never detect.

How, and why this way: a score map of a tile holds about 1.5 Mpx of which well under 1 %
exceed a calibrated threshold, clustered in a few hundred rows and columns. Labelling the
whole map with statistics (``cv2.connectedComponentsWithStats``) cost about 10 ms per map,
most of it in the statistics pass, and the peak search gathered over the whole map. Here:

1. rows and columns with no exceedance are collapsed, each run of them to one empty line
   (:func:`collapse_empty`); this keeps 8-connectivity and every component's extent exactly;
2. the small image is labelled without statistics (``cv2.connectedComponents``);
3. bounding boxes, areas and peaks are reduced over the exceeding pixels only (a list in
   row-major order), with ``np.minimum.at`` / ``np.maximum.at`` and ``np.bincount``.

``tests/detectors/test_extract.py`` checks the result equal, field for field and in order,
to a plain ``scipy.ndimage.label`` reference; ``tools/bench/detectors.py extract`` measures the speed.
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
    length_m: float | None = None
    """Extended object only (:mod:`.objects`): length of its long axis, metres; else None."""
    width_m: float | None = None
    """Extended object only: its extent across the long axis, metres."""
    axis_deg: float | None = None
    """Extended object only: direction of the long axis in the tile, degrees in [-90, 90):
    0 along-track (increasing rows), +90 towards increasing range."""
    joint: tuple[tuple[str, float], ...] | None = None
    """Every enabled detector's response around this detection: (detector, maximum score over
    the template window of the anchor, NaN where it covered none), for look-level evidence
    (SPEC 6.1); None until the detect stage fills it in."""
    patch: int = 0
    """Textured patch of its unit the anchor lies in (:mod:`.objects`: a patch gives one look,
    at its strongest place), numbered from 1 per unit; 0 none."""
    headroom_db: float = math.inf
    """How far the seabed's mean intensity at the anchor's range lies below the recording's full
    scale, dB (:func:`~atr_node.calibration.looks.headroom_db`; inf: unknown or float data):
    where it is small the recording clips a target's echo, and the look is scored with the
    clipped places' likelihood ratios (SPEC 6.1, docs/fusion.md); set with ``joint``."""


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
        hot = g > tau  # in g's dtype, as the SPEC states it; NaN compares False
    if g.size == 0 or not hot.any():
        return []
    small, row_of, col_of = collapse_empty(hot)
    n, labels = cv2.connectedComponents(small.view(np.uint8), connectivity=8, ltype=cv2.CV_32S)
    # The exceeding pixels, in row-major order of the small image, hence of the map (row_of
    # and col_of are increasing).
    pix = np.flatnonzero(small)
    lab = labels.reshape(-1)[pix].astype(np.intp)  # intp indices: the fast path of ufunc.at
    r, c = np.divmod(pix, small.shape[1])
    if small is not hot:
        r, c = row_of[r], col_of[c]
    # Bounding boxes and areas of components 1..n-1 (label 0, the background, has no pixel).
    big = np.iinfo(np.intp).max
    r0, r1 = np.full(n, big), np.full(n, -1)
    c0, c1 = np.full(n, big), np.full(n, -1)
    np.minimum.at(r0, lab, r)
    np.maximum.at(r1, lab, r)
    np.minimum.at(c0, lab, c)
    np.maximum.at(c1, lab, c)
    area = np.bincount(lab, minlength=n)
    width_m = (c1 - c0 + 1) * dr_m
    height_m = (r1 - r0 + 1) * dx_m
    # A relative slack keeps a component of exactly min or max metres (k * dr in floating point).
    tol = 1e-9 * max_extent_m
    keep = ((width_m >= min_extent_m - tol) & (width_m <= max_extent_m + tol)
            & (height_m >= min_extent_m - tol) & (height_m <= max_extent_m + tol))
    keep[0] = False
    if not keep.any():
        return []
    sel = np.flatnonzero(keep[lab])
    lab, r, c = lab[sel], r[sel], c[sel]
    val = g.reshape(-1)[r * g.shape[1] + c].astype(np.float64)
    # Peak: the largest gamma of the component, and of the pixels holding it the first one in
    # row-major order, i.e. the smallest position in this (row-major) list.
    top = np.full(n, -np.inf)
    np.maximum.at(top, lab, val)
    at_top = np.flatnonzero(val == top[lab])
    first = np.full(n, big)
    np.minimum.at(first, lab[at_top], at_top)
    peak = np.sort(first[keep])  # list positions are row-major: sorted by (row, col) of the peak
    return [Detection(detector=detector, row=int(pr), col=int(pc), gamma=float(v), range_m=float(range0_m + pc * dr_m),
                      extent_range_m=float(width_m[k]), extent_along_m=float(height_m[k]), n_pixels=int(area[k]))
            for pr, pc, v, k in zip(r[peak], c[peak], val[peak], lab[peak])]


def collapse_empty(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shrink a mask by collapsing each run of empty rows, and of empty columns, to one line.

    Exact for 8-connected components: pixels in adjacent non-empty rows (columns) stay
    adjacent, and pixels separated by at least one empty row (column) stay separated by one.
    A component lies within one run of non-empty rows and one of non-empty columns, each of
    which keeps its length, so its extent, area and the row-major order of its pixels are
    unchanged. Leading and trailing empty lines are dropped (a crop to the content).

    Parameters
    ----------
    mask : ndarray of bool, shape (rows, cols)
        With at least one True pixel.

    Returns
    -------
    small : ndarray of bool, shape (h, w)
        The collapsed mask, or ``mask`` itself when it has no empty line to collapse.
    row_of : ndarray of intp, shape (h,)
        Row of ``mask`` of each row of ``small`` (a separator: the first empty row of its run).
    col_of : ndarray of intp, shape (w,)
        Likewise for columns.
    """
    rows, row_pos = _kept_lines(mask.any(axis=1))
    cols, col_pos = _kept_lines(mask.any(axis=0))
    h, w = int(row_pos[-1]) + 1, int(col_pos[-1]) + 1
    if h * w == mask.size:
        return mask, np.arange(mask.shape[0]), np.arange(mask.shape[1])
    row_of, col_of = _line_map(rows, row_pos, h), _line_map(cols, col_pos, w)
    # a separator maps to an empty line of the mask, so two takes build the small image
    return mask.take(row_of, axis=0).take(col_of, axis=1), row_of, col_of


def _kept_lines(non_empty: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the non-empty lines, and their positions once every gap is one line wide."""
    idx = np.flatnonzero(non_empty)
    gap = np.empty(idx.size, dtype=np.intp)
    gap[0] = 0
    gap[1:] = np.diff(idx) > 1  # a run of empty lines before this one
    return idx, np.arange(idx.size) + np.cumsum(gap)


def _line_map(idx: np.ndarray, pos: np.ndarray, size: int) -> np.ndarray:
    """Original index of every line of the collapsed image (separators: one past the line before)."""
    out = np.empty(size, dtype=np.intp)
    out[pos] = idx
    sep = np.setdiff1d(np.arange(size), pos, assume_unique=True)
    out[sep] = out[sep - 1] + 1  # a separator always follows a kept line
    return out


def place_at_peak(found: list[Detection], reference: np.ndarray, *, row0: int, length_px: int, echo_px: int,
                  shadow_px: np.ndarray, range0_m: float, dr_m: float) -> list[Detection]:
    """``found`` with each point detection moved to the peak of ``reference`` (another
    detector's score map, the matched filter's) within its template window: rows
    ``[i + row0, i + row0 + length_px)``, columns ``[j - echo_px, j + shadow_px[j])``, clipped
    to the map (``detectors.relocate``, docs/detectors.md "Where a detection is placed").

    Only the place moves (``row``, ``col``, ``range_m``); the score, extent and joint responses
    stay those of the detection. A detection stays where it is when the window holds no finite
    reference score or its peak is not positive (no echo brighter than its shadow), and an
    extended object (``length_m`` set) keeps its centre. Ties: the first pixel in row-major order.
    """
    if not found:
        return found
    import dataclasses

    from .windows import window_bounds

    ref = np.asarray(reference)
    cols = ref.shape[1]
    out = []
    for x in found:
        if x.length_m is not None:
            out.append(x)
            continue
        j = min(max(int(x.col), 0), cols - 1)
        r0, r1, c0, c1 = window_bounds(ref.shape, int(x.row), j, row0=row0, length_px=length_px, echo_px=echo_px,
                                       shadow_px=int(shadow_px[j]))
        w = ref[r0:r1, c0:c1] if r0 < r1 and c0 < c1 else ref[:0, :0]
        finite = np.isfinite(w)
        if not finite.any():
            out.append(x)
            continue
        k = int(np.argmax(np.where(finite, w, -np.inf)))  # argmax: the first of equal maxima
        if not float(w.flat[k]) > 0.0:
            out.append(x)
            continue
        dr, dc = divmod(k, w.shape[1])
        col = c0 + dc
        out.append(dataclasses.replace(x, row=r0 + dr, col=col, range_m=float(range0_m + col * dr_m)))
    return out
