"""Smoke run of tools/bench/node.py latency: the stage times of every unit add up to its latency."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

from atr_node.node.timing import STAGES

TOOL = Path(__file__).resolve().parents[2] / "tools" / "bench" / "node.py"


def test_latency_breakdown_quick_stages_add_up(tmp_path):
    out = tmp_path / "stages.json"
    res = subprocess.run([sys.executable, str(TOOL), "latency", "--quick", "--interval-s", "0.3", "--warm-up-s", "0.5",
                          "--json", str(out)], capture_output=True, text=True, timeout=240)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "median" in res.stdout and "heartbeat latency" in res.stdout
    units = json.loads(out.read_text())
    assert len(units) >= 4
    parts = [k for k in STAGES if k != "total"]
    # a unit the main process scored has no worker stages, and one released without an arrival
    # time no ingest or total (NaN: not measured); which units those are depends on the load
    complete = [u for u in units if all(math.isfinite(u[k]) for k in [*parts, "total"])]
    assert complete, units
    for u in complete:
        assert math.isclose(sum(u[k] for k in parts), u["total"], rel_tol=0, abs_tol=1e-9)
    assert all(math.isfinite(u["deposit"]) and math.isfinite(u["contacts"]) for u in units)  # every unit fused
        # no comparison of wall-clock stage times here (issue 20: they fail on a loaded machine,
        # and a unit the main process scores has no worker stage at all): the tool reports them
