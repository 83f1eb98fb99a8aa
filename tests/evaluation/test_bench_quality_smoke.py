"""Smoke test of the held-out quality benchmark (tools/bench/quality.py) on one tiny scene."""

from __future__ import annotations

import json
import sys
from pathlib import Path

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
    assert "| sand-7-2x60 | DS look (default) |" in (out / "quality.md").read_text()


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


def test_quality_benchmark_usage_errors(capsys):
    assert bench_quality.main(["--seabeds", "mud"]) == 2
    assert "unknown seabed" in capsys.readouterr().err
