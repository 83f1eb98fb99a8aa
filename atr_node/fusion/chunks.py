"""Chunk storage of the evidence grid and the per-leg evidence layer (SPEC section 7).

:class:`ChunkStack` is a growable stack of fixed-size per-chunk arrays with a
``(cy, cx) -> slot`` table, so that every operation on many chunks is one numpy expression
on ``arr[slots]``. Freed slots (chunks of an open leg committed early) are reused.

:class:`LegLayer` holds the evidence of one open leg, per (chunk, detector, cell): the
maximum T mass of the detections whose gate reached the cell and the maximum Pd over the
covered pixels of the cell, ``-1`` meaning none. :func:`layer_terms` turns a layer into the
log terms the leg adds to the accumulators, one piece per (leg, detector, cell), T mass
only on cells the same (leg, detector) covered (one footprint, SPEC 6.1).
"""

from __future__ import annotations

import numpy as np

Key = tuple[int, int]


class ChunkStack:
    """Growable stack of per-chunk arrays of shape ``item``, with a key -> slot table."""

    def __init__(self, item: tuple[int, ...], fill: float, *, buffer: np.ndarray | None = None) -> None:
        self.item, self.fill = item, fill
        self.slot: dict[Key, int] = {}
        self.free: list[int] = []
        self.high = 0
        """Slots ever used; the capacity beyond stays untouched (not resident in memory)."""
        # a buffer of a discarded stack (its pages already mapped): every slot is filled
        # when allocated, so its old contents never show
        ok = buffer is not None and buffer.shape[1:] == tuple(item) and buffer.dtype == np.float64
        self.arr = buffer if ok else np.empty((4, *item))

    def __len__(self) -> int:
        return len(self.slot)

    @property
    def keys(self) -> list[Key]:
        return list(self.slot)

    def slots(self, keys: list[Key] | None = None) -> np.ndarray:
        """Slots of ``keys`` (default: all, in insertion order) as an int64 array."""
        keys = self.keys if keys is None else keys
        return np.array([self.slot[k] for k in keys], dtype=np.int64)

    def get(self, key: Key) -> int:
        """Slot of ``key``, allocated (filled with ``fill``) if new. May replace ``arr``:
        index ``arr`` only after this call."""
        s = self.slot.get(key)
        if s is None:
            if self.free:
                s = self.free.pop()
            else:
                s = self.high
                self.high += 1
                if s == self.arr.shape[0]:
                    # doubling keeps growth amortised O(1); np.empty leaves the new capacity
                    # untouched, so the OS maps its pages only when slots are used
                    grown = np.empty((2 * s, *self.item))
                    grown[:s] = self.arr
                    self.arr = grown
                self.arr[s] = self.fill
            self.slot[key] = s
        return s

    def reserve(self, n: int) -> None:
        """Room for ``n`` slots in all, its memory written now.

        Slots allocated later, up to ``n``, then copy nothing (no doubling) and touch no fresh
        page: a node reserves at start what its first tiles would otherwise page-fault in, on
        the target VM about 1 s of the first 8-Mpx tiles' fusion (``docs/fusion.md``).
        """
        n = int(n)
        if n > self.arr.shape[0]:
            grown = np.empty((n, *self.item))
            grown[:self.high] = self.arr[:self.high]
            self.arr = grown
        self.arr[self.high:n] = self.fill  # unused slots: get() fills them again when it allocates

    def release(self, keys: list[Key]) -> None:
        """Forget chunks and reset their slots for reuse."""
        slots = [self.slot.pop(k) for k in keys]
        self.arr[slots] = self.fill
        self.free.extend(slots)

    def gather(self, keys: list[Key] | None = None) -> np.ndarray:
        """Copy of the arrays of ``keys`` (default all), (K, *item)."""
        return self.arr[self.slots(keys)]

    def view(self, keys: list[Key]) -> np.ndarray:
        """The arrays of ``keys`` (K, *item): a view of the stack if they hold slots 0..K-1 in
        order (no copy), else a copy. Read it before changing the stack."""
        slots = self.slots(keys)
        if slots.size and slots[0] == 0 and slots[-1] == slots.size - 1 and np.all(np.diff(slots) == 1):
            return self.arr[:slots.size]
        return self.arr[slots]


class LegLayer:
    """Evidence of one open leg (see the module docstring)."""

    def __init__(self, n_det: int, nn: int, *, buffer: np.ndarray | None = None) -> None:
        # buffer: the array of a closed leg's layer, reused (no page faults, no growth copies)
        self.chunks = ChunkStack((n_det, 2, nn), -1.0, buffer=buffer)
        self.t = -np.inf
        self.n_obs = 0
        """Observations of this leg so far."""
        self.touched: dict[Key, int] = {}
        """chunk -> ``n_obs`` when last touched (for early commit behind the vehicle)."""
        self.retired: set[Key] = set()
        """Chunks of this leg already committed early."""

    def stale(self, after_obs: int) -> list[Key]:
        """Chunks not touched by the last ``after_obs`` observations of the leg."""
        if after_obs <= 0:
            return []
        return [k for k, n in self.touched.items() if self.n_obs - n >= after_obs]


def layer_terms(p: np.ndarray, eps: float, *, per_detector: bool = True
                ) -> tuple[np.ndarray, np.ndarray, int, np.ndarray | None]:
    """Log terms one leg adds, from its layer ``p`` (K, n_det, 2, nn) (SPEC sections 6-7).

    Per (detector, cell): T evidence ``log1p(-c)`` where a detection's gate reached the cell
    and the detector covered it (one footprint, SPEC 6.1), else notT evidence ``log1p(-Pd)``
    where the detector covered it, else nothing; masses
    clamped to ``1 - eps`` (SPEC section 6).

    Parameters
    ----------
    p : ndarray (K, n_det, 2, nn)
        Layer values, -1 meaning no evidence.
    eps : float
        Clamp: masses above ``1 - eps`` count as ``1 - eps``.
    per_detector : bool
        Also return the per-detector terms (diagnostics; the read-out paths do not need
        them).

    Returns
    -------
    (d_lt, d_ln, n_clamped, per_det)
        (K, nn) additions to L_T and L_N, the number of masses clamped, and the
        per-detector terms (K, n_det, 2, nn), or None.
    """
    d_lt, d_ln, n_clamped, per_det, _ = layer_terms_covered(p, eps, per_detector=per_detector, coverage=False)
    return d_lt, d_ln, n_clamped, per_det


def layer_terms_covered(p: np.ndarray, eps: float, *, per_detector: bool = True, coverage: bool = True
                        ) -> tuple[np.ndarray, np.ndarray, int, np.ndarray | None, np.ndarray | None]:
    """:func:`layer_terms`, and the (K, nn) bool cells covered by some detector (a Pd
    value >= 0 in the layer: the coverage bitmap of the leg; a gate's T mass alone does not
    cover a cell), from the same masks (None if not ``coverage``)."""
    c, q = p[:, :, 0], p[:, :, 1]
    has_t = c >= 0.0
    has_n = q >= 0.0  # this (leg, detector) covered the cell: its footprint
    covered = has_n.any(axis=1) if coverage else None
    # the gate excludes notT: T wins for this (leg, detector). With has_t clipped to the
    # footprint below, has_n & ~clipped == has_n & ~has_t: no need to clip it first
    has_n &= ~has_t
    top = 1.0 - eps
    # T evidence is rare (near detections): its terms only in the chunks that hold some
    rows_t = np.flatnonzero(has_t.any(axis=(1, 2)))
    # one footprint for T and notT (SPEC 6.1): a gate's T mass counts only on cells this
    # (leg, detector) covered, where it could as well have given notT. Clipped here, when
    # the terms are formed, not when the gate is deposited: the leg's footprint is complete
    # only once its later tile cores arrived, and a maximum layer then clipped is free of
    # the tile cut, of the order of arrival and of merges (open layers combine by maximum)
    c_t, has_ct = c[rows_t], has_t[rows_t] & (q[rows_t] >= 0.0)
    n_clamped = int(np.count_nonzero(has_ct & (c_t > top)) + np.count_nonzero(has_n & (q > top)))
    # per (detector, cell) term log1p(-min(|m|, top)) where there is evidence, +0.0 elsewhere
    # (|m|: a -0.0 mass gives -0.0 as ever). Computed on contiguous copies, in place: a
    # boolean assignment into the strided view of a (K, n_det, 2, nn) array costs 5x more
    t_t = _terms(c_t, has_ct, top)
    t_n = _terms(q, has_n, top)
    d_ln = _sum_detectors(t_n, p.shape)
    d_lt = np.zeros_like(d_ln)  # chunks without T: a sum of +0.0 terms
    if t_t is not None:
        d_lt[rows_t] = _sum_detectors(t_t, t_t.shape)
    if not per_detector:
        return d_lt, d_ln, n_clamped, None, covered
    terms = np.zeros(p.shape)
    if t_t is not None:
        terms[rows_t, :, 0] = t_t
    if t_n is not None:
        terms[:, :, 1] = t_n
    return d_lt, d_ln, n_clamped, terms, covered


def _sum_detectors(t: np.ndarray | None, shape: tuple[int, ...]) -> np.ndarray:
    """(K, nn) sum over detectors of ``t`` (K, n_det, nn), in the fixed detector order (the
    same sum bit for bit everywhere); +0.0 (a sum of +0.0 terms) if ``t`` is None."""
    if t is None:
        return np.zeros((shape[0], shape[-1]))
    s = t[:, 0].copy()
    for d in range(1, t.shape[1]):
        s += t[:, d]
    return s


def _terms(m: np.ndarray, has: np.ndarray, top: float) -> np.ndarray | None:
    """(K, n_det, nn) ``log1p(-min(|m|, top))`` where ``has``, +0.0 elsewhere; None if no
    element has evidence. Element for element the values of a masked evaluation: log1p is
    applied to contiguous float64 arrays either way."""
    if has.all():
        x = np.abs(m)
        np.minimum(x, top, out=x)
        np.negative(x, out=x)
        return np.log1p(x, out=x)
    n_has = int(np.count_nonzero(has))
    if n_has == 0:
        return None
    if 4 * n_has < m.size:  # sparse (T evidence: near detections only)
        out = np.zeros(m.shape)
        out[has] = np.log1p(-np.minimum(np.abs(m[has]), top))
        return out
    x = np.abs(m)
    np.minimum(x, top, out=x)
    np.copyto(x, 0.0, where=~has)  # no evidence: log1p(-0.0), replaced by +0.0 below
    np.negative(x, out=x)
    np.log1p(x, out=x)
    np.copyto(x, 0.0, where=~has)
    return x
