"""Score maps of the enabled detectors for one ground-range tile (SPEC sections 1-2).

One pass builds the images the enabled detectors need (valid mask, normalised image, matched
filter image, segment codes) into padded buffers and integrates each once with OpenCV
(:mod:`.sat`); then blocks of anchor rows read every window sum from the tables
(:mod:`.reader`) and the detector formulas (:mod:`.formulas`) turn them into scores. A
detector switched off costs nothing: its images, tables and sums are not built (the median,
for example, is computed only for the matched filter and the SMF). When no data fills whole
columns only (nadir gap, past maximum range: the usual case) neither the mask nor the matched
filter image is needed: counts follow from geometry and J's means from those of I_n.

Tiles cut along-track are scored with margin rows above and below the core
(:func:`score_strip`): the core's scores then equal those of the uncut strip, provided the
column statistics (background b(j), median m(j)) are the same, e.g. from a
:class:`~.background.BackgroundTracker` and a leg-level median passed in.
"""

from __future__ import annotations

from typing import Iterable

import cv2
import numpy as np

from ..config import DETECTOR_NAMES, DetectorSettings, TemplateSettings
from ..errors import AtrError
from .background import column_mean, column_median
from .formulas import NEEDS
from .reader import read_scores
from .sat import Padding, SummedAreaTables, Workspace
from .windows import window_geometry

_BLOCK_BYTES = 1 << 20
"""Target size of one block of rows while filling the images, so they stay in cache."""


def _enabled(enabled: Iterable[str] | None, detectors: DetectorSettings) -> tuple[str, ...]:
    names = tuple(detectors.enabled if enabled is None else enabled)
    bad = [d for d in names if d not in NEEDS]
    if bad:
        raise AtrError(f"score_maps: unknown detector(s) {bad}; expected some of {list(DETECTOR_NAMES)}")
    return tuple(d for d in DETECTOR_NAMES if d in names)


def _column_array(value: np.ndarray | None, cols: int, what: str) -> np.ndarray | None:
    if value is None:
        return None
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.size != cols:
        raise AtrError(f"score_maps: {what} has {a.size} values, the tile {cols} columns")
    return a


def _build_tables(x: np.ndarray, valid: np.ndarray, all_valid: bool, separable: bool, needs: set[str],
                  b_eff: np.ndarray, med: np.ndarray | None, pad: Padding, float64: bool,
                  workspace: Workspace | None, *, col_valid: np.ndarray, row_valid: np.ndarray) -> SummedAreaTables:
    """Fill the padded images the needed sums read, block of rows by block, and integrate each.

    With a ``separable`` valid mask (every column all valid or all empty) the counts come from
    geometry (:mod:`.reader`) and no mask table is built.
    """
    sat = SummedAreaTables(x.shape, pad, workspace)
    ftype = np.float64 if float64 else np.float32
    fdepth = cv2.CV_64F if float64 else cv2.CV_32F
    want_p = bool(needs & {"p_E", "p_S"})
    want_j = bool(needs & {"j_E", "j_S"})
    want_g = bool(needs & {"g_E", "g_S", "ag_C"})

    if not separable:
        n_full, n_in = sat.buffer("n", np.uint8)
    if want_p:
        p_full, p_in = sat.buffer("p", ftype)
    if want_j:
        j_full, j_in = sat.buffer("j", ftype)
        # J = I_n - median(I_n) = I / b(j) - m(j) / b(j) (SPEC 2.1).
        shift = np.nan_to_num(med / b_eff, nan=1.0, posinf=1.0, neginf=1.0).astype(ftype)
    if want_p or want_j:
        inv_b = (1.0 / b_eff).astype(ftype)
    if want_g:
        # SMF segments (SPEC 2.3) held doubled: 2S + 2 in 0..4, pad and no data = 2 (S = 0);
        # thresholds in float64 as the SPEC writes them (I < 0.3 m(j), ...).
        g_full, g_in = sat.buffer("g", np.uint8, fill=2)
        ag_full, ag_in = sat.buffer("ag", np.uint8)
        thresholds = [(_float32_bound(f * med, +1), +1) for f in (2.0, 4.0)] + \
                     [(_float32_bound(f * med, -1), -1) for f in (0.6, 0.3)]
        # NaN compares false; only infinite pixels need masking out of the segments.
        # Infinite pixels are no data: their segment codes are masked pixel by pixel, or, with
        # a separable mask (they then fill whole columns or rows), with the empty columns below.
        check_inf = not all_valid and not separable
    zero_by_pixel = not all_valid and not separable

    block = max(1, _BLOCK_BYTES // (8 * max(1, x.shape[1])))
    for r0 in range(0, x.shape[0], block):
        rows = slice(r0, r0 + block)
        xb, vb = x[rows], valid[rows]
        if not separable:
            n_in[rows] = vb
        if want_p or want_j:
            # I_n = I / b(j); p = I_n - 1 centres it on its expected mean (SPEC 2).
            i_n = np.multiply(xb, inv_b, dtype=ftype, out=None if want_j else p_in[rows])
            if want_j:
                np.subtract(i_n, shift, out=j_in[rows])
                if zero_by_pixel:
                    np.copyto(j_in[rows], 0, where=~vb)
            if want_p:
                np.subtract(i_n, 1, out=p_in[rows])
                if zero_by_pixel:
                    np.copyto(p_in[rows], 0, where=~vb)
        if want_g:
            gb, agb = g_in[rows], ag_in[rows]
            with np.errstate(invalid="ignore"):
                hits = [np.greater(xb, t) if sign > 0 else np.less(xb, t) for t, sign in thresholds]
            if check_inf and np.isinf(xb).any():
                for hit in hits:
                    hit &= vb
            # |2S| = highs + lows; 2S + 2 = 2 + highs - lows (the four tests are nested).
            np.add(hits[0], hits[1], out=agb, dtype=np.uint8)
            np.add(agb, 2, out=gb)
            lows = np.add(hits[2], hits[3], dtype=np.uint8)
            gb -= lows
            agb += lows

    if separable and not all_valid:
        # No data in whole columns and whole rows: zero them run by run.
        # (segment codes: 2 = S 0 in g, 0 in |2S|; an infinite pixel compared as a hit)
        bufs = [(p_in, 0)] if want_p else []
        bufs += [(j_in, 0)] if want_j else []
        bufs += [(g_in, 2), (ag_in, 0)] if want_g else []
        empty = np.flatnonzero(~col_valid)
        if empty.size:
            for run in np.split(empty, np.flatnonzero(np.diff(empty) > 1) + 1):
                cols = slice(int(run[0]), int(run[-1]) + 1)
                for buf, fill in bufs:
                    buf[:, cols] = fill
        empty_rows = np.flatnonzero(~row_valid)
        if empty_rows.size:
            for buf, fill in bufs:
                buf[empty_rows, :] = fill
    if not separable:
        sat.add("n", n_full, cv2.CV_32S)
    if want_p and "p2_S" in needs:
        # Squares always in float64: their table is not centred and grows with the tile, and
        # the variance E[p^2] - E[p]^2 cancels digits in deep shadows (float32 lost 1-2 std).
        sat.add_with_squares("p", "p2", p_full, fdepth, cv2.CV_64F)
    elif want_p:
        sat.add("p", p_full, fdepth)
    if want_j:
        sat.add("j", j_full, fdepth)
    if want_g:
        sat.add("g", g_full, cv2.CV_32S)
        sat.add("ag", ag_full, cv2.CV_32S)
    return sat


def _float32_bound(t: np.ndarray, sign: int) -> np.ndarray:
    """float32 thresholds that compare float32 pixels exactly as the float64 ``t`` would.

    ``x > t`` equals ``x > floor32(t)`` and ``x < t`` equals ``x < ceil32(t)`` for every
    float32 x, where floor32 / ceil32 are the nearest float32 at or below / above t.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        t32 = t.astype(np.float32)
        if sign > 0:
            return np.where(t32 > t, np.nextafter(t32, np.float32(-np.inf)), t32)
        return np.where(t32 < t, np.nextafter(t32, np.float32(np.inf)), t32)


def _score_rows(x: np.ndarray, *, first_row: int, stop_row: int, range0_m: float, dr_m: float,
                dx_m: float, altitude_m: float, template: TemplateSettings, detectors: DetectorSettings,
                enabled: Iterable[str] | None, background: np.ndarray | None,
                median: np.ndarray | None, workspace: Workspace | None) -> dict[str, np.ndarray]:
    """Scores of anchor rows [first_row, stop_row) of tile ``x``, shape (stop - first, cols)."""
    names = _enabled(enabled, detectors)
    rows, cols = x.shape
    n_out = max(0, stop_row - first_row)
    float64 = detectors.precision == "float64"
    ftype = np.float64 if float64 else np.float32
    if not names:
        return {}
    if n_out == 0 or cols == 0:
        return {d: np.empty((n_out, cols), ftype) for d in names}

    geom = window_geometry(range0_m + dr_m * np.arange(cols), dr_m=dr_m, dx_m=dx_m,
                           altitude_m=altitude_m, template=template)
    needs = set().union(*(NEEDS[d] for d in names))
    if workspace is None:
        workspace = Workspace()
    # Fresh memory costs a page fault per page (on a virtual machine as much as a pass over
    # it): the mask lives in the workspace, and OpenCV counts it about 10x faster than numpy.
    valid = np.isfinite(x, out=workspace.array("valid", x.shape, bool))
    valid_u8 = valid.view(np.uint8)
    per_col = cv2.reduce(valid_u8, 0, cv2.REDUCE_SUM, dtype=cv2.CV_32S).reshape(-1).astype(np.int64)
    per_row = cv2.reduce(valid_u8, 1, cv2.REDUCE_SUM, dtype=cv2.CV_32S).reshape(-1).astype(np.int64)
    all_valid = bool((per_col == rows).all())
    # Common case: no data only in whole columns (nadir gap, beyond maximum range) and whole
    # rows (ping drop-outs): the valid mask is the outer product of a row and a column mask
    # exactly when every column holds all the non-empty rows and every row all the non-empty
    # columns (or nothing).
    n_vrows, n_vcols = int(np.count_nonzero(per_row)), int(np.count_nonzero(per_col))
    separable = bool(((per_col == n_vrows) | (per_col == 0)).all() and ((per_row == n_vcols) | (per_row == 0)).all())

    b = _column_array(background, cols, "background")
    if b is None and needs & {"p_E", "p_S", "j_E", "j_S"}:
        # With whole-column no-data a plain column sum gives the NaN-aware mean (NaN columns
        # stay NaN, as column_mean gives them), one pass cheaper.
        b = (cv2.reduce(x, 0, cv2.REDUCE_SUM, dtype=cv2.CV_64F).reshape(-1) / rows
             if separable and n_vrows == rows else column_mean(x))
    # A column without data or with b <= 0 (all zeros) keeps I_n = I: its windows are NaN or 0.
    b_eff = np.ones(cols) if b is None else np.where(np.isfinite(b) & (b > 0), b, 1.0)
    med = _column_array(median, cols, "median")
    if med is None and needs & {"j_E", "j_S", "g_E", "g_S", "ag_C"}:
        med = column_median(x, valid_counts=per_col)

    median_n = None
    table_needs = needs
    if separable and needs & {"j_E", "j_S"}:
        # mean(J, window) = mean(I_n, window) - mean of median_j(I_n) over its valid columns:
        # with whole-column no-data the matched filter needs no table of its own (SPEC 2.1).
        median_n = np.nan_to_num(med / b_eff, nan=1.0, posinf=1.0, neginf=1.0)
        table_needs = (needs - {"j_E", "j_S"}) | {"p_E", "p_S"}
    pad = Padding.for_geometry(geom)
    sat = _build_tables(x, valid, all_valid, separable, table_needs, b_eff, med, pad, float64, workspace,
                        col_valid=per_col > 0, row_valid=per_row > 0)
    return read_scores(sat, geom, names, needs, first_row, n_out, detectors, ftype,
                       col_valid=per_col > 0 if separable else None, median_n=median_n,
                       row_valid=per_row > 0 if separable else None)


def score_maps(pixels: np.ndarray, *, range0_m: float, dr_m: float, dx_m: float, altitude_m: float,
               template: TemplateSettings, detectors: DetectorSettings,
               enabled: Iterable[str] | None = None, background: np.ndarray | None = None,
               median: np.ndarray | None = None, workspace: Workspace | None = None) -> dict[str, np.ndarray]:
    """Score map of every enabled detector over a whole ground-range tile (SPEC section 2).

    Parameters
    ----------
    pixels : ndarray, shape (rows, cols)
        Linear intensity (the node squares amplitude tiles first: ``Tile.as_intensity``; the
        levels of SPEC 2 are intensity levels), ground range; NaN (any non-finite value) = no data.
    range0_m, dr_m : float
        Ground range of column 0 and column spacing, metres.
    dx_m : float
        Row (along-track) spacing, metres.
    altitude_m : float
        Sonar altitude above the seabed, metres (sets the shadow length).
    template : TemplateSettings
        The generic target (SPEC section 1).
    detectors : DetectorSettings
        Floors, ``min_valid_fraction``, ``precision`` and ``decimation``.
    enabled : iterable of str, optional
        Detectors to run; default ``detectors.enabled``.
    background : ndarray, shape (cols,), optional
        b(j), e.g. from :class:`~.background.BackgroundTracker`; default: this tile's
        NaN-aware column means.
    median : ndarray, shape (cols,), optional
        m(j), the per-range median of the raw pixels; default: this tile's NaN-aware column
        medians. Give it (with ``background``) to make scores independent of tiling.
    workspace : Workspace, optional
        Buffers reused from call to call (tiles of one shape); default: fresh memory.

    Returns
    -------
    dict of str to ndarray, each shape (rows, cols)
        gamma_d at every anchor pixel (SPEC section 1), float64 (float32 with
        ``precision = "float32"``); NaN where one of the detector's windows has fewer than
        ``min_valid_fraction`` of its pixels valid (parts off the tile count as no data).
        With ``decimation`` n, every n-th row and column is scored and repeated over its
        n x n block.
    """
    x = _as_tile(pixels)
    return _score_rows(x, first_row=0, stop_row=x.shape[0], range0_m=range0_m, dr_m=dr_m, dx_m=dx_m,
                       altitude_m=altitude_m, template=template, detectors=detectors, enabled=enabled,
                       background=background, median=median, workspace=workspace)


def score_strip(pixels: np.ndarray, *, core_rows: tuple[int, int], range0_m: float, dr_m: float,
                dx_m: float, altitude_m: float, template: TemplateSettings, detectors: DetectorSettings,
                enabled: Iterable[str] | None = None, background: np.ndarray | None = None,
                median: np.ndarray | None = None, workspace: Workspace | None = None) -> dict[str, np.ndarray]:
    """Scores of the core rows of a tile that carries margin rows above and below.

    Same as ``score_maps(...)[d][core_rows[0]:core_rows[1]]`` but only the core is scored.
    With at least ``required_margin(geometry)[0]`` rows of margin on each side (fewer at the
    ends of a leg), and the same ``background`` and ``median``, the core's scores equal those
    of the uncut strip.

    Parameters
    ----------
    core_rows : (start, stop)
        Rows of ``pixels`` that form the core, 0 <= start <= stop <= rows.
    Others : see :func:`score_maps`.

    Returns
    -------
    dict of str to ndarray, each shape (stop - start, cols)
    """
    x = _as_tile(pixels)
    start, stop = (int(v) for v in core_rows)
    if not 0 <= start <= stop <= x.shape[0]:
        raise AtrError(f"score_strip: core_rows {core_rows!r} outside the tile's {x.shape[0]} rows")
    return _score_rows(x, first_row=start, stop_row=stop, range0_m=range0_m, dr_m=dr_m, dx_m=dx_m,
                       altitude_m=altitude_m, template=template, detectors=detectors, enabled=enabled,
                       background=background, median=median, workspace=workspace)


def _as_tile(pixels: np.ndarray) -> np.ndarray:
    a = np.asarray(pixels)
    if a.ndim != 2:
        raise AtrError(f"score_maps: pixels must be a 2-D (rows, cols) array, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.complexfloating):
        raise AtrError(f"score_maps: pixels must be real numbers, got dtype {a.dtype}")
    return np.ascontiguousarray(a, dtype=np.float32)
