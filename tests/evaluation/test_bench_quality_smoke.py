"""Smoke test of the held-out quality benchmark (tools/bench/quality.py) on one tiny scene."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

TOOLS = Path(__file__).resolve().parents[2] / "tools" / "bench"
sys.path.insert(0, str(TOOLS))

import quality as bench_quality  # noqa: E402


def test_quality_benchmark_scores_every_method_and_checks(tmp_path):
    out = tmp_path / "q"
    rc = bench_quality.main(["--seabeds", "sand", "--seeds", "7", "--legs", "2", "--leg-length", "60",
                             "--online-calibration", "off", "--out", str(out), "--json", str(tmp_path / "q.json"),
                             "--recordings", "none"])
    assert rc == 0
    body = json.loads((tmp_path / "q.json").read_text())
    (scene,) = body["scenes"]
    assert set(scene["methods"]) >= {"DS look (default)", "DS paper (prior 0.1)", "OR", "vote 2 of 4"}
    ds = scene["methods"]["DS look (default)"]
    assert 0.0 <= ds["pd_max"] <= 1.0 and ds["no_detection"] == 0
    assert ds["one_leg_objects"] >= 1 and 0 <= ds["one_leg_above_report"] <= ds["one_leg_objects"]
    assert set(scene["checks"]) >= {"ds_fewer_false_alarms", "one_leg_below_report_95pct", "reliability_rises"}
    # DS default's false alarms read off its own ROC at each baseline's Pd
    baselines = {k for k in scene["methods"] if not k.startswith("DS ")}
    assert set(ds["fa_at_pd_of"]) == baselines
    for k in baselines:
        pd, fa = scene["methods"][k]["op_pd"], ds["fa_at_pd_of"][k]
        if pd == 0:
            assert fa == 0.0
        elif pd > ds["pd_max"] + 1e-3:
            assert fa == math.inf
        elif pd < ds["pd_max"] - 1e-3:
            assert math.isfinite(fa) and fa <= ds["fa_at_max"]
    assert "| sand-7-2x60 | DS look (default) |" in (out / "quality.md").read_text()
    assert scene["variant"] == "base" and body["pooled_reliability"]["base"]["scenes"] == 1
    assert (sum(x["contacts"] for x in body["pooled_reliability"]["base"]["bins"])
            == sum(x["contacts"] for x in ds["reliability"]))
    # what the false alarms lie on: every one counted once, as many as the ROC and the
    # operating point count
    for name in ("DS look (default)", "DS paper (prior 0.1)"):
        f = scene["methods"][name]
        op = f["fa_anatomy"]["op"]
        assert op["false_alarms"] == f["op_fa"] == sum(op[k] for k in bench_quality.FA_KINDS)
        if "0.8" in f["fa_anatomy"]:
            a = f["fa_anatomy"]["0.8"]
            assert a["false_alarms"] == f["fa_at_0.8"] == sum(a[k] for k in bench_quality.FA_KINDS)
        else:
            assert f["fa_at_0.8"] == math.inf
    pooled = body["pooled_fa_anatomy"]["base / DS look (default)"]["op"]
    assert pooled == {k: ds["fa_anatomy"]["op"][k] for k in pooled}
    # do the legs agree: the node's shift of its two legs against the generator's nav errors
    (shift,) = scene["leg_shifts"]
    assert (shift["leg_a"], shift["leg_b"]) == (0, 1) and shift["truth_distance_m"] is not None
    assert shift["error_m"] == pytest.approx(math.hypot(shift["east_m"] - shift["truth_east_m"],
                                                        shift["north_m"] - shift["truth_north_m"]), abs=2e-3)
    if shift["support"] >= 5:
        assert body["pooled_leg_shifts"]["base"]["pairs"] == 1
        assert "Do the legs agree?" in (out / "quality.md").read_text()


def test_quality_benchmark_scores_a_real_recording_for_every_method(real_data, tmp_path):
    """A shared recording has no ground truth: each method's contacts, the objects read by eye
    it finds and the wreck's contacts; DS look's row is what the node publishes (replay)."""
    import subprocess

    xtf = real_data / "xtf" / "scotsman-iver2.xtf"
    rc = bench_quality.main(["--seabeds", "sand", "--seeds", "7", "--legs", "2", "--leg-length", "60",
                             "--online-calibration", "off", "--out", str(tmp_path / "q"),
                             "--json", str(tmp_path / "q.json"), "--recordings", str(xtf)])
    assert rc == 0
    (rec,) = json.loads((tmp_path / "q.json").read_text())["recordings"]
    methods = rec["methods"]
    assert set(methods) >= {"DS look (default)", "DS paper (prior 0.1)", "OR", "vote 2 of 4"}
    assert any(k.startswith("AND-3") for k in methods)
    ds = methods["DS look (default)"]
    assert ds["placed"] == ds["contacts"] and ds["no_detection"] == 0 and ds["marks"] == 1
    assert 1 <= ds["wreck_contacts"] <= ds["contacts"]
    # OR keeps every group: never fewer contacts than the vote or AND
    assert methods["OR"]["contacts"] >= max(methods["vote 2 of 4"]["contacts"],
                                            next(v for k, v in methods.items() if k.startswith("AND-3"))["contacts"])
    out = tmp_path / "c.jsonl"
    r = subprocess.run([sys.executable, "-m", "atr_node", "replay", str(xtf), "--publish", "none", "--speed", "max",
                        "--online-calibration", "off", "--contacts-out", str(out), "--quiet"], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    live = [c for c in map(json.loads, out.read_text().splitlines()) if c["state"] != "withdrawn"]
    from atr_node.config import Settings

    assert ds["contacts"] == sum(1 for c in live if c["bel"] >= Settings().fusion.report_bel)
    assert "| scotsman-iver2.xtf | DS look (default) |" in (tmp_path / "q" / "quality.md").read_text()


def _scene(ds_extra: dict, and_op: tuple[float, int]) -> dict:
    ds = {"pd_max": 1.0, "fa_at_max": 45.0, "fa_at_0.8": 21.0, "fa_at_0.9": 22.0, "op_pd": 0.938, "op_fa": 31,
          "roc_fa_at_op_pd": 22.0, "no_detection": 0, "one_leg_covered_objects": 0, "one_leg_covered_above_report": 0,
          "multi_look_targets": 0, "multi_look_above_report": 0, "reliability": [], **ds_extra}
    paper = {"pd_max": 1.0, "fa_at_max": 60.0, "fa_at_0.8": 30.0, "fa_at_0.9": 40.0, "op_pd": 1.0, "op_fa": 70}
    base = {"pd_max": and_op[0], "fa_at_max": and_op[1], "op_pd": and_op[0], "op_fa": and_op[1]}
    return {"scene": "s", "targets": 16, "methods": {"DS look (default)": ds, "DS paper (prior 0.1)": paper,
                                                     "AND-3 (mf+z+lac)": base, "OR": dict(base)}}


def test_fewer_false_alarms_is_judged_at_the_baseline_s_own_pd():
    """AND-3 at Pd 15/16 with 42 false alarms. DS default reaches that Pd with 24 on its ROC:
    fewer. Without the ROC's reading (an older JSON) only the recorded points stand in (Pd 1.0 at
    45, the next point at or above 0.938), and DS looks worse."""
    from atr_node.config import Settings

    and_op = (0.938, 42)
    read = _scene({"fa_at_pd_of": {"AND-3 (mf+z+lac)": 24.0, "OR": 24.0}}, and_op)
    assert bench_quality.checks(read, Settings())["ds_fewer_false_alarms"] is True
    old = _scene({}, and_op)
    assert bench_quality.checks(old, Settings())["ds_fewer_false_alarms"] is False
    # and the ROC's reading can fail too: more false alarms than the baseline at its Pd
    worse = _scene({"fa_at_pd_of": {"AND-3 (mf+z+lac)": 43.0, "OR": 24.0}}, and_op)
    assert bench_quality.checks(worse, Settings())["ds_fewer_false_alarms"] is False


def _rel_scene(variant: str, rows: list[tuple[str, int, int]]) -> dict:
    return {"variant": variant, "methods": {"DS look (default)": {"reliability": [
        {"bel": b, "contacts": n, "targets": round(k / n, 3), "on_target": k} for b, n, k in rows]}}}


def test_the_benchmark_reads_the_anatomy_at_the_roc_s_pd_0_8_point():
    """The threshold read at a Pd is the curve's point with the fewest false alarms there, so
    the anatomy there counts the false alarms ``fa_at_pd`` gives."""
    from atr_node.evaluation.scoring import fa_anatomy, roc

    truth = np.array([[0.0, 0.0], [100.0, 0.0]])
    contacts = np.array([[0.5, 0.0], [-1.0, 1.0], [100.0, 1.0], [50.0, 51.0], [200.0, 200.0]])
    scores = np.array([0.9, 0.8, 0.7, 0.95, 0.5])
    curve = roc("x", contacts, scores, truth)
    thr = bench_quality._threshold_at_pd(curve, 1.0)
    assert thr == 0.7
    a = fa_anatomy(contacts, scores, truth, threshold=thr, one_leg_en=np.array([[50.0, 50.0]]))
    assert a["false_alarms"] == curve.fa_at_pd(1.0) == 2 and a["second_on_target"] == 1 and a["one_leg_object"] == 1
    assert bench_quality._threshold_at_pd(roc("y", contacts[:1], scores[:1], truth), 1.0) is None


def test_pooled_reliability_sums_the_scenes_of_a_variant():
    """Two scenes whose own tables dip (a bin of 3 at 0.67, then 0.20): pooled, the counts add
    up bin by bin, the shares and their Wilson intervals are those of the sums, and the
    pooled table rises. Another variant is pooled apart, and an older table without
    ``on_target`` gives the count back from its share."""
    from atr_node.calibration.stats import wilson_interval

    a = _rel_scene("base", [("[0.5, 0.7)", 3, 2), ("[0.7, 0.9)", 10, 2), ("[0.9, 0.99)", 6, 4)])
    b = _rel_scene("base", [("[0.5, 0.7)", 7, 0), ("[0.7, 0.9)", 5, 3)])
    c = _rel_scene("byte", [("[0.7, 0.9)", 4, 1)])
    old = {"variant": "byte", "methods": {"DS look (default)": {"reliability": [
        {"bel": "[0.7, 0.9)", "contacts": 6, "targets": 0.333}]}}}
    got = bench_quality.pooled_reliability([a, b, c, old])
    base = got["base"]
    assert base["scenes"] == 2
    assert [(x["bel"], x["contacts"], x["on_target"]) for x in base["bins"]] == [
        ("[0.5, 0.7)", 10, 2), ("[0.7, 0.9)", 15, 5), ("[0.9, 0.99)", 6, 4)]
    for x in base["bins"]:
        lo, hi = wilson_interval(x["on_target"], x["contacts"])
        assert x["share"] == round(x["on_target"] / x["contacts"], 3)
        assert (x["low"], x["high"]) == (round(float(lo), 3), round(float(hi), 3))
    assert base["rises"] is True
    assert [(x["contacts"], x["on_target"]) for x in got["byte"]["bins"]] == [(10, 3)]
    dip = bench_quality.pooled_reliability([_rel_scene("base", [("[0.5, 0.7)", 10, 5), ("[0.7, 0.9)", 10, 2)])])
    assert dip["base"]["rises"] is False


def test_pooled_checks_sum_each_scene_s_counts():
    """Two scenes that each fail a per-scene check by one look (12 of 13 multi-look targets
    above report_bel; one of 5 covered one-leg objects above it): pooled, the counts add up,
    the shares carry the Wilson interval of the sums (checked against the closed form here),
    a baseline whose Pd DS never reaches on a scene is pooled over the other scenes only, and
    the per-scene checks are counted, not replaced."""
    from atr_node.config import Settings

    a = _scene({"fa_at_pd_of": {"AND-3 (mf+z+lac)": 24.0, "OR": 24.0}, "multi_look_targets": 13,
                "multi_look_above_report": 12, "one_leg_covered_objects": 5, "one_leg_covered_above_report": 1,
                "reliability": [{"bel": "[0.5, 0.7)", "contacts": 4, "targets": 0.25, "on_target": 1}]},
               (0.938, 42))
    b = _scene({"fa_at_pd_of": {"AND-3 (mf+z+lac)": 50.0, "OR": math.inf}, "multi_look_targets": 13,
                "multi_look_above_report": 13, "one_leg_covered_objects": 4, "one_leg_covered_above_report": 0,
                "op_fa": 40, "roc_fa_at_op_pd": 19.0, "no_detection": 2,
                "reliability": [{"bel": "[0.5, 0.7)", "contacts": 6, "targets": 0.167, "on_target": 1}]},
               (1.0, 42))
    b["methods"]["OR"]["pd_max"] = 1.0
    for sc in (a, b):
        sc["checks"] = bench_quality.checks(sc, Settings())
    assert a["checks"]["multi_look_above_report_95pct"] is False and a["checks"]["one_leg_below_report_95pct"] is False
    g = bench_quality.pooled_checks([a, b])["base"]
    assert g["scenes"] == 2 and g["targets"] == 32
    assert g["pd_max"] == {"DS look": 32, "OR": 31}  # round(0.938 * 16) = 15, and 16
    assert g["fewer"]["AND-3"] == {"scenes": 2, "DS look": 74.0, "AND-3": 84.0}
    assert g["fewer"]["OR"] == {"scenes": 1, "DS look": 24.0, "OR": 42.0}
    assert g["fewer"]["DS paper at Pd 0.8"] == {"scenes": 2, "DS look": 42.0, "DS paper": 60.0}
    assert g["op"] == {"false_alarms": 71, "roc_at_op_pd": 41.0} and g["no_detection"] == 2

    def wilson(k, n, z=1.959963984540054):
        p = k / n
        c = (p + z * z / (2 * n)) / (1 + z * z / n)
        h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
        return round(c - h, 3), round(c + h, 3)

    assert g["multi_look"][:3] == [25, 26, round(25 / 26, 3)] and tuple(g["multi_look"][3:]) == wilson(25, 26)
    assert g["one_leg"][:3] == [8, 9, round(8 / 9, 3)] and tuple(g["one_leg"][3:]) == wilson(8, 9)
    assert g["scenes_passing"]["multi_look_above_report_95pct"] == 1
    assert g["scenes_passing"]["no_contact_without_detection"] == 1
    assert g["reliability_rises"] is True
    text = "\n".join(bench_quality.pooled_checks_markdown({"base": g}))
    assert "multi-look targets above report_bel: 25 of 26, 96.2 %" in text and "OR 24 against 42 (1 of 2 scenes)" in text


def test_quality_benchmark_usage_errors(capsys):
    assert bench_quality.main(["--seabeds", "mud"]) == 2
    assert "unknown seabed" in capsys.readouterr().err
    assert bench_quality.main(["--variants", "base,blurry"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--variants 'base,blurry'" in err and "clumpy" in err


def test_a_variant_is_its_own_scene_and_reused_only_as_itself(tmp_path):
    """--variants: each variant of a seed in its own folder; a base scene is never taken for a
    variant's (nor the other way round)."""
    out = tmp_path / "q"
    args = ["--seabeds", "sand", "--seeds", "7", "--legs", "2", "--leg-length", "60", "--online-calibration", "off",
            "--out", str(out), "--recordings", "none", "--json", str(tmp_path / "q.json")]
    assert bench_quality.main(args + ["--variants", "base,coarse"]) == 0
    got = json.loads((tmp_path / "q.json").read_text())
    assert [s["scene"] for s in got["scenes"]] == ["sand-7-2x60", "sand-7-2x60-coarse"]
    coarse = json.loads((out / "sand-7-2x60-coarse" / "scene.json").read_text())
    assert coarse["variant"]["name"] == "coarse" and coarse["dr_m"] == 0.2
    assert "variant" not in json.loads((out / "sand-7-2x60" / "scene.json").read_text())
    assert bench_quality._reusable(out / "sand-7-2x60", "sand", 7, 2, 60.0, "base")
    assert not bench_quality._reusable(out / "sand-7-2x60", "sand", 7, 2, 60.0, "coarse")
    assert not bench_quality._reusable(out / "sand-7-2x60-coarse", "sand", 7, 2, 60.0, "base")
    assert bench_quality._reusable(out / "sand-7-2x60-coarse", "sand", 7, 2, 60.0, "coarse")


def test_covering_legs_is_the_node_s_coverage_at_pd_0_8():
    """Issue 17 judges the one-leg objects that another look covered at Pd >= 0.8: a leg counts
    where its beam passed over the point on its side, a detector scored the pixel there and
    the look's P(y) at that range is at least 0.8."""
    from types import SimpleNamespace

    import numpy as np

    from atr_node.calibration.model import PerformanceModel
    from atr_node.geo import MissionFrame, tile_geometry
    from atr_node.records.tile import Tile, TileNav

    frame = MissionFrame("ltp", 43.0, 7.0)
    rows, cols, dr = 300, 600, 0.1
    e, n = np.zeros(rows), np.arange(rows) * 0.1  # heading north from the origin
    lat, lon = frame.to_latlon(e, n)
    tile = Tile("t", 3, "stbd", 0, np.ones((rows, cols), np.float32), "intensity", 0.0, dr, 0.1, False,
                1.7e9 + 0.1 * np.arange(rows), nav=TileNav(lat, lon, np.zeros(rows), np.full(rows, 8.0)))
    geom = tile_geometry(tile, frame)
    covered = np.ones((rows, cols), bool)
    covered[:, :60] = False  # the nadir gap: 0-6 m
    model = PerformanceModel.shipped()
    dets = ("mf", "lac", "smf", "z")
    unit = SimpleNamespace(leg=3, geometry=geom, ranges_m=tile.ranges_m, model=model,
                           result=SimpleNamespace(covered=lambda d: covered))
    run = SimpleNamespace(units=[unit])
    pd_40 = float(model.look(dets).pd_at(40.0))
    assert pd_40 >= 0.8
    assert bench_quality.covering_legs(run, (40.0, 15.0), dets) == {3}  # starboard, 40 m, ping 150
    assert bench_quality.covering_legs(run, (-40.0, 15.0), dets) == set()  # the other side
    assert bench_quality.covering_legs(run, (3.0, 15.0), dets) == set()  # in the nadir gap
    assert bench_quality.covering_legs(run, (40.0, 45.0), dets) == set()  # past the last ping
    assert bench_quality.covering_legs(run, (70.0, 15.0), dets) == set()  # beyond the swath
    assert bench_quality.covering_legs(run, (40.0, 15.0), dets, pd_min=pd_40 + 1e-9) == set()
    # the P(y) each covering leg read there; a leg not covering is not listed
    got = bench_quality.covering_pd(run, (40.0, 15.0), dets)  # read at the beam's own range, 40 m to 1e-9
    assert set(got) == {3} and abs(got[3] - pd_40) < 1e-6
    assert bench_quality.covering_pd(run, (3.0, 15.0), dets) == {}


def test_one_run_per_folder_and_only_finished_scenes_are_reused(tmp_path, capsys):
    """A second run on a folder in use stops at once with one line (exit 2) and writes
    nothing; a scene folder is reused only when its scene.json is this generator's for the
    same parameters: a folder whose run was interrupted (no scene.json), or an older
    generator's, is made again. Two runs on one folder once scored each other's half-written
    scenes (Pd 0 on whole scenes)."""
    import fcntl

    out = tmp_path / "q"
    args = ["--seabeds", "sand", "--seeds", "7", "--legs", "2", "--leg-length", "60", "--online-calibration", "off",
            "--out", str(out), "--recordings", "none"]
    out.mkdir()
    with open(out / ".lock", "w") as other:  # another run holds the folder
        other.write("4242\n")
        other.flush()
        fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
        rc = bench_quality.main(args + ["--json", str(tmp_path / "q.json")])
        err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "in use by another run (pid 4242)" in err
    assert sorted(p.name for p in out.iterdir()) == [".lock"] and not (tmp_path / "q.json").exists()
    # an interrupted scene: its tiles there, no scene.json; and a stale one of another generator
    scene = out / "sand-7-2x60"
    scene.mkdir()
    (scene / "mission.atrlog").write_bytes(b"ATRLOG half")
    (scene / ".truth.csv.tmp-999999").write_text("a killed run's")  # removed under the lock
    assert bench_quality.main(args) == 0
    assert not list(scene.glob(".*"))
    meta = json.loads((scene / "scene.json").read_text())
    assert meta["seed"] == 7 and (scene / "mission.atrlog").stat().st_size > 1000
    first = (scene / "mission.atrlog").read_bytes()
    meta["generator_version"] = "0"
    (scene / "scene.json").write_text(json.dumps(meta))
    (scene / "mission.atrlog").write_bytes(b"stale")
    assert bench_quality.main(args) == 0
    assert (scene / "mission.atrlog").read_bytes() == first  # made again, byte for byte the same scene
    mtime = (scene / "mission.atrlog").stat().st_mtime_ns
    assert bench_quality.main(args) == 0 and (scene / "mission.atrlog").stat().st_mtime_ns == mtime  # reused
    # a scene it cannot make (a file where its folder goes): one line, exit 1, nothing written
    (out / "sand-8-2x60").write_text("x")
    capsys.readouterr()
    assert bench_quality.main(args + ["--seeds", "8", "--json", str(tmp_path / "q8.json")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "sand-8-2x60" in err and "not a folder" in err
    assert not (tmp_path / "q8.json").exists()
    assert bench_quality.main(args + ["--seeds", "x7"]) == 2 and "expected comma-separated integers" in capsys.readouterr().err


def test_peakedness_against_a_direct_sort():
    import rock_cue

    rng = np.random.default_rng(3)
    img = rng.exponential(1.0, (60, 80))
    img[30, 40] = 50.0  # a glint
    img[5, 5] = np.nan
    row, col, dx, dr = 30, 40, 0.1, 0.1
    h, w = 15, 20  # 1.5 m and 2 m of 0.1 m pixels
    win = img[row - h:row + h + 1, col - w:col + w + 1].ravel()
    top = np.sort(win[np.isfinite(win)])[::-1]
    want = top[:5].mean() / top[:50].mean()
    assert math.isclose(rock_cue.peakedness(img, row, col, dx_m=dx, dr_m=dr), want, rel_tol=1e-12)
    # at the image's edge the window is cut, not wrapped; too few pixels give NaN
    edge = img[0:16, 0:21].ravel()
    top = np.sort(edge[np.isfinite(edge)])[::-1]
    assert math.isclose(rock_cue.peakedness(img, 0, 0, dx_m=dx, dr_m=dr), top[:5].mean() / top[:50].mean(),
                        rel_tol=1e-12)
    assert math.isnan(rock_cue.peakedness(np.full((5, 5), 1.0), 2, 2, dx_m=dx, dr_m=dr))
    # a spread echo (a flat patch) is less peaked than the glint
    flat = np.ones((60, 80))
    flat[25:36, 30:51] = 10.0
    assert rock_cue.peakedness(flat, row, col, dx_m=dx, dr_m=dr) == 1.0
    assert rock_cue.peakedness(img, row, col, dx_m=dx, dr_m=dr) > 2.0


def test_rock_cue_part_smoke(tmp_path, capsys):
    rc = bench_quality.main(["rock-cue", "--quick", "--online-calibration", "off", "--out", str(tmp_path / "s"),
                             "--json", str(tmp_path / "r.json")])
    assert rc == 0
    (scene,) = json.loads((tmp_path / "r.json").read_text())["scenes"]
    assert scene["contacts"] > 0 and len(scene["bel"]) == 2
    assert scene["n"]["injected"] > 0 and scene["median_cue"]["injected"] > scene["median_cue"]["seabed"]
    auc = scene["auc_targets_vs_rocks_bel08"]
    assert math.isnan(auc) or 0.0 <= auc <= 1.0
    assert "| sand-201-2x60 |" in capsys.readouterr().out
    # the held-out seeds never measure an idea
    assert bench_quality.main(["rock-cue", "--seeds", "101", "--out", str(tmp_path / "h")]) == 2


def test_look_pd_pairs_and_their_fidelity():
    """One pair per target and covering leg: the P(y) that leg's look had there and whether a
    detection of that leg within 3 m made a look detection; log loss and Brier against a
    direct computation."""
    import math
    from types import SimpleNamespace

    import numpy as np

    from atr_node.calibration.model import PerformanceModel
    from atr_node.detectors.extract import Detection
    from atr_node.geo import MissionFrame, tile_geometry
    from atr_node.records.tile import Tile, TileNav

    frame = MissionFrame("ltp", 43.0, 7.0)
    rows, cols, dr = 300, 600, 0.1
    lat, lon = frame.to_latlon(np.zeros(rows), np.arange(rows) * 0.1)
    tile = Tile("t", 3, "stbd", 0, np.ones((rows, cols), np.float32), "intensity", 0.0, dr, 0.1, False,
                1.7e9 + 0.1 * np.arange(rows), nav=TileNav(lat, lon, np.zeros(rows), np.full(rows, 8.0)))
    geom = tile_geometry(tile, frame)
    covered = np.ones((rows, cols), bool)
    covered[:, :60] = False
    model = PerformanceModel.shipped()
    dets = ("mf", "lac", "smf", "z")
    table = model.look(dets)
    strong = tuple((d, 50.0 * model.tau[d]) for d in dets)  # far past every threshold: a look detection
    i, r, _ = geom.locate(40.0, 15.0)
    j = int(np.argmin(np.abs(tile.ranges_m - r)))
    hit = Detection("mf", i, j, strong[0][1], float(tile.ranges_m[j]), 0.6, 2.0, 50, joint=strong)
    unit = SimpleNamespace(leg=3, geometry=geom, ranges_m=tile.ranges_m, model=model,
                           result=SimpleNamespace(covered=lambda d: covered, detections={"mf": [hit]}))
    run = SimpleNamespace(units=[unit])
    assert bool(table.detects(model.look_score(dict(strong), dets)))
    # detected at 40 m, missed at 50 m, not covered in the nadir gap or on the other side
    pairs = bench_quality.look_pd_pairs(run, [(40.0, 15.0), (50.0, 15.0), (3.0, 15.0), (-40.0, 15.0)], dets)
    assert len(pairs) == 2
    (r1, p1, d1), (r2, p2, d2) = pairs
    assert d1 is True and d2 is False and abs(r1 - 40.0) < 0.1 and abs(r2 - 50.0) < 0.1
    assert p1 == float(table.pd_at(r1)) and p2 == float(table.pd_at(r2))
    f = bench_quality.pd_fidelity(pairs)
    assert f["pairs"] == 2 and f["detected"] == 0.5
    want = -(math.log(p1) + math.log(1.0 - p2)) / 2.0
    assert abs(f["log_loss"] - want) < 1e-4 and abs(f["brier"] - ((1 - p1) ** 2 + p2 ** 2) / 2.0) < 1e-4
    assert [b["pairs"] for b in f["bands"]] == [0, 1, 1]
