"""Seabed objects in a unit's normalised image: one detection per extended object, bands as background.

The detectors look for a mine-sized echo and shadow (SPEC sections 1-3). On a wreck they fire
all along its edges, each component a detection of its own, and the fusion turns them into
dozens of contacts; components longer than ``max_extent_m`` are dropped, so what is left of
the wreck is its scattered small pieces. Here the unit's image is segmented into objects
where the evidence is, and the detections are regrouped (:func:`group_detections`):

1. ``I_n = I / b(j)`` (the detectors' normalised image), averaged over cells of about half
   the template's echo width (``cell_m``) and smoothed by a Gaussian of one cell;
2. highlight: ``> object_highlight x m``, grown by hysteresis (``HYSTERESIS``); shadow:
   ``< object_shadow x m``; ``m`` the median of the unit's cells (the seabed level, robust
   while objects cover under half of the unit);
3. a range column bright on ``BAND_FRACTION`` of the unit's rows, in ``I_n`` or in the
   intensities against their range trend, is a band at constant range: background; its
   level is raised to the band's, so a band cannot join an object (dark bands likewise);
4. highlight or shadow, closed morphologically over ``CLOSE_LENGTHS`` template lengths, 8-connected: an object's
   echo and its shadow are one component, so the broken outline of a hull is one object;
5. per component, the extent from its highlight cells only (the shadow is not the object):
   centroid, long-axis direction from the second moments, length and width as the spread
   of the cells along and across that axis (plus one cell). The steps below decide on all
   of them; an extended object's reported extent and centre come from its echo only
   (:func:`_echo`: the highlight cells in front of its shadow, over the rows the shadow
   covers), since bright seabed past the shadow joins the component through it;
6. an object needs a shadow at the coarse scale (``I_n`` smoothed by a Gaussian of
   :data:`COARSE_LENGTHS` template lengths below the shadow level somewhere in its
   component): over that scale seabed texture (ripples, rock, sand waves) averages out, so a
   textured patch, however bright, is seabed and its detections stay as they are (a target
   in a ripple field keeps its own); the shadow of a hull metres across does not. And the
   component must hold acoustic shadow: at least :data:`SHADOW_SHARE` of its smoothed cells
   below :data:`SHADOW_DEPTH` of the shadow level (no echo at all). Dark seabed (mud, dark sand in
   the SASSED textures) passes the coarse test, but is -5 to -8 dB, not -10 dB and below;
   without this test nearly every unit of one such scene was a 30-60 m object;
7. an object (one that passed step 6) at least ``2 x template.length_m`` long is
   **extended**; one longer than ``max_object_length_m``, or a narrow one within ``BAND_AXIS_DEG`` of the track that spans
   the whole unit or lies along a band column (a band at constant range, drifting with the
   altitude), is **background**;
8. a component without a coarse shadow (step 6; dark seabed is not one), at least
   ``2 x template.length_m`` and at most ``max_object_length_m`` long, is a **textured
   patch** (a rock pile, a mound, a patch of coarse sand). Its detections stay as they are,
   marked with the patch (``Detection.patch``) only with ``detectors.patch_one_look`` (off by
   default): the evidence then takes one look per patch, at its strongest place
   (``node/evidence.py``). A declutter option, not the default: on the held-out generator's
   development seeds (201-202) it halved the false alarms (450 to 229) but lost 8 of 94
   targets, a target in a SASSED patch beside a stronger texture feature; on the river
   recording it makes a rocky mound one contact, not eight (docs/detectors.md).

A detection whose anchor lies in an extended object (its component, dilated by
``MARGIN_LENGTHS`` template lengths) joins it: the object gives ONE detection per detector, with the gamma of the
strongest, placed at the object's centroid (the centre of its highlight) and carrying the
extent. Why the centre and not the strongest anchor: on a wreck the anchors lie on its edges
(the echo/shadow boundary), metres from the object and from each other depending on the
detector; the centre is the same for every detector and every look, so the looks of one
wreck deposit their evidence at one place, and it is what an operator sends a vehicle to.
Only the unit whose core holds the centre emits the object; a neighbour that sees it with
its centre in a margin drops it (clamped into its core it was a second contact, a few metres
off, depending on where the tiles were cut). A wreck longer than a unit's margins is still
seen in pieces, one per unit, each centred in its own core: the contacts join them
(``fusion/contacts.py``, footprints that overlap or touch are one contact).
Detections in background objects are dropped; all others are kept as
:func:`~.extract.find_detections` gives them (extent filter ``[min_extent_m, max_extent_m]``
included: detections are extracted without the upper bound, which is applied here, so a
component too long for a mine still counts when it lies on a wreck).

The cost is two passes over the unit's pixels (``I_n`` and the intensities' block sums: the
band test reads the intensities themselves) and a few operations on the cells: about 17 ms
per 1.5-Mpx unit on one core (docs/detectors.md), spent only on units where a detector has a
detection (``node/detect.py``).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace
from typing import Sequence

import cv2
import numpy as np
from scipy import ndimage

from .extract import Detection

BAND_FRACTION = 0.8
"""A range column that is highlight on this fraction of the unit's rows is a band."""
BAND_AXIS_DEG = 15.0
"""An object spanning the unit along-track within this angle of the track is a band."""
HYSTERESIS = 0.3
"""A cell this far (0: seabed, 1: the highlight level) that touches a highlight is one."""
CLOSE_LENGTHS = 1.0
"""Gaps of up to about this many template lengths between the highlight and shadow pieces of
an object are closed (the near and far rims of a hull, its shadow)."""
COARSE_LENGTHS = 0.5
"""Sigma of the coarse scale, in template lengths: an extended object has a shadow there (a
patch of ripples, rock or sand waves is bright and dark on a finer scale, so it has none)."""
SHADOW_DEPTH = 1.0 / 3.0
"""An acoustic shadow cell: its mean ``I_n`` below this fraction of the shadow level (0.1 x the
seabed's with the default ``object_shadow`` 0.3, -10 dB): no echo at all, not dark seabed."""
SHADOW_SHARE = 0.02
"""An extended object's component holds at least this share of acoustic shadow cells (smoothed
``I_n``; the Iver2 wreck 9.5 %, numpy hulls and their pieces 33-36 %; dark patches of SASSED
texture, which pass the coarse test, at most 0.1 %, a numpy patchwork of dark seabed 0.3 %)."""
MARGIN_LENGTHS = 0.5
"""A detection anchored this many template lengths from an object belongs to it."""


@dataclass(frozen=True)
class SeabedObject:
    """One object of a unit (its highlight cells), in the unit's pixel coordinates."""

    row: float
    """Centroid row (fractional, in the unit's rows)."""
    col: float
    """Centroid column (fractional)."""
    length_m: float
    """Extent along the long axis."""
    width_m: float
    """Extent across the long axis."""
    axis_deg: float
    """Long axis in the tile, in [-90, 90): 0 along-track (increasing rows), +90 towards
    increasing range."""
    extent_along_m: float
    """Bounding box of the highlight along-track."""
    extent_range_m: float
    """Bounding box of the highlight across-track."""
    n_pixels: int
    """Pixels of the highlight cells."""
    background: bool
    """Too long, or a band at constant range: its detections are dropped."""


@dataclass(frozen=True, eq=False)
class ObjectMap:
    """Extended and background objects of one unit, and which cells belong to them."""

    owner: np.ndarray
    """int32 (cells rows, cells cols): 0 none, k > 0 ``objects[k - 1]`` (dilated), -1 a band column."""
    block: tuple[int, int]
    """Pixels per cell (rows, cols)."""
    objects: tuple[SeabedObject, ...]
    shape: tuple[int, int]
    """The unit's pixels (rows, cols)."""
    patch: np.ndarray | None = None
    """int32 (cells rows, cells cols): k > 0 where textured patch k lies (step 8), 0 elsewhere;
    None: no patch."""

    def _cells(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cell (row, col) of unit pixels (rows, cols), clipped to the cell grid."""
        fy, fx = self.block
        h, w = self.owner.shape
        return (np.clip(np.asarray(rows, dtype=np.intp) // fy, 0, h - 1),
                np.clip(np.asarray(cols, dtype=np.intp) // fx, 0, w - 1))

    def patch_at(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Patch (as in ``patch``, 0 none) of unit pixels (rows, cols)."""
        if self.patch is None:
            return np.zeros(np.shape(rows), np.int32)
        return self.patch[self._cells(rows, cols)]

    def owner_at(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Owner (as in ``owner``) of unit pixels (rows, cols)."""
        return self.owner[self._cells(rows, cols)]


def find_objects(pixels: np.ndarray, background: np.ndarray, *, dr_m: float, dx_m: float,
                 template_length_m: float, echo_width_m: float, highlight: float, shadow: float,
                 max_length_m: float) -> ObjectMap:
    """Extended and background objects of one unit (see the module docstring).

    Parameters
    ----------
    pixels : ndarray, shape (rows, cols)
        The unit's ground-range intensities (margins included), NaN where no data.
    background : ndarray, shape (cols,)
        b(j), the per-range background the detectors normalise by.
    dr_m, dx_m : float
        Column and row spacing, metres.
    template_length_m, echo_width_m : float
        The target template (``TemplateSettings``): an object at least twice its length is
        extended; cells are about half its echo width.
    highlight, shadow : float
        Levels, as multiples of the unit's median cell.
    max_length_m : float
        Longer objects are background.

    Returns
    -------
    ObjectMap
    """
    x = np.asarray(pixels, dtype=np.float32)
    rows, cols = x.shape
    cell_m = 0.5 * echo_width_m
    fy, fx = max(1, round(cell_m / dx_m)), max(1, round(cell_m / dr_m))
    cy, cx = fy * dx_m, fx * dr_m
    h, w = -(-rows // fy), -(-cols // fx)
    if rows == 0 or cols == 0:
        return ObjectMap(np.zeros((h, w), np.int32), (fy, fx), (), (rows, cols))
    b = np.asarray(background, dtype=np.float32).reshape(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        inv_b = np.where(np.isfinite(b) & (b > 0), 1.0 / b, np.nan).astype(np.float32)
    # block sums of I_n and of the valid count, on a zero-padded copy (one pass each)
    xn = np.zeros((h * fy, w * fx), np.float32)
    np.multiply(x, inv_b[None, :], out=xn[:rows, :cols])
    valid = np.isfinite(xn)
    valid[rows:, :] = False  # the padding is no data (it filled the last cells with zeros)
    valid[:, cols:] = False
    xn[~valid] = 0.0
    # block means (INTER_AREA with whole factors: the mean of each fy x fx block, in C)
    s = cv2.resize(xn, (w, h), interpolation=cv2.INTER_AREA)
    n = cv2.resize(valid.view(np.uint8).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    ok = n >= 0.5
    if not ok.any():
        return ObjectMap(np.zeros((h, w), np.int32), (fy, fx), (), (rows, cols))
    mean = np.where(ok, s / np.maximum(n, 1e-6), 0.0).astype(np.float32)
    level = float(np.median(mean[ok]))
    if not level > 0:
        return ObjectMap(np.zeros((h, w), np.int32), (fy, fx), (), (rows, cols))
    mean[~ok] = level  # no data reads as seabed
    sm = cv2.GaussianBlur(mean, (0, 0), 1.0, borderType=cv2.BORDER_REFLECT)
    # 3. bands at constant range: a column's level is the larger of the unit's and the one it
    # exceeds on BAND_FRACTION of its rows, so a band is flattened (and an object on it is
    # measured against the band); only in a unit long enough that an object cannot fill it
    long_enough = ok.sum(axis=0) * cy >= 4 * template_length_m
    q_lo, q_hi = np.quantile(sm, (1.0 - BAND_FRACTION, BAND_FRACTION), axis=0)
    # b(j) follows a band that stays put, so a band shows in I_n only where it drifts: bands
    # are found in the intensities themselves (their cell means, smoothed as I_n is), against
    # their median over +-4 template lengths of range (the range trend of the seabed: gains,
    # beam pattern). Not as I_n times b(j): b(j) is a mean, and one bright target raises it in
    # its own columns, so smoothed I_n times that b(j) made the target's column a "band"
    xr = np.zeros((h * fy, w * fx), np.float32)
    np.copyto(xr[:rows, :cols], x, where=valid[:rows, :cols])
    raw = np.where(ok, cv2.resize(xr, (w, h), interpolation=cv2.INTER_AREA) / np.maximum(n, 1e-6), np.nan)
    gaps = np.flatnonzero(~ok.all(axis=0))  # columns with no-data cells (the median costs 3 ms a unit)
    if gaps.size:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a column without data: the unit's median
            col_level = np.nanmedian(raw[:, gaps], axis=0)
        col_level = np.where(np.isfinite(col_level), col_level, np.median(raw[ok]))
        raw[:, gaps] = np.where(ok[:, gaps], raw[:, gaps], col_level[None, :])  # no data reads as its column's seabed
    raw = raw.astype(np.float32)
    # smoothed along track only: a column's quantile needs no smoothing across range, and a
    # narrow band (a few cells wide) keeps its level
    raw = ndimage.gaussian_filter1d(raw, 1.0, axis=0, mode="reflect")
    q_raw, med_raw = np.quantile(raw, (1.0 - BAND_FRACTION, 0.5), axis=0)
    trend = ndimage.median_filter(med_raw, size=2 * round(4 * template_length_m / cx) + 1, mode="nearest")
    band = long_enough & ((q_lo > highlight * level) | (q_raw > highlight * trend))
    bright_level = np.where(long_enough, np.maximum(q_lo, level), level)[None, :]
    hi = ok & (sm > highlight * bright_level)
    # hysteresis: cells above HYSTERESIS of the way from the seabed to the highlight level
    # that touch a highlight are highlight too (the dimmer parts of a hull between its rims)
    weak = (ok & (sm > (1.0 + HYSTERESIS * (highlight - 1.0)) * bright_level)).view(np.uint8)
    n_weak, weak_lab = cv2.connectedComponents(weak, connectivity=8, ltype=cv2.CV_32S)
    seeded = np.zeros(n_weak, bool)
    seeded[weak_lab[hi]] = True
    seeded[0] = False
    hi = seeded[weak_lab]
    # likewise a dark band (the water column next to the nadir) is flattened, not a shadow
    shadow_level = shadow * np.where(long_enough, np.minimum(q_hi, level), level)[None, :]
    lo = ok & (sm < shadow_level)
    # 6. the coarse scale: seabed texture (ripples, rock, sand waves) averages out over it, the
    # shadow of an object metres across does not. The echo is blurred in too, so a low hull's
    # shadow of 2-3 m behind a bright echo can fail the test (docs/detectors.md: its
    # detections then stay separate). Clipping highlights to the seabed level first keeps
    # such a shadow, but made dark SASSED texture an "object" again: 90 against 94 of the
    # development seeds' 96 targets
    deep = ok & (cv2.GaussianBlur(mean, (0, 0),
                                  sigmaX=COARSE_LENGTHS * template_length_m / cx,
                                  sigmaY=COARSE_LENGTHS * template_length_m / cy,
                                  borderType=cv2.BORDER_REFLECT) < shadow_level)
    # acoustic shadow (no echo) on the smoothed cells: with cells of one pixel, plain speckle
    # puts about 7 % of the seabed's cells below a tenth of its median
    dark = ok & (sm < SHADOW_DEPTH * shadow_level)
    owner = np.zeros((h, w), np.int32)
    # 4. echo and shadow pieces of one object, joined
    close_m, margin_m = CLOSE_LENGTHS * template_length_m, MARGIN_LENGTHS * template_length_m
    ky, kx = 2 * round(0.5 * close_m / cy) + 1, 2 * round(0.5 * close_m / cx) + 1
    mask = cv2.morphologyEx((hi | lo).view(np.uint8), cv2.MORPH_CLOSE,
                            cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (kx, ky)))
    n_lab, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8, ltype=cv2.CV_32S)
    extended_m = 2.0 * template_length_m
    span_rows = np.flatnonzero(ok.any(axis=1))
    first_row, last_row = (int(span_rows[0]), int(span_rows[-1])) if span_rows.size else (0, -1)
    my, mx = max(1, round(margin_m / cy)), max(1, round(margin_m / cx))
    dil = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * mx + 1, 2 * my + 1))
    objects: list[SeabedObject] = []
    patch: np.ndarray | None = None
    n_patch = 0
    for k in range(1, n_lab):
        c0, r0, bw, bh = (int(v) for v in stats[k, :4])
        if math.hypot(bw * cx, bh * cy) < extended_m:
            continue  # too small to be extended whatever its shape
        win = labels[r0:r0 + bh, c0:c0 + bw] == k
        yy, xx = np.nonzero(win & hi[r0:r0 + bh, c0:c0 + bw])
        if yy.size < 3:
            continue  # a shadow without an echo: not an object
        obj = _shape(yy + r0, xx + c0, cy, cx, fy, fx)
        spans = int(yy.min()) + r0 <= first_row + 1 and int(yy.max()) + r0 >= last_row - 1
        # a band: spanning the unit, or a piece of one along the edge of a band column
        along_track = abs(obj.axis_deg) <= BAND_AXIS_DEG and obj.width_m <= extended_m
        is_band = along_track and (bool(band[max(c0 - 1, 0):c0 + bw + 1].any()) or (
            spans and (last_row - first_row + 1) * cy >= 4 * template_length_m))
        if obj.length_m < extended_m and not is_band:
            continue
        coarse_shadow = bool(deep[r0:r0 + bh, c0:c0 + bw][win].any())
        if not is_band and not (coarse_shadow and dark[r0:r0 + bh, c0:c0 + bw][win].mean() >= SHADOW_SHARE):
            # no shadow at the coarse scale: textured seabed, not an object; one of at most
            # max_length_m is a patch (8.), larger fields of texture are left as they are.
            # Dark seabed (a coarse shadow but no acoustic shadow) is seabed, not a patch
            if not coarse_shadow and obj.length_m <= max_length_m:
                if patch is None:
                    patch = np.zeros((h, w), np.int32)
                n_patch += 1
                patch[r0:r0 + bh, c0:c0 + bw][win] = n_patch
            continue
        background = bool(is_band or obj.length_m > max_length_m)
        if not background:
            # its echo (5.): the highlight cells not beyond its shadow (bright seabed past the
            # shadow, or after the stern, joins the component through the shadow and the closing)
            ey, ex = _echo(win, hi[r0:r0 + bh, c0:c0 + bw], lo[r0:r0 + bh, c0:c0 + bw], my)
            if ey.size >= 3:
                echo = _shape(ey + r0, ex + c0, cy, cx, fy, fx)
                if echo.length_m >= extended_m:  # else (a broken shadow) the whole highlight
                    obj = echo
        obj = replace(obj, background=background)
        objects.append(obj)
        # its cells, and a margin, belong to it (the first object wins where margins meet)
        pr0, pc0 = max(r0 - my, 0), max(c0 - mx, 0)
        pr1, pc1 = min(r0 + bh + my, h), min(c0 + bw + mx, w)
        grown = cv2.dilate((labels[pr0:pr1, pc0:pc1] == k).view(np.uint8), dil).view(bool)
        sub = owner[pr0:pr1, pc0:pc1]
        sub[grown & (sub == 0)] = -1 if obj.background else len(objects)
    if band.any():  # a band's detections are background, but those of an object on it are its
        band = np.convolve(band, np.ones(3), mode="same") > 0  # and a cell either side (its edges)
        owner[(owner == 0) & band[None, :]] = -1
    return ObjectMap(owner, (fy, fx), tuple(objects), (rows, cols), patch)


def _echo(win: np.ndarray, hi: np.ndarray, lo: np.ndarray, reach: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns (in the component's box) of an object's echo: its highlight cells in
    rows within ``reach`` rows of one where it has a shadow cell, at ranges up to that shadow's
    far end (columns increase with range). A hull's echo lies in front of its shadow, over the
    rows the shadow covers; bright seabed beyond the shadow or past the stern is not the
    hull. Empty when the component has no shadow cell."""
    shade = win & lo
    rows = np.flatnonzero(shade.any(axis=1))
    if not rows.size:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    ends = win.shape[1] - 1 - np.argmax(shade[rows, ::-1], axis=1)  # last shadow column per shadow row
    # a row without shadow takes the end of the nearest shadow row within reach (the rows at
    # the bow and stern, the rims beside a broken shadow); not the farthest end within reach:
    # an oblique hull's shadow ends farther on every row, and that reached into the seabed
    gap = np.abs(np.arange(win.shape[0])[:, None] - rows[None, :])  # rows x shadow rows (one box)
    j = np.argmin(gap, axis=1)  # the nearest shadow row, the lower one on a tie
    far = np.where(gap[np.arange(gap.shape[0]), j] <= reach, ends[j], -1)
    y, x = np.nonzero(win & hi)
    keep = x <= far[y]
    return y[keep], x[keep]


def _shape(y: np.ndarray, x: np.ndarray, cy: float, cx: float, fy: int, fx: int) -> SeabedObject:
    """Centroid, axis and extents of a set of cells (row y, column x)."""
    ym, xm = (y + 0.5) * cy, (x + 0.5) * cx  # cell centres, metres
    my, mx = ym.mean(), xm.mean()
    dy, dx = ym - my, xm - mx
    syy, sxx, sxy = (dy * dy).mean(), (dx * dx).mean(), (dy * dx).mean()
    # principal axis of the 2x2 second-moment matrix (y = along-track, x = range)
    theta = 0.5 * math.atan2(2.0 * sxy, syy - sxx)
    c, s = math.cos(theta), math.sin(theta)
    along, across = dy * c + dx * s, -dy * s + dx * c
    # one cell's extent along each axis (the cells are cy x cx rectangles)
    length = float(along.max() - along.min()) + abs(c) * cy + abs(s) * cx
    width = float(across.max() - across.min()) + abs(s) * cy + abs(c) * cx
    deg = math.degrees(theta)
    deg = (deg + 90.0) % 180.0 - 90.0
    return SeabedObject(row=(my / cy) * fy - 0.5, col=(mx / cx) * fx - 0.5, length_m=max(length, width),
                        width_m=min(length, width), axis_deg=deg,
                        extent_along_m=float((y.max() - y.min() + 1) * cy),
                        extent_range_m=float((x.max() - x.min() + 1) * cx), n_pixels=int(y.size * fy * fx),
                        background=False)


def group_detections(detections: Sequence[Detection], objects: ObjectMap | None, *, core_start: int,
                     core_rows: int, range0_m: float, dr_m: float, min_extent_m: float,
                     max_extent_m: float, patches: bool = False) -> list[Detection]:
    """One detector's detections of a unit, regrouped by object (see the module docstring).

    Parameters
    ----------
    detections : sequence of Detection
        From :func:`~.extract.find_detections` on the core's scores, with no upper extent
        bound (rows relative to the core), in its order.
    objects : ObjectMap or None
        The unit's objects (None: only the extent filter applies).
    core_start, core_rows : int
        First unit row of the core, and its number of rows.
    range0_m, dr_m : float
        Ground range of column 0, column spacing.
    min_extent_m, max_extent_m : float
        The extent filter of detections outside extended objects.
    patches : bool
        Mark the detections in a textured patch with its number (``Detection.patch``; the
        evidence keeps one look per patch, ``node/evidence.py``); False: leave them unmarked.

    Returns
    -------
    list of Detection
        Ordered by row, then column, as :func:`~.extract.find_detections` orders them.
    """
    tol = 1e-9 * max_extent_m  # as find_detections: a component of exactly min or max metres

    def fits(d: Detection) -> bool:
        return (min_extent_m - tol <= d.extent_range_m <= max_extent_m + tol
                and min_extent_m - tol <= d.extent_along_m <= max_extent_m + tol)

    if objects is None or not detections or (not objects.objects and not (objects.owner < 0).any()
                                             and (objects.patch is None or not patches)):
        return [d for d in detections if fits(d)]
    rows = np.array([d.row + core_start for d in detections])
    cols = np.array([d.col for d in detections])
    own = objects.owner_at(rows, cols)
    patch = objects.patch_at(rows, cols) if patches else np.zeros(len(detections), np.int32)
    out: list[Detection] = []
    best: dict[int, Detection] = {}
    for d, k, p in zip(detections, own.tolist(), patch.tolist()):
        if k < 0:
            continue  # background
        if k == 0:
            if fits(d):
                out.append(replace(d, patch=int(p)) if p else d)
        elif k not in best or d.gamma > best[k].gamma:
            best[k] = d
    for k, d in best.items():
        obj = objects.objects[k - 1]
        row = round(obj.row) - core_start
        if not 0 <= row < core_rows:
            # its centre lies in a margin: the object is the neighbouring unit's, which sees it
            # there in its core (clamped into this core it would be a second contact, a few
            # metres off, depending on where the tiles were cut)
            continue
        col = min(max(round(obj.col), 0), objects.shape[1] - 1)
        out.append(replace(d, row=int(row), col=int(col), range_m=float(range0_m + col * dr_m),
                           extent_range_m=obj.extent_range_m, extent_along_m=obj.extent_along_m,
                           n_pixels=obj.n_pixels, length_m=obj.length_m, width_m=obj.width_m,
                           axis_deg=obj.axis_deg))
    out.sort(key=lambda d: (d.row, d.col))
    return out
