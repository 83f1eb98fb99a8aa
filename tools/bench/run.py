#!/usr/bin/env python3
"""Run one benchmark subject in this (fresh) process under the harness; ``atr-node bench`` calls it.

    python tools/bench/run.py fusion --quick --json out.json

Each subject runs its module's ``main(argv)`` (``tools/bench/<subject>.py``, every part) in
this process, with the harness's run open, so every :func:`harness.measure` /
:func:`harness.record` call lands in the JSON; the whole time and exit status are recorded too. A fresh process per subject, so a
script's thread settings (set before numpy loads) hold and subjects do not warm each other up.
"""

from __future__ import annotations

import argparse
import importlib.util
import shlex
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
TOOLS = HERE.parent
sys.path.insert(0, str(HERE))

import harness  # noqa: E402

SUBJECTS: tuple[str, ...] = ("detectors", "fusion", "ingest", "node", "calibration", "simulation", "batch",
                             "operators", "quality")
"""The subjects: each is the module ``tools/bench/<subject>.py`` with ``main(argv) -> int`` taking
``--quick`` (several parts run in turn: see :func:`harness.subject_main`)."""


def _load(subject: str):
    path = HERE / f"{subject}.py"
    name = f"bench_{subject}"  # a bare "node" or "fusion" in sys.modules would read as a package of ours
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # dataclasses and pickling look the module up by name
    spec.loader.exec_module(mod)
    return mod


def run_subject(subject: str, *, quick: bool, extra: list[str] | None = None) -> tuple[harness.Run, int]:
    """Run ``subject``'s module (every part, or ``extra``: a part and its options); the harness
    run and the worst exit status."""
    argv = list(extra or []) + (["--quick"] if quick else [])
    run = harness.start(subject, quick=quick, argv=argv)
    worst = 0
    try:
        print(f"== {subject}: tools/bench/{subject}.py", flush=True)
        mod = _load(subject)
        t0 = time.perf_counter()
        worst = int(mod.main(argv) or 0)
        harness.record(f"{subject} whole run", [time.perf_counter() - t0], clock="wall")
        harness.value(f"{subject} exit status", worst)
    finally:
        harness.finish()
    return run, worst


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("subject", choices=SUBJECTS)
    p.add_argument("--quick", action="store_true", help="small sizes: a smoke run")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON to FILE ('-': stdout)")
    p.add_argument("--part", metavar="'PART OPTIONS'", default="",
                   help="one part of the subject and its options, quoted (e.g. --part 'extract --mission')")
    a = p.parse_args(argv)
    run, rc = run_subject(a.subject, quick=a.quick, extra=shlex.split(a.part))
    print(f"\n== {a.subject}: harness summary (median, min, max over the repeats)")
    print(harness.format_table(run), flush=True)
    if a.json:
        harness.write_json(run, a.json)
    return rc


if __name__ == "__main__":
    raise SystemExit(main())
