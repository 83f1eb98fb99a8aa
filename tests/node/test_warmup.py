"""Warming the node's processes up (issue 7, latency): small pages, the worker's warm-up unit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from atr_node.calibration.model import PerformanceModel
from atr_node.config import ConfigError, NodeSettings, Settings
from atr_node.node.pipeline import Pipeline
from atr_node.node.warmup import keep_small_pages, warm_up_shape, warm_up_worker


def _hugepage_advice() -> bool:
    from numpy._core.multiarray import _set_madvise_hugepage
    prev = _set_madvise_hugepage(False)
    _set_madvise_hugepage(prev)
    return bool(prev)


def test_keep_small_pages_turns_the_advice_off_unless_the_user_chose(monkeypatch):
    before = _hugepage_advice()
    from numpy._core.multiarray import _set_madvise_hugepage
    try:
        _set_madvise_hugepage(True)
        monkeypatch.setenv("NUMPY_MADVISE_HUGEPAGE", "1")
        assert keep_small_pages() is False and _hugepage_advice() is True
        monkeypatch.delenv("NUMPY_MADVISE_HUGEPAGE")
        assert keep_small_pages() is True and _hugepage_advice() is False
    finally:
        _set_madvise_hugepage(before)


def test_warm_up_shape_covers_the_requested_pixels():
    s = Settings().sensor
    for mpx in (0.01, 1.0, 8.0, 8.2):
        rows, cols = warm_up_shape(s, mpx)
        assert cols == 1501  # 150 m / 0.1 m + 1: the nominal range axis
        assert rows * cols >= 1.125 * mpx * 1e6 > (rows - 1) * cols


def test_warm_up_worker_scores_a_synthetic_unit_in_process():
    s = Settings()
    shape = warm_up_worker(s.sensor, s.template, s.detectors, tuple(s.detectors.enabled), 0.03)
    assert shape == warm_up_shape(s.sensor, 0.03) and shape[0] > 0
    assert warm_up_worker(s.sensor, s.template, s.detectors, tuple(s.detectors.enabled), 0.0) == (0, 0)


def test_bad_warm_up_size_is_rejected_with_its_key():
    with pytest.raises(ConfigError, match="node.warm_up_mpx"):
        NodeSettings(warm_up_mpx=-1.0)


@pytest.mark.parametrize("mode", ["live", "replay"])
def test_live_worker_warms_up_at_start_replay_worker_only_imports(mode):
    s = Settings()
    s = s.replace(node=dataclasses.replace(s.node, warm_up_mpx=0.05))
    pipe = Pipeline(s, model=PerformanceModel.shipped(), workers=1, mode=mode)
    try:
        got = pipe.warming.result(timeout=120)
        if mode == "live":
            assert tuple(got) == warm_up_shape(s.sensor, 0.05)
        else:
            assert got is None
        # the worker runs with small pages too
        assert pipe._pool.submit(_hugepage_advice).result(timeout=60) is False
        assert np.isfinite(pipe.stats.detect_s)
    finally:
        pipe.close()


def test_fusion_reserve_covers_the_steady_open_layer_of_warm_up_units():
    from atr_node.node.warmup import fusion_reserve_chunks
    s = Settings()
    n = fusion_reserve_chunks(s)
    # 8 Mpx at 0.1 m x 0.1 m = 80,000 m2 per unit; chunks of 32 x 0.5 m = 256 m2;
    # commit_after_obs (6) + 2 units, plus a quarter for chunks cut by the edges
    assert n == int(np.ceil(1.25 * 80_000 / 256 * 8))
    smaller = s.replace(node=dataclasses.replace(s.node, warm_up_mpx=1.0))
    assert fusion_reserve_chunks(smaller) == int(np.ceil(n / 8))


@pytest.mark.parametrize("mode", ["live", "replay"])
def test_a_node_maps_its_grid_memory_at_start(mode):
    from atr_node.node.warmup import fusion_reserve_chunks
    s = Settings()
    s = s.replace(node=dataclasses.replace(s.node, warm_up_mpx=0.05))
    pipe = Pipeline(s, model=PerformanceModel.shipped(), workers=0, mode=mode)
    off = Pipeline(s.replace(node=dataclasses.replace(s.node, warm_up_mpx=0.0)), model=PerformanceModel.shipped(),
                   workers=0, mode=mode)
    try:
        spare = pipe.grid._spare
        assert spare is not None and spare.shape[0] == fusion_reserve_chunks(s) > 0
        assert (spare == -1.0).all()
        assert getattr(off.grid, "_spare", None) is None  # warm_up_mpx = 0: grown on demand
    finally:
        pipe.close()
        off.close()
