"""Smoke run of tools/bench/batch.py (the figures themselves are measured by the tool, not tested)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

TOOL = Path(__file__).resolve().parents[2] / "tools" / "bench" / "batch.py"


def test_bench_batch_quick_runs_and_finds_identical_contacts():
    r = subprocess.run([sys.executable, str(TOOL), "--quick"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "identical contacts: yes" in r.stdout
    assert "| serial (one process) |" in r.stdout and "| local Dask, 2 workers |" in r.stdout


def test_bench_batch_help():
    r = subprocess.run([sys.executable, str(TOOL), "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "--quick" in r.stdout
