"""Unit pixels through shared-memory slots (issue 7): exact, reused, read-only, released."""

from __future__ import annotations

import os

import numpy as np
import pytest

from atr_node.calibration.model import PerformanceModel
from atr_node.config import Settings
from atr_node.io.atrlog import read_atrlog
from atr_node.node import pixelshm
from atr_node.node.detect import DetectJob, detect
from atr_node.node.pipeline import Pipeline
from atr_node.node.pixelshm import PixelSlots, detect_in_slot, slot_pixels

pytestmark = pytest.mark.skipif(not pixelshm.available(), reason="memfd_create and /proc (Linux) needed")


def test_slots_round_trip_bit_for_bit_and_are_reused():
    slots = PixelSlots()
    rng = np.random.default_rng(0)
    a = rng.standard_normal((300, 201)).astype(np.float32)
    a[5, :7] = np.nan
    ra = slots.put(a)
    got = slot_pixels(ra)
    assert got.tobytes() == a.tobytes() and got.shape == a.shape and got.dtype == a.dtype
    with pytest.raises(ValueError):  # read-only in the reader: cannot corrupt the slot
        got[0, 0] = 1.0
    b = rng.standard_normal((100, 201)).astype(np.float32)
    rb = slots.put(b)  # a is still busy: a second slot
    assert rb.serial != ra.serial and slots.slots == 2
    slots.release(ra)
    c = rng.standard_normal((290, 201)).astype(np.float32)
    rc = slots.put(c)  # fits a's slot, now free: reused, and the reader sees the new pixels
    assert rc.serial == ra.serial and slots.slots == 2
    assert slot_pixels(rc).tobytes() == c.tobytes()
    big = np.ones((2000, 201), np.float32)
    slots.release(rb)
    rbig = slots.put(big)  # too large for the free slot: it is replaced, not kept
    assert slots.slots == 2 and rbig.capacity >= big.nbytes and rbig.serial not in (ra.serial, rb.serial)
    assert slot_pixels(rbig).tobytes() == big.tobytes()  # a reused fd number is a new slot to the reader
    fds = [rc.fd, rbig.fd]
    slots.close()
    for fd in fds:
        with pytest.raises(OSError):
            os.fstat(fd)


def test_an_allocated_slot_is_sent_without_a_copy_or_given_back():
    slots = PixelSlots()
    a = slots.alloc((300, 201), np.float32)
    a[...] = np.arange(300 * 201, dtype=np.float32).reshape(300, 201)
    assert slots.slots == 1 and len(slots._busy) == 1
    ra = slots.put(a)  # the array is already in its slot: no new slot, the reader sees it
    assert slots.slots == 1 and ra.shape == (300, 201)
    assert slot_pixels(ra).tobytes() == a.tobytes()
    a[0, 0] = -1.0  # the same memory, not a copy
    assert slot_pixels(ra)[0, 0] == -1.0
    copy = a.copy()
    rc = slots.put(copy)  # not from alloc: copied into another slot
    assert rc.serial != ra.serial and slot_pixels(rc).tobytes() == copy.tobytes()
    slots.release(ra)
    slots.release(rc)
    b = slots.alloc((100, 201), np.float32)  # takes a free slot
    assert slots.slots == 2 and len(slots._busy) == 1
    slots.discard(b)  # never sent: free again
    assert not slots._busy and not slots._staged and slots.slots == 2
    slots.discard(np.zeros(3))  # not one of its arrays: nothing happens
    slots.close()


def test_units_are_written_into_slots_and_every_slot_comes_back(small_mission):
    """With slots, the strip writes each unit's pixels straight into a slot; the slot stays
    the unit's until its fusion (a unit the main process takes back from the worker
    included), and the strip keeps no view of it (its margin rows are copies)."""
    import time
    settings, _cfg, files = small_mission
    pipe = Pipeline(settings, model=PerformanceModel.shipped(), workers=1, mode="replay")
    ref = Pipeline(settings, model=PerformanceModel.shipped(), workers=0, mode="replay")
    try:
        pipe.channel._probe[0].result(timeout=120)
        seen = []
        real_submit = pipe.channel.submit

        def submit(job):
            seen.append(any(job.pixels is arr for arr, _ in pipe.channel.slots._staged.values()))
            return real_submit(job)

        pipe.channel.submit = submit
        pipe._pool.submit(time.sleep, 2.0)  # a busy worker: the main process steals units
        recs = list(read_atrlog(files.atrlog))
        for rec in recs[:len(recs) * 2 // 3]:
            pipe.feed(rec)
        assert pipe.strips._legs
        for st in pipe.strips._legs.values():  # the rows kept for the next unit own their memory
            for rows in (st.context, st.pending):
                assert rows.px.base is None
        for rec in recs[len(recs) * 2 // 3:]:
            pipe.feed(rec)
        pipe.finish()
        got = pipe.contacts
        assert seen and all(seen)
        assert pipe.stats.units_main >= 1
        slots = pipe.channel.slots
        assert not slots._busy and not slots._staged and pipe.channel.in_use == 0
        assert got == ref.replay(read_atrlog(files.atrlog)).contacts and len(got) > 0
    finally:
        ref.close()
        pipe.close()


def test_two_slot_pools_in_one_process_do_not_share_memory():
    a, b = PixelSlots(), PixelSlots()
    try:
        ra = a.put(np.full((10, 10), 1.0, np.float32))
        rb = b.put(np.full((10, 10), 2.0, np.float32))
        assert (ra.fd, ra.serial) != (rb.fd, rb.serial)
        assert float(slot_pixels(ra)[0, 0]) == 1.0 and float(slot_pixels(rb)[0, 0]) == 2.0
    finally:
        a.close()
        b.close()


def test_detection_on_a_slot_equals_detection_on_the_array():
    s = Settings()
    rng = np.random.default_rng(1)
    px = rng.rayleigh(1.0, size=(400, 601)).astype(np.float32)
    px[200:204, 300:306] += 8.0  # something to detect
    job = DetectJob(0, px, (40, 360), 5.0, 0.1, 0.1, 14.0, np.ones(601), np.ones(601),
                    {d: 2.0 for d in s.detectors.enabled}, tuple(s.detectors.enabled), s.template, s.detectors)
    slots = PixelSlots()
    try:
        ref = slots.put(px)
        got = detect_in_slot(DetectJob(**{**job.__dict__, "pixels": np.empty((0, 0), np.float32)}), ref)
    finally:
        slots.close()
    want = detect(job)
    assert sum(len(v) for v in want.detections.values()) > 0
    assert got.detections == want.detections
    assert all(np.array_equal(got.covered(d), want.covered(d)) for d in s.detectors.enabled)


def test_replay_through_slots_equals_in_process_and_releases_them(small_mission):
    settings, _cfg, files = small_mission
    ref = Pipeline(settings, model=PerformanceModel.shipped(), workers=0, mode="replay")
    pipe = Pipeline(settings, model=PerformanceModel.shipped(), workers=1, mode="replay")
    try:
        pipe.channel._probe[0].result(timeout=120)  # the worker read the probe slot right
        assert pipe.channel.ready  # so every unit goes through a slot
        want = ref.replay(read_atrlog(files.atrlog)).contacts
        got = pipe.replay(read_atrlog(files.atrlog)).contacts
        slots = pipe.channel.slots
        assert slots is not None and slots.slots >= 1 and not slots._busy and pipe.channel.in_use == 0
        assert not slots._staged  # every unit written into a slot was sent
        assert got == want and len(got) > 0
    finally:
        ref.close()
        pipe.close()


def test_a_worker_that_cannot_read_slots_gets_pixels_through_the_pipe(small_mission):
    """A probe answered wrong (as by a worker that cannot open the node's memory) turns the
    slots off: units go through the pipe, results unchanged."""
    from concurrent.futures import Future
    settings, _cfg, files = small_mission
    pipe = Pipeline(settings, model=PerformanceModel.shipped(), workers=1, mode="replay")
    try:
        pipe.channel._probe[0].result(timeout=120)
        bad: Future = Future()
        bad.set_exception(PermissionError("/proc/1/fd/3"))
        pipe.channel._probe = (bad, *pipe.channel._probe[1:])
        assert not pipe.channel.ready and pipe.channel.slots is None
        ref = Pipeline(settings, model=PerformanceModel.shipped(), workers=0, mode="replay")
        try:
            assert pipe.replay(read_atrlog(files.atrlog)).contacts == ref.replay(read_atrlog(files.atrlog)).contacts
        finally:
            ref.close()
    finally:
        pipe.close()
