"""Evaluation (issue 8): scoring against truth (ICD section 5), ROC curves, the paper's
comparisons on the same detections, the evaluate command and the demo's report on a small
mission."""

from __future__ import annotations

import itertools
import json
import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from atr_node.calibration.model import PerformanceModel
from atr_node.errors import AtrError
from atr_node.evaluation.evaluate import evaluate_log
from atr_node.evaluation.scoring import local_en, match, read_clutter, read_truth, roc
from atr_node.fusion.baselines import leader_groups

def brute_force_matches(c, t, r):
    """Largest number of one-to-one pairs within r, by trying every assignment."""
    best = 0
    n_c, n_t = len(c), len(t)
    for perm in itertools.permutations(range(n_c), min(n_c, n_t)):
        ok = sum(1 for k, ci in enumerate(perm) if math.dist(c[ci], t[k]) <= r) if n_c >= n_t else 0
        best = max(best, ok)
    for perm in itertools.permutations(range(n_t), min(n_c, n_t)):
        ok = sum(1 for k, ti in enumerate(perm) if math.dist(c[k], t[ti]) <= r) if n_t > n_c else 0
        best = max(best, ok)
    return best


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 5), st.integers(0, 5), st.integers(0, 10_000))
def test_match_is_a_maximum_one_to_one_matching(n_c, n_t, seed):
    rng = np.random.default_rng(seed)
    c = rng.uniform(0, 8, (n_c, 2))
    t = rng.uniform(0, 8, (n_t, 2))
    pairs = match(c, t, radius_m=3.0)
    assert len({i for i, _ in pairs}) == len(pairs) == len({k for _, k in pairs})
    assert all(math.dist(c[i], t[k]) <= 3.0 for i, k in pairs)
    assert len(pairs) == brute_force_matches([tuple(x) for x in c], [tuple(x) for x in t], 3.0)


def test_duplicates_on_one_target_are_false_alarms_and_roc_sweeps():
    truth = np.array([[0.0, 0.0], [20.0, 0.0]])
    contacts = np.array([[0.5, 0.0], [1.0, 0.0], [20.0, 2.9], [50.0, 0.0]])
    scores = [0.9, 0.8, 0.7, 0.95]
    curve = roc("x", contacts, scores, truth)
    by_thr = {p.threshold: p for p in curve.points}
    assert by_thr[0.95].pd == 0.0 and by_thr[0.95].false_alarms == 1
    assert by_thr[0.9].pd == 0.5 and by_thr[0.9].false_alarms == 1
    assert by_thr[0.8].pd == 0.5 and by_thr[0.8].false_alarms == 2  # second contact on target 0
    assert by_thr[0.7].pd == 1.0 and by_thr[0.7].false_alarms == 2
    assert curve.fa_at_pd(1.0) == 2 and curve.best_pd() == 1.0
    assert curve.at_threshold(0.85).threshold == 0.9


def test_local_en_against_geodesic():
    from pyproj import Geod

    g = Geod(ellps="WGS84")
    lon2, lat2, _ = g.fwd(9.85, 44.08, 60.0, 500.0)
    e, n = local_en(np.array([lat2]), np.array([lon2]), 44.08, 9.85)
    assert abs(math.hypot(e[0], n[0]) - 500.0) < 2.0  # equirectangular: metres, fine for a 3 m match


def test_leader_groups_do_not_chain():
    xy = np.array([[i * 2.0, 0.0] for i in range(10)])  # a line of points 2 m apart
    n, lab = leader_groups(xy, np.ones(10), radius_m=3.0)
    assert n >= 4  # single linkage at 3 m would make one 18 m group
    for g in range(n):
        pts = xy[lab == g]
        assert np.ptp(pts[:, 0]) <= 6.0


def test_truth_file_errors(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("lat,lon\n1,2\n")
    with pytest.raises(AtrError, match="header"):
        read_truth(p)
    p.write_text("lat_deg,lon_deg,shape\n44.0,abc,cylinder\n")
    with pytest.raises(AtrError, match="line 2"):
        read_truth(p)


def test_evaluate_log_compares_every_method_on_the_same_detections(small_mission, tmp_path):
    s, _, files = small_mission
    # known clutter (here: a point 10 m north of each target): the node row says what its
    # false alarms lie on, every one counted once
    k = tmp_path / "clutter.csv"
    k.write_text("lat_deg,lon_deg,shape,target_like\n" + "".join(
        f"{t.lat_deg + 10.0 / 111195.0:.9f},{t.lon_deg:.9f},rock,{i % 2}\n" for i, t in enumerate(read_truth(files.truth))))
    res = evaluate_log(s, files.atrlog, files.truth, tmp_path, model=PerformanceModel.shipped(), name="small",
                       clutter=read_clutter(k))
    anatomy = res.stats["node_false_alarm_anatomy"]
    assert sum(anatomy.values()) == res.rows[0].false_alarms
    assert f"of the {res.rows[0].false_alarms} false alarms" in res.stats["node_false_alarm_anatomy_text"]
    names = [r.method for r in res.rows]
    assert sum(n.endswith("alone") for n in names) == 4
    assert any(n.startswith("AND") for n in names) and any(n.startswith("OR") for n in names)
    # the node's own row first, then the comparison pass's fusions: the paper's form (SPEC 6.1:
    # in every evaluation) and the node's without missed detections, with them, with the weakest
    assert res.rows[0].source == "node's contacts" and "the node, as published" in names[0]
    assert sum(n.startswith("DS") for n in names[1:]) == 4
    assert sum("as in the paper" in n for n in names) == 1
    for r in res.rows:
        assert 0.0 <= r.pd <= 1.0 and r.false_alarms >= 0
    # OR of all four finds at least what each AND finds (same detections, same gate)
    by = {r.method.split(" (")[0]: r for r in res.rows[1:] if not r.method.endswith("alone")}
    assert by["OR"].pd >= by["AND"].pd - 1e-12
    assert set(res.claims) == {"1 highest Pd", "2 fewer FA than AND of 3 best", "3 OR far worse",
                               "4 weakest does not degrade"}
    for f in ("roc.png", "mosaic.png", "belief.png", "result.json", "contacts.jsonl"):
        assert (tmp_path / f).stat().st_size > 1000
    back = json.loads((tmp_path / "result.json").read_text())
    assert back["targets"] == 5 and len(back["rows"]) == len(res.rows)


def test_evaluate_command_scores_contacts_out(small_mission, tmp_path):
    s, cfg, files = small_mission
    out = tmp_path / "c.jsonl"
    r = subprocess.run([sys.executable, "-m", "atr_node", "replay", str(files.atrlog), "--config", str(cfg),
                        "--online-calibration", "off", "--publish", "none", "--contacts-out", str(out), "--quiet"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([sys.executable, "-m", "atr_node", "evaluate", "--truth", str(files.truth), "--contacts",
                        str(out), "--out", str(tmp_path / "ev")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    assert summary["targets"] == 5 and 0 <= summary["pd"] <= 1
    # an independent count: targets with a live contact of Bel >= 0.5 within 3 m
    truth = read_truth(files.truth)
    contacts = [json.loads(x) for x in out.read_text().splitlines()]
    live = [c for c in contacts if c["state"] != "withdrawn" and c["bel"] >= 0.5]
    lat0, lon0 = truth[0].lat_deg, truth[0].lon_deg
    te = np.column_stack(local_en(np.array([t.lat_deg for t in truth]), np.array([t.lon_deg for t in truth]),
                                  lat0, lon0))
    ce = np.column_stack(local_en(np.array([c["lat_deg"] for c in live]), np.array([c["lon_deg"] for c in live]),
                                  lat0, lon0)).reshape(-1, 2)
    hit = sum(1 for t in te if len(ce) and np.min(np.hypot(*(ce - t).T)) <= 3.0)
    assert summary["matched"] <= hit  # one-to-one can only match fewer than "any contact nearby"
    assert summary["pd"] == pytest.approx(summary["matched"] / 5)


def test_demo_command_runs_start_to_end_on_a_small_mission(tmp_path):
    r = subprocess.run([sys.executable, "-m", "atr_node", "demo", "--small", "--missions", "1",
                        "--online-calibration", "off", "--out", str(tmp_path)], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    report = (tmp_path / "report.md").read_text()
    assert "mission-1-silt" in report and "| method | source | Pd |" in report
    for png in ("mosaic.png", "roc.png", "belief.png"):
        assert f"mission-1-silt/{png}" in report and (tmp_path / "mission-1-silt" / png).is_file()
    assert "claim 1 highest Pd" in r.stdout
