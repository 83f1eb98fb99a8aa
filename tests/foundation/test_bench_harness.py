"""The benchmark harness (tools/bench/harness.py) and ``atr-node bench --json``: statistics
against the standard library's, pairing order, and a real quick run through the command."""

from __future__ import annotations

import importlib.util
import json
import statistics
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


harness = _load("harness", ROOT / "tools" / "bench" / "harness.py")


def test_statistics_match_the_standard_library():
    run = harness.start("t")
    try:
        t = harness.record("x", [0.3, 0.1, 0.2, 0.5], work=10.0, work_unit="px")
        calls = []
        m = harness.measure("f", lambda: calls.append(1), repeat=4, warmup=2)
    finally:
        harness.finish()
    assert (t.median_s, t.min_s, t.max_s) == (statistics.median([0.3, 0.1, 0.2, 0.5]), 0.1, 0.5)
    assert t.rate() == pytest.approx(10.0 / 0.25)
    assert len(calls) == 6 and len(m.samples_s) == 4  # warm-up calls run, not kept
    d = json.loads(json.dumps(run.to_dict()))
    assert [r["name"] for r in d["results"]] == ["x", "f"] and d["machine"]["cpu_count"] >= 1


def test_paired_alternates_baseline_then_candidate():
    order = []
    harness.start("t")
    try:
        p = harness.paired("p", lambda: order.append("c"), lambda: order.append("b"), repeat=3, warmup=1)
    finally:
        harness.finish()
    assert order == ["b", "c"] * 4
    assert len(p.ratios) <= 3 and p.to_dict()["kind"] == "paired"


def test_bad_repeat_is_refused():
    with pytest.raises(ValueError):
        harness.measure("f", lambda: None, repeat=0)


def test_subjects_agree_with_the_runner():
    from atr_node.commands.bench import SUBJECTS

    runner = _load("bench_run", ROOT / "tools" / "bench" / "run.py")
    assert tuple(runner.SUBJECTS) == SUBJECTS
    for s in SUBJECTS:
        assert (ROOT / "tools" / "bench" / f"{s}.py").is_file(), s


def test_subject_parts_dispatch():
    """A subject module's parts: ``PART args`` to that part, ``--quick`` alone to every part,
    other options to the first part (so each old script's command line still works)."""
    calls = []
    parts = {"a": lambda argv: calls.append(("a", argv)) or 0, "b": lambda argv: calls.append(("b", argv)) or 3}
    assert harness.subject_main("doc", parts, ["b", "--x", "1"]) == 3
    assert harness.subject_main("doc", parts, ["--quick"]) == 3  # worst exit status of the parts
    assert harness.subject_main("doc", parts, ["--x", "1"]) == 0
    assert calls == [("b", ["--x", "1"]), ("a", ["--quick"]), ("b", ["--quick"]), ("a", ["--x", "1"])]


@pytest.mark.parametrize("subject", ["detectors", "fusion", "ingest", "node", "calibration", "simulation", "batch",
                                     "operators", "quality"])
def test_every_subject_module_has_help(subject):
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "bench" / f"{subject}.py"), "--help"],
                       capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 0 and r.stdout.strip(), r.stderr[-2000:]


def test_atr_node_bench_json_quick(tmp_path):
    """The command end to end on the cheapest subject: JSON with timings and machine info."""
    out = tmp_path / "b.json"
    r = subprocess.run([sys.executable, "-m", "atr_node", "bench", "operators", "--quick", "--json", str(out)],
                       capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-2000:]
    runs = json.loads(out.read_text())
    assert [x["subject"] for x in runs] == ["operators"]
    names = {x["name"] for x in runs[0]["results"]}
    assert "export csv, 100 contacts" in names
    for x in runs[0]["results"]:
        assert x["min_s"] <= x["median_s"] <= x["max_s"]
    assert "cpu_count" in runs[0]["machine"]


def test_atr_node_bench_part_options_reach_the_module(tmp_path):
    """``--part 'PART OPTIONS'``: the subject's module gets them, and the JSON records them."""
    out = tmp_path / "b.json"
    r = subprocess.run([sys.executable, "-m", "atr_node", "bench", "operators", "--json", str(out), "--part",
                        "--quick --sizes 20"], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-2000:]
    (run,) = json.loads(out.read_text())
    assert run["options"]["argv"] == ["--quick", "--sizes", "20"]
    assert "export csv, 20 contacts" in {x["name"] for x in run["results"]}
    r = subprocess.run([sys.executable, "-m", "atr_node", "bench", "all", "--part", "x"], capture_output=True,
                       text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 2 and "--part needs one subject" in r.stderr


def test_atr_node_bench_unknown_subject_is_usage():
    r = subprocess.run([sys.executable, "-m", "atr_node", "bench", "nosuch"], capture_output=True, text=True,
                       timeout=120, cwd=ROOT)
    assert r.returncode == 2 and "invalid choice" in r.stderr
