"""Smoke runs of the calibration tools (their full runs are benchmarks, not tests)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from atr_node.calibration.model import PerformanceModel

TOOLS = Path(__file__).resolve().parents[2] / "tools"


def _tool(name: str):
    spec = importlib.util.spec_from_file_location(name.replace("/", "_"), TOOLS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_bench_calibration_quick(capsys):
    assert _tool("bench/calibration").main(["--quick"]) == 0
    out = capsys.readouterr().out
    assert "total" in out and "error against run time" in out
    rows = [line.split() for line in out.splitlines() if line.strip().split(" ")[0].isdigit()]
    assert {r[0] for r in rows} == {"25", "50", "100", "200"}


def test_make_shipped_model_quick(tmp_path, capsys):
    out = tmp_path / "m.json"
    assert _tool("make_shipped_model").main(["--quick", "--targets", "10", "--out", str(out), "--seabeds", "silt,rock"]) == 0
    m = PerformanceModel.load(out)
    assert m.provenance["seabed"] == "silt+rock" and m.provenance["n_images"] == 2
    assert set(m.tau) == {"mf", "lac", "smf", "z"}
