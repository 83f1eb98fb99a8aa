"""Smoke test of tools/bench/fusion.py node (run by hand for figures: no timing asserted)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

TOOL = Path(__file__).resolve().parents[2] / "tools" / "bench" / "fusion.py"


def test_bench_node_fusion_quick_prints_its_table():
    res = subprocess.run([sys.executable, str(TOOL), "node", "--quick"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    for row in ("EvidenceGrid.add_observation", "ContactTracker.update", "EvidenceGrid.close_all", "first touch"):
        assert row in res.stdout
    assert "contact messages" in res.stdout and " 0 tile cores" not in res.stdout
    help_text = subprocess.run([sys.executable, str(TOOL), "node", "--help"], capture_output=True, text=True,
                               check=True).stdout
    assert "--quick" in help_text and "--repeat" in help_text
