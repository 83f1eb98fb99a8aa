"""The summed-area engine: padded tables built once per tile, box sums read by whole-array slices.

Every detector statistic is a sum over axis-aligned rectangles (SPEC section 1). For an image
``B`` its summed-area table ``T[y, x] = sum(B[:y, :x])`` (``cv2.integral``, shape
``(rows + 1, cols + 1)``) gives any box sum from four corners::

    sum(B[y0:y1, x0:x1]) = T[y1, x1] - T[y0, x1] - T[y1, x0] + T[y0, x0]

Images are laid into a buffer padded on every side by the windows' reach, with the pad
holding "no data" (0 in the value and mask images), so every window of every pixel of the tile
is a rectangle inside the buffer: no clipping, no special case at the edges, and a window that
runs off the tile simply counts the missing part as no data. Reads are done for a block of
anchor rows at a time: a *row strip* ``D = T[i + off1] - T[i + off0]`` (a slice difference)
then a column difference ``D[:, c1] - D[:, c0]`` with per-column offsets (a slice where the
offset is constant, a gather where it depends on range). Blocks are sized to stay in cache.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import cv2
import numpy as np

from .windows import WindowGeometry

ColumnIndex = slice | np.ndarray
"""Columns of a table to read: a slice where offsets are constant, an int array otherwise."""


@dataclass(frozen=True)
class Padding:
    """Pixels of no data around the tile in the buffers, so every window fits inside."""

    top: int
    bottom: int
    left: int
    right: int

    @classmethod
    def for_geometry(cls, geometry: WindowGeometry) -> "Padding":
        up, down, left, right = geometry.reach()
        return cls(top=up, bottom=down, left=left, right=right)


_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
"""glibc ``mallopt`` parameters (malloc.h)."""
_malloc_tuned = False


def keep_freed_memory(trim_bytes: int = 256 << 20, mmap_bytes: int = 32 << 20) -> bool:
    """Ask glibc's malloc to keep freed memory for reuse instead of returning it to the system.

    The detectors work block by block with temporaries of about 1 MB. By default glibc gives
    the top of its heap back to the system once more than a few MB of it is free (and serves
    some blocks with fresh ``mmap``), so the next block touches fresh pages again: a page fault
    per 4 kB, which on a virtual machine costs as much as the arithmetic. Measured on the
    2048 x 4096 benchmark tile: 277-293 ms best of 12 with the defaults, 192-219 ms with
    freed memory kept (``tools/bench/detectors.py score``). Memory is only kept up to
    ``trim_bytes`` free at the top of the heap; allocations under ``mmap_bytes`` come from the
    heap. Once per process; a no-op (False) where malloc is not glibc's, or with the
    environment variable ``ATR_KEEP_FREED_MEMORY=0`` (to measure the defaults).
    """
    global _malloc_tuned
    if os.environ.get("ATR_KEEP_FREED_MEMORY", "1") == "0":  # malloc's defaults, for A/B runs
        return False
    if _malloc_tuned:
        return True
    try:
        import ctypes
        import ctypes.util

        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        ok = bool(libc.mallopt(_M_TRIM_THRESHOLD, int(trim_bytes))) and bool(libc.mallopt(_M_MMAP_THRESHOLD, int(mmap_bytes)))
    except (OSError, AttributeError, TypeError):
        return False
    _malloc_tuned = ok
    return ok


class Workspace:
    """Buffers kept between calls, so tiles of the same shape reuse memory.

    Fresh memory costs a page fault per page on first touch, which on a virtual machine can
    cost more than the summed-area tables themselves; a node scoring tile after tile keeps one
    workspace per worker thread and passes it to :func:`~.engine.score_maps`. Not thread-safe.
    """

    def __init__(self) -> None:
        self._arrays: dict[str, np.ndarray] = {}
        keep_freed_memory()  # the blocks' temporaries too are reused, not page-faulted anew

    def array(self, name: str, shape: tuple[int, ...], dtype: np.dtype | type) -> np.ndarray:
        """An uninitialised C-contiguous array ``name`` of this shape and dtype.

        It is a view into a byte buffer kept under ``name`` and reused whenever it is large
        enough, so units of slightly different shapes (a leg's first and last, margins) do not
        reallocate; a buffer that must grow takes 1/8 more than asked for.
        """
        dt = np.dtype(dtype)
        nbytes = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
        buf = self._arrays.get(name)
        if buf is None or buf.size < nbytes:
            buf = self._arrays[name] = np.empty(nbytes + nbytes // 8, np.uint8)
        return buf[:nbytes].view(dt).reshape(shape)

    def clear(self) -> None:
        """Release every buffer."""
        self._arrays.clear()


class SummedAreaTables:
    """Summed-area tables of several images of one tile, on a common padded grid.

    Parameters
    ----------
    shape : (rows, cols)
        The tile's shape.
    padding : Padding
        No-data border around the tile in every buffer.
    workspace : Workspace, optional
        Where buffers and tables live; default: fresh memory.
    """

    def __init__(self, shape: tuple[int, int], padding: Padding, workspace: Workspace | None = None) -> None:
        self.rows, self.cols = shape
        self.pad = padding
        self.ws = workspace if workspace is not None else Workspace()
        self.tables: dict[str, np.ndarray] = {}

    def buffer(self, name: str, dtype: np.dtype | type, fill: float = 0) -> tuple[np.ndarray, np.ndarray]:
        """A padded image buffer whose pad holds ``fill``, and a view of its tile interior.

        The interior is left uninitialised: the caller writes every pixel of it.

        Returns
        -------
        full : ndarray, shape (top + rows + bottom, left + cols + right)
        interior : ndarray, shape (rows, cols), a view into ``full``
        """
        p = self.pad
        full = self.ws.array("image " + name, (p.top + self.rows + p.bottom, p.left + self.cols + p.right), dtype)
        full[:p.top] = fill
        full[p.top + self.rows:] = fill
        full[p.top:p.top + self.rows, :p.left] = fill
        full[p.top:p.top + self.rows, p.left + self.cols:] = fill
        return full, full[p.top:p.top + self.rows, p.left:p.left + self.cols]

    def _table(self, name: str, buffer: np.ndarray, sdepth: int) -> np.ndarray:
        dtype = {cv2.CV_32S: np.int32, cv2.CV_32F: np.float32, cv2.CV_64F: np.float64}[sdepth]
        return self.ws.array("table " + name, (buffer.shape[0] + 1, buffer.shape[1] + 1), dtype)

    def add(self, name: str, buffer: np.ndarray, sdepth: int) -> None:
        """Integrate a padded buffer into table ``name`` (``sdepth``: cv2.CV_32S/32F/64F)."""
        self.tables[name] = cv2.integral(buffer, self._table(name, buffer, sdepth), sdepth=sdepth)

    def add_with_squares(self, name: str, name_sq: str, buffer: np.ndarray, sdepth: int,
                         sqdepth: int | None = None) -> None:
        """Tables of a buffer and of its square in one pass (``cv2.integral2``)."""
        sqdepth = sdepth if sqdepth is None else sqdepth
        self.tables[name], self.tables[name_sq] = cv2.integral2(
            buffer, self._table(name, buffer, sdepth), self._table(name_sq, buffer, sqdepth),
            sdepth=sdepth, sqdepth=sqdepth)

    def strip(self, name: str, first_row: int, count: int, step: int, off0: int, off1: int) -> np.ndarray:
        """Row strips of table ``name`` for ``count`` anchor rows from ``first_row`` by ``step``.

        Returns ``D`` with ``D[k, x] = sum(B[i + off0 : i + off1, :x])`` for anchor row
        ``i = first_row + k * step`` (tile coordinates); shape (count, padded cols + 1).
        """
        t = self.tables[name]
        a = first_row + self.pad.top
        stop = (count - 1) * step + 1
        lo = t[a + off0:a + off0 + stop:step]
        hi = t[a + off1:a + off1 + stop:step]
        return hi - lo

    def columns(self, offsets: np.ndarray | int, anchors: slice | np.ndarray) -> ColumnIndex:
        """Padded table column of ``anchor + offset`` for each anchor column.

        ``offsets`` is an int or a per-tile-column array; ``anchors`` a slice (start, stop,
        step) of tile columns. A constant offset gives a slice (a view), a varying one an index
        array (a gather).
        """
        x0 = self.pad.left
        if isinstance(offsets, (int, np.integer)):
            if isinstance(anchors, slice):
                start, stop, step = anchors.indices(self.cols)
                return slice(start + x0 + int(offsets), stop + x0 + int(offsets), step)
            return np.asarray(anchors) + (x0 + int(offsets))
        js = np.arange(self.cols)[anchors]
        return (js + x0 + np.asarray(offsets)[js]).astype(np.intp)


MIN_SLICE_RUN = 256
"""Anchor columns over which both offsets of a box must stay constant for :class:`ColumnPairs`
to read them as slices (views) instead of gathers: each extra piece costs a call per block."""


class ColumnPairs:
    """The two columns ``(col0, col1)`` of a box difference, split into pieces of anchors.

    A gather (``np.take``) moves each item about three times slower than a slice difference
    reads it. Where a window's offset is constant over a long run of anchors (the shadow past
    the range where it reaches ``shadow_max_m``, the context window with it) that run is read
    as slices; the rest as gathers. Computed once per tile, used for every block.

    Parameters
    ----------
    col0, col1 : slice or ndarray
        From :meth:`SummedAreaTables.columns`, selecting the same number of columns.
    step : int
        Table columns between consecutive anchors (the decimation).
    min_run : int, optional
        Shortest run of anchors read as slices; default :data:`MIN_SLICE_RUN`.
    """

    def __init__(self, col0: ColumnIndex, col1: ColumnIndex, step: int = 1, min_run: int | None = None) -> None:
        idx0, idx1 = _as_index(col0), _as_index(col1)
        if idx0.size != idx1.size:
            raise ValueError(f"ColumnPairs: {idx0.size} and {idx1.size} columns")
        self.n = n = idx0.size
        # Anchors k whose columns both lie ``step`` past those of anchor k - 1.
        linear = np.zeros(n, bool)
        if n > 1:
            linear[1:] = (np.diff(idx0) == step) & (np.diff(idx1) == step)
        # Runs: [a, b) with linear[a + 1 : b] all true (a run starts at a non-linear anchor).
        starts = np.flatnonzero(~linear)
        bounds = np.append(starts, n)
        pieces: list[tuple[int, int, bool]] = []  # (a, b, as slices)
        for a, b in zip(bounds[:-1], bounds[1:]):
            a, b = int(a), int(b)
            as_slices = b - a >= (MIN_SLICE_RUN if min_run is None else min_run)
            if pieces and not as_slices and not pieces[-1][2]:
                pieces[-1] = (pieces[-1][0], b, False)  # merge short runs into one gather
            else:
                pieces.append((a, b, as_slices))
        self.pieces: tuple[tuple[slice, ColumnIndex, ColumnIndex], ...] = tuple(
            (slice(a, b),) + tuple(_piece(i, a, b, step, sl) for i in (idx0, idx1)) for a, b, sl in pieces)

    @property
    def gathered(self) -> int:
        """Anchors read by gathers (for tests and benchmarks)."""
        return sum(p[0].stop - p[0].start for p in self.pieces
                   if not (isinstance(p[1], slice) and isinstance(p[2], slice)))


def _as_index(col: ColumnIndex) -> np.ndarray:
    if isinstance(col, slice):
        return np.arange(col.start, col.stop, col.step or 1, dtype=np.intp)
    return np.asarray(col, dtype=np.intp)


def _piece(idx: np.ndarray, a: int, b: int, step: int, as_slice: bool) -> ColumnIndex:
    """Columns of anchors [a, b): a slice where they advance by ``step``, else indices."""
    part = idx[a:b]
    if as_slice or part.size == 1 or bool((np.diff(part) == step).all()):
        return slice(int(part[0]), int(part[0]) + step * part.size, step)
    return part


def box(strip: np.ndarray, pairs: ColumnPairs) -> np.ndarray:
    """Column difference of a row strip: the box sums ``D[:, col1] - D[:, col0]``.

    Parameters
    ----------
    strip : ndarray, shape (count, padded cols + 1)
        From :meth:`SummedAreaTables.strip`.
    pairs : ColumnPairs
        The columns to read, from :meth:`SummedAreaTables.columns`.

    Returns
    -------
    ndarray, shape (count, pairs.n)
    """
    if len(pairs.pieces) == 1:
        _, col0, col1 = pairs.pieces[0]
        return _read(strip, col1) - _read(strip, col0)
    out = np.empty((strip.shape[0], pairs.n), strip.dtype)
    for cols, col0, col1 in pairs.pieces:
        np.subtract(_read(strip, col1), _read(strip, col0), out=out[:, cols])
    return out


def _read(strip: np.ndarray, cols: ColumnIndex) -> np.ndarray:
    return strip[:, cols] if isinstance(cols, slice) else _gather(strip, cols)


def _gather(strip: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``strip[:, cols]``; integer tables go through a float view of the same item size, which
    numpy's ``take`` moves about twice as fast as int32 items."""
    if strip.dtype.kind in "iu":
        as_float = np.dtype(f"f{strip.dtype.itemsize}")
        return np.take(strip.view(as_float), cols, axis=1).view(strip.dtype)
    return np.take(strip, cols, axis=1)
