"""Smoke run of tools/bench/detectors.py score: it runs, prints its tables, and its scipy.ndimage
reference (an independent implementation) agrees with score_maps (``--check``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

TOOL = Path(__file__).resolve().parents[2] / "tools" / "bench" / "detectors.py"


def test_bench_quick_runs_and_agrees_with_scipy():
    res = subprocess.run([sys.executable, str(TOOL), "score", "--quick", "--rows", "160", "--cols", "700", "--check"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    for line in ("memory copy of the tile", "score_maps all four", "scipy.ndimage, all four",
                 "float32", "decimation 2", "decimation 4"):
        assert line in res.stdout, res.stdout


def test_bench_help():
    res = subprocess.run([sys.executable, str(TOOL), "score", "--help"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and "--quick" in res.stdout
