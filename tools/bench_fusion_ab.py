#!/usr/bin/env python3
"""The node's main-process fusion, this code against a reference copy: same results? how fast?

A generated mission (default 4 legs of 200 m, 200 m swath per side, tiles of 1024 pings: the
32-Mpx replay of ``tools/bench_node.py``) is replayed once through the node's pipeline in this
process, recording every call the pipeline makes to the evidence grid and the contact tracker
(``tools/bench_node_fusion.py``). That call sequence then goes through a fresh grid and tracker
of each implementation:

* ``atr_node.fusion`` (this tree), and
* ``--reference DIR``: a copy of an older ``atr_node/fusion`` package (e.g. extracted from
  git: ``mkdir -p /tmp/ref && git archive HEAD atr_node/fusion | tar -x -C /tmp/ref``, then
  pass ``/tmp/ref/atr_node/fusion``). Its relative imports of the rest of ``atr_node`` are
  rewritten to absolute ones in a temporary copy.

Checked after every call: a digest of the whole grid state (accumulators, coverage bitmaps,
open layers, chunk slots and every insertion order) and, per contact update, the published
messages; both must be identical. Timed: process CPU of each call kind, best of ``--repeat``,
the two implementations interleaved (alternating first) so that a busy neighbour on a shared
machine weighs on both alike. NumPy's huge-page advice is off, as in the node's processes.
``--quick``: a small mission, one repetition (a smoke run). Without ``--reference`` only this
tree is timed.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import importlib  # noqa: E402
import re  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_node_fusion import mission_settings, record_calls, replay_calls  # noqa: E402


def grid_digest(grid) -> str:
    """SHA-256 of everything a grid holds, insertion orders included."""
    h = hashlib.sha256()
    for st in (grid._ln, grid._lt):
        h.update(repr(list(st.slot.items())).encode())
        for k in st.slot:
            h.update(st.arr[st.slot[k]].tobytes())
    for k, legs in grid.cover.items():
        for leg, b in legs.items():
            h.update(repr((k, leg)).encode())
            h.update(b"all" if b is None else b.tobytes())
    h.update(repr([list(grid.last_t.items()), list(grid.changed.items()), grid.n_clamped, grid.n_reopened,
                   grid.stamp, len(grid.detections), sorted(grid.closed_legs)]).encode())
    for leg, layer in grid.open.items():
        h.update(repr((leg, list(layer.chunks.slot.items()), list(layer.touched.items()), sorted(layer.retired),
                       layer.n_obs, layer.t)).encode())
        for k, s in layer.chunks.slot.items():
            h.update(layer.chunks.arr[s].tobytes())
    return h.hexdigest()


def load_reference(path: Path, tmp: Path) -> str:
    """Import a copy of an ``atr_node/fusion`` folder as package ``fusion_ref``."""
    dst = tmp / "fusion_ref"
    shutil.copytree(path, dst)
    for f in dst.glob("*.py"):
        src = f.read_text()
        src = re.sub(r"^from \.\.(\w)", r"from atr_node.\1", src, flags=re.M)
        src = re.sub(r"^from \.\. import", "from atr_node import", src, flags=re.M)
        f.write_text(src)
    sys.path.insert(0, str(tmp))
    importlib.import_module("fusion_ref")
    return "fusion_ref"


def replay(pkg: str, settings, frame, calls, *, check: bool) -> tuple[list[float], list, list[str]]:
    """Calls through a fresh grid and tracker of package ``pkg``: CPU s per kind, messages, digests."""
    from atr_node.fusion import association_gate_m

    grid_cls = importlib.import_module(pkg + ".grid").EvidenceGrid
    tracker_cls = importlib.import_module(pkg + ".contacts").ContactTracker
    gate = association_gate_m(settings.fusion, settings.template)
    grid = grid_cls(settings.fusion, gate_m=gate, detectors=tuple(settings.detectors.enabled))
    tracker = tracker_cls(settings.fusion, frame, gate_m=gate)
    digests: list[str] = []
    spent, updates = replay_calls(grid, tracker, calls,
                                  after=(lambda g: digests.append(grid_digest(g))) if check else None)
    return spent, [[m.to_message() for m in out] for out in updates], digests


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reference", type=Path, help="folder of an older atr_node/fusion package to compare with")
    ap.add_argument("--quick", action="store_true", help="small mission, one repetition")
    ap.add_argument("--repeat", type=int, default=7, help="timed replays per implementation (best of N)")
    ap.add_argument("--legs", type=int, default=4)
    ap.add_argument("--swath-m", type=float, default=200.0)
    ap.add_argument("--tile-pings", type=int, default=1024)
    args = ap.parse_args(argv)
    from atr_node.node.warmup import keep_small_pages
    from atr_node.simulation.mission import generate_mission

    keep_small_pages()  # as the node does
    s = mission_settings(args)
    with tempfile.TemporaryDirectory() as tmp:
        files = generate_mission(s, Path(tmp) / "m", seed=11)
        calls, frame, pixels = record_calls(s, files.atrlog)
        pkgs = ["atr_node.fusion"]
        if args.reference is not None:
            pkgs.insert(0, load_reference(args.reference, Path(tmp)))
        results = {p: replay(p, s, frame, calls, check=True) for p in pkgs}
        same = True
        if len(pkgs) == 2:
            (_, m0, d0), (_, m1, d1) = results[pkgs[0]], results[pkgs[1]]
            bad = next((i for i, (a, b) in enumerate(zip(d0, d1)) if a != b), None)
            same = bad is None and m0 == m1
            print(f"grid state identical after every call: {bad is None}"
                  + ("" if bad is None else f" (first difference after call {bad}: {calls[bad][0]})"))
            print(f"contact messages identical (ids, order, values): {m0 == m1} "
                  f"({sum(len(m) for m in m1)} messages)")
        best: dict[str, list[float]] = {}
        for r in range(1 if args.quick else max(1, args.repeat)):
            for p in (pkgs if r % 2 else pkgs[::-1]):
                spent = replay(p, s, frame, calls, check=False)[0]
                best[p] = spent if p not in best else [min(a, b) for a, b in zip(best[p], spent)]
    n_obs = sum(c[0] == "obs" for c in calls)
    n_upd = sum(c[0] == "update" for c in calls)
    print(f"mission: {pixels / 1e6:.1f} Mpx in {n_obs} tile cores, {n_upd} contact updates "
          f"(CPU s, best of {1 if args.quick else args.repeat}, one core, interleaved)")
    print(f"{'implementation':18s} {'add_observation':>16s} {'update':>8s} {'close_all':>10s} {'total':>8s}")
    for p in pkgs:
        b = best[p]
        print(f"{'reference' if p == 'fusion_ref' else 'this tree':18s} {b[0]:16.3f} {b[1]:8.3f} {b[2]:10.3f} "
              f"{sum(b):8.3f}")
    if len(pkgs) == 2:
        print(f"saving: {100.0 * (1.0 - sum(best[pkgs[1]]) / sum(best[pkgs[0]])):.1f} % of the fusion CPU")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
