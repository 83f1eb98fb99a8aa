"""The on-line calibration worker: a real spawned process fed real tiles. Replays switch at the
configured tile count and give the same model as an in-process calibration of the same tiles;
live mode never waits; a failing worker leaves the given model in place."""

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
                    calibration=CalibrationSettings(online_tiles=2, online_iterations=2, targets_per_image=5,
                                                    online_switch_tile=3, seed=4))


@pytest.fixture(scope="module")
def fallback() -> PerformanceModel:
    return PerformanceModel.shipped()


def test_replay_switches_exactly_at_the_tile_count_with_the_same_model(fallback):
    tiles = _tiles(5)
    used = []
    with OnlineCalibrator(SETTINGS, fallback, deterministic=True) as oc:
        for k, tile in enumerate(tiles):
            model = oc.model_for(k)
            used.append(model is fallback)
            oc.offer(tile)
            if k == 1:
                time.sleep(0.5)  # the worker may well be done early: the switch must still wait
        assert oc.switched_at == 3 and oc.error is None and oc.done
        online = oc.model
    assert used == [True, True, True, False, False]
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
        for k, tile in enumerate(_tiles(4)):
            assert oc.model_for(k) is fallback
            oc.offer(tile)
        assert oc.switched_at is None and oc.error and "no detector" in oc.error


def test_end_of_input_before_enough_tiles(fallback):
    s = Settings(detectors=DetectorSettings(enabled=("mf",)),
                 calibration=CalibrationSettings(online_tiles=4, online_iterations=1, targets_per_image=3,
                                                 online_switch_tile=4))
    with OnlineCalibrator(s, fallback, deterministic=True) as oc:
        oc.offer(_tiles(1)[0])
        oc.end_of_input()
        model = oc.model_for(4)
        assert oc.switched_at == 4 and model is not fallback
        assert model.provenance["n_images"] == 1
