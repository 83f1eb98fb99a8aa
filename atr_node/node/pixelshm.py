"""Unit pixels to the detection worker through shared memory, not through a pipe (issue 7).

A strip unit of an 8-Mpx tile is 34 MB of float32 pixels. Sent as an argument of the
worker's job it is pickled, written through the executor's pipe, read and unpickled into
fresh memory in the worker: 0.115-0.19 s on the target VM for the round trip of one such
array to an idle worker (measured 2026-11-23), latency added to every tile. Instead the main
process copies the pixels into a *slot*: an anonymous shared-memory file (``memfd``: no path,
nothing written outside the node's data directory, nothing left behind by a SIGKILL) that it
keeps mapped; the job carries the slot's reference, and the worker maps the same memory once
(through ``/proc/<node pid>/fd/<fd>``) and reads the pixels in place, read-only (a detector
that wrote into its input would fail loudly, not corrupt the slot). A slot is reused once its
unit's result is back, so after the first units no memory is touched for the first time on
either side. Results are unchanged: the worker sees the same pixels, bit for bit.

Linux only (``os.memfd_create`` and ``/proc``); the pipeline checks at start that the worker
can read a slot (:func:`probe`) and sends pixels through the pipe until then, or for good if
it cannot.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import mmap
import os
from collections import OrderedDict
from concurrent.futures import Executor, Future
from dataclasses import dataclass

import numpy as np

from ..errors import describe
from .detect import DetectJob, DetectResult, detect

log = logging.getLogger(__name__)

MIN_SLOT_BYTES = 1 << 20
WORKER_MAPS = 24
"""Mappings the worker keeps (least recently used beyond that are closed)."""
_SERIAL = itertools.count(1)
"""Slot numbers, unique in this process (fd numbers are reused; serials are not)."""


@dataclass(frozen=True)
class SlotRef:
    """A unit's pixels in a slot: whose memory, which one, the array's shape and dtype."""

    pid: int
    fd: int
    serial: int
    capacity: int
    shape: tuple[int, ...]
    dtype: str


def available() -> bool:
    """Whether this system has anonymous shared-memory files (Linux ``memfd_create``)."""
    return hasattr(os, "memfd_create") and os.path.isdir(f"/proc/{os.getpid()}/fd")


class _Slot:
    def __init__(self, capacity: int) -> None:
        self.serial = next(_SERIAL)
        self.capacity = capacity
        self.fd = os.memfd_create(f"atr-node-px-{self.serial}", os.MFD_CLOEXEC)
        try:
            os.ftruncate(self.fd, capacity)
            self.mm = mmap.mmap(self.fd, capacity)
        except OSError:
            os.close(self.fd)
            raise

    def close(self) -> None:
        try:
            self.mm.close()
        except BufferError:  # an array still views it: unmapped when the last one goes
            pass
        os.close(self.fd)


class PixelSlots:
    """Main-process side: a pool of shared-memory slots for unit pixels."""

    def __init__(self) -> None:
        if not available():
            raise OSError("no anonymous shared memory (memfd_create) on this system")
        self._free: list[_Slot] = []
        self._busy: dict[int, _Slot] = {}
        self._staged: dict[int, tuple[np.ndarray, _Slot]] = {}
        """id(array) -> (array, slot): arrays handed out by :meth:`alloc`, not yet :meth:`put`."""

    def _take(self, nbytes: int) -> _Slot:
        fits = [s for s in self._free if s.capacity >= nbytes]
        if fits:
            slot = min(fits, key=lambda s: s.capacity)
            self._free.remove(slot)
        else:
            if self._free:  # a free slot too small for today's units: replace it
                self._free.pop(0).close()
            slot = _Slot(max(MIN_SLOT_BYTES, nbytes + nbytes // 8))
        self._busy[slot.serial] = slot
        return slot

    def alloc(self, shape: tuple[int, ...], dtype: np.dtype | str) -> np.ndarray:
        """An array in a free slot, for the caller to fill and then :meth:`put` (no copy
        then), or :meth:`discard`. The slot stays taken until the ref ``put`` returns is
        released."""
        dtype = np.dtype(dtype)
        nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        slot = self._take(nbytes)
        arr = np.ndarray(shape, dtype, buffer=slot.mm)
        self._staged[id(arr)] = (arr, slot)
        return arr

    def discard(self, pixels: np.ndarray) -> None:
        """An array from :meth:`alloc` that will not be sent: its slot is free again."""
        staged = self._staged.pop(id(pixels), None)
        if staged is not None and staged[0] is pixels:
            self._free.append(self._busy.pop(staged[1].serial))

    def put(self, pixels: np.ndarray) -> SlotRef:
        """``pixels`` in a slot: in place if :meth:`alloc` gave them, else copied into a free
        slot (a new one if none is large enough)."""
        staged = self._staged.pop(id(pixels), None)
        if staged is not None and staged[0] is pixels:
            slot = staged[1]
        else:
            slot = self._take(int(pixels.nbytes))
            np.ndarray(pixels.shape, pixels.dtype, buffer=slot.mm)[...] = pixels
        return SlotRef(os.getpid(), slot.fd, slot.serial, slot.capacity, tuple(pixels.shape), pixels.dtype.str)

    def release(self, ref: SlotRef) -> None:
        """The worker is done with ``ref``: its slot can take another unit."""
        slot = self._busy.pop(ref.serial, None)
        if slot is not None:
            self._free.append(slot)

    @property
    def slots(self) -> int:
        return len(self._free) + len(self._busy)

    def close(self) -> None:
        """Unmap and close every slot (the memory goes when the worker's mappings do)."""
        for slot in [*self._free, *self._busy.values()]:
            slot.close()
        self._free, self._busy, self._staged = [], {}, {}


_MAPS: OrderedDict[tuple[int, int], mmap.mmap] = OrderedDict()
"""Worker side: (pid, serial) -> read-only mapping of that slot, most recently used last."""


def slot_pixels(ref: SlotRef) -> np.ndarray:
    """Worker side: the pixels of ``ref``, read in place from the slot's mapping."""
    key = (ref.pid, ref.serial)
    mm = _MAPS.get(key)
    if mm is None:
        with open(f"/proc/{ref.pid}/fd/{ref.fd}", "rb") as fh:
            mm = mmap.mmap(fh.fileno(), ref.capacity, access=mmap.ACCESS_READ)
        _MAPS[key] = mm
        while len(_MAPS) > WORKER_MAPS:
            _MAPS.popitem(last=False)[1].close()
    _MAPS.move_to_end(key)
    return np.ndarray(ref.shape, np.dtype(ref.dtype), buffer=mm)


def detect_in_slot(job: DetectJob, ref: SlotRef) -> DetectResult:
    """Worker side: :func:`~atr_node.node.detect.detect` on the pixels of ``ref``."""
    return detect(dataclasses.replace(job, pixels=slot_pixels(ref)))


def probe(ref: SlotRef) -> bytes:
    """Worker side: the bytes of ``ref`` (the pipeline checks the worker reads slots right)."""
    return slot_pixels(ref).tobytes()


_NO_PIXELS = np.empty((0, 0), np.float32)
"""Placeholder pixels of a job whose pixels travel in a slot."""


class SlotChannel:
    """How the pipeline sends jobs to its worker: pixels in slots once the worker has read a
    probe slot right, through the pipe until then (or for good: no memfd, a failed probe,
    shared memory full).

    Parameters
    ----------
    pool : Executor
        The worker pool (one worker process).
    """

    def __init__(self, pool: Executor) -> None:
        self.pool = pool
        self.slots: PixelSlots | None = None
        self._refs: dict[int, SlotRef] = {}
        self._probe: tuple[Future, bytes, SlotRef] | None = None
        if not available():
            return
        try:
            self.slots = PixelSlots()
            sample = np.arange(64, dtype=np.float32).reshape(8, 8)
            ref = self.slots.put(sample)
            self._probe = (pool.submit(probe, ref), sample.tobytes(), ref)
        except OSError as exc:
            log.warning("unit pixels through the pipe: no shared-memory slots (%s)", exc)
            self.close()

    @property
    def ready(self) -> bool:
        """Whether jobs now carry their pixels in slots (the probe came back right)."""
        if self.slots is None:
            return False
        if self._probe is not None:
            fut, want, ref = self._probe
            if not fut.done():
                return False
            self._probe = None
            self.slots.release(ref)
            exc = fut.exception()
            if exc is not None or fut.result() != want:
                log.warning("unit pixels through the pipe: the worker cannot read shared-memory slots (%s)",
                            exc or "wrong bytes")
                self.close()
                return False
        return True

    def submit(self, job: DetectJob) -> Future:
        """Submit :func:`detect` of ``job`` to the worker, its pixels in a slot if ready."""
        ref = None
        if self.ready:
            try:
                ref = self.slots.put(job.pixels)
            except OSError as exc:  # shared memory exhausted: this unit goes through the pipe
                log.warning("unit pixels through the pipe: %s", describe(exc))
        if ref is None:
            return self.pool.submit(detect, job)
        fut = self.pool.submit(detect_in_slot, dataclasses.replace(job, pixels=_NO_PIXELS), ref)
        self._refs[id(fut)] = ref
        return fut

    def alloc(self, shape: tuple[int, ...], dtype: np.dtype | str = np.float32) -> np.ndarray:
        """An array for a unit's pixels: in a slot when jobs travel in slots (:meth:`submit`
        then sends it without a copy), else ordinary memory. An array that will not be
        submitted goes back with :meth:`discard`."""
        if self.ready:
            try:
                return self.slots.alloc(shape, dtype)
            except OSError as exc:  # shared memory exhausted: ordinary memory, the pipe
                log.warning("unit pixels through the pipe: %s", describe(exc))
        return np.empty(shape, dtype)

    def discard(self, pixels: np.ndarray) -> None:
        if self.slots is not None:
            self.slots.discard(pixels)

    def rekey(self, old: Future, new: Future) -> None:
        """The slot of ``old``'s job now belongs to ``new`` (a unit taken back from the worker)."""
        ref = self._refs.pop(id(old), None)
        if ref is not None:
            self._refs[id(new)] = ref

    def done(self, fut: Future) -> None:
        """The unit of ``fut`` is finished with: its slot (if any) can take another unit."""
        ref = self._refs.pop(id(fut), None)
        if ref is not None and self.slots is not None:
            self.slots.release(ref)

    @property
    def in_use(self) -> int:
        return len(self._refs)

    def close(self) -> None:
        if self.slots is not None:
            self.slots.close()
            self.slots = None
