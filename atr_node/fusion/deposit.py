"""Pixels to cells: the per-(detector, cell) maximum Pd of a tile core (SPEC section 7).

The notT evidence of one (leg, detector, cell) is ``log1p(-Pd)`` with Pd the maximum over
the cell's covered pixels of ``Pd_d(r_j)`` (one piece per cell, free of the tile cut). Cells
are 0.5 m and pixels 0.1 m, so some 25 pixels share a cell: this module reduces the pixels
of a block of rows to its distinct cells before the grid looks up chunks and scatters into
the leg's layer (``EvidenceGrid._deposit_pd``), so that the per-pixel work is a few numpy
passes per row block and one ``np.maximum.at`` per detector into a small dense box.

Exactness. Cells are ``floor((p + r u) / cell_m)`` exactly as :func:`pixel_cells` computes
them (``r u + p`` is the same float: IEEE addition commutes); the box index is formed from
those integral floats, exact below 2^53; maximum is exact, associative and commutative. So
the result is bit for bit that of a per-pixel scatter (``tests/fusion/test_deposit.py``).

Speed. Work happens in sub-blocks of ``SUB_PIXELS`` pixels in scratch buffers reused from
call to call: fresh multi-megabyte temporaries cost a page fault per 4 kB, as much as the
arithmetic itself.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..geo import TileGeometry

SUB_PIXELS = 1 << 18
"""Pixels reduced at once (scratch of 32 bytes per pixel, reused: 8 MB)."""


class PdReducer:
    """Reduces blocks of pixels to (cell, per-detector maximum Pd), with reusable scratch.

    Parameters
    ----------
    cell_m : float
        Cell size of the grid (m).
    sub_pixels : int
        Pixels per sub-block (bounds the scratch memory: 32 bytes per pixel).
    """

    def __init__(self, cell_m: float, *, sub_pixels: int = SUB_PIXELS) -> None:
        self.cell_m = float(cell_m)
        self.sub_pixels = int(sub_pixels)
        self._buf = np.empty((0, 0))
        self._ibuf = np.empty(0, dtype=np.int64)
        self._cols = np.empty(0, dtype=np.intp)
        self._cols_w = 0

    def __getstate__(self) -> dict:
        """Pickled (a grid sent to another process) without its scratch buffers."""
        return {"cell_m": self.cell_m, "sub_pixels": self.sub_pixels}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["cell_m"], sub_pixels=state["sub_pixels"])

    def _scratch(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(2, n) float64 (the two coordinate planes) and (n,) int64 (the box index)."""
        if self._buf.shape[1] < n:
            self._buf, self._ibuf = np.empty((2, n)), np.empty(n, dtype=np.int64)
        return self._buf, self._ibuf

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
        for a in range(r0, r1, step):
            parts.append(self._reduce_sub(geometry, covered, pd, slice(a, min(r1, a + step)), slice(c0, c1)))
        if len(parts) == 1:
            return parts[0]
        return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
                np.concatenate([p[2] for p in parts], axis=1))

    def _reduce_sub(self, geometry: TileGeometry, covered: Sequence[np.ndarray], pd: Sequence[np.ndarray],
                    rows: slice, cols: slice) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`reduce` of one sub-block (cells unique within it)."""
        h_px = rows.stop - rows.start
        w_px = cols.stop - cols.start
        n = h_px * w_px
        buf, ibuf = self._scratch(n)
        fy, fx = buf[0, :n].reshape(h_px, w_px), buf[1, :n].reshape(h_px, w_px)
        # world(i, j) = p_i + r_j u_i (atr_node.geo.georef), cell = floor(world / cell_m):
        # the expression of pixel_cells, evaluated in place
        r = geometry.ranges_m[None, cols]
        for f, pos, u in ((fy, geometry.north_m, geometry.un), (fx, geometry.east_m, geometry.ue)):
            np.multiply(r, u[rows, None], out=f)
            f += pos[rows, None]
            f /= self.cell_m
            np.floor(f, out=f)
        if w_px > 1 and np.all(r[0, 1:] >= r[0, :-1]):
            # ranges increase along a row, and p + r u, / cell_m and floor are monotone in r
            # (IEEE rounding is monotone): a row's extremes are at its first or last column
            ends = np.concatenate([fy[:, 0], fy[:, -1]]), np.concatenate([fx[:, 0], fx[:, -1]])
        else:
            ends = fy, fx
        y0, y1, x0, x1 = float(ends[0].min()), float(ends[0].max()), float(ends[1].min()), float(ends[1].max())
        h, w = int(y1) - int(y0) + 1, int(x1) - int(x0) + 1
        local = ibuf[:n]
        if h * w <= max(4 * n, 1 << 16) and max(abs(y0), abs(y1), abs(x0), abs(x1)) * (w + 2) < 2.0 ** 52:
            # dense box over the sub-block's cells: local = (iy - y0) w + (ix - x0), exact in
            # float64 (integers below 2^53), one cast
            fy *= w  # (iy - y0) w + (ix - x0) = iy w + ix - (y0 w + x0): all exact integers
            fy += fx
            fy -= y0 * w + x0
            np.copyto(local, fy.reshape(-1), casting="unsafe")
            g = np.arange(h * w, dtype=np.int64)
            cell_iy, cell_ix = g // w + int(y0), g % w + int(x0)
        else:
            # a footprint far wider than a tile (a nav jump): only the cells present
            iy, ix = fy.reshape(-1).astype(np.int64), fx.reshape(-1).astype(np.int64)
            order = np.lexsort((ix, iy))
            sy, sx = iy[order], ix[order]
            first = np.r_[True, (sy[1:] != sy[:-1]) | (sx[1:] != sx[:-1])]
            local[order] = np.cumsum(first) - 1
            cell_iy, cell_ix = sy[first], sx[first]
        # Pd depends on the column only, so a pixel in the same cell and column as the pixel
        # above it, with the same coverage, has the same value: only the first pixel of each
        # such vertical run (about one in three) is scattered. Coverage that is constant down
        # each column of the sub-block (the valid window: the usual case) folds into the
        # per-column values (-1: not covered); otherwise a change of coverage starts a run.
        loc2 = local.reshape(h_px, w_px)
        first_px = np.empty((h_px, w_px), dtype=bool)
        first_px[0] = True
        np.not_equal(loc2[1:], loc2[:-1], out=first_px[1:])
        per_det = []  # (column values, pixel coverage or None)
        for cov, p in zip(covered, pd):
            c = cov[rows, cols]
            col_any = c.any(axis=0)
            if not col_any.any():
                per_det.append(None)
                continue
            # uncovered pixels carry -1: a no-op under the maximum (Pd is in [0, 1])
            pcol = np.where(col_any, p[cols], -1.0)
            if np.array_equal(c.all(axis=0), col_any):
                per_det.append((pcol, None))
            else:
                first_px[1:] |= c[1:] != c[:-1]
                per_det.append((pcol, c))
        idx = np.flatnonzero(first_px)
        loc_k = local[idx]
        col_k = self._columns(h_px, w_px)[idx]
        box = np.full((len(covered), cell_iy.size), -1.0)
        for j, item in enumerate(per_det):
            if item is None:
                continue
            pcol, c = item
            v = pcol[col_k]
            if c is not None:
                v[~c.reshape(-1)[idx]] = -1.0
            np.maximum.at(box[j], loc_k, v)
        keep = np.flatnonzero((box >= 0.0).any(axis=0))
        return cell_iy[keep], cell_ix[keep], box[:, keep]

    def _columns(self, h_px: int, w_px: int) -> np.ndarray:
        """Column of each pixel of an (h_px, w_px) sub-block, flattened (a cached prefix: a
        row-major block of fewer rows is a prefix of one of more)."""
        n = h_px * w_px
        if self._cols_w != w_px or self._cols.size < n:
            self._cols = np.tile(np.arange(w_px, dtype=np.intp), max(h_px, self.sub_pixels // max(w_px, 1)))
            self._cols_w = w_px
        return self._cols[:n]
