"""Smoke run of tools/bench/detectors.py extract: it runs, prints its table, and the previous
implementation it times (cv2 with statistics) gives the same detections as find_detections
(``--check``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

TOOL = Path(__file__).resolve().parents[2] / "tools" / "bench" / "detectors.py"


def test_bench_extract_quick_runs_and_agrees_with_the_previous_code():
    res = subprocess.run([sys.executable, str(TOOL), "extract", "--quick", "--rows", "200", "--cols", "600", "--check"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    for line in ("before ms/Mpx", "now ms/Mpx", "(mean per map)", "coverage bits of node.detect"):
        assert line in res.stdout, res.stdout
    assert " NO" not in res.stdout, res.stdout
    rows = [ln for ln in res.stdout.splitlines() if ln.split()[:1] and ln.split()[0] in ("mf", "lac", "smf", "z")]
    assert len(rows) == 12 and all(ln.rstrip().endswith("yes") for ln in rows), res.stdout


def test_bench_extract_mission_mode_runs_and_agrees():
    res = subprocess.run([sys.executable, str(TOOL), "extract", "--quick", "--rows", "64", "--cols", "300", "--repeat", "1",
                          "--mission", "--mission-units", "1", "--check"],
                         capture_output=True, text=True, timeout=180)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "generated mission" in res.stdout and "node detect(job), per unit" in res.stdout, res.stdout
    assert "same: yes" in res.stdout, res.stdout


def test_bench_extract_help():
    res = subprocess.run([sys.executable, str(TOOL), "extract", "--help"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and "--quick" in res.stdout
