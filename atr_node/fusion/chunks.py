"""Chunk storage of the evidence grid and the per-leg evidence layer (SPEC section 7).

:class:`ChunkStack` is a growable stack of fixed-size per-chunk arrays with a
``(cy, cx) -> slot`` table, so that every operation on many chunks is one numpy expression
on ``arr[slots]``. Freed slots (chunks of an open leg committed early) are reused.

:class:`LegLayer` holds the evidence of one open leg, per (chunk, detector, cell): the
maximum T mass of the detections whose gate reached the cell and the maximum Pd over the
covered pixels of the cell, ``-1`` meaning none. :func:`layer_terms` turns a layer into the
log terms the leg adds to the accumulators, one piece per (leg, detector, cell).
"""

from __future__ import annotations

import numpy as np

Key = tuple[int, int]


class ChunkStack:
    """Growable stack of per-chunk arrays of shape ``item``, with a key -> slot table."""

    def __init__(self, item: tuple[int, ...], fill: float) -> None:
        self.item, self.fill = item, fill
        self.slot: dict[Key, int] = {}
        self.free: list[int] = []
        self.high = 0
        """Slots ever used; the capacity beyond stays untouched (not resident in memory)."""
        self.arr = np.empty((4, *item))

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

    def release(self, keys: list[Key]) -> None:
        """Forget chunks and reset their slots for reuse."""
        slots = [self.slot.pop(k) for k in keys]
        self.arr[slots] = self.fill
        self.free.extend(slots)

    def gather(self, keys: list[Key] | None = None) -> np.ndarray:
        """Copy of the arrays of ``keys`` (default all), (K, *item)."""
        return self.arr[self.slots(keys)]


class LegLayer:
    """Evidence of one open leg (see the module docstring)."""

    def __init__(self, n_det: int, nn: int) -> None:
        self.chunks = ChunkStack((n_det, 2, nn), -1.0)
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

    Per (detector, cell): T evidence ``log1p(-c)`` where a detection's gate reached the cell,
    else notT evidence ``log1p(-Pd)`` where the detector covered it, else nothing; masses
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
    c, q = p[:, :, 0], p[:, :, 1]
    has_t = c >= 0.0
    has_n = (q >= 0.0) & ~has_t  # the gate excludes notT: T wins for this (leg, detector)
    top = 1.0 - eps
    n_clamped = int(np.count_nonzero(has_t & (c > top)) + np.count_nonzero(has_n & (q > top)))
    terms = np.zeros(p.shape)
    # log1p only where there is evidence (T evidence is rare: near detections); elsewhere the
    # term is 0. Element for element the values of where(has, log1p(-min(|m|, top)), 0)
    # (|m| keeps a -0.0 mass giving the same signed zero as ever)
    for which, m, has in ((0, c, has_t), (1, q, has_n)):
        if has.all():
            terms[:, :, which] = np.log1p(-np.minimum(np.abs(m), top))  # |m|: as below (-0.0)
        elif has.any():
            terms[:, :, which][has] = np.log1p(-np.minimum(np.abs(m[has]), top))
    d_lt, d_ln = terms[:, 0, 0].copy(), terms[:, 0, 1].copy()
    for d in range(1, p.shape[1]):  # fixed detector order: the same sum bit for bit everywhere
        d_lt += terms[:, d, 0]
        d_ln += terms[:, d, 1]
    return d_lt, d_ln, n_clamped, terms if per_detector else None
