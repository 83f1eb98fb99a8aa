"""Smoke run of tools/bench/node.py replay (the node's throughput and latency benchmark): it runs end
to end on small missions and its figures are consistent with each other."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

TOOL = Path(__file__).resolve().parents[2] / "tools" / "bench" / "node.py"


def test_bench_node_quick_reports_consistent_figures(tmp_path):
    out = tmp_path / "bench.json"
    res = subprocess.run([sys.executable, str(TOOL), "replay", "--quick", "--runs", "2", "--interval-s", "0.5", "--json", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "end-to-end replay" in res.stdout and "latency" in res.stdout
    body = json.loads(out.read_text())
    t, lat = body["throughput"], body["latency"]
    assert t["tiles"] > 0 and t["mpx"] > 0 and t["wall_s"] > 0
    assert abs(t["mpx_per_s"] - t["mpx"] / t["wall_s"]) <= 1e-9 * t["mpx_per_s"]
    # two runs, each in its own process, summarised
    rates = [r["mpx_per_s"] for r in t["runs"]]
    assert len(rates) == 2 and all(r["mpx"] == t["mpx"] for r in t["runs"])
    assert t["min_mpx_per_s"] == min(rates) <= t["median_mpx_per_s"] <= t["max_mpx_per_s"] == max(rates)
    assert t["runs_at_target"] == sum(r >= 20.0 for r in rates)
    assert lat["samples"] > 0 and 0 < lat["p50_ms"] <= lat["p99_ms"]


def test_bench_node_help():
    res = subprocess.run([sys.executable, str(TOOL), "replay", "--help"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and "--tp-swath-m" in res.stdout
