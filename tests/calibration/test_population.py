"""Calibration with the injected population (issue 17 item 5): what it records, and that weak
targets lower P(y) on the same image (real detectors, real simulator)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from atr_node.calibration.estimate import estimate_model
from atr_node.calibration.model import PerformanceModel
from atr_node.calibration.responses import Responses, collect_responses
from atr_node.calibration.sources import synthetic_images
from atr_node.config import CalibrationSettings, PopulationSettings, Settings


def settings_with(pop: PopulationSettings, **cal) -> Settings:
    return Settings(calibration=CalibrationSettings(population=pop, **cal))


@pytest.fixture(scope="module")
def images():
    return synthetic_images(1, settings=Settings(), rows=768, cols=600, seed=4, seabed="sand")


def mean_pd(model: PerformanceModel, d: str) -> float:
    y = model.detectors[d].pyr
    return float(np.sum(y.detected) / max(np.sum(y.injected), 1))


def test_weak_population_has_lower_pd_than_the_nominal_one_on_the_same_image(images):
    """Same image, same seed, same number of targets: a population whose varied targets echo
    10 dB below the model and are half buried reaches the detectors' thresholds less often.
    The thresholds are set on the nominal targets (``threshold_on = "nominal"``), so they do
    not sink to follow the weak targets, and P(y) shows the weak ones' misses."""
    nominal = settings_with(PopulationSettings(mode="fixed"))
    weak_pop = PopulationSettings(mode="varied", reflectivity_db=(-10.0, -10.0), burial_fraction=(0.5, 0.5), tilt_deg=0.0,
                                  size_scale=(0.6, 0.6), nominal_fraction=0.35)
    weak = settings_with(weak_pop)
    r_nom = collect_responses(images, settings=nominal, iterations=4, targets_per_image=25, seed=3)
    r_weak = collect_responses(images, settings=weak, iterations=4, targets_per_image=25, seed=3)
    assert r_nom.nominal.all() and 0.2 < r_weak.nominal.mean() < 0.5
    m_nom = estimate_model(r_nom, calibration=nominal.calibration)
    m_weak = estimate_model(r_weak, calibration=weak.calibration)
    assert m_weak.estimation["threshold_on"] == "nominal"
    lower = 0
    for d in Settings().detectors.enabled:
        # weak targets respond less than nominal ones of the same run
        x = r_weak.target[d]
        assert np.nanmedian(x[~r_weak.nominal]) < np.nanmedian(x[r_weak.nominal])
        lower += mean_pd(m_weak, d) < mean_pd(m_nom, d) - 0.05
    assert lower >= 3, {d: (mean_pd(m_nom, d), mean_pd(m_weak, d)) for d in Settings().detectors.enabled}
    # Dobeck on the whole weak population instead: the thresholds sink to keep Pd at 0.95
    m_all = estimate_model(r_weak, calibration=dataclasses.replace(
        weak.calibration, population=dataclasses.replace(weak_pop, threshold_on="population")))
    assert m_all.estimation["threshold_on"] == "population"
    assert sum(m_all.tau[d] < m_weak.tau[d] for d in m_all.tau) >= 3


def test_model_file_records_the_population(images, tmp_path):
    pop = PopulationSettings(mode="varied", reflectivity_db=(-6.0, 4.0), tilt_deg=15.0)
    s = settings_with(pop)
    resp = collect_responses(images, settings=s, iterations=1, targets_per_image=10, seed=0)
    assert set(resp.target_traits) == {"nominal", "reflectivity_db", "height_m", "headroom_db", "whole"}
    refl = resp.target_traits["reflectivity_db"][~resp.nominal]
    assert refl.size and refl.min() >= -6.0 and refl.max() <= 4.0
    model = estimate_model(resp, calibration=s.calibration)
    path = model.save(tmp_path / "m.json")
    back = PerformanceModel.load(path)
    rec = back.provenance["population"]
    assert rec["mode"] == "varied" and rec["reflectivity_db"] == [-6.0, 4.0] and rec["tilt_deg"] == 15.0
    assert rec["n_nominal"] == int(resp.nominal.sum())
    assert back.estimation["threshold_on"] in ("nominal", "population")  # nominal needs >= 20 nominal targets


def test_traits_survive_head_and_concat():
    r = Responses(("mf",), {"mf": np.arange(4.0)}, {"mf": np.zeros(3)}, np.arange(4.0), ("a",) * 4, {},
                  {"nominal": np.array([1.0, 0, 1, 0]), "reflectivity_db": np.array([0.0, -3, 0, 5])})
    assert r.head(2).nominal.tolist() == [True, False]
    c = Responses.concat([r, r.head(1)])
    assert c.nominal.tolist() == [True, False, True, False, True]
    assert c.target_traits["reflectivity_db"].tolist() == [0.0, -3, 0, 5, 0]
    with pytest.raises(ValueError, match="trait"):
        Responses(("mf",), {"mf": np.arange(4.0)}, {"mf": np.zeros(3)}, np.arange(4.0), (), {},
                  {"nominal": np.ones(3)})
    # responses without traits (e.g. older code paths) count every target as nominal
    bare = Responses(("mf",), {"mf": np.arange(4.0)}, {"mf": np.zeros(3)}, np.arange(4.0))
    assert bare.nominal.all()
