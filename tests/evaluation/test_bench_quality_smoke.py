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
                             "--online-calibration", "off", "--out", str(out), "--json", str(tmp_path / "q.json")])
    assert rc == 0
    body = json.loads((tmp_path / "q.json").read_text())
    (scene,) = body["scenes"]
    assert set(scene["methods"]) >= {"DS look (default)", "DS paper (prior 0.1)", "OR", "vote 2 of 4"}
    ds = scene["methods"]["DS look (default)"]
    assert 0.0 <= ds["pd_max"] <= 1.0 and ds["no_detection"] == 0
    assert ds["one_leg_objects"] >= 1 and 0 <= ds["one_leg_above_report"] <= ds["one_leg_objects"]
    assert set(scene["checks"]) >= {"ds_fewer_false_alarms", "one_leg_below_report_95pct", "reliability_rises"}
    assert "| sand-7-2x60 | DS look (default) |" in (out / "quality.md").read_text()


def test_quality_benchmark_usage_errors(capsys):
    assert bench_quality.main(["--seabeds", "mud"]) == 2
    assert "unknown seabed" in capsys.readouterr().err
