"""Pixels to cells: the per-(detector, cell) maximum Pd of a tile core (SPEC section 7).

The notT evidence of one (leg, detector, cell) is ``log1p(-Pd)`` with Pd the maximum over
the cell's covered pixels of ``Pd_d(r_j)`` (one piece per cell, free of the tile cut). Cells
are 0.5 m and pixels 0.1 m, so some 25 pixels share a cell: this module reduces the pixels
of a block of rows to its distinct cells before the grid looks up chunks and scatters into
the leg's layer (``EvidenceGrid._deposit_pd``).

Per sub-block (:meth:`PdReducer._reduce_sub`):

1. the two cell planes ``floor((p_i + r_j u_i) / cell_m)``, three passes each when ``cell_m``
   is a power of two (an exact scaling, :meth:`PdReducer._cell_planes`);
2. vertical runs: a pixel in the same cell as the pixel above it adds no (cell, column) pair,
   so only the first pixel of each run is an *entry* (about one pixel in five);
3. horizontal groups: consecutive entries of one row in one cell cover consecutive columns
   ``[a, a + len)``; Pd depends on the column only, so a group's value is a range maximum of
   the per-column values, read from a sparse table (``max(T_k[a], T_k[a + len - 2^k])``,
   a few levels: groups are about five columns long);
4. one ``np.maximum.at`` per detector of the groups into a dense box of the sub-block's
   cells. Columns whose coverage changes down the sub-block are taken pixel by pixel; a
   detector whose coverage changes in many columns (the first rows of a strip) takes the
   pixel path of step 2 with runs also cut where its coverage changes.

Exactness. Cells are ``floor((p + r u) / cell_m)`` exactly as :func:`pixel_cells` computes
them (``r u + p`` is the same float: IEEE addition commutes; see :meth:`_cell_planes` for
the scaled form); the box index is formed from those integral floats, exact below 2^53;
maximum is exact, associative and commutative. So the result is bit for bit that of a
per-pixel scatter (``tests/fusion/test_deposit.py``).

Speed. Work happens in sub-blocks of ``SUB_PIXELS`` pixels in scratch buffers reused from
call to call: fresh multi-megabyte temporaries cost a page fault per 4 kB, as much as the
arithmetic itself.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..geo import TileGeometry

SUB_PIXELS = 1 << 18
"""Pixels reduced at once (scratch of 18 bytes per pixel, reused: 4.5 MB)."""


class PdReducer:
    """Reduces blocks of pixels to (cell, per-detector maximum Pd), with reusable scratch.

    Parameters
    ----------
    cell_m : float
        Cell size of the grid (m).
    sub_pixels : int
        Pixels per sub-block (bounds the scratch memory: 18 bytes per pixel).
    """

    def __init__(self, cell_m: float, *, sub_pixels: int = SUB_PIXELS) -> None:
        self.cell_m = float(cell_m)
        self.sub_pixels = int(sub_pixels)
        mant, exp = math.frexp(self.cell_m)
        # 1 / cell_m when cell_m is a power of two (an exact scaling, see _cell_planes)
        self._scale = 1.0 / self.cell_m if mant == 0.5 and -50 < exp < 50 else None
        self._buf = np.empty((0, 0))
        self._first = self._tmp = np.empty(0, dtype=bool)

    def __getstate__(self) -> dict:
        """Pickled (a grid sent to another process) without its scratch buffers."""
        return {"cell_m": self.cell_m, "sub_pixels": self.sub_pixels}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["cell_m"], sub_pixels=state["sub_pixels"])

    def _scratch(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(2, n) float64 (the two cell planes) and two (n,) bool (run starts, a comparison)."""
        if self._buf.shape[1] < n:
            self._buf = np.empty((2, n))
            self._first, self._tmp = np.empty(n, dtype=bool), np.empty(n, dtype=bool)
        return self._buf, self._first, self._tmp

    def reduce(self, geometry: TileGeometry, covered: Sequence[np.ndarray], pd: Sequence[np.ndarray], rows: slice,
               cols: slice) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-(detector, cell) maximum Pd over the covered pixels of ``[rows, cols]``.

        Parameters
        ----------
        geometry : TileGeometry
            Georeferencing of the core rows.
        covered : sequence of ndarray of bool, each (core rows, core cols)
            Per detector, the covered pixels.
        pd : sequence of ndarray of float64, each (core cols,)
            Per detector, Pd at each column (in [0, 1]).
        rows, cols : slice
            The block (``step`` None).

        Returns
        -------
        (iy, ix, vmax)
            Cells (M,) int64 covered by at least one detector, and ``vmax`` (n_det, M):
            the maximum Pd of each detector there, -1 where that detector covered no pixel
            of the cell. A cell may appear more than once (in several sub-blocks): callers
            combine by maximum.
        """
        c0, c1, _ = cols.indices(geometry.ranges_m.size)
        r0, r1, _ = rows.indices(geometry.east_m.size)
        width = c1 - c0
        step = max(1, self.sub_pixels // max(width, 1))
        parts = []
        scaled = self.scaled(geometry, slice(r0, r1), slice(c0, c1))  # once for the sub-blocks
        for a in range(r0, r1, step):
            parts.append(self._reduce_sub(geometry, covered, pd, slice(a, min(r1, a + step)), slice(c0, c1),
                                          scaled))
        if len(parts) == 1:
            return parts[0]
        return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
                np.concatenate([p[2] for p in parts], axis=1))

    def _reduce_sub(self, geometry: TileGeometry, covered: Sequence[np.ndarray], pd: Sequence[np.ndarray],
                    rows: slice, cols: slice, scaled: bool | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`reduce` of one sub-block (cells unique within it): the run path, or the
        pixel path (:meth:`_reduce_pixels`) for a footprint far wider than the block."""
        h_px, w_px = rows.stop - rows.start, cols.stop - cols.start
        n = h_px * w_px
        buf, first, tmp = self._scratch(n)
        fy, fx = buf[0, :n].reshape(h_px, w_px), buf[1, :n].reshape(h_px, w_px)
        self._cell_planes(geometry, rows, cols, fy, fx, scaled)
        box = self._box(geometry, cols, fy, fx)
        if box is None:
            return self._reduce_pixels(covered, pd, rows, cols, fy, fx)
        y0, x0, h, w = box
        off = y0 * w + x0
        # 1. vertical runs: a pixel in the same cell as the pixel above it adds no (cell,
        # column) pair; the first pixel of each run (about one in five) is an entry
        first = first[:n].reshape(h_px, w_px)
        first[0] = True
        np.not_equal(fy[1:], fy[:-1], out=first[1:])
        ne = tmp[:n - w_px].reshape(h_px - 1, w_px)
        np.not_equal(fx[1:], fx[:-1], out=ne)
        first[1:] |= ne
        idx = np.flatnonzero(first)
        key = fy.reshape(-1)[idx]
        key *= w  # (iy - y0) w + (ix - x0) = iy w + ix - (y0 w + x0): exact integers in float64
        key += fx.reshape(-1)[idx]
        key -= off
        loc = key.astype(np.int64)
        # 2. horizontal groups: consecutive entries of one row in one cell cover consecutive
        # columns [a, a + len): their maximum is a range maximum of the column values
        brk = np.empty(idx.size, dtype=bool)
        brk[0] = True
        np.not_equal(loc[1:], loc[:-1], out=brk[1:])
        brk[1:] |= np.diff(idx) != 1
        gs = np.flatnonzero(brk)
        g_len = np.diff(np.append(gs, idx.size))
        g_start = idx[gs]
        g_col = g_start - g_start // w_px * w_px
        if int((g_col + g_len).max()) > w_px:  # a group across a row end (a block a cell wide)
            gs, g_len, g_col = np.arange(idx.size), np.ones(idx.size, dtype=np.int64), idx % w_px
        g_loc = loc[gs]
        # range maximum from a sparse table: max(T_k[a], T_k[a + len - 2^k]), 2^k <= len < 2^(k+1)
        levels = int(g_len.max()).bit_length()
        k = np.frexp(g_len)[1].astype(np.int64) - 1  # floor(log2(len)), exact for integers
        i1 = k * w_px + g_col
        i2 = i1 + g_len - (1 << k)
        out = np.full((len(covered), h * w), -1.0)
        table = np.full((levels, w_px), -1.0)
        by_pixel = []  # detectors whose coverage changes down many columns
        for j, (cov, p) in enumerate(zip(covered, pd)):
            c = cov[rows, cols]
            col_any = c.any(axis=0)
            if not col_any.any():
                continue
            # uncovered pixels count -1: a no-op under the maximum (Pd is in [0, 1]); columns
            # whose coverage changes down the sub-block are taken pixel by pixel
            varying = np.flatnonzero(col_any & ~c.all(axis=0))
            pcol = np.where(col_any, p[cols], -1.0)
            if 8 * varying.size > w_px:
                by_pixel.append((j, c, pcol))
                continue
            if varying.size:
                cv = c[:, varying]
                kv = fy[:, varying] * w + fx[:, varying] - off
                np.maximum.at(out[j], kv[cv].astype(np.int64), np.broadcast_to(pcol[varying], cv.shape)[cv])
                pcol[varying] = -1.0
            table[0] = pcol
            for lev in range(1, levels):
                s = 1 << (lev - 1)
                np.maximum(table[lev - 1, :w_px - s], table[lev - 1, s:], out=table[lev, :w_px - s])
            flat = table.reshape(-1)
            np.maximum.at(out[j], g_loc, np.maximum(flat[i1], flat[i2]))
        if by_pixel:
            # the vertical runs cut where the coverage of one of these detectors changes: within
            # a run, cell, column and coverage are those of its first pixel
            for _, c, _ in by_pixel:
                first[1:] |= c[1:] != c[:-1]
            idx = np.flatnonzero(first)
            key = fy.reshape(-1)[idx] * w + fx.reshape(-1)[idx] - off
            loc, col = key.astype(np.int64), idx % w_px
            for j, c, pcol in by_pixel:
                v = pcol[col]
                v[~c.reshape(-1)[idx]] = -1.0
                np.maximum.at(out[j], loc, v)
        keep = np.flatnonzero((out >= 0.0).any(axis=0))
        ky = keep // w
        # np.take: a fancy index behind a slice (out[:, keep]) is 4x slower here
        return ky + int(y0), keep - ky * w + int(x0), np.take(out, keep, axis=1)

    def scaled(self, geometry: TileGeometry, rows: slice = slice(None), cols: slice = slice(None)) -> bool:
        """Whether :meth:`_cell_planes` may scale (see there) for these rows and columns."""
        return self._scale is not None and _tame(geometry.ranges_m[cols]) and all(
            _tame(a[rows]) for a in (geometry.north_m, geometry.un, geometry.east_m, geometry.ue))

    def _cell_planes(self, geometry: TileGeometry, rows: slice, cols: slice, fy: np.ndarray, fx: np.ndarray,
                     scaled: bool | None = None) -> None:
        """Cells ``floor((p_i + r_j u_i) / cell_m)`` of the block into ``fy``, ``fx`` (h, w),
        bit for bit :func:`~atr_node.fusion.observation.pixel_cells`.

        With ``cell_m = 2^e`` and every operand zero or within ``2^-400 .. 2^400``, division
        by ``cell_m`` is an exact scaling that commutes with rounding:
        ``fl(fl(r u) + p) / cell_m = fl(fl((r / cell_m) u) + p / cell_m)``, one pass less.
        ``scaled``: :meth:`scaled` of these rows and columns or of a superset (None: found here).
        """
        r = geometry.ranges_m[cols]
        if scaled is None:
            scaled = self.scaled(geometry, rows, cols)
        for f, pos, u in ((fy, geometry.north_m, geometry.un), (fx, geometry.east_m, geometry.ue)):
            uu, pp = u[rows], pos[rows]
            if scaled:
                np.multiply(r * self._scale, uu[:, None], out=f)
                f += (pp * self._scale)[:, None]
            else:  # the expression of pixel_cells, in place
                np.multiply(r[None, :], uu[:, None], out=f)
                f += pp[:, None]
                f /= self.cell_m
            np.floor(f, out=f)

    @staticmethod
    def _box(geometry: TileGeometry, cols: slice, fy: np.ndarray, fx: np.ndarray
             ) -> tuple[float, float, int, int] | None:
        """(y0, x0, h, w) of the dense box of the block's cells, or None if too large (a nav
        jump) or beyond exact float64 integers."""
        h_px, w_px = fy.shape
        r = geometry.ranges_m[cols]
        if w_px > 1 and np.all(r[1:] >= r[:-1]):
            # ranges increase along a row, and p + r u, / cell_m and floor are monotone in r
            # (IEEE rounding is monotone): a row's extremes are at its first or last column
            ends = np.concatenate([fy[:, 0], fy[:, -1]]), np.concatenate([fx[:, 0], fx[:, -1]])
        else:
            ends = fy, fx
        y0, y1, x0, x1 = float(ends[0].min()), float(ends[0].max()), float(ends[1].min()), float(ends[1].max())
        h, w = int(y1) - int(y0) + 1, int(x1) - int(x0) + 1
        if h * w <= max(4 * h_px * w_px, 1 << 16) and max(abs(y0), abs(y1), abs(x0), abs(x1)) * (w + 2) < 2.0 ** 52:
            return y0, x0, h, w
        return None

    @staticmethod
    def _reduce_pixels(covered: Sequence[np.ndarray], pd: Sequence[np.ndarray], rows: slice, cols: slice,
                       fy: np.ndarray, fx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel by pixel, the cells present found by one sort (a footprint far wider than a
        tile: a nav jump)."""
        iy, ix = fy.reshape(-1).astype(np.int64), fx.reshape(-1).astype(np.int64)
        order = np.lexsort((ix, iy))
        sy, sx = iy[order], ix[order]
        first = np.r_[True, (sy[1:] != sy[:-1]) | (sx[1:] != sx[:-1])]
        local = np.empty(iy.size, dtype=np.int64)
        local[order] = np.cumsum(first) - 1
        out = np.full((len(covered), int(first.sum())), -1.0)
        for j, (cov, p) in enumerate(zip(covered, pd)):
            c = cov[rows, cols].reshape(-1)
            np.maximum.at(out[j], local[c], np.broadcast_to(p[cols], fy.shape).reshape(-1)[c])
        keep = np.flatnonzero((out >= 0.0).any(axis=0))
        return sy[first][keep], sx[first][keep], out[:, keep]


def _tame(a: np.ndarray) -> bool:
    """Every value zero or of magnitude within 2^-400 .. 2^400 (so products, sums and
    power-of-two scalings of such values stay normal: exact scaling, see _cell_planes)."""
    m = np.abs(a)
    return bool(np.all((m == 0.0) | ((m >= 2.0 ** -400) & (m <= 2.0 ** 400))))
