"""Smoke test of ``tools/figures/real_recordings.py``: the node on a shared real file, its contacts
mapped back onto the recorded waterfall and drawn (the docs figures come from this tool)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

TOOL = Path(__file__).resolve().parents[2] / "tools" / "figures" / "real_recordings.py"


def test_the_tool_places_every_contact_and_draws_the_waterfall(real_data, tmp_path):
    table = tmp_path / "t.json"
    r = subprocess.run([sys.executable, str(TOOL), str(real_data / "xtf" / "scotsman-iver2.xtf"), "--out",
                        str(tmp_path), "--json", str(table), "--", "--online-calibration", "off"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    row = json.loads(table.read_text())[0]
    assert row["contacts"] >= 1 and row["placed"] == row["contacts"]
    assert row["zones"]["water column"] == 0 and row["zones"]["first return"] == 0
    assert row["wreck_contacts"] and len(row["wreck_contacts"]) <= 3
    png = tmp_path / "real_scotsman-iver2.png"
    assert png.stat().st_size > 10_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
