"""Performance-model estimation from hand-made responses and its versioned file: round trip,
older versions and corruption refused with a clear ModelFileError."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from atr_node.calibration.estimate import estimate_model
from atr_node.calibration.model import FORMAT_VERSION, PerformanceModel, _digest
from atr_node.calibration.responses import Responses
from atr_node.config import CalibrationSettings, ThresholdSettings
from atr_node.errors import ModelFileError


def _responses(rng, m=600, k=5000) -> Responses:
    r = rng.uniform(15.0, 95.0, size=m)
    # Pd falls with range for "mf"; "z" has no covered target at all (all NaN).
    x_mf = rng.normal(3.0 - 0.02 * r, 1.0)
    x_n = rng.normal(0.0, 1.0, size=k)
    return Responses(
        detectors=("mf", "z"),
        target={"mf": x_mf, "z": np.full(m, np.nan)},
        nontarget={"mf": x_n, "z": rng.normal(size=k)},
        target_range_m=r, target_shape=("cylinder",) * m,
        provenance={"seed": 7, "seabed": "hand-made", "sensor": {"frequency_hz": 120e3}},
    )


@pytest.fixture
def model(rng) -> PerformanceModel:
    return estimate_model(_responses(rng), calibration=CalibrationSettings(), thresholds=ThresholdSettings(z=2.5))


def test_estimated_model_thresholds_confidence_and_pd(model, rng):
    x = model.detectors["mf"]
    assert x.tau_source == "dobeck" and x.pd_at_tau >= 0.95
    assert model.detectors["z"].tau_source == "config" and model.tau["z"] == 2.5
    g = np.linspace(-5, 10, 301)
    for d in ("mf", "z"):
        c = model.confidence(d, g)
        assert np.all((c > 0) & (c < 1)) and np.all(np.diff(c) >= 0)
        assert model.pd(d, np.array([0.0, 5.0, 100.01, 500.0])).tolist() == [0.0, 0.0, 0.0, 0.0]
    # no covered target for z: every bin empty, Pd 0 everywhere (no evidence)
    assert np.all(model.pd("z", np.linspace(10, 100, 50)) == 0.0)
    assert np.isnan(model.confidence("mf", np.nan))
    assert model.thresholds().mf == model.tau["mf"] and model.thresholds().lac == ThresholdSettings().lac
    with pytest.raises(KeyError, match="not in this model"):
        model.pd("smf", 10.0)


def test_file_round_trip_is_exact(model, tmp_path):
    path = model.save(tmp_path / "m.json")
    back = PerformanceModel.load(path)
    assert back.tau == model.tau
    g = np.linspace(-3, 8, 97)
    r = np.linspace(0, 120, 97)
    for d in model.detectors:
        np.testing.assert_array_equal(back.confidence(d, g), model.confidence(d, g))
        np.testing.assert_array_equal(back.pd(d, r), model.pd(d, r))
        np.testing.assert_array_equal(back.detectors[d].pyr.injected, model.detectors[d].pyr.injected)
    assert back.provenance["seed"] == 7 and back.provenance["seabed"] == "hand-made"
    assert back.provenance["n_target_responses"] == 600
    body = json.loads(path.read_text())
    assert body["format_version"] == FORMAT_VERSION and "isotonic_adjusted" in body["detectors"]["mf"]["confidence"]


def _rewrite(path, mutate, *, fix_digest=True):
    body = json.loads(path.read_text())
    mutate(body)
    if fix_digest:
        body["sha256"] = _digest({k: v for k, v in body.items() if k != "sha256"})
    path.write_text(json.dumps(body))


def test_older_and_newer_versions_are_refused(model, tmp_path):
    for version in (0, FORMAT_VERSION + 1, None):
        p = model.save(tmp_path / f"v{version}.json")
        _rewrite(p, lambda b: b.__setitem__("format_version", version))
        with pytest.raises(ModelFileError, match=r"format version .* regenerate"):
            PerformanceModel.load(p)


@pytest.mark.parametrize("mutate, fix, match", [
    (lambda b: b["detectors"]["mf"].__setitem__("tau", 99.0), False, "checksum"),
    (lambda b: b["detectors"]["mf"]["confidence"]["c"].__setitem__(0, 1.0), True, "strictly inside"),
    (lambda b: b["detectors"]["mf"]["confidence"]["c"].reverse(), True, "non-decreasing"),
    (lambda b: b["detectors"]["mf"]["pyr"]["pd"].pop(), True, "key 'detectors.mf.pyr.pd': expected"),
    (lambda b: b["detectors"]["mf"].__setitem__("tau", "high"), True, "key 'detectors.mf.tau': should be float"),
    (lambda b: b["detectors"]["mf"].pop("pyr"), True, "key 'detectors.mf.pyr': missing"),
    (lambda b: b["detectors"].clear(), True, "no detector"),
    (lambda b: b.__setitem__("format", "something-else"), True, "not an atr-node performance model"),
    (lambda b: b["detectors"]["mf"]["pyr"]["detected"].__setitem__(0, 10 ** 6), True, "detected"),
])
def test_corrupted_files_are_refused_with_the_key(model, tmp_path, mutate, fix, match):
    p = model.save(tmp_path / "m.json")
    _rewrite(p, mutate, fix_digest=fix)
    with pytest.raises(ModelFileError, match=match) as err:
        PerformanceModel.load(p)
    assert str(p) in str(err.value)


def test_truncated_missing_and_binary_files_are_refused(model, tmp_path):
    p = model.save(tmp_path / "m.json")
    text = p.read_text()
    p.write_text(text[: len(text) // 2])
    with pytest.raises(ModelFileError, match="not valid JSON"):
        PerformanceModel.load(p)
    p.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(ModelFileError, match="cannot read"):
        PerformanceModel.load(p)
    with pytest.raises(ModelFileError, match="cannot read"):
        PerformanceModel.load(tmp_path / "absent.json")


def test_responses_head_and_concat(rng):
    a = _responses(rng, m=100, k=50)
    b = _responses(rng, m=30, k=20)
    ab = Responses.concat([a, b])
    assert ab.n_targets == 130 and ab.nontarget["mf"].size == 70
    h = ab.head(110)
    assert h.n_targets == 110
    np.testing.assert_array_equal(h.target["mf"], ab.target["mf"][:110])
    np.testing.assert_array_equal(h.nontarget["mf"], ab.nontarget["mf"])


def test_empty_responses_give_a_defined_model(tmp_path):
    """SPEC section 8: no target and no cell at all (e.g. an all-NaN image) still gives a model
    whose confidence is the prior and whose Pd is 0 everywhere (no evidence)."""
    empty = Responses(detectors=("mf", "smf"), target={"mf": np.empty(0), "smf": np.empty(0)},
                      nontarget={"mf": np.empty(0), "smf": np.full(3, np.nan)}, target_range_m=np.empty(0))
    m = estimate_model(empty, calibration=CalibrationSettings(prior="fixed", prior_target=0.2),
                       thresholds=ThresholdSettings())
    assert m.tau == {"mf": ThresholdSettings().mf, "smf": ThresholdSettings().smf}
    for d in ("mf", "smf"):
        assert m.detectors[d].tau_source == "config"
        np.testing.assert_allclose(m.confidence(d, np.array([-1.0, 0.0, 5.0])), 0.2)
        assert np.all(m.pd(d, np.linspace(-10, 500, 30)) == 0.0)
    back = PerformanceModel.load(m.save(tmp_path / "empty.json"))
    assert np.isnan(back.detectors["mf"].pd_at_tau)


def test_single_target_and_single_cell(tmp_path):
    one = Responses(detectors=("z",), target={"z": np.array([4.0])}, nontarget={"z": np.array([0.5])},
                    target_range_m=np.array([42.0]))
    m = estimate_model(one, calibration=CalibrationSettings(range_bin_m=10.0), thresholds=ThresholdSettings())
    p = m.detectors["z"]
    assert p.tau < 4.0 and p.pd_at_tau == 1.0
    assert p.pyr.injected.tolist() == [1] and p.pyr.edges_m.tolist() == [40.0, 50.0]
    assert m.pd("z", 45.0) == pytest.approx(0.75) and m.pd("z", 39.0) == 0.0
    c = m.confidence("z", np.array([p.tau, 4.0, 100.0]))
    assert np.all((c > 0) & (c < 1)) and np.all(np.diff(c) >= 0)


def test_dict_round_trip_for_snapshots(model):
    back = PerformanceModel.from_dict(model.to_dict(), where="snapshot")
    assert back.tau == model.tau
    body = model.to_dict()
    body["detectors"]["mf"]["tau"] += 1.0
    with pytest.raises(ModelFileError, match="snapshot: corrupted"):
        PerformanceModel.from_dict(body, where="snapshot")


def test_model_pickles_for_worker_processes(model):
    import pickle

    back = pickle.loads(pickle.dumps(model))
    assert back.tau == model.tau
    np.testing.assert_array_equal(back.pd("mf", np.linspace(0, 120, 13)), model.pd("mf", np.linspace(0, 120, 13)))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 200.0), st.floats(-5.0, 50.0)), max_size=40),
       st.lists(st.floats(-5.0, 50.0), max_size=40), st.sampled_from(["jeffreys", "laplace"]),
       st.floats(0.5, 0.99))
def test_property_codec_round_trip_and_invariants(targets, cells, smoothing, pd_target):
    r = np.array([t[0] for t in targets])
    x = np.array([t[1] for t in targets])
    resp = Responses(detectors=("lac",), target={"lac": x}, nontarget={"lac": np.array(cells)}, target_range_m=r)
    m = estimate_model(resp, calibration=CalibrationSettings(smoothing=smoothing, pd_target=pd_target))
    back = PerformanceModel.from_dict(json.loads(json.dumps(m.to_dict())))
    g = np.linspace(-10, 60, 71)
    rr = np.linspace(-10, 250, 53)
    np.testing.assert_array_equal(back.confidence("lac", g), m.confidence("lac", g))
    np.testing.assert_array_equal(back.pd("lac", rr), m.pd("lac", rr))
    c = back.confidence("lac", g)
    assert np.all((c > 0) & (c < 1)) and np.all(np.diff(c) >= 0)
    p = back.pd("lac", rr)
    assert np.all((p >= 0) & (p <= 1))
    if r.size:
        assert np.all(p[(rr < back.detectors["lac"].pyr.edges_m[0]) | (rr > back.detectors["lac"].pyr.edges_m[-1])] == 0)


@pytest.mark.parametrize("look_weights", ["sum", "fit"])
def test_targets_cut_by_the_swath_end_count_in_p_y_only(rng, look_weights):
    """A target whose shadow the swath's end cut (trait ``whole`` 0) counts in P(y), detected or
    not, and nowhere else: thresholds, confidence curves, look scores and weights are those of
    the whole targets alone, and P(y) in the cut targets' bin is their own share over tau."""
    m, n_cut, k = 600, 150, 5000
    r = np.concatenate([rng.uniform(15.0, 80.0, m), rng.uniform(85.0, 90.0, n_cut)])
    common = rng.normal(size=m + n_cut)
    shift = np.where(np.arange(m + n_cut) < m, 3.0, 0.5)  # cut targets: weak (half their shadow gone)
    tgt = {d: shift + 0.8 * common + 0.6 * rng.normal(size=m + n_cut) for d in ("mf", "lac")}
    cells = {d: rng.normal(size=k) for d in ("mf", "lac")}
    whole = (np.arange(m + n_cut) < m).astype(np.float64)
    full = Responses(("mf", "lac"), tgt, cells, r, ("cylinder",) * (m + n_cut), {"cell_area_m2": 5.0},
                     {"whole": whole})
    sub = Responses(("mf", "lac"), {d: v[:m] for d, v in tgt.items()}, cells, r[:m], ("cylinder",) * m,
                    {"cell_area_m2": 5.0})
    cal = CalibrationSettings(look_weights=look_weights)
    a, b = (estimate_model(x, calibration=cal, thresholds=ThresholdSettings()) for x in (full, sub))
    g = np.linspace(-3.0, 8.0, 45)
    for d in ("mf", "lac"):
        assert a.tau[d] == b.tau[d] and a.detectors[d].pd_at_tau == b.detectors[d].pd_at_tau
        np.testing.assert_array_equal(a.confidence(d, g), b.confidence(d, g))
        np.testing.assert_array_equal(a.pd(d, [17.5, 42.5, 77.5]), b.pd(d, [17.5, 42.5, 77.5]))
        # the cut targets' bin, 85-90 m: Jeffreys (detected + 1/2) / (injected + 1), by hand
        hit = int(np.sum(tgt[d][m:] > a.tau[d]))
        assert a.pd(d, 87.5) == pytest.approx((hit + 0.5) / (n_cut + 1), rel=1e-12)
        assert b.pd(d, 87.5) == 0.0  # without them: outside the span
    la, lb = a.look(("mf", "lac")), b.look(("mf", "lac"))
    assert la.tau == lb.tau and la.tau_source == lb.tau_source
    np.testing.assert_array_equal(la.confidence_at(g), lb.confidence_at(g))
    assert a.looks.weights == b.looks.weights and (a.looks.weights is not None) == (look_weights == "fit")
    assert 0.0 < la.pd_at(87.5) < la.pd_at(42.5)
