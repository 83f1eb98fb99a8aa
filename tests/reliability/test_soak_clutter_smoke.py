"""Smoke run of ``tools/soak/soak_clutter.py`` (issue 21 item 3): a small mission under Pareto-1.5
speckle on every tile, replayed by ``atr-node replay`` in a child process, within 2 GiB."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_soak_clutter_quick(tmp_path):
    out = tmp_path / "fig.json"
    p = subprocess.run([sys.executable, str(REPO / "tools" / "soak" / "soak_clutter.py"), "--quick", "--json", str(out),
                        "--keep", str(tmp_path / "work")], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr
    fig = json.loads(out.read_text())
    assert fig["exit"] == 0 and fig["tiles"] > 0
    assert fig["contacts"] > 0  # the clutter did make contacts
    assert fig["peak_rss_mib"] < 2048
    assert "peak RSS" in p.stdout and "Traceback" not in p.stderr
