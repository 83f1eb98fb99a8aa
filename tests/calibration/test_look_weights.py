"""Fitted weights of the look score (``calibration.look_weights = "fit"``, SPEC 6.1): the
detectors' dependence measured on the joint responses. Checked against the closed forms of
conditionally independent and of duplicated evidence, and through the model file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from atr_node.calibration.estimate import estimate_model
from atr_node.calibration.looks import fit_weights, subset_key
from atr_node.calibration.model import PerformanceModel, _digest
from atr_node.calibration.responses import Responses
from atr_node.config import CalibrationSettings, ThresholdSettings
from atr_node.errors import ModelFileError

DETS = ("mf", "lac", "smf", "z")


def _llr(rng, mu, n_t, n_n):
    """Terms that are the true log likelihood ratios of N(mu, 1) against N(0, 1), one column per
    mean, independent given the class: ``l = mu x - mu^2 / 2``."""
    mu = np.asarray(mu, dtype=np.float64)
    x_t = rng.normal(mu, 1.0, (n_t, mu.size))
    x_n = rng.normal(0.0, 1.0, (n_n, mu.size))
    return mu * x_t - mu ** 2 / 2, mu * x_n - mu ** 2 / 2


def test_independent_true_log_ratios_keep_weight_one(rng):
    """Conditionally independent detectors whose terms are their true log likelihood ratios:
    the posterior log odds is exactly their sum (plus the prior's), so the logistic fit's optimum
    is every weight 1. 20,000 of each class: the fit lands within a few standard errors."""
    u_t, u_n = _llr(rng, [1.0, 1.5, 0.7], 20_000, 20_000)
    w = fit_weights(u_t, u_n)
    np.testing.assert_allclose(w, 1.0, atol=0.06)


def test_duplicated_evidence_shares_one_weight(rng):
    """A detector that repeats another's evidence exactly (two highlight detectors reading the
    same echo): the sum counts it twice; the fit gives the pair one weight between them (equal
    halves, by symmetry and the pull towards 1), the independent third keeps 1."""
    u_t, u_n = _llr(rng, [1.2, 1.0], 20_000, 20_000)
    u_t, u_n = u_t[:, [0, 0, 1]], u_n[:, [0, 0, 1]]
    w = fit_weights(u_t, u_n)
    assert w[0] + w[1] == pytest.approx(1.0, abs=0.06)
    assert w[0] == pytest.approx(w[1], abs=1e-3)
    assert w[2] == pytest.approx(1.0, abs=0.06)


def test_evidence_that_tells_nothing_gets_no_weight_and_none_goes_negative(rng):
    """A term that is noise alike in both classes: weight near 0, never below (a stronger
    response must never lower z)."""
    u_t, u_n = _llr(rng, [1.0], 20_000, 20_000)
    noise_t, noise_n = rng.normal(0, 1, (20_000, 1)), rng.normal(0, 1, (20_000, 1))
    anti_t, anti_n = rng.normal(-0.5, 1, (20_000, 1)), rng.normal(0, 1, (20_000, 1))  # lower on targets
    w = fit_weights(np.hstack([u_t, noise_t, anti_t]), np.hstack([u_n, noise_n, anti_n]))
    assert w[0] == pytest.approx(1.0, abs=0.06)
    assert 0.0 <= w[1] < 0.05
    assert w[2] == 0.0


def test_weights_without_data_are_the_plain_sum():
    assert fit_weights(np.zeros((0, 3)), np.ones((5, 3))).tolist() == [1.0, 1.0, 1.0]
    assert fit_weights(np.ones((5, 2)), np.zeros((0, 2))).tolist() == [1.0, 1.0]
    # one response of each kind: the pull towards 1 holds the fit near the sum, finite
    w = fit_weights(np.array([[2.0, 2.0]]), np.array([[-1.0, -1.0]]))
    assert np.all(np.isfinite(w)) and np.all(w >= 0)


def _responses(rng, m=1500, k=6000) -> Responses:
    """MF and Z read the same echo (Z = MF plus a little noise on both classes), SMF the
    shadow, LAC independent: the sum counts the echo twice."""
    r = rng.uniform(10.0, 60.0, size=m)
    echo_t, echo_n = rng.normal(3.0, 1.0, m), rng.normal(0.0, 1.0, k)
    target = {"mf": echo_t, "z": echo_t + rng.normal(0, 0.05, m), "smf": rng.normal(3.0, 1.0, m),
              "lac": rng.normal(2.0, 1.0, m)}
    nontarget = {"mf": echo_n, "z": echo_n + rng.normal(0, 0.05, k), "smf": rng.normal(0.0, 1.0, k),
                 "lac": rng.normal(0.0, 1.0, k)}
    return Responses(DETS, target, nontarget, r, ("cylinder",) * m, {"cell_area_m2": 5.0})


def test_the_model_scores_with_its_weights_and_the_file_keeps_them(rng, tmp_path):
    resp = _responses(rng)
    cal = dict(prior="fixed", prior_target=0.1, look_pd=0.0)
    fit = estimate_model(resp, calibration=CalibrationSettings(look_weights="fit", **cal),
                         thresholds=ThresholdSettings())
    plain = estimate_model(resp, calibration=CalibrationSettings(look_weights="sum", **cal),
                           thresholds=ThresholdSettings())
    assert plain.looks.weights is None and "weights" not in plain.looks.info
    w = fit.looks.weights[subset_key(DETS)]
    # the echo counted once between MF and Z; SMF and LAC, independent, about 1 (the terms are
    # binned estimates, and the fit sees only the responses on which the look fired)
    assert w["mf"] + w["z"] == pytest.approx(1.0, abs=0.25)
    assert w["smf"] == pytest.approx(1.0, abs=0.25) and w["lac"] == pytest.approx(1.0, abs=0.25)
    # z is the weighted sum of the same terms the plain sum adds (a direct computation)
    g = {d: np.linspace(-2, 6, 17) for d in DETS}
    direct = sum(w[d] * plain.looks.lrs[d](g[d]) for d in DETS)
    np.testing.assert_allclose(fit.look_score(g, DETS), direct, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(plain.look_score(g, DETS), sum(plain.looks.lrs[d](g[d]) for d in DETS))
    # a subset has weights of its own: with Z off, MF carries the echo alone
    w3 = fit.looks.weights[subset_key(("mf", "lac", "smf"))]
    assert w3["mf"] == pytest.approx(1.0, abs=0.25)
    # the file keeps them, and refuses a negative one naming the key
    back = PerformanceModel.load(fit.save(tmp_path / "m.json"))
    np.testing.assert_array_equal(back.look_score(g, DETS), fit.look_score(g, DETS))
    body = json.loads((tmp_path / "m.json").read_text())
    body["looks"]["weights"][subset_key(DETS)]["smf"] = -0.5
    body["sha256"] = _digest({k: v for k, v in body.items() if k != "sha256"})
    (tmp_path / "bad.json").write_text(json.dumps(body))
    with pytest.raises(ModelFileError, match=r"looks\.weights\.mf\+lac\+smf\+z"):
        PerformanceModel.load(tmp_path / "bad.json")


def test_clipped_places_get_weights_of_their_own(rng):
    """Where the recording clips, MF and Z read the same saturated pixels (Z = MF there, on
    targets and cells alike); elsewhere they respond independently. The fit on each side finds
    it: the clipped places give the pair one weight between them, the others about 1 each; and
    the model scores each place with its own weights."""
    m, k = 2000, 8000
    clip_t, clip_n = np.arange(m) % 2 == 0, np.arange(k) % 2 == 0
    mf_t, mf_n = rng.normal(3.0, 1.0, m), rng.normal(0.0, 1.0, k)
    z_t = np.where(clip_t, mf_t, rng.normal(3.0, 1.0, m))
    z_n = np.where(clip_n, mf_n, rng.normal(0.0, 1.0, k))
    target = {"mf": mf_t, "z": z_t, "smf": rng.normal(3.0, 1.0, m), "lac": rng.normal(2.0, 1.0, m)}
    nontarget = {"mf": mf_n, "z": z_n, "smf": rng.normal(0, 1, k), "lac": rng.normal(0, 1, k)}
    resp = Responses(DETS, target, nontarget, rng.uniform(10, 60, m), ("cylinder",) * m, {"cell_area_m2": 5.0},
                     {"headroom_db": np.where(clip_t, 3.0, 20.0)}, np.where(clip_n, 3.0, 20.0))
    model = estimate_model(resp, calibration=CalibrationSettings(look_weights="fit", clip_headroom_db=10.0,
                                                                 prior="fixed", look_pd=0.0),
                           thresholds=ThresholdSettings())
    key = subset_key(DETS)
    w, wc = model.looks.weights[key], model.looks.weights_clipped[key]
    assert w["mf"] == pytest.approx(1.0, abs=0.3) and w["z"] == pytest.approx(1.0, abs=0.3)
    assert wc["mf"] + wc["z"] == pytest.approx(1.0, abs=0.3)
    assert wc["smf"] == pytest.approx(1.0, abs=0.3)
    g = {"mf": np.array([4.0]), "z": np.array([4.0]), "smf": np.array([0.0]), "lac": np.array([0.0])}
    direct_c = sum(wc[d] * model.looks.lrs_clipped[d](g[d]) for d in DETS)
    np.testing.assert_allclose(model.look_score(g, DETS, headroom_db=3.0), direct_c, rtol=1e-12)
    direct = sum(w[d] * model.looks.lrs[d](g[d]) for d in DETS)
    np.testing.assert_allclose(model.look_score(g, DETS, headroom_db=20.0), direct, rtol=1e-12)



@pytest.mark.parametrize("clipped_cells, fitted", [(0, False), (199, False), (200, True), (4000, True)])
def test_auto_fits_where_the_seabed_clips(rng, clipped_cells, fitted):
    """``look_weights = "auto"`` (the default): the weights are fitted when at least
    ``AUTO_FIT_CLIPPED_CELLS`` (200) of the calibration's clean cells lie within
    ``clip_headroom_db`` of the recording's full scale, and the model is then the one ``"fit"``
    makes; else every term weighs 1 and the model is the one ``"sum"`` makes. Float data (no full
    scale: headroom inf) never fits. MF and Z read the same pixels here, so a fit would give the
    pair one weight between them: the two cases differ in the scores, not only in a flag."""
    from atr_node.calibration.estimate import AUTO_FIT_CLIPPED_CELLS

    assert AUTO_FIT_CLIPPED_CELLS == 200
    m, k = 1000, 4000
    mf_t, mf_n = rng.normal(3.0, 1.0, m), rng.normal(0.0, 1.0, k)
    target = {"mf": mf_t, "z": mf_t.copy(), "smf": rng.normal(3.0, 1.0, m), "lac": rng.normal(2.0, 1.0, m)}
    nontarget = {"mf": mf_n, "z": mf_n.copy(), "smf": rng.normal(0, 1, k), "lac": rng.normal(0, 1, k)}
    h_n = np.full(k, np.inf)
    h_n[:clipped_cells] = 3.0
    resp = Responses(DETS, target, nontarget, rng.uniform(10, 60, m), ("cylinder",) * m, {"cell_area_m2": 5.0},
                     {"headroom_db": np.full(m, np.inf)}, h_n)
    cal = dict(clip_headroom_db=10.0, prior="fixed", look_pd=0.0)
    auto = estimate_model(resp, calibration=CalibrationSettings(look_weights="auto", **cal),
                          thresholds=ThresholdSettings())
    want = estimate_model(resp, calibration=CalibrationSettings(look_weights="fit" if fitted else "sum", **cal),
                          thresholds=ThresholdSettings())
    assert (auto.looks.weights is not None) is fitted
    g = {d: np.array([1.0, 2.5, 4.0]) for d in DETS}
    np.testing.assert_array_equal(auto.look_score(g, DETS), want.look_score(g, DETS))
    a, b = auto.look(DETS), want.look(DETS)
    assert a.tau == b.tau
    np.testing.assert_array_equal(a.confidence.confidence, b.confidence.confidence)
    if fitted:
        w = auto.looks.weights[subset_key(DETS)]
        assert w["mf"] + w["z"] == pytest.approx(1.0, abs=0.35)
        assert "look_weights auto" in auto.looks.info["weights"]


def test_the_default_is_auto():
    assert CalibrationSettings().look_weights == "auto"
