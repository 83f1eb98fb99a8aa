#!/usr/bin/env python3
"""Soak with heavy-tailed clutter: every tile of a generated mission multiplied by Pareto speckle.

Pareto speckle of shape 1.5 (infinite variance) on every pixel puts thousands of detections in
every leg: the evidence grid fills with belief regions holding hundreds of detection groups
(issue 21 item 3: 2.9-6 GB and 45-138 s, ``ContactTracker._split`` built a cells x groups
matrix). The mission is generated (``atr-node simulate``), its tiles re-written as float32
with the speckle, then replayed as a person would (``atr-node replay --speed max --publish
none``) in a child process; the child's peak RSS (``resource.getrusage(RUSAGE_CHILDREN)``: the
largest of the node's processes, the detection worker included) and wall time are printed,
with the contacts published.

Exit status 0 when the run ended with exit 0 and its peak RSS is within ``--budget-gib``,
1 otherwise (the line says which), 2 usage.

Examples::

    python tools/soak_clutter.py --quick                 # 2 legs of 60 m, seconds
    python tools/soak_clutter.py                         # 6 legs of 200 m, Pareto 1.5
    python tools/soak_clutter.py --legs 10 --leg-length-m 300 --shape 1.2 --json out.json
    python tools/soak_clutter.py --speckle loguniform    # log-uniform speckle instead
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from atr_node.io.atrlog import AtrLogWriter, read_atrlog  # noqa: E402
from atr_node.records.tile import Tile  # noqa: E402

GIB = 1 << 30


def speckle(rng: np.random.Generator, shape: tuple[int, int], *, kind: str = "pareto",
            pareto_shape: float = 1.5) -> np.ndarray:
    """Multiplicative speckle (float32): Pareto of ``pareto_shape`` with scale 1 (mean 3 at
    1.5, infinite variance), or log-uniform over 6 decades."""
    if kind == "pareto":
        return (rng.pareto(pareto_shape, size=shape) + 1.0).astype(np.float32)
    if kind == "loguniform":
        return np.exp(rng.uniform(0.0, np.log(1e6), size=shape)).astype(np.float32)
    raise ValueError(f"unknown speckle {kind!r}: expected pareto or loguniform")


def add_clutter(src: Path, dst: Path, *, seed: int = 0, kind: str = "pareto", pareto_shape: float = 1.5,
                mode: str = "multiply") -> int:
    """Copy the .atrlog ``src`` to ``dst`` with every sonar tile's pixels multiplied by speckle
    (written as float32, no data kept as NaN); other records unchanged. Returns the tiles."""
    rng = np.random.default_rng(seed)
    n = 0
    with AtrLogWriter(dst) as w:
        for rec in read_atrlog(src):
            msg = rec.msg
            if rec.link == "sonar":
                tile = Tile.from_map(msg)
                sp = speckle(rng, tile.shape, kind=kind, pareto_shape=pareto_shape)
                # replace: the speckle is the whole image (its median level kept), no seabed left
                px = (np.nanmedian(tile.pixels) * sp if mode == "replace" else tile.pixels * sp)
                px[np.isnan(tile.pixels)] = np.nan
                msg = tile.replace(pixels=np.minimum(px, np.float32(3e38)), wire_dtype="float32").to_map()
                n += 1
            w.write(rec.t, rec.link, msg)
    return n


def _env() -> dict[str, str]:
    """The environment of the child runs: this tree's ``atr_node`` first."""
    old = os.environ.get("PYTHONPATH")
    return {**os.environ, "PYTHONPATH": str(REPO) + (os.pathsep + old if old else "")}


def simulate(out: Path, *, legs: int, leg_length_m: float, seed: int) -> Path:
    """A generated mission (``atr-node simulate``); returns its .atrlog."""
    cmd = [sys.executable, "-m", "atr_node", "simulate", "--out", str(out), "--seed", str(seed),
           "--legs", str(legs), "--leg-length", str(leg_length_m)]
    subprocess.run(cmd, check=True, capture_output=True, cwd=REPO, env=_env())
    return out / "mission.atrlog"


def replay_peak(log: Path, out_dir: Path, *, extra: list[str] | None = None, timeout_s: float = 3600.0) -> dict:
    """Replay ``log`` in a child process (``atr-node replay``); its exit code, wall time, peak
    RSS (the largest of its processes, from ``getrusage`` in a fresh measuring process) and
    contacts."""
    contacts = out_dir / "contacts.jsonl"
    probe = (
        "import json, resource, subprocess, sys, time\n"
        "t0 = time.monotonic()\n"
        "p = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n"
        "dt = time.monotonic() - t0\n"
        "peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024\n"
        "print(json.dumps({'rc': p.returncode, 'wall_s': dt, 'peak_rss_b': peak, 'stderr': p.stderr[-4000:]}))\n"
    )
    cmd = [sys.executable, "-c", probe, sys.executable, "-m", "atr_node", "replay", str(log), "--publish", "none",
           "--speed", "max", "--online-calibration", "off", "--contacts-out", str(contacts), *(extra or [])]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, cwd=out_dir, env=_env())
    res = json.loads(p.stdout.strip().splitlines()[-1])
    n = 0
    if contacts.exists():
        n = sum(1 for line in contacts.open() if line.strip())
    res["contacts"] = n
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="exit status: 0 within budget, 1 over budget or the run failed, 2 usage")
    ap.add_argument("--legs", type=int, default=6, help="survey legs (default 6)")
    ap.add_argument("--leg-length-m", type=float, default=200.0, help="leg length, m (default 200)")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--speckle", choices=("pareto", "loguniform"), default="pareto")
    ap.add_argument("--shape", type=float, default=1.5, help="Pareto shape (default 1.5: infinite variance)")
    ap.add_argument("--budget-gib", type=float, default=2.0, help="peak RSS allowed, GiB (default 2)")
    ap.add_argument("--quick", action="store_true", help="2 legs of 60 m (a smoke run)")
    ap.add_argument("--keep", metavar="DIR", help="work in DIR and keep the mission (default: a temporary folder)")
    ap.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    args = ap.parse_args(argv)
    if args.quick:
        args.legs, args.leg_length_m = 2, 60.0
    if args.legs < 1 or not args.leg_length_m > 0 or not args.shape > 0:
        ap.error("--legs must be >= 1, --leg-length-m and --shape > 0")
    with tempfile.TemporaryDirectory(prefix="soak_clutter_") as tmp:
        work = Path(args.keep) if args.keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        src = simulate(work / "clean", legs=args.legs, leg_length_m=args.leg_length_m, seed=args.seed)
        log = work / "clutter.atrlog"
        t0 = time.monotonic()
        tiles = add_clutter(src, log, seed=args.seed, kind=args.speckle, pareto_shape=args.shape)
        t_gen = time.monotonic() - t0
        res = replay_peak(log, work)
    peak_gib = res["peak_rss_b"] / GIB
    fig = {"legs": args.legs, "leg_length_m": args.leg_length_m, "speckle": args.speckle, "shape": args.shape,
           "tiles": tiles, "generate_s": round(t_gen, 2), "replay_s": round(res["wall_s"], 2),
           "peak_rss_mib": round(res["peak_rss_b"] / (1 << 20), 1), "contacts": res["contacts"], "exit": res["rc"]}
    print(f"soak_clutter: {tiles} tiles ({args.legs} legs of {args.leg_length_m:g} m, {args.speckle}"
          f"{' ' + format(args.shape, 'g') if args.speckle == 'pareto' else ''}), replay {res['wall_s']:.1f} s, "
          f"peak RSS {fig['peak_rss_mib']:.0f} MiB, {res['contacts']} contact rows, exit {res['rc']}")
    if args.json:
        Path(args.json).write_text(json.dumps(fig, indent=2) + "\n")
    if res["rc"] != 0:
        tail = res["stderr"].strip().splitlines()[-1:] or ["(no message)"]
        print(f"soak_clutter: the replay failed with exit {res['rc']}: {tail[0]}", file=sys.stderr)
        return 1
    if peak_gib > args.budget_gib:
        print(f"soak_clutter: peak RSS {peak_gib:.2f} GiB is over the {args.budget_gib:g} GiB budget", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
