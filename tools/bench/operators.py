"""Benchmark of the operators' tools: export of N contacts (GeoJSON, KML, CSV), the monitor's
screen rendering, $EXWPT formatting, and the belief-map PNG; prints a table.

    python tools/bench/operators.py            # N = 100, 1000, 10000 contacts
    python tools/bench/operators.py --quick    # N = 100 only, fewer repeats

Figures depend on the machine and its load: take them on a quiet machine.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from atr_node.node import wire
from atr_node.operators.beliefmap import draw_belief_map
from atr_node.operators.book import book_of
from atr_node.operators.export import render
from atr_node.operators.exwpt import format_exwpt
from atr_node.operators.monitor import render_screen
from atr_node.operators.stream import NodeFollower

sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402  (tools/bench/harness.py: repeats, warm-up, statistics, JSON)


def contacts(n: int, seed: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        bel = float(rng.uniform(0.5, 1.0))
        out.append(wire.contact_message(id=i + 1, state="update", t=1.7e9 + i, lat_deg=44.0 + rng.uniform(0, 0.05),
                                        lon_deg=9.8 + rng.uniform(0, 0.05), east_m=float(rng.uniform(0, 4000)),
                                        north_m=float(rng.uniform(0, 4000)), sigma_m=1.5, bel=bel, pl=1.0,
                                        m_theta=1.0 - bel, looks=2, detections=3, detectors=["mf", "smf"], legs=[0, 1]))
    return out


def best_of(fn, repeats: int, name: str = "") -> float:
    """Minimum wall time of ``fn`` over ``repeats`` runs after one warm-up, through the harness
    (which keeps the median and maximum too, for ``atr-node bench operators --json``)."""
    return harness.measure(name or getattr(fn, "__name__", "call"), fn, repeat=repeats, warmup=1, clock="wall").min_s


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="N = 100 only, 2 repeats")
    ap.add_argument("--sizes", type=int, nargs="+", help="contact counts (default 100 1000 10000)")
    args = ap.parse_args(argv)
    sizes = args.sizes or ([100] if args.quick else [100, 1000, 10000])
    repeats = 2 if args.quick else 5
    follower = NodeFollower("tcp://127.0.0.1:1")  # never receives: only its book and counters are used
    print(f"{'N contacts':>10} {'geojson ms':>11} {'kml ms':>8} {'csv ms':>8} {'screen ms':>10} "
          f"{'exwpt us/sent':>14} {'png ms':>8}")
    with tempfile.TemporaryDirectory() as d:
        for n in sizes:
            cs = contacts(n)
            t = {fmt: best_of(lambda: render(cs, fmt), repeats, f"export {fmt}, {n} contacts") * 1e3
                 for fmt in ("geojson", "kml", "csv")}
            follower.book = book_of(cs)
            t_screen = best_of(lambda: render_screen(follower, now=time.monotonic(), width=110, max_rows=30),
                               repeats, f"monitor screen, {n} contacts") * 1e3
            t_ex = best_of(lambda: [format_exwpt(c) for c in cs], repeats, f"$EXWPT, {n} contacts") / n * 1e6
            t_png = best_of(lambda: draw_belief_map(Path(d) / "m.png", cs), 1 if n > 1000 else repeats,
                            f"belief-map PNG, {n} contacts") * 1e3
            print(f"{n:>10} {t['geojson']:>11.1f} {t['kml']:>8.1f} {t['csv']:>8.1f} {t_screen:>10.2f} "
                  f"{t_ex:>14.1f} {t_png:>8.0f}")
    follower.close()
    line = len(format_exwpt(contacts(1)[0]))
    print(f"\n$EXWPT sentence of a typical contact: {line} bytes -> {9600 / 10 / line:.1f} sentences/s at 9600 baud "
          f"(8N1), {115200 / 10 / line:.0f} at 115200")
    harness.value("exwpt_sentence_bytes", line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
