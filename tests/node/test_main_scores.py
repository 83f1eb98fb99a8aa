"""The main process scoring units rather than waiting for a busy worker: in replay it steals
the units the worker has not started (``node.replay_main_scores``), live it holds units back
while the worker is busy and scores them when idle (``node.live_main_scores``). The same
contacts as in-process, whoever scored each unit."""

from __future__ import annotations

import dataclasses
import time

import pytest

from atr_node.calibration.model import PerformanceModel
from atr_node.io.atrlog import read_atrlog
from atr_node.node.pipeline import Pipeline


def test_main_process_steals_when_the_worker_is_busy_and_contacts_are_unchanged(small_mission):
    settings, _cfg, files = small_mission
    ref = Pipeline(settings, model=PerformanceModel.shipped(), workers=0, mode="replay")
    pipe = Pipeline(settings, model=PerformanceModel.shipped(), workers=1, mode="replay")
    try:
        want = ref.replay(read_atrlog(files.atrlog)).contacts
        pipe.warming.result(timeout=120)
        # the worker sleeps: the main process ingests the whole replay, then, rather than wait,
        # scores every unit the worker has not started (all but the one already in the
        # executor's call queue)
        pipe._pool.submit(time.sleep, 3.0)
        got = pipe.replay(read_atrlog(files.atrlog)).contacts
        st = pipe.stats
        assert 1 <= st.units_main <= st.units - 1
        assert got == want and len(got) > 0
        assert pipe.channel.in_use == 0  # every slot back, stolen units' included
    finally:
        ref.close()
        pipe.close()


def test_switched_off_the_main_process_only_waits(small_mission):
    settings, _cfg, files = small_mission
    off = settings.replace(node=dataclasses.replace(settings.node, replay_main_scores=False))
    pipe = Pipeline(off, model=PerformanceModel.shipped(), workers=1, mode="replay")
    try:
        pipe._pool.submit(time.sleep, 1.0)
        pipe.replay(read_atrlog(files.atrlog))
        assert pipe.stats.units_main == 0 and pipe.stats.units > 2
    finally:
        pipe.close()


def _live(settings, **node):
    return settings.replace(node=dataclasses.replace(settings.node, **node))


def _live_reference(small_mission):
    """Live settings for these tests, the mission's records, and the contacts of an in-process
    run. No degraded mode (it would change the scores): the queue may grow while the worker
    sleeps."""
    settings, _cfg, files = small_mission
    s = _live(settings, warm_up_mpx=0.05, queue_tiles=1000)
    recs = list(read_atrlog(files.atrlog))
    ref = Pipeline(s, model=PerformanceModel.shipped(), workers=0, mode="live")
    try:
        for rec in recs:
            ref.feed(rec)
        ref.finish()
        return s, recs, ref.contacts
    finally:
        ref.close()


def test_live_units_wait_in_the_main_process_which_scores_them_when_idle(small_mission):
    """Live, the worker busy: the next units are held in the main process, which scores the
    newest itself when the links are quiet (``tick``); the contacts are those of an
    in-process run, and every slot comes back."""
    s, recs, want = _live_reference(small_mission)
    pipe = Pipeline(s, model=PerformanceModel.shipped(), workers=1, mode="live")
    try:
        pipe.warming.result(timeout=120)
        assert pipe.main_warming.wait(timeout=120)
        pipe._pool.submit(time.sleep, 2.0)  # the worker is busy for a while
        held = 0
        for rec in recs:
            pipe.feed(rec)
            held = max(held, sum(f is None for _, _, f, _ in pipe._inflight))
            pipe.tick(rec.t)
        pipe.finish()
        assert held >= 1 and pipe.stats.units_main >= 1
        assert pipe.stats.units_degraded == 0 and pipe.inflight == 0
        assert pipe.channel.in_use == 0 and not pipe.channel.slots._staged and not pipe.channel.slots._busy
        assert pipe.contacts == want and len(want) > 0
    finally:
        pipe.close()


@pytest.mark.parametrize("node", [{"live_main_scores": False}, {"warm_up_mpx": 0.0}])
def test_live_main_scoring_off_sends_every_unit_to_the_worker(small_mission, node):
    settings, _cfg, files = small_mission
    pipe = Pipeline(_live(settings, **node), model=PerformanceModel.shipped(), workers=1, mode="live")
    try:
        assert pipe.main_warming is None
        pipe._pool.submit(time.sleep, 1.0)
        for rec in read_atrlog(files.atrlog):
            pipe.feed(rec)
            assert all(f is not None for _, _, f, _ in pipe._inflight)
            pipe.tick(rec.t)
        pipe.finish()
        assert pipe.stats.units_main == 0 and pipe.stats.units > 2
    finally:
        pipe.close()


def test_live_held_units_reach_the_worker_oldest_first(small_mission):
    """Units held while the worker was busy go to it oldest first, also when a newer unit
    arrives once it is free: a drain (as before a snapshot) then finds nothing out of order
    and the contacts are those of an in-process run."""
    s, recs, want = _live_reference(small_mission)
    pipe = Pipeline(s, model=PerformanceModel.shipped(), workers=1, mode="live")
    try:
        pipe.wait_ready(timeout=120)
        pipe._pool.submit(time.sleep, 1.0)
        half = len(recs) // 2
        for rec in recs[:half]:  # no tick: nothing is scored here, units pile up held
            pipe.feed(rec)
        assert sum(f is None for _, _, f, _ in pipe._inflight) >= 2
        time.sleep(1.5)  # the worker is free again, held units still waiting
        for rec in recs[half:]:
            pipe.feed(rec)
            if pipe.stats.tiles_in % 4 == 0:
                pipe.drain()
        pipe.finish()
        assert pipe.contacts == want and len(want) > 0
        assert pipe.channel.in_use == 0 and not pipe.channel.slots._staged
    finally:
        pipe.close()


def test_live_queue_counts_tiles_not_the_units_a_long_tile_makes(small_mission):
    """Live, the worker busy: a leg re-cut into one 700-ping tile per side makes 2 units a side
    at once (25.6 m each; the third waits for the leg's end). ``node.queue_tiles`` = 1 is one
    tile's worth of units (3 here), so the 4 units of the leg's two tiles degrade the node
    (decimation) but none is dropped. Before, the limit counted units: 2 of the 4 were dropped."""
    from atr_node.io.recut import fixed, recut_records

    settings, _cfg, files = small_mission
    s = _live(settings, warm_up_mpx=0.05, queue_tiles=1, live_main_scores=False)
    recs = recut_records(read_atrlog(files.atrlog), fixed(1024))
    first_leg_end = next(i for i, r in enumerate(recs) if r.link == "sonar" and int(r.msg["leg"]) > 0)
    pipe = Pipeline(s, model=PerformanceModel.shipped(), workers=1, mode="live")
    try:
        pipe.warming.result(timeout=120)
        pipe._pool.submit(time.sleep, 3.0)  # the worker is busy while the leg's tiles arrive
        for rec in recs[:first_leg_end]:
            pipe.feed(rec)
        assert pipe.tiles_merged == 2 and pipe.inflight == 4
        assert pipe.stats.tiles_dropped == 0 and pipe.stats.units_degraded >= 1
        pipe.finish()
        assert pipe.stats.tiles_dropped == 0 and pipe.inflight == 0
    finally:
        pipe.close()
