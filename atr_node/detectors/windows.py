"""Range-adaptive detector windows around the anchor pixel (SPEC section 1).

Every score map value gamma(i, j) belongs to the *anchor* (i, j): the boundary between the
echo zone and the shadow zone of the generic target, centred along-track. Relative to it, in
pixels (rows = pings along-track, columns = ground-range bins)::

    rows      [i + row0, i + row1)                    row0 = -(L // 2), row1 = row0 + L
    echo      columns [j - W, j)                      W = max(1, round(W_m / dr))
    shadow    columns [j, j + S(j))                   S(j) = max(1, round(S(r_j) / dr))
    context   rows [i + ctx_row0, i + ctx_row1), columns [j + ctx_col0(j), j + ctx_col1(j))

with ``S(r) = h r / (H - h)`` clipped to ``[shadow_min_m, shadow_max_m]`` (``shadow_max_m``
when H <= h: a target as tall as the sonar's altitude shadows the whole window) and
``L = max(1, round(length_m / dx))``. The context window of the segmented matched filter is
``context_factor`` times the template (echo + shadow) in each direction, centred on it.
``round`` is round-half-to-even (Python's ``round`` and ``np.rint``), as in the shared
contract, so the simulation's truth anchors land on the same pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import TemplateSettings
from ..errors import GeometryError


def shadow_length_m(range_m: np.ndarray | float, *, altitude_m: float,
                    template: TemplateSettings) -> np.ndarray:
    """Ground length of the template's shadow, S(r) = h r / (H - h), clipped (SPEC section 1).

    Parameters
    ----------
    range_m : array_like
        Ground ranges r, metres; any shape. r <= 0 gives ``shadow_min_m``.
    altitude_m : float
        Sonar altitude H above the seabed, metres.
    template : TemplateSettings
        Target height h and the clip interval [shadow_min_m, shadow_max_m].

    Returns
    -------
    ndarray of float64, shape of ``range_m``
        S(r) in metres, always finite and within the clip interval.
    """
    r = np.asarray(range_m, dtype=np.float64)
    h, lo, hi = template.height_m, template.shadow_min_m, template.shadow_max_m
    if not np.isfinite(altitude_m):
        raise GeometryError(f"altitude_m must be finite, got {altitude_m!r}")
    if altitude_m <= h:
        # Geometric optics has no finite shadow when the sonar is not above the target top.
        return np.full(r.shape, hi)
    with np.errstate(invalid="ignore"):
        s = h * r / (altitude_m - h)
    return np.clip(np.nan_to_num(s, nan=lo), lo, hi)


def _px(length_m: np.ndarray | float, step_m: float) -> np.ndarray:
    """max(1, round(length / step)) in pixels, round half to even."""
    return np.maximum(1, np.rint(np.asarray(length_m, dtype=np.float64) / step_m)).astype(np.int64)


@dataclass(frozen=True, eq=False)
class WindowGeometry:
    """Per-column window sizes in pixels, relative to the anchor (see the module docstring).

    Attributes hold offsets, so a window of anchor (i, j) covers rows ``[i + row0, i + row1)``
    and so on; arrays have one entry per column of the tile.
    """

    echo_px: int
    """W: echo zone width in columns (the zone is columns [j - W, j))."""
    length_px: int
    """L: along-track length of the echo and shadow zones in rows."""
    shadow_px: np.ndarray
    """S(j): shadow zone width per column, int64 (cols,); the zone is columns [j, j + S(j))."""
    row0: int
    """First row offset of the echo and shadow zones, -(L // 2)."""
    ctx_row0: int
    """First row offset of the SMF context window."""
    ctx_row1: int
    """End row offset (exclusive) of the SMF context window."""
    ctx_col0: np.ndarray
    """First column offset of the context window per column, int64 (cols,), negative."""
    ctx_col1: np.ndarray
    """End column offset (exclusive) of the context window per column, int64 (cols,)."""

    @property
    def row1(self) -> int:
        """End row offset (exclusive) of the echo and shadow zones."""
        return self.row0 + self.length_px

    @property
    def cols(self) -> int:
        return int(self.shadow_px.size)

    def reach(self) -> tuple[int, int, int, int]:
        """(up, down, left, right): how far any window reaches from its anchor, in pixels.

        ``up`` rows above the anchor row, ``down`` rows at and below it (exclusive end),
        ``left`` columns before the anchor column, ``right`` columns from it (exclusive end).
        """
        up = max(-self.row0, -self.ctx_row0, 0)
        down = max(self.row1, self.ctx_row1, 1)
        left = max(self.echo_px, int(-self.ctx_col0.min(initial=0)))
        right = max(int(self.shadow_px.max(initial=1)), int(self.ctx_col1.max(initial=1)))
        return up, down, left, right


def window_geometry(ranges_m: np.ndarray, *, dr_m: float, dx_m: float, altitude_m: float,
                    template: TemplateSettings, context_factor: float | None = None) -> WindowGeometry:
    """Window sizes in pixels for every column of a ground-range tile (SPEC section 1).

    Parameters
    ----------
    ranges_m : ndarray, shape (cols,)
        Ground range r_j of each column, metres.
    dr_m, dx_m : float
        Column (ground range) and row (along-track) spacing, metres; > 0.
    altitude_m : float
        Sonar altitude H above the seabed, metres (any finite value; H <= h is handled).
    template : TemplateSettings
        The generic target: length, echo width, height, shadow clip, context factor.
    context_factor : float, optional
        Overrides ``template.context_factor``.

    Returns
    -------
    WindowGeometry

    Raises
    ------
    GeometryError
        Non-positive or non-finite pixel spacing, or a non-finite altitude.
    """
    if not (np.isfinite(dr_m) and dr_m > 0 and np.isfinite(dx_m) and dx_m > 0):
        raise GeometryError(f"pixel spacing must be finite and > 0, got dr_m={dr_m!r}, dx_m={dx_m!r}")
    ranges = np.asarray(ranges_m, dtype=np.float64).reshape(-1)
    w = int(_px(template.echo_width_m, dr_m))
    ln = int(_px(template.length_m, dx_m))
    s = _px(shadow_length_m(ranges, altitude_m=altitude_m, template=template), dr_m)
    cf = template.context_factor if context_factor is None else float(context_factor)
    row0 = -(ln // 2)
    # Context: cf times the template (W + S wide, L long), centred on the template (SPEC 2.3).
    ctx_len = max(ln, int(np.rint(cf * ln)))
    ctx_row0 = row0 - (ctx_len - ln) // 2
    tw = w + s
    ctx_w = np.maximum(tw, np.rint(cf * tw).astype(np.int64))
    ctx_col0 = -w - (ctx_w - tw) // 2
    return WindowGeometry(echo_px=w, length_px=ln, shadow_px=s, row0=row0, ctx_row0=ctx_row0,
                          ctx_row1=ctx_row0 + ctx_len, ctx_col0=ctx_col0, ctx_col1=ctx_col0 + ctx_w)


def required_margin(geometry: WindowGeometry) -> tuple[int, int]:
    """(rows, cols) of margin a tile needs so that its core scores do not depend on the cut.

    A core pixel's windows stay inside the tile when the tile extends ``rows`` rows above and
    below the core and ``cols`` columns left and right of it. Tiles span the whole swath in
    range, so in practice only the row margin matters: columns whose windows run off the tile
    score with the missing pixels counted as no data, in every tiling alike.
    """
    up, down, left, right = geometry.reach()
    return max(up, down - 1), max(left, right - 1)


def window_bounds(shape: tuple[int, int], row: int, col: int, *, row0: int, length_px: int, echo_px: int,
                  shadow_px: int) -> tuple[int, int, int, int]:
    """Rows ``[r0, r1)`` and columns ``[c0, c1)`` of the template window of anchor (row, col),
    rows ``[row + row0, row + row0 + length_px)``, columns ``[col - echo_px, col + shadow_px)``,
    clipped to a map of ``shape``; empty (``r0 >= r1`` or ``c0 >= c1``) when it lies off the map."""
    rows, cols = shape
    return (max(0, row + row0), min(rows, row + row0 + length_px), max(0, col - echo_px), min(cols, col + shadow_px))
