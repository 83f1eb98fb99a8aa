"""Look-level tables (SPEC 6.1) from joint responses, checked against direct float64 counts,
closed forms, and the single-detector tables they must reduce to."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from atr_node.calibration.estimate import estimate_model
from atr_node.calibration.looks import area_prior, subset_key, tail_table, with_prior
from atr_node.calibration.model import PerformanceModel
from atr_node.calibration.responses import Responses
from atr_node.config import CalibrationSettings, ThresholdSettings
from atr_node.errors import ModelFileError

DETS = ("mf", "lac", "smf", "z")


def joint_responses(rng, *, m=1500, k=20000, rho=0.8) -> Responses:
    """Four detectors whose responses share a common part (correlation ``rho``): targets shifted
    up, fading with range; the same cells for every detector (joint)."""
    r = rng.uniform(10.0, 60.0, size=m)

    def draws(n, shift):
        common = rng.normal(size=n)
        return {d: shift + math.sqrt(rho) * common + math.sqrt(1 - rho) * rng.normal(size=n) for d in DETS}

    target = draws(m, 3.5 - 0.03 * r)
    nontarget = draws(k, 0.0)
    return Responses(DETS, target, nontarget, r, ("cylinder",) * m, {"cell_area_m2": 5.0})


def test_tail_table_is_the_jeffreys_survival_at_its_knots(rng):
    x = rng.gamma(2.0, size=5000)
    t = tail_table(x)
    direct = -np.log(((x[None, :] >= t.gamma[:, None]).sum(axis=1) + 0.5) / (x.size + 1.0))
    np.testing.assert_allclose(t.u, np.maximum.accumulate(np.maximum(direct, 0.0)), rtol=0, atol=1e-12)
    assert np.all(np.diff(t.gamma) > 0) and np.all(np.diff(t.u) >= 0)
    assert t(np.nan) == 0.0 and t(-1e300) == t.u[0]
    # beyond the data: the exponential tail, slope 1 / mean excess over the top 5 % (for a
    # gamma(2) sample the excess is close to exponential with mean near 1)
    top = np.sort(x)[-250:]
    assert t.slope == pytest.approx(1.0 / np.mean(top - np.sort(x)[-251]), rel=1e-12)
    assert t(x.max() + 0.5) == pytest.approx(t.u[-1] + 0.5 * t.slope, rel=1e-12)
    # at most one decade of survival beyond the data: an extreme value does not carry the look
    assert t(np.inf) == t(1e300) == pytest.approx(t.u[-1] + math.log(10.0), rel=1e-12)
    # the upper tail is resolved: the top knot is the largest response
    assert t.gamma[-1] == x.max()
    assert tail_table(np.full(7, np.nan)).u.tolist() == [0.0, 0.0]  # no response: tells nothing


@pytest.mark.parametrize("look_z_min", [-math.inf, -1.0, 0.0, 2.0])  # -1: look_pd 0.9 decides, 2: the floor
@pytest.mark.parametrize("look_pd", [0.0, 0.9, 0.95, 0.99])  # 0.99: more than the fired share, rule off
def test_look_pd_is_the_share_of_targets_on_which_the_look_detected(rng, look_pd, look_z_min):
    """P(y) of a look: injected targets on which a detector fired and, with look_pd > 0, the
    look score reached z_tau; z_tau the largest threshold keeping look_pd of them (0: any); with
    the likelihood-ratio score, also z > look_z_min (a look whose detectors together favour the
    seabed is a miss)."""
    resp = joint_responses(rng)
    cal = CalibrationSettings(prior="fixed", look_pd=look_pd, look_z_min=look_z_min)
    model = estimate_model(resp, calibration=cal, thresholds=ThresholdSettings())
    floors = 0
    for subset in (("mf",), ("mf", "smf"), DETS):
        table = model.look(subset)
        fired = np.zeros(resp.n_targets, bool)
        for d in subset:
            fired |= resp.target[d] > model.tau[d]
        z = np.asarray(model.look_score({d: resp.target[d] for d in subset}, subset), dtype=np.float64)
        zn = np.asarray(model.look_score({d: resp.nontarget[d] for d in subset}, subset), dtype=np.float64)
        # the node scores one look at a time: the arrays' scores are those, on a sample
        for i in range(0, resp.n_targets, 97):
            one = float(model.look_score({d: np.float64(resp.target[d][i]) for d in subset}, subset))
            assert one == z[i] or (math.isnan(one) and math.isnan(z[i]))
        fired_n = np.zeros(zn.size, bool)
        for d in subset:
            fired_n |= resp.nontarget[d] > model.tau[d]
        # z_tau by direct count: the k-th strongest fired target, k = ceil(look_pd * targets);
        # without either rule every fired look (target or cell) detects
        k = math.ceil(look_pd * resp.n_targets - 1e-9)
        z_tau = np.sort(z[fired])[::-1][k - 1] if look_pd > 0 and fired.sum() >= k else -math.inf
        lowest = min(z[fired].min(), zn[fired_n].min())
        if look_z_min > -math.inf and lowest <= look_z_min and look_z_min >= z_tau:
            assert table.tau_source == "look_z" and table.tau == look_z_min  # the floor: z > look_z_min
            floors += 1
        elif look_pd > 0 and fired.mean() >= look_pd:
            assert table.tau_source == "look_pd"
            kept = fired & (z > table.tau)
            assert kept.mean() >= look_pd  # look_pd of the targets detect ...
            assert table.tau == np.nextafter(z_tau, -np.inf)
            z_next = float(np.nextafter(table.tau, np.inf))  # ... and no higher threshold keeps them
            assert (fired & (z > z_next)).mean() < look_pd
        else:  # the rules are off: every fired look detects
            assert table.tau_source == "look" and (z[fired] > table.tau).all()
        fired &= z > table.tau
        # the confidence table's exceedances are exactly the detecting looks (targets and cells)
        assert table.confidence.n_target_above == int(fired.sum())
        assert table.confidence.n_nontarget_above == int((fired_n & (zn > table.tau)).sum())
        edges = table.pyr.edges_m
        for b in range(edges.size - 1):
            inb = (resp.target_range_m >= edges[b]) & (resp.target_range_m < edges[b + 1])
            n, k = int(inb.sum()), int(fired[inb].sum())
            if n:
                assert table.pyr.injected[b] == n and table.pyr.detected[b] == k
                assert table.pyr.pd[b] == pytest.approx((k + 0.5) / (n + 1.0), abs=1e-12)
        assert table.pd_at_tau == pytest.approx(fired.mean(), abs=1e-12)
    if look_z_min == 2.0:
        assert floors == 3  # the floor decided every table: the test reached its branch
    if look_z_min == -1.0 and look_pd == 0.9:
        assert floors < 3  # look_pd's threshold above the floor decided some table: that branch too


def test_one_detector_look_is_that_detectors_own_table(rng):
    """For a single detector z is a monotone function of gamma and "fired" is gamma > tau:
    the look confidence at z(gamma) is the detector's c(gamma) (without the floor look_z_min,
    which keeps only the looks at z > 0 and so conditions the table on more than firing)."""
    resp = joint_responses(rng)
    model = estimate_model(resp, calibration=CalibrationSettings(prior="fixed", look_z_min=-math.inf),
                           thresholds=ThresholdSettings())
    g = np.quantile(resp.target["smf"][resp.target["smf"] > model.tau["smf"]], np.linspace(0.02, 0.98, 25))
    z = model.look_score({"smf": g}, ("smf",))
    np.testing.assert_allclose(model.look(("smf",)).confidence_at(z), model.confidence("smf", g), atol=0.03)


def test_copies_of_one_detector_add_nothing(rng):
    """Four identical detectors are one piece of evidence: the look table of the four is the
    table of one (z is 4 u(gamma), fired sets equal), where the paper's form would count
    the same detection four times."""
    resp = joint_responses(rng)
    same = Responses(DETS, {d: resp.target["mf"] for d in DETS}, {d: resp.nontarget["mf"] for d in DETS},
                     resp.target_range_m, resp.target_shape, resp.provenance)
    model = estimate_model(same, calibration=CalibrationSettings(prior="fixed"), thresholds=ThresholdSettings(),
                           taus={d: 1.5 for d in DETS})
    one, four = model.look(("mf",)), model.look(DETS)
    g = np.linspace(1.6, 4.0, 13)
    c1 = one.confidence_at(model.look_score({"mf": g}, ("mf",)))
    c4 = four.confidence_at(model.look_score({d: g for d in DETS}, DETS))
    np.testing.assert_allclose(c4, c1, atol=0.02)
    np.testing.assert_allclose(four.pyr.pd, one.pyr.pd, atol=1e-12)
    # the paper: four simple supports of c combine to 1 - (1 - c)^4
    paper, mid = 1 - (1 - c1) ** 4, c1 < 0.9
    assert mid.sum() >= 4 and np.all(paper[mid] > c4[mid] + 0.05)


def test_correlated_detectors_give_less_than_independent_ones(rng):
    """With correlated detectors (rho 0.8) the look's confidence at a typical target is far
    below the paper's product of four simple supports from the same responses."""
    resp = joint_responses(rng, rho=0.8)
    model = estimate_model(resp, calibration=CalibrationSettings(prior="fixed"), thresholds=ThresholdSettings())
    strong = {d: np.array([np.median(resp.target[d])]) for d in DETS}
    c_look = float(model.look(DETS).confidence_at(model.look_score(strong, DETS))[0])
    c_each = [float(model.confidence(d, strong[d])[0]) for d in DETS]
    paper = 1 - np.prod([1 - c for c in c_each])
    assert 0.0 < c_look < paper
    # the look confidence still grows with the evidence
    z = model.look_score({d: np.linspace(0, 5, 50) for d in DETS}, DETS)
    assert np.all(np.diff(model.look(DETS).confidence_at(z)) >= 0)


def test_every_subset_has_a_table_and_the_file_keeps_them(rng, tmp_path):
    model = estimate_model(joint_responses(rng, m=400, k=4000), calibration=CalibrationSettings(),
                           thresholds=ThresholdSettings())
    assert len(model.looks.tables) == 15 and subset_key(("z", "mf")) == "mf+z"
    back = PerformanceModel.load(model.save(tmp_path / "m.json"))
    g = {d: np.linspace(-1, 5, 31) for d in DETS}
    for key, table in model.looks.tables.items():
        dets = key.split("+")
        np.testing.assert_array_equal(back.look(dets).confidence_at(back.look_score(g, dets)),
                                      table.confidence_at(model.look_score(g, dets)))
        np.testing.assert_array_equal(back.look(dets).pyr.pd, table.pyr.pd)
    # a corrupted look table is refused with the key named
    body = json.loads((tmp_path / "m.json").read_text())
    body["looks"]["tables"]["mf+lac"]["confidence"]["c"][0] = 1.5
    from atr_node.calibration.model import _digest

    body["sha256"] = _digest({k: v for k, v in body.items() if k != "sha256"})
    (tmp_path / "bad.json").write_text(json.dumps(body))
    with pytest.raises(ModelFileError, match=r"looks\.tables\.mf\+lac\.confidence\.c"):
        PerformanceModel.load(tmp_path / "bad.json")
    # a model file from before SPEC 6.1 (no looks) still loads, without look tables
    del body["looks"]
    body["sha256"] = _digest({k: v for k, v in body.items() if k != "sha256"})
    (tmp_path / "old.json").write_text(json.dumps(body))
    old = PerformanceModel.load(tmp_path / "old.json")
    assert old.looks is None and old.look(DETS) is None


def test_area_prior_closed_form_and_recorded():
    assert area_prior(400.0, 5.0) == pytest.approx(1 - math.exp(-400 * 5.0 / 1e6), rel=1e-15)
    assert area_prior(1e-300, 1e-300) == 1e-12 and area_prior(1e6, 1e9) == 1 - 1e-12


def test_area_prior_is_used_and_written_into_the_model(rng):
    resp = joint_responses(rng, m=300, k=3000)
    model = estimate_model(resp, calibration=CalibrationSettings(prior="area", target_density_km2=1000.0),
                           thresholds=ThresholdSettings())
    est = model.estimation
    assert est["prior"] == "area" and est["cell_area_m2"] == 5.0 and est["target_density_km2"] == 1000.0
    assert est["prior_target"] == pytest.approx(1 - math.exp(-1000 * 5.0 / 1e6))
    fixed = estimate_model(resp, calibration=CalibrationSettings(prior="fixed", prior_target=0.1),
                           thresholds=ThresholdSettings())
    assert fixed.estimation["prior"] == "fixed" and fixed.prior_target == 0.1


def test_with_prior_matches_a_model_made_with_that_prior(rng):
    """Re-reading the tables under another prior (odds ratio) gives the tables estimated with
    it, wherever the isotonic fit did not move them."""
    resp = joint_responses(rng)
    a = estimate_model(resp, calibration=CalibrationSettings(prior="fixed", prior_target=0.1),
                       thresholds=ThresholdSettings())
    b = estimate_model(resp, calibration=CalibrationSettings(prior="fixed", prior_target=0.003),
                       thresholds=ThresholdSettings())
    moved = a.with_prior(0.003)
    for d in DETS:
        ca, cb = a.detectors[d].confidence, b.detectors[d].confidence
        if not ca.isotonic_adjusted and not cb.isotonic_adjusted:
            np.testing.assert_allclose(moved.detectors[d].confidence.confidence, cb.confidence, rtol=1e-9)
    assert moved.prior_target == 0.003
    np.testing.assert_allclose(with_prior(np.array([0.5]), 0.5, 0.1), [0.1], rtol=1e-15)


def test_ranked_confidence_breaks_ties_by_z_and_moves_nothing_else():
    """c + e c (1 - c) s(z), s = 1/2 + atan(z / 10) / pi: computed directly in float64 here;
    strictly increasing in z at a fixed c in (0, 1) and in c at a fixed z; within e / 4 of c;
    0, 1 and NaN unchanged; finite for any z."""
    from atr_node.calibration.looks import CONFIDENCE_TIE, ranked_confidence

    c = np.array([1e-12, 0.01, 0.3, 0.5, 0.878, 1 - 1e-12])
    for z in (-40.0, -1.0, 0.0, 3.7, 25.0):
        s = 0.5 + math.atan(z / 10.0) / math.pi
        np.testing.assert_allclose(ranked_confidence(c, z), c + CONFIDENCE_TIE * c * (1 - c) * s, rtol=1e-15, atol=0)
    zs = np.linspace(-60.0, 60.0, 241)
    for ci in c[1:-1]:
        r = ranked_confidence(np.full(zs.size, ci), zs)
        assert np.all(np.diff(r) > 0) and np.all(np.abs(r - ci) <= CONFIDENCE_TIE / 4)
    cs = np.linspace(0.0, 1.0, 1001)
    for z in (-1e300, -5.0, 0.0, 5.0, 1e300, math.inf, -math.inf):
        r = ranked_confidence(cs, z)
        assert np.all(np.isfinite(r)) and np.all(np.diff(r) > 0)
    assert ranked_confidence(0.0, 7.0) == 0.0 and ranked_confidence(1.0, 7.0) == 1.0
    assert np.isnan(ranked_confidence(np.nan, 1.0)) and np.isnan(ranked_confidence(0.5, np.nan))
