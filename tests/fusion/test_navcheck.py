"""Do the legs agree? (atr_node.fusion.navcheck): the shift between two legs' views of the same
objects, against a direct computation on synthetic records and against the held-out
generator's own nav errors through a real replay."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from atr_node.evaluation.heldout import generate_scene, leg_shift_truth
from atr_node.fusion.grid import DetectionRecord
from atr_node.fusion.navcheck import NavCheck, leg_anchors, leg_shifts, near_pairs, shift_mode, sigma_to_hold


def _rec(leg, e, n, conf=0.8, length_m=None):
    return DetectionRecord(leg, "mf", float(e), float(n), 0.0, conf, 1.0, length_m=length_m)


def _survey(rng, shift, *, objects=30, clutter=40, noise_m=0.2, legs=(0, 1)):
    """Records of ``objects`` seen by every leg (leg k displaced by k * shift, plus noise) and
    ``clutter`` seen by one leg each; also the objects' true displacements leg 1 - leg 0."""
    obj = rng.uniform(0.0, 100.0, size=(objects, 2))
    recs, seen = [], {}
    for k in legs:
        p = obj + k * np.asarray(shift) + rng.normal(0.0, noise_m, size=obj.shape)
        seen[k] = p
        recs += [_rec(k, e, n) for e, n in p]
        recs += [_rec(k, e, n) for e, n in rng.uniform(0.0, 100.0, size=(clutter, 2))]
    return recs, seen[1] - seen[0]


def test_near_pairs_are_every_pair_within_the_distance():
    rng = np.random.default_rng(1)
    pa, pb = rng.uniform(0, 50, size=(40, 2)), rng.uniform(0, 50, size=(35, 2))
    d = np.hypot(pa[:, None, 0] - pb[None, :, 0], pa[:, None, 1] - pb[None, :, 1])
    want = sorted(zip(*np.nonzero(d < 6.0)))
    got = [tuple(x) for x in near_pairs(pa, pb, 6.0).tolist()]
    assert got == [(int(i), int(j)) for i, j in want] and len(want) > 20
    assert near_pairs(pa, np.zeros((0, 2)), 6.0).shape == (0, 2)


def test_shift_mode_ignores_displacements_spread_over_the_disc():
    rng = np.random.default_rng(2)
    true = np.array([2.0, -1.5]) + rng.normal(0, 0.15, size=(12, 2))
    stray = rng.uniform(-8, 8, size=(40, 2))
    stray = stray[np.hypot(*(stray - [2.0, -1.5]).T) > 2.5]  # none near the true shift
    s, m = shift_mode(np.vstack([stray, true]), 10.0, 1.0)
    assert m.sum() == len(true) and m[-len(true):].all()
    np.testing.assert_allclose(s, true.mean(axis=0), atol=1e-12)
    s, m = shift_mode(np.zeros((0, 2)), 10.0, 1.0)
    assert np.isnan(s).all() and m.size == 0


@pytest.mark.parametrize("shift", [(0.0, 0.0), (3.5, -2.0), (-6.0, 4.0)])
def test_leg_shifts_recover_the_displacement_of_the_objects_both_legs_see(shift):
    rng = np.random.default_rng(3)
    recs, disp = _survey(rng, shift)
    (s,) = leg_shifts(recs)
    assert (s.leg_a, s.leg_b) == (0, 1)
    assert s.support >= 27  # of the 30 objects; the clutter scatters over the search disc
    assert s.support > 3 * s.chance
    ref = disp.mean(axis=0)  # direct: the true pairs' mean displacement
    assert math.hypot(s.east_m - ref[0], s.north_m - ref[1]) < 0.15
    assert abs(s.distance_m - math.hypot(*shift)) < 0.3


def test_weak_records_and_extended_objects_are_left_out():
    recs = [_rec(0, 1, 1), _rec(0, 5, 5, conf=0.1), _rec(0, 9, 9, length_m=20.0), _rec(1, 3, 3),
            _rec(1, 3, 3), _rec(0, math.nan, 2)]
    a = leg_anchors(recs, min_confidence=0.3)
    assert a[0].tolist() == [[1.0, 1.0]] and a[1].tolist() == [[3.0, 3.0]]  # duplicates once


def test_sigma_to_hold_gives_a_gate_that_holds_the_shift():
    for dist in (0.5, 2.9, 3.3, 4.6, 9.0):
        sig = sigma_to_hold(dist, gate_sigmas=2.0, length_m=2.0)
        assert 2.0 * sig + 1.0 >= dist + 1.0 and sig * 2 == round(sig * 2)
        assert 2.0 * (sig - 0.5) + 1.0 < dist + 1.0 or sig == 0.5  # not more than needed


def test_navcheck_flags_each_pair_beyond_the_gate_once(caplog):
    rng = np.random.default_rng(4)
    recs, _ = _survey(rng, (3.0, 3.0), legs=(0, 1, 2))  # legs 4.2 m apart, 0 and 2 8.5 m
    nc = NavCheck(gate_m=3.0, gate_sigmas=2.0, nav_sigma_m=1.0, length_m=2.0)
    with caplog.at_level("WARNING", logger="atr_node.fusion.navcheck"):
        assert nc.update(recs, {0}) == []  # one leg: nothing to compare
        new = nc.update(recs, {0, 1})
        assert [(s.leg_a, s.leg_b) for s in new] == [(0, 1)]
        assert nc.update(recs, {0, 1}) == []  # checked already
        nc.update(recs, {0, 1, 2})
    assert [(s.leg_a, s.leg_b) for s in nc.flagged] == [(0, 1), (0, 2), (1, 2)]
    assert len(caplog.records) == 3
    msg = caplog.records[0].getMessage()
    assert abs(nc.flagged[0].distance_m - math.hypot(3.0, 3.0)) < 0.3
    assert "legs 0 and 1 disagree: 30 objects seen on both" in msg
    assert f"{nc.flagged[0].distance_m:.1f} m apart" in msg
    assert "nav_sigma_m to about 2.5 (now 1)" in msg
    assert nc.summary().startswith("navigation: 3 of 3 pairs of legs")
    worst = nc.flagged[1]
    assert f"up to {worst.distance_m:.1f} m, legs 0 and 2" in nc.summary()
    assert "about 4.5 would hold them" in nc.summary()


def test_navcheck_is_quiet_within_the_gate_and_on_few_objects():
    rng = np.random.default_rng(5)
    recs, _ = _survey(rng, (1.5, -1.0))
    nc = NavCheck(gate_m=3.0, gate_sigmas=2.0, nav_sigma_m=1.0, length_m=2.0)
    nc.update(recs, {0, 1})
    assert nc.flagged == [] and nc.summary() is None and len(nc.shifts) == 1
    few, _ = _survey(rng, (5.0, 0.0), objects=4, clutter=0)
    nc = NavCheck(gate_m=3.0, gate_sigmas=2.0, nav_sigma_m=1.0, length_m=2.0)
    nc.update(few, {0, 1})
    assert nc.flagged == [] and nc.shifts[0].support == 4


def _scene_points(d: Path) -> np.ndarray:
    pts = []
    for name in ("truth.csv", "clutter.csv"):
        with open(d / name, newline="") as fh:
            pts += [(float(r["east_m"]), float(r["north_m"])) for r in csv.DictReader(fh)]
    return np.array(pts)


@pytest.mark.parametrize("variant", ["nav2", "base"])
def test_replay_measures_the_generator_s_nav_error_and_says_when_it_beats_the_gate(tmp_path, variant):
    """Seed 2's nav2 scene puts its two legs 4.6 m apart (the generator's truth), beyond the
    default gate of 3 m; its base scene 1.2 m (the same draws, a quarter)."""
    d = tmp_path / variant
    generate_scene(d, seabed="sand", seed=2, legs=2, leg_length_m=80.0, variant=variant)
    summary = tmp_path / "summary.json"
    p = subprocess.run([sys.executable, "-m", "atr_node", "replay", str(d / "mission.atrlog"), "--publish", "none",
                        "--speed", "max", "--online-calibration", "off", "--summary", str(summary),
                        "--contacts-out", str(tmp_path / "c.jsonl")],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    got = json.loads(summary.read_text())
    (s,) = got["leg_shifts"]
    truth = leg_shift_truth(json.loads((d / "scene.json").read_text()), 0, 1, _scene_points(d))
    assert s["support"] >= 5
    assert math.hypot(s["east_m"] - truth[0], s["north_m"] - truth[1]) < 0.6
    last = p.stderr.strip().splitlines()[-1]
    if variant == "nav2":
        assert np.hypot(*truth) > 4.0 and s["flagged"]
        assert "navigation: 1 of 1 pairs of legs" in last and "fusion.nav_sigma_m = 1 is too small" in last
        assert "legs 0 and 1 disagree" in p.stderr
    else:
        assert np.hypot(*truth) < 1.5 and not s["flagged"]
        assert got["navigation"] is None and "navigation" not in last and "disagree" not in p.stderr
        # a bench user's report says the legs agree, and how far apart they are
        e = subprocess.run([sys.executable, "-m", "atr_node", "evaluate", "--log", str(d / "mission.atrlog"), "--truth",
                            str(d / "truth.csv"), "--online-calibration", "off", "--out", str(tmp_path / "ev")],
                           capture_output=True, text=True, timeout=600)
        assert e.returncode == 0, e.stderr
        report = (tmp_path / "ev" / "evaluation.md").read_text()
        assert (f"Navigation: the legs agree: 1 pair of legs measured on the objects both see, the largest shift "
                f"{s['distance_m']:.1f} m (legs 0 and 1, {s['support']} objects) within the association gate of 3.0 m."
                in report)


def test_report_says_the_legs_agree_or_what_it_could_not_measure():
    rng = np.random.default_rng(8)
    recs, _ = _survey(rng, (1.0, 0.5))
    nc = NavCheck(gate_m=3.0, gate_sigmas=2.0, nav_sigma_m=1.0, length_m=2.0)
    assert nc.report() is None  # nothing compared yet
    nc.update(recs, {0, 1})
    assert nc.report().startswith("navigation: the legs agree: 1 pair of legs")
    assert "within the association gate of 3.0 m" in nc.report()
    few, _ = _survey(rng, (1.0, 0.5), objects=3, clutter=0)
    nc = NavCheck(gate_m=3.0, gate_sigmas=2.0, nav_sigma_m=1.0, length_m=2.0)
    nc.update(few, {0, 1})
    assert nc.report() == "navigation: 1 pair of legs compared, none with 5 objects seen on both"


def test_navcheck_logs_the_first_pairs_and_counts_the_rest(caplog):
    rng = np.random.default_rng(6)
    recs = []
    objects = rng.uniform(0, 100, size=(25, 2))
    for leg in range(5):  # every leg 1.6 m further east and north: every pair beyond a 1.5 m gate
        recs += [_rec(leg, e, n) for e, n in objects + leg * 1.6]
    nc = NavCheck(gate_m=1.5, gate_sigmas=2.0, nav_sigma_m=0.25, length_m=2.0)
    with caplog.at_level("WARNING", logger="atr_node.fusion.navcheck"):
        nc.update(recs, set(range(5)))
    assert len(nc.flagged) == 10 and len(caplog.records) == 5
    assert "further pairs are counted" in caplog.records[-1].getMessage()
    assert nc.summary().startswith("navigation: 10 of 10 pairs of legs")


def test_shift_mode_keeps_its_disc_when_the_mean_falls_between_two_clumps():
    """Two clumps at opposite edges of the densest disc: their mean lies more than mode_m from
    every displacement; the mode stays the disc's votes and their mean."""
    d = np.array([[0.0, 0.0]] * 3 + [[2.05, 0.0]] * 3)  # one vote disc of 1 m holds both (cells of 0.5 m)
    s, m = shift_mode(d, 10.0, 1.0)
    assert m.all() and np.allclose(s, d.mean(axis=0))


def test_a_second_pass_counts_its_pairs_without_logging_them_again(caplog):
    rng = np.random.default_rng(9)
    recs, _ = _survey(rng, (4.0, 0.0))
    nc = NavCheck(gate_m=3.0, gate_sigmas=2.0, nav_sigma_m=1.0, length_m=2.0)
    nc.log_pairs = False
    with caplog.at_level("WARNING", logger="atr_node.fusion.navcheck"):
        nc.update(recs, {0, 1})
    assert len(nc.flagged) == 1 and not caplog.records and nc.summary().startswith("navigation: 1 of 1")
