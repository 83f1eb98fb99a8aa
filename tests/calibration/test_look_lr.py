"""The likelihood-ratio look score (``calibration.look_score = "lr"``, SPEC 6.1): per-detector
log likelihood ratios checked against closed forms and exact bin probabilities, and the model
file that carries them."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import stats

from atr_node.calibration.estimate import estimate_model
from atr_node.calibration.looks import LR_CAP, LR_TIE, lr_edges, lr_table, tail_table
from atr_node.calibration.model import PerformanceModel, _digest
from atr_node.calibration.responses import Responses
from atr_node.config import CalibrationSettings, ThresholdSettings
from atr_node.errors import ConfigError, ModelFileError

DETS = ("mf", "lac", "smf", "z")


def test_lr_table_is_the_log_ratio_of_the_bin_probabilities(rng):
    """Targets N(2, 1), background N(0, 1): at each knot the table is the log ratio of the two
    normals' probabilities of its bin (exact, from the CDF), and close to the closed-form
    density ratio ``2 x - 2`` in the middle."""
    t, n = rng.normal(2.0, 1.0, 200_000), rng.normal(0.0, 1.0, 200_000)
    tab = lr_table(t, n, bins=24)
    assert np.all(np.diff(tab.gamma) > 0) and np.all(np.diff(tab.l) >= 0)
    edges = lr_edges(t, n, bins=24)  # the bins it works on: 12 quantile bins of each kind, merged
    assert edges.size == 26 and np.all(np.diff(edges) > 0)  # 13 edges each, none shared here
    p_t = np.diff(stats.norm.cdf(edges, 2.0, 1.0))
    p_n = np.diff(stats.norm.cdf(edges, 0.0, 1.0))
    exact = np.clip(np.log(p_t / p_n), -LR_CAP, LR_CAP)
    inner = slice(2, -2)  # the open end bins hold the far tails of both: compared at their counts
    # sampling error of a log ratio of two counts: sqrt(1/k_t + 1/k_n); 4 of them, and the
    # isotonic fit's pooling (none expected here: the true ratio increases)
    tol = 4.0 * np.sqrt(1.0 / (t.size * p_t) + 1.0 / (n.size * p_n))
    assert np.all(np.abs(tab.l - exact)[inner] <= tol[inner]), (tab.l - exact, tol)
    assert np.median(np.abs(tab.l - exact)[inner]) < 0.03
    mid = (tab.gamma > 0.3) & (tab.gamma < 1.7)
    np.testing.assert_allclose(tab.l[mid], 2.0 * tab.gamma[mid] - 2.0, atol=0.06)
    # a weak response counts against (Fisher's tail never goes below 0), a strong one for
    assert tab(-1.0) < -2.5 and tab(3.0) > 2.5 and tail_table(n)(-1.0) >= 0.0


def test_few_targets_among_many_cells_still_resolve_the_top(rng):
    """30 injected targets among 20,000 clean cells (a short recording's on-line calibration):
    the bins follow the targets too, so a response above most targets is far more target-like
    than one at the background's 99th percentile (pooled quantile bins put both in one bin)."""
    t, n = rng.normal(5.0, 1.0, 30), rng.normal(0.0, 1.0, 20_000)
    edges = lr_edges(t, n, bins=24)
    assert np.sum(edges > np.quantile(n, 0.999)) >= 10
    tab = lr_table(t, n, bins=24)
    assert tab(6.0) - tab(2.3) > 3.0


def test_lr_table_is_isotonic_capped_and_silent_without_data(rng):
    # a non-monotone ratio (targets in the middle of a wide background) is pooled, not followed
    t = rng.normal(0.0, 0.3, 20_000)
    n = rng.normal(0.0, 2.0, 20_000)
    tab = lr_table(t, n)
    assert np.all(np.diff(tab.l) >= 0)
    # separated samples hit the cap, never beyond it
    sep = lr_table(rng.normal(50.0, 1.0, 50_000), rng.normal(0.0, 1.0, 50_000))
    assert sep.l.max() == pytest.approx(LR_CAP) and sep.l.min() == pytest.approx(-LR_CAP)
    assert sep(np.nan) == 0.0 and sep(1e300) == pytest.approx(LR_CAP) and sep(-1e300) == pytest.approx(-LR_CAP)
    for empty in ((np.array([np.nan]), n), (t, np.array([]))):
        flat = lr_table(*empty)
        assert flat.l.tolist() == [0.0, 0.0] and flat(3.0) == 0.0
    # with the tail: LR_TIE u added, so the strongest responses still rank
    tail = tail_table(n)
    tied = lr_table(t, n, tail=tail)
    g = np.array([n.max() + 0.5, n.max() + 1.0])
    np.testing.assert_allclose(tied(g), tab(g) + LR_TIE * tail(g), rtol=1e-12)
    assert tied(g[1]) > tied(g[0]) and tied(np.nan) == 0.0


def responses(rng, *, m=2000, k=20000) -> Responses:
    """MF and SMF respond on every target; LAC and Z also fire on the background's scatterers
    (a heavy tail), where MF and SMF stay low: the clutter Fisher's sum cannot tell apart."""
    r = rng.uniform(10.0, 60.0, size=m)
    target = {"mf": rng.normal(4.0, 1.0, m), "smf": rng.normal(4.0, 1.0, m),
              "lac": rng.normal(3.0, 1.0, m), "z": rng.normal(3.0, 1.0, m)}
    nontarget = {"mf": rng.normal(0.0, 1.0, k), "smf": rng.normal(0.0, 1.0, k),
                 "lac": rng.standard_t(2, k), "z": rng.standard_t(2, k)}
    return Responses(DETS, target, nontarget, r, ("cylinder",) * m, {"cell_area_m2": 5.0})


def test_lr_ranks_a_target_above_scatterers_that_fisher_ranks_above_it(rng):
    resp = responses(rng)
    cal = dict(prior="fixed", prior_target=0.1, look_pd=0.0)  # the scores' ranking, every fired look
    lr = estimate_model(resp, calibration=CalibrationSettings(look_score="lr", **cal), thresholds=ThresholdSettings())
    fisher = estimate_model(resp, calibration=CalibrationSettings(look_score="fisher", **cal),
                            thresholds=ThresholdSettings())
    assert lr.looks.lrs is not None and fisher.looks.lrs is None
    assert lr.looks.info["score"].startswith("z = sum over detectors of l_d")
    weak_target = {"mf": 2.5, "smf": 2.5, "lac": 1.0, "z": 1.0}
    scatterer = {"mf": 0.5, "smf": 0.5, "lac": 60.0, "z": 60.0}

    def c(model, resp_):
        z = model.look_score({d: np.array([v]) for d, v in resp_.items()}, DETS)
        return float(model.look(DETS).confidence_at(z)[0])

    assert c(fisher, scatterer) > c(fisher, weak_target)
    assert c(lr, weak_target) > c(lr, scatterer)
    # and the LR look's confidence is still a measured, non-decreasing table
    table = lr.look(DETS)
    assert np.all(np.diff(table.confidence.confidence) >= 0)
    assert 0.0 < table.confidence.confidence.min() and table.confidence.confidence.max() < 1.0


def test_the_model_file_keeps_the_lr_tables_and_refuses_a_bad_one(rng, tmp_path):
    model = estimate_model(responses(rng, m=400, k=4000), calibration=CalibrationSettings(look_score="lr"),
                           thresholds=ThresholdSettings())
    back = PerformanceModel.load(model.save(tmp_path / "m.json"))
    g = {d: np.linspace(-3, 8, 45) for d in DETS}
    for key in model.looks.tables:
        dets = key.split("+")
        np.testing.assert_array_equal(back.look_score(g, dets), model.look_score(g, dets))
    body = json.loads((tmp_path / "m.json").read_text())
    body["looks"]["lr"]["smf"]["l"][0] = 99.0  # no longer non-decreasing
    body["sha256"] = _digest({k: v for k, v in body.items() if k != "sha256"})
    (tmp_path / "bad.json").write_text(json.dumps(body))
    with pytest.raises(ModelFileError, match=r"looks\.lr\.smf"):
        PerformanceModel.load(tmp_path / "bad.json")
    # a model without LR tables (Fisher, or from before) reads as before: z from the tails
    del body["looks"]["lr"]
    body["looks"].pop("weights", None)  # weights of the LR terms (look_weights = "fit"): not in such a file
    body["sha256"] = _digest({k: v for k, v in body.items() if k != "sha256"})
    (tmp_path / "fisher.json").write_text(json.dumps(body))
    old = PerformanceModel.load(tmp_path / "fisher.json")
    assert old.looks.lrs is None
    np.testing.assert_array_equal(old.look_score(g, DETS), sum(old.looks.tails[d](g[d]) for d in DETS))


def test_look_score_setting_is_checked(tmp_path):
    from atr_node.config import load_settings

    cfg = tmp_path / "c.toml"
    cfg.write_text('[calibration]\nlook_score = "sum"\n')
    with pytest.raises(ConfigError, match="calibration.look_score"):
        load_settings(cfg)


def test_lr_score_survives_the_extremes():
    """SPEC 8: responses of +-inf, NaN (not covered) and one-sample tables give finite z."""
    tab = lr_table(np.array([1.0]), np.array([0.0]), tail=tail_table(np.array([0.0])))
    z = tab(np.array([-np.inf, np.inf, np.nan, 0.5]))
    assert np.all(np.isfinite(z)) and z[2] == 0.0
    assert math.isfinite(float(lr_table(np.array([np.inf, 1.0]), np.array([0.0, -np.inf]))(0.0)))
