"""Smoke run of the error-against-run-time tool (the full table is in README)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

TOOL = Path(__file__).resolve().parents[2] / "tools" / "bench" / "quality.py"


def test_speed_options_quick_prints_one_row_per_option(tmp_path):
    out = tmp_path / "rows.json"
    r = subprocess.run([sys.executable, str(TOOL), "speed-options", "--quick", "--json", str(out)], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    rows = [line for line in r.stdout.splitlines() if line.startswith("| ") and not line.startswith("| option")]
    assert len(rows) == 3
    assert "reference" in rows[0] and "scores: max" in rows[1] and "P(y)" in rows[2]
    import json

    data = json.loads(out.read_text())
    assert [d["option"].split(":")[0] for d in data][1] == "detectors"
    assert all(0.0 <= d["pd"] <= 1.0 and d["wall_s"] > 0 for d in data)
