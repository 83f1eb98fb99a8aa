"""The on-line calibration worker: a real spawned process fed real tiles. Replays wait for the
model once the worker has its images (or the input ended) and give the same model as an
in-process calibration of the same tiles; live mode never waits; a failing worker leaves the
given model in place. (The node's hold of its first tiles: test_online_short.py.)"""

from __future__ import annotations

import time

import numpy as np
import pytest

from atr_node.calibration.estimate import estimate_model
from atr_node.calibration.model import PerformanceModel
from atr_node.calibration.online import OnlineCalibrator
from atr_node.calibration.responses import CalibrationImage, collect_responses
from atr_node.calibration.sources import synthetic_seabed
from atr_node.config import CalibrationSettings, DetectorSettings, Settings
from atr_node.records.tile import Tile


def _tiles(n: int, rows: int = 240, cols: int = 500) -> list[Tile]:
    out = []
    for k in range(n):
        px = synthetic_seabed(rows, cols, range0_m=28.0, dr_m=0.1, dx_m=0.1, seabed="silt",
                              rng=np.random.default_rng(100 + k))
        out.append(Tile("m", 1, "stbd", k, px, "intensity", 28.0, 0.1, 0.1, False,
                        1e9 + k * rows * 0.05 + np.arange(rows) * 0.05))
    return out


SETTINGS = Settings(detectors=DetectorSettings(enabled=("mf", "z")),
                    calibration=CalibrationSettings(online_tiles=2, online_iterations=2, targets_per_image=5, seed=4))


@pytest.fixture(scope="module")
def fallback() -> PerformanceModel:
    return PerformanceModel.shipped()


def test_replay_waits_for_the_model_of_its_images_and_it_equals_an_in_process_one(fallback):
    tiles = _tiles(3)
    with OnlineCalibrator(SETTINGS, fallback, deterministic=True) as oc:
        assert oc.gathering and oc.model is fallback
        for tile in tiles:
            oc.offer(tile)  # the third is not taken: online_tiles = 2
        assert oc.offered == 2 and not oc.gathering and not oc.done
        assert oc.wait() and oc.done
        assert oc.progress == (4, 4)  # 2 images x 2 iterations: every injection round reported
        assert oc.rounds_here == 2  # the second image's, by this process while it waited
        assert oc.switched_at == 1 and oc.error is None and oc.images == 2
        online = oc.model
        assert oc.model_for(7) is online
    # the same tiles and seed in this process give the same tables
    images = [CalibrationImage.from_tile(t, altitude_m=SETTINGS.sensor.altitude_m) for t in tiles[:2]]
    resp = collect_responses(images, settings=SETTINGS, iterations=2, targets_per_image=5, seed=4)
    ref = estimate_model(resp, calibration=SETTINGS.calibration, thresholds=SETTINGS.detectors.threshold)
    assert online.tau == ref.tau
    for d in ("mf", "z"):
        np.testing.assert_array_equal(online.detectors[d].confidence.confidence, ref.detectors[d].confidence.confidence)
        np.testing.assert_array_equal(online.detectors[d].pyr.detected, ref.detectors[d].pyr.detected)
    assert online.provenance["source"] == "on-line"


def test_live_mode_never_waits_and_switches_when_ready(fallback):
    tiles = _tiles(2)
    with OnlineCalibrator(SETTINGS, fallback, deterministic=False) as oc:
        assert oc.model_for(0) is fallback  # nothing delivered yet: no wait
        for t in tiles:
            oc.offer(t)
        k = 2
        deadline = time.monotonic() + 120.0  # a guard against hanging, not a timing assertion
        while oc.switched_at is None and oc.error is None and time.monotonic() < deadline:
            oc.model_for(k)
            k += 1
            time.sleep(0.05)
        assert oc.error is None and oc.switched_at is not None and oc.switched_at >= 2
        assert oc.model is not fallback and set(oc.model.tau) == {"mf", "z"}


def test_failed_worker_keeps_the_given_model(fallback):
    # No detector enabled: the worker's model has no detector and is refused; the node keeps
    # its model and says why.
    bad = Settings(detectors=DetectorSettings(enabled=()), calibration=SETTINGS.calibration)
    with OnlineCalibrator(bad, fallback, deterministic=True) as oc:
        for tile in _tiles(4):
            oc.offer(tile)
        assert oc.wait() and oc.model is fallback and oc.model_for(5) is fallback
        assert oc.switched_at is None and oc.error and "no detector" in oc.error
        assert oc.outcome()["state"] == "failed"


def test_a_stop_request_ends_the_wait_and_a_later_wait_takes_the_answer(fallback):
    with OnlineCalibrator(SETTINGS, fallback, deterministic=True) as oc:
        for tile in _tiles(2):
            oc.offer(tile)
        assert oc.wait(lambda: True) is False and not oc.done and oc.model is fallback
        assert oc.wait() and oc.switched_at == 1


def test_end_of_input_before_enough_tiles(fallback):
    s = Settings(detectors=DetectorSettings(enabled=("mf",)),
                 calibration=CalibrationSettings(online_tiles=4, online_iterations=1, targets_per_image=3))
    with OnlineCalibrator(s, fallback, deterministic=True) as oc:
        oc.offer(_tiles(1)[0])
        oc.end_of_input()
        assert not oc.gathering
        model = oc.model_for(1)
        assert oc.switched_at == 1 and model is not fallback
        assert model.provenance["n_images"] == 1
        out = oc.outcome()
        assert (out["offered"], out["of"], out["images"]) == (1, 4, 1)
