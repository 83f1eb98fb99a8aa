"""Smoke test of tools/bench_fusion_ab.py (run by hand for figures: no timing asserted).

Compared with itself (``--reference`` the tree's own ``atr_node/fusion``, imported as a copy),
the tool must find identical grid states and contact messages; its digest must also see a
difference when there is one (a reference whose commit adds a constant)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TOOL = ROOT / "tools" / "bench_fusion_ab.py"


def test_bench_fusion_ab_quick_against_itself_finds_identical_results():
    res = subprocess.run([sys.executable, str(TOOL), "--quick", "--reference", str(ROOT / "atr_node" / "fusion")],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "grid state identical after every call: True" in res.stdout
    assert "contact messages identical (ids, order, values): True" in res.stdout
    for row in ("reference", "this tree", "saving"):
        assert row in res.stdout
    help_text = subprocess.run([sys.executable, str(TOOL), "--help"], capture_output=True, text=True,
                               check=True).stdout
    assert "--quick" in help_text and "--reference" in help_text


def test_bench_fusion_ab_sees_a_changed_accumulator(tmp_path):
    ref = tmp_path / "fusion"
    ref.mkdir()
    for f in (ROOT / "atr_node" / "fusion").glob("*.py"):
        (ref / f.name).write_text(f.read_text())
    grid = ref / "grid.py"
    src = grid.read_text()
    assert "self._ln.arr[slots] += d_ln" in src
    grid.write_text(src.replace("self._ln.arr[slots] += d_ln", "self._ln.arr[slots] += d_ln * (1.0 + 2.0 ** -40)"))
    res = subprocess.run([sys.executable, str(TOOL), "--quick", "--reference", str(ref)], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 1, res.stdout + res.stderr
    assert "grid state identical after every call: False" in res.stdout
