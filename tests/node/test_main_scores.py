"""Replay with the main process scoring units rather than waiting for a busy worker
(``node.replay_main_scores``: it steals the units the worker has not started): the same
contacts as in-process, whoever scored each unit."""

from __future__ import annotations

import dataclasses
import time

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
