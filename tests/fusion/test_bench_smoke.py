"""Smoke test of tools/bench/fusion.py grid (the benchmark itself is run by hand: no timing asserted)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

TOOL = Path(__file__).resolve().parents[2] / "tools" / "bench" / "fusion.py"


def test_bench_fusion_quick_prints_its_table():
    out = subprocess.run([sys.executable, str(TOOL), "grid", "--quick"], capture_output=True, text=True, timeout=120,
                         check=True).stdout
    for row in ("deposit", "commit leg", "raw accumulate", "closed-form evaluation", "persistent total"):
        assert row in out
    assert "B/covered cell" in out
    help_text = subprocess.run([sys.executable, str(TOOL), "grid", "--help"], capture_output=True, text=True,
                               check=True).stdout
    assert "--quick" in help_text
