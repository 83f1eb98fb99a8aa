"""Run the benchmarks of a source checkout (tools/bench/): detectors, fusion, ingest, node,
calibration, simulation, batch, operators, quality (the held-out contact-quality benchmark,
issue 17), or all of them.

    atr-node bench fusion                     # one subject, full size
    atr-node bench all --quick                # every subject, small sizes (a smoke run)
    atr-node bench node --json node.json      # and the results as JSON (median, min, max, machine)

Each subject runs in a fresh Python process through the harness (tools/bench/harness.py):
repeats, warm-up, median/min/max, paired ratios against a baseline, machine info. Each
subject is one module, tools/bench/<subject>.py, of one or more parts; it runs on its own too
(python tools/bench/<subject>.py [PART] --help), and a part with its options runs under the
harness with ``atr-node bench SUBJECT --json FILE --part 'PART OPTIONS'``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

TOOLS = Path(__file__).resolve().parents[2] / "tools"
RUNNER = TOOLS / "bench" / "run.py"
SUBJECTS = ("detectors", "fusion", "ingest", "node", "calibration", "simulation", "batch", "operators", "quality")
"""The same names as ``SUBJECTS`` in tools/bench/run.py (a test checks they agree)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("subject", nargs="?", default="all", choices=(*SUBJECTS, "all"),
                        help="which subject (default: all)")
    parser.add_argument("--quick", action="store_true", help="small sizes: a smoke run")
    parser.add_argument("--json", metavar="FILE", help="write every subject's results as a JSON list to FILE")
    parser.add_argument("--part", metavar="'PART OPTIONS'", default="",
                        help="one part of the subject and its options, quoted, as its module takes them "
                             "(e.g. atr-node bench detectors --json d.json --part 'extract --mission --check')")


def run(args: argparse.Namespace) -> int:
    if not RUNNER.is_file():
        print(f"atr-node bench: the benchmarks are in a source checkout's tools/bench/, not found at {RUNNER} "
              "(install with 'pip install -e .' from a checkout)", file=sys.stderr)
        return 2
    part = getattr(args, "part", "") or ""
    if part and args.subject == "all":
        print("atr-node bench: --part needs one subject, not all", file=sys.stderr)
        return 2
    names = list(SUBJECTS) if args.subject == "all" else [args.subject]
    worst, runs = 0, []
    with tempfile.TemporaryDirectory() as tmp:
        for n in names:
            out = Path(tmp) / f"{n}.json"
            cmd = [sys.executable, str(RUNNER), n, "--json", str(out)] + (["--quick"] if args.quick else [])
            if part:
                cmd += ["--part", part]
            rc = subprocess.call(cmd)
            worst = max(worst, rc)
            if out.is_file():
                runs.append(json.loads(out.read_text()))
            elif rc == 0:
                rc = worst = 1
            if rc:
                print(f"atr-node bench: {n} failed (exit status {rc})", file=sys.stderr)
    if args.json:
        dest = Path(args.json)
        part = dest.with_name(dest.name + ".part")
        part.write_text(json.dumps(runs, indent=1) + "\n")
        part.replace(dest)  # whole or not at all
    return 1 if worst else 0
