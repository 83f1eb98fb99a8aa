"""Smoke tests of tools/figures/xtf_mosaic.py and tools/bench/ingest.py xtf on the real recording."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parents[2] / "tools" / "figures" / "xtf_mosaic.py"


@pytest.mark.parametrize("altitude", ["altimeter", "sonar"])
def test_mosaic_png_and_table(iver2, real_data, tmp_path, altitude):
    out = tmp_path / "m.png"
    survey = real_data / "xtf" / "ScotsmanLongitudeLatitudeCaris.csv"
    contacts = tmp_path / "contacts.jsonl"
    contacts.write_text('{"id": 7, "lat_deg": 48.445712, "lon_deg": -68.828120}\n')
    res = subprocess.run([sys.executable, str(TOOL), str(iver2), "--out", str(out), "--quick", "--altitude", altitude,
                          "--survey", str(survey), "--contacts", str(contacts)], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000
    assert "1/ 138/  281  stbd     4.06" in res.stdout
    ping = int(re.search(r"contact 7: ping (\d+), ground range \+", res.stdout).group(1))
    assert 270 <= ping <= 290  # drawn on the waterfall next to the hit, starboard
    if altitude == "altimeter":
        assert "ScotsmanLongitudeLatitudeCaris: V 11.9 m" in res.stdout
    else:  # the hit returns before the seabed's first return: the wreck stands above the seabed
        assert "returns before the seabed" in res.stdout


def test_bench_quick_prints_its_table(iver2):
    bench = TOOL.parents[1] / "bench" / "ingest.py"
    res = subprocess.run([sys.executable, str(bench), "xtf", str(iver2), "--quick"], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    rows = [line.split()[0] for line in res.stdout.splitlines()[2:]]
    assert rows == ["read", "read+sonar-altitude", "write", "xtf->atrlog", "atrlog->xtf", "ground"]
