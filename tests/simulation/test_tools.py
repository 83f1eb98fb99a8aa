"""Smoke runs of the simulation tools (the full runs are for a quiet machine)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

TOOLS = Path(__file__).resolve().parents[2] / "tools"


def load(name: str):
    spec = importlib.util.spec_from_file_location(name.replace("/", "_"), TOOLS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_gallery_quick(tmp_path, capsys):
    out = tmp_path / "g.png"
    assert load("figures/gallery_signatures").main(["--quick", "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10000


def test_bench_quick(capsys):
    assert load("bench/simulation").main(["--quick"]) == 0
    text = capsys.readouterr().out
    assert "whole signatures" in text and "mission generation" in text
    rows = {tuple(ln.split()[:2]): ln.split()[2:] for ln in text.splitlines()
            if ln.strip().startswith(("dense ", "rays ", "strips "))}
    assert len(rows) == 7
    # rays at k = 2 are the dense tracer bit for bit: the same error against the fine trace
    assert rows["rays", "2"][1:] == rows["dense", "2"][1:]
    # errors fall with k, and strips are closer than rays at the same k
    err = {key: float(v[1].rstrip("%")) for key, v in rows.items()}
    assert err["rays", "4"] < err["rays", "2"] < err["rays", "1"]
    assert err["strips", "2"] < err["rays", "2"]
