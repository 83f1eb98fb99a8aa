"""Run the benchmarks in tools/ (a source checkout): detectors, fusion, simulation,
calibration, links, node, batch, operators, xtf, quality (the held-out contact-quality benchmark,
issue 17), or all of them, each printing its table.

    atr-node bench detectors            # one benchmark, full size
    atr-node bench all --quick          # every benchmark, small sizes (a smoke run)

Each benchmark is also a script of its own (python tools/bench_<name>.py --help) with more
options. The figures are in README and docs/.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

TOOLS = Path(__file__).resolve().parents[2] / "tools"
BENCHES = {
    "detectors": "bench_detectors.py", "fusion": "bench_fusion.py", "simulation": "bench_simulation.py",
    "calibration": "bench_calibration.py", "links": "bench_links.py", "node": "bench_node.py",
    "batch": "bench_batch.py", "operators": "bench_operators.py", "xtf": "xtf_bench.py",
    "quality": "bench_quality.py",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("which", choices=(*BENCHES, "all"), help="which benchmark")
    parser.add_argument("--quick", action="store_true", help="small sizes: a smoke run")


def run(args: argparse.Namespace) -> int:
    names = list(BENCHES) if args.which == "all" else [args.which]
    missing = [n for n in names if not (TOOLS / BENCHES[n]).is_file()]
    if missing:
        print(f"atr-node bench: the benchmark scripts are in the source checkout's tools/ folder, not found at "
              f"{TOOLS} (install with 'pip install -e .' from a checkout)", file=sys.stderr)
        return 2
    worst = 0
    for n in names:
        print(f"== {n} ({BENCHES[n]})", flush=True)
        cmd = [sys.executable, str(TOOLS / BENCHES[n])] + (["--quick"] if args.quick else [])
        rc = subprocess.call(cmd)
        worst = max(worst, rc)
    return worst
