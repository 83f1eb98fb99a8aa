"""Look-level evidence in the grid (SPEC 6.1): one piece per look and cell, built by
``node.evidence.unit_observations`` from a model estimated on joint responses."""

from __future__ import annotations

import math

import numpy as np
import pytest

from atr_node.calibration.estimate import estimate_model
from atr_node.calibration.looks import CONFIDENCE_TIE, ranked_confidence
from atr_node.calibration.responses import Responses
from atr_node.config import CalibrationSettings, FusionSettings, ThresholdSettings
from atr_node.detectors.extract import Detection
from atr_node.fusion import EvidenceGrid, Observation
from atr_node.fusion.mass import closed_form
from atr_node.node.evidence import evidence_layers, unit_observations

from .conftest import pixel_of, track_geometry

DETS = ("mf", "lac", "smf", "z")
POINT = (35.0, 20.0)  # east, north


def look_c(table, z) -> float:
    """A look's T mass as the node deposits it: the table's c(z), its ties broken by z."""
    return float(ranked_confidence(table.confidence_at(z), z))


@pytest.fixture(scope="module")
def responses():
    rng = np.random.default_rng(3)
    m, k = 1500, 20000
    r = rng.uniform(10.0, 60.0, size=m)

    def draws(n, shift):
        common = rng.normal(size=n)
        return {d: shift + math.sqrt(0.8) * common + math.sqrt(0.2) * rng.normal(size=n) for d in DETS}

    resp = Responses(DETS, draws(m, 3.5), draws(k, 0.0), r, ("cylinder",) * m, {"cell_area_m2": 5.0})
    return resp


@pytest.fixture(scope="module")
def model(responses):
    """Every fired look detects (look_pd 0, no floor on z); 10 m range bins: Pd(r) flat enough
    for the closed forms below."""
    return estimate_model(responses, calibration=CalibrationSettings(prior="fixed", prior_target=0.01, look_pd=0.0,
                                                                     look_z_min=-math.inf, range_bin_m=10.0),
                          thresholds=ThresholdSettings())


@pytest.fixture(scope="module")
def model_95(responses):
    """The rule look_pd: a look detects where z keeps 95 % of the injected targets (alone, no
    floor on z)."""
    return estimate_model(responses, calibration=CalibrationSettings(prior="fixed", prior_target=0.01, look_pd=0.95,
                                                                     look_z_min=-math.inf),
                          thresholds=ThresholdSettings())


@pytest.fixture(scope="module")
def model_z(responses):
    """The floor alone (look_pd 0, look_z_min 0 as by default): a look detects where z > 0."""
    return estimate_model(responses, calibration=CalibrationSettings(prior="fixed", prior_target=0.01, look_pd=0.0),
                          thresholds=ThresholdSettings())


def look(frame, model, leg, east0, heading, *, hit: bool, layers, gamma: float | dict = 4.5):
    g = track_geometry(frame, east0_m=east0, north0_m=0.0 if heading == 0.0 else 40.0, heading_deg=heading, rows=400,
                       cols=500, leg=leg)
    row, col = pixel_of(g, *POINT)
    gam = gamma if isinstance(gamma, dict) else {d: gamma for d in DETS}
    joint = tuple((d, gam[d]) for d in DETS)
    dets = {d: [Detection(d, row, col, gam[d], float(g.ranges_m[col]), 0.6, 2.0, 50, joint=joint)]
            if hit and gam[d] > model.tau[d] else [] for d in DETS}
    cov = np.ones((400, 500), bool)
    obs = unit_observations(model, dets, lambda d: cov, g.ranges_m, DETS, layers)
    return Observation(leg, 1.7e9 + leg, g, obs)


def bel(frame, model, views, evidence, gamma: float | dict = 4.5):
    """Bel(T) at POINT after the views (leg, east0, heading, hit[, the view's own gamma])."""
    layers = evidence_layers(evidence, model, DETS)
    grid = EvidenceGrid(FusionSettings(evidence=evidence), gate_m=3.0, detectors=DETS, layers=layers)
    for leg, east0, heading, hit, *own in views:
        grid.add_observation(look(frame, model, leg, east0, heading, hit=hit, layers=layers,
                                  gamma=own[0] if own else gamma))
    grid.close_all()
    return float(grid.masses_at(*POINT).m_t), grid


def test_a_look_is_one_piece_of_evidence(frame, model):
    """Four detectors of one look give the look's confidence, not four supports."""
    b_look, grid = bel(frame, model, [(1, 0.0, 0.0, True)], "look")
    assert grid.layers == ("look",) and {r.detector for r in grid.detections} == set(DETS)
    z = model.look_score({d: np.float64(4.5) for d in DETS}, DETS)
    assert b_look == pytest.approx(look_c(model.look(DETS), z), rel=1e-9)
    b_paper, _ = bel(frame, model, [(1, 0.0, 0.0, True)], "paper")
    each = [float(model.confidence(d, 4.5)) for d in DETS]
    assert b_paper == pytest.approx(1 - np.prod([1 - c for c in each]), rel=1e-9)
    assert b_look < b_paper


def test_an_object_on_one_leg_that_another_look_missed_falls_below_report(frame, model):
    """Seen by leg 1, covered and missed by leg 2 at Pd about 0.99: under look evidence it ends
    below report_bel; the paper's four supports keep it near certainty."""
    views = [(1, 0.0, 0.0, True), (2, 70.0, 180.0, False)]
    b_look, _ = bel(frame, model, views, "look")
    b_paper, _ = bel(frame, model, views, "paper")
    pd = float(model.look(DETS).pd_at(35.0))
    c = look_c(model.look(DETS), model.look_score({d: np.float64(4.5) for d in DETS}, DETS))
    assert b_look == pytest.approx(c * (1 - pd) / (1 - c * pd), rel=1e-6)  # Dempster, closed form
    assert b_look < FusionSettings().report_bel < b_paper


def test_two_detecting_looks_stay_above_report(frame, model):
    b, _ = bel(frame, model, [(1, 0.0, 0.0, True), (2, 70.0, 180.0, True)], "look")
    c = look_c(model.look(DETS), model.look_score({d: np.float64(4.5) for d in DETS}, DETS))
    assert b == pytest.approx(1 - (1 - c) ** 2, rel=1e-9) and b > FusionSettings().report_bel


def test_look_extremes_confidence_one_pd_one_and_many_looks(frame, model):
    """SPEC 8 for the new evidence: a look at confidence 1 against one at Pd 1 (both clamped,
    counted), and 10^5 looks in the accumulators: finite, in [0, 1]."""
    import dataclasses

    table = model.look(DETS)
    conf = dataclasses.replace(table.confidence, confidence=np.ones_like(table.confidence.confidence))
    pyr = dataclasses.replace(table.pyr, pd=np.ones_like(table.pyr.pd))
    extreme = dataclasses.replace(model, looks=type(model.looks)(model.looks.tails,
                                                                 {"mf+lac+smf+z": dataclasses.replace(
                                                                     table, confidence=conf, pyr=pyr)}))
    b, grid = bel(frame, extreme, [(1, 0.0, 0.0, True), (2, 70.0, 180.0, False)], "look")
    assert math.isfinite(b) and 0.0 <= b <= 1.0 and grid.n_clamped >= 2
    lt = np.full(3, 1e5 * math.log1p(-0.9))
    ln = np.array([0.0, 1e5 * math.log1p(-0.5), -np.inf])
    m = closed_form(lt, ln)
    assert np.all(np.isfinite(m.m_t)) and np.all((m.m_t >= 0) & (m.m_t <= 1))


def test_a_model_without_look_tables_falls_back_to_the_paper(frame, model, caplog):
    import dataclasses

    old = dataclasses.replace(model, looks=None)
    assert evidence_layers("look", old, DETS) == DETS
    assert "no look-level table" in caplog.text


def test_a_look_that_fired_weakly_is_a_miss(frame, model_95):
    """One detector just over its threshold, the others quiet: z below the look's z_tau. Under
    the default rule (look_pd 0.95) that look gives no T mass, so the object ends with the
    same Bel as if the look had not fired at all; counted as a detection it kept its T mass."""
    tau = model_95.tau
    weak = {d: (tau[d] + 0.05 if d == "lac" else tau[d] - 3.0) for d in DETS}
    z = model_95.look_score({d: np.float64(v) for d, v in weak.items()}, DETS)
    table = model_95.look(DETS)
    assert z < table.tau < model_95.look_score({d: np.float64(4.5) for d in DETS}, DETS)
    weak_look = [(1, 0.0, 0.0, True), (2, 70.0, 180.0, True)]
    b, grid = bel(frame, model_95, weak_look, "look", gamma=weak)
    assert b == 0.0 and grid.detections == []  # both looks weak: no T mass, no detection record
    two_strong, _ = bel(frame, model_95, weak_look, "look")
    # a strong look, then a weak one: as a strong look and a miss
    b_mixed, _ = bel(frame, model_95, [(1, 0.0, 0.0, True), (2, 70.0, 180.0, True, weak)], "look")
    b_miss, _ = bel(frame, model_95, [(1, 0.0, 0.0, True), (2, 70.0, 180.0, False)], "look")
    assert b_mixed == pytest.approx(b_miss, rel=1e-12) and b_mixed < two_strong


def test_without_the_look_rule_every_fired_look_detects(frame, model):
    """A table made with look_pd 0 (or before the rule: ``tau_source = "look"``) keeps every
    look on which a detector fired, even one scoring below anything the calibration saw."""
    table = model.look(DETS)
    assert table.tau_source == "look"
    tau = model.tau
    weak = {d: (tau[d] + 1e-3 if d == "lac" else -50.0) for d in DETS}
    z = model.look_score({d: np.float64(v) for d, v in weak.items()}, DETS)
    assert z < table.tau  # below every fired calibration score
    b, grid = bel(frame, model, [(1, 0.0, 0.0, True)], "look", gamma=weak)
    assert len(grid.detections) == 1 and b == pytest.approx(look_c(table, z), rel=1e-12) and b > 0


STRONG_THEN_MISS = [(1, 0.0, 0.0, True), (2, 70.0, 180.0, False)]
"""A strong look on leg 1, leg 2 covering POINT at 35 m without a detection."""


def _strong_then_weak(model) -> list[tuple]:
    """A strong look on leg 1, then leg 2 with LAC and Z just over their thresholds and MF and
    SMF well under theirs: a look whose detectors together favour the seabed."""
    weak = {d: (model.tau[d] + 0.05 if d in ("lac", "z") else model.tau[d] - 1.0) for d in DETS}
    return [(1, 0.0, 0.0, True), (2, 70.0, 180.0, True, weak)]


def test_a_look_whose_detectors_favour_the_seabed_is_a_miss(frame, model, model_z):
    """z <= 0 (calibration.look_z_min, the default): the detectors' log likelihood ratios sum
    to evidence for the seabed. Such a look gives no T mass and its miss stands, so an object
    with a strong look and such a look ends as a strong look and a miss; without the floor
    (the same responses, ``model``) the weak look is a detection and the miss is gone."""
    table = model_z.look(DETS)
    assert table.tau_source == "look_z" and table.tau == 0.0
    legs = _strong_then_weak(model_z)
    weak = legs[1][4]
    z = model_z.look_score({d: np.float64(v) for d, v in weak.items()}, DETS)
    assert z <= 0.0 < model_z.look_score({d: np.float64(4.5) for d in DETS}, DETS)
    assert z > model.look(DETS).tau  # the same look detects without the floor
    b_mixed, grid = bel(frame, model_z, legs, "look")
    b_miss, _ = bel(frame, model_z, STRONG_THEN_MISS, "look")
    c = look_c(table, model_z.look_score({d: np.float64(4.5) for d in DETS}, DETS))
    q = float(table.pd_at(35.0))  # leg 2 sees POINT at 35 m (as in the one-leg test above)
    assert b_mixed == pytest.approx(b_miss, rel=1e-12)
    assert b_mixed == pytest.approx(c * (1 - q) / (1 - c * q), rel=1e-6)  # Dempster, closed form
    assert [d.leg for d in grid.detections] == [1, 1, 1, 1]  # the weak look left no detection record
    b_open, grid_open = bel(frame, model, legs, "look")
    assert 2 in {d.leg for d in grid_open.detections} and b_open > b_mixed


def test_a_look_table_of_an_unknown_source_keeps_its_threshold(frame, model_z):
    """Only a ``"look"`` table (every fired look detects) keeps looks below its tau; any other
    source, one this code does not know included, makes them misses, as its P(y) counts them."""
    import dataclasses

    table = model_z.look(DETS)
    future = dataclasses.replace(model_z, looks=dataclasses.replace(
        model_z.looks, tables={"mf+lac+smf+z": dataclasses.replace(table, tau_source="look_future")}))
    b_future, _ = bel(frame, future, _strong_then_weak(model_z), "look")
    b_miss, _ = bel(frame, model_z, STRONG_THEN_MISS, "look")
    assert b_future == pytest.approx(b_miss, rel=1e-12)


def test_a_look_on_clipped_seabed_is_scored_with_the_clipped_tables(frame):
    """A model whose clipped places have their own likelihood ratios (an 8-bit file's bright
    seabed, docs/fusion.md): the node scores a detection with the table of its headroom, and
    the look's T mass is the look table's c(z) of that score."""
    rng = np.random.default_rng(11)
    m, k = 2000, 20000
    c_t, c_n = rng.random(m) < 0.5, rng.random(k) < 0.5
    target = {d: rng.normal(size=m) + np.where(c_t & (d != "smf"), 1.0, 3.0) for d in DETS}
    resp = Responses(DETS, target, {d: rng.normal(size=k) for d in DETS}, rng.uniform(10.0, 60.0, m),
                     ("cylinder",) * m, {"cell_area_m2": 5.0}, {"headroom_db": np.where(c_t, 5.0, 30.0)},
                     np.where(c_n, 5.0, 30.0))
    mod = estimate_model(resp, calibration=CalibrationSettings(prior="fixed", prior_target=0.01, look_pd=0.0,
                                                               look_z_min=-math.inf),
                         thresholds=ThresholdSettings())
    assert mod.looks.lrs_clipped is not None
    g = track_geometry(frame, east0_m=0.0, north0_m=0.0, heading_deg=0.0, rows=400, cols=500, leg=1)
    row, col = pixel_of(g, *POINT)
    gam = {"mf": 1.5, "lac": 1.5, "z": 1.5, "smf": 1.5}  # closed-form l: 1 each clipped, 0 free
    joint = tuple((d, gam[d]) for d in DETS)
    cov = np.ones((400, 500), bool)
    layers = evidence_layers("look", mod, DETS)
    conf = {}
    for head in (6.0, 25.0):
        dets = {d: [Detection(d, row, col, gam[d], float(g.ranges_m[col]), 0.6, 2.0, 50, joint=joint,
                              headroom_db=head)] if gam[d] > mod.tau[d] else [] for d in DETS}
        (obs,) = unit_observations(mod, dets, lambda d: cov, g.ranges_m, DETS, layers)
        assert obs.detections
        conf[head] = [r.confidence for r in obs.detections]
        z = float(mod.look_score({d: np.float64(v) for d, v in gam.items()}, DETS, headroom_db=head))
        assert conf[head] == pytest.approx([look_c(mod.look(DETS), z)] * len(conf[head]), rel=1e-12)
    assert min(conf[6.0]) > max(conf[25.0])


def test_looks_the_table_cannot_tell_apart_rank_by_their_score(frame, model):
    """Two looks scoring above every clean cell of the calibration get the same c(z) from the
    table (its flat top); deposited, the stronger one's T mass and Bel are the higher, each
    within CONFIDENCE_TIE / 4 of the table's value."""
    table = model.look(DETS)
    z = {g: float(model.look_score({d: np.float64(g) for d in DETS}, DETS)) for g in (3.75, 4.5)}
    assert z[4.5] > z[3.75] and float(table.confidence_at(z[4.5])) == float(table.confidence_at(z[3.75]))
    b = {g: bel(frame, model, [(1, 0.0, 0.0, True)], "look", gamma=g)[0] for g in (3.75, 4.5)}
    assert b[4.5] > b[3.75]
    for g in b:
        assert abs(b[g] - float(table.confidence_at(z[g]))) <= CONFIDENCE_TIE / 4


def _spread_look(frame, model, object_m):
    """One look (leg 1) on one object: MF anchored at POINT with the strongest joint responses,
    SMF 1.5 m further along track and Z 1.2 m nearer in range with weaker ones, and LAC on a
    second object 6 m along track; the grid's detection records after it."""
    g = track_geometry(frame, east0_m=0.0, north0_m=0.0, heading_deg=0.0, rows=400, cols=500, leg=1)
    row, col = pixel_of(g, *POINT)
    strong = tuple((d, 4.5) for d in DETS)
    weaker = tuple((d, 3.5) for d in DETS)
    at = {"mf": (row, col, strong), "smf": (row + 15, col, weaker), "z": (row, col - 12, weaker),
          "lac": (row + 60, col, weaker)}
    dets = {d: [Detection(d, r, c, dict(j)[d], float(g.ranges_m[c]), 0.6, 2.0, 50, joint=j)] for d, (r, c, j) in at.items()}
    layers = evidence_layers("look", model, DETS)
    obs = unit_observations(model, dets, lambda d: np.ones((400, 500), bool), g.ranges_m, DETS, layers,
                            geometry=g, object_m=object_m)
    grid = EvidenceGrid(FusionSettings(), gate_m=3.0, detectors=DETS, layers=layers)
    grid.add_observation(Observation(1, 1.7e9, g, obs))
    grid.close_all()
    return {r.detector: (r.east_m, r.north_m, r.confidence) for r in grid.detections}


def test_a_looks_detections_of_one_object_take_its_strongest_anchor(frame, model):
    """Anchors of one look within the template's length (2 m) of a stronger one are placed at
    it, each keeping its detector and its own confidence; an anchor 6 m away stands; with
    object_m = 0 every anchor stands (the positions the detectors gave)."""
    merged = _spread_look(frame, model, 2.0)
    apart = _spread_look(frame, model, 0.0)
    assert set(merged) == set(apart) == set(DETS)
    for d in ("smf", "z"):
        assert merged[d][:2] == pytest.approx(merged["mf"][:2], abs=1e-9)
        assert math.hypot(apart[d][0] - apart["mf"][0], apart[d][1] - apart["mf"][1]) == pytest.approx(
            1.5 if d == "smf" else 1.2, abs=0.11)
        assert merged[d][2] == apart[d][2] < merged["mf"][2]
    assert merged["lac"] == apart["lac"] and math.hypot(merged["lac"][0] - merged["mf"][0],
                                                         merged["lac"][1] - merged["mf"][1]) == pytest.approx(6.0, abs=0.11)


def test_one_anchor_per_object_greedy_from_the_strongest(frame):
    """Closed cases of the rule: ties go to the first; a detection between two anchors takes the
    stronger; extended objects neither take nor give an anchor."""
    from types import SimpleNamespace

    from atr_node.node.evidence import one_anchor_per_object

    g = track_geometry(frame, east0_m=0.0, north0_m=0.0, heading_deg=0.0, rows=400, cols=500, leg=1)

    def det(row, col, length=None):
        return SimpleNamespace(row=row, col=col, length_m=length)

    # along track 0.1 m per row: rows 0, 15, 30 are 1.5 m apart; 60 is 6 m from 0
    assert one_anchor_per_object([det(0, 100), det(15, 100), det(60, 100)], [1.0, 2.0, 3.0], g, 2.0) == [1, 1, 2]
    assert one_anchor_per_object([det(0, 100), det(15, 100)], [2.0, 2.0], g, 2.0) == [0, 0]
    # row 30 is 1.5 m from row 15 (weaker) and 1.5 m from row 45 (stronger)
    assert one_anchor_per_object([det(15, 100), det(30, 100), det(45, 100)], [5.0, 1.0, 9.0], g, 2.0) == [0, 2, 2]
    assert one_anchor_per_object([det(0, 100, 20.0), det(5, 100)], [9.0, 1.0], g, 2.0) == [0, 1]
    assert one_anchor_per_object([det(0, 100), det(5, 100, 20.0)], [9.0, 1.0], g, 2.0) == [0, 1]
    assert one_anchor_per_object([det(0, 100), det(5, 100)], [9.0, 1.0], g, 0.0) == [0, 1]
