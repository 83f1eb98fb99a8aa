#!/usr/bin/env python3
"""SIGKILL the node at random points, many times, and check nothing accepted is lost.

The node is ``atr-node replay LOG --state-dir DIR`` (the same pipeline, snapshots and resume
as aboard). First one uninterrupted run gives the reference contacts and its wall time.
Then rounds: each round starts from an empty state directory and runs the same command
again and again, each time SIGKILLing it after a uniformly random delay in [0, reference wall
time], until a run reaches the end of the log by itself. After every kill the current
snapshot is checked: ``CURRENT`` names a complete folder and it loads into a fresh pipeline.
At the end of every round, the contacts must equal the reference, field for field.

Reported: kills, kills that found a snapshot, snapshots verified and corrupted, restarts
survived (runs after a kill that resumed and ran to their end or their next kill), rounds
whose final contacts equal the reference.

Examples::

    python tools/soak/kill_restart.py --quick                  # 3 kills on a 2-leg mission
    python tools/soak/kill_restart.py --kills 100 --legs 3     # about 10 minutes on 2 loaded cores
    python tools/soak/kill_restart.py --log m.atrlog --config m.toml --kills 50
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

MISSION = """
[simulation]
mission_legs = {legs}
mission_leg_length_m = 70.0
mission_swath_m = 30.0
mission_targets = 5
mission_tile_pings = 128
mission_clutter_per_km2 = 1000.0

[node]
snapshot_every_tiles = {every}
queue_tiles = 4
"""


@dataclass
class KillStats:
    kills: int = 0
    kills_with_snapshot: int = 0
    snapshots_verified: int = 0
    snapshots_corrupted: int = 0
    restarts: int = 0
    rounds: int = 0
    rounds_equal: int = 0
    failures: list[str] = field(default_factory=list)
    run_s: list[float] = field(default_factory=list)


def replay_cmd(log: Path, cfg: Path, out: Path, state: Path, *, workers: int, online: str) -> list[str]:
    return [sys.executable, "-m", "atr_node", "replay", str(log), "--config", str(cfg), "--online-calibration", online,
            "--publish", "none", "--contacts-out", str(out), "--state-dir", str(state), "--quiet",
            "--workers", str(workers)]


def verify_snapshot(state: Path, cfg: Path) -> str | None:
    """None when ``state`` has no snapshot or a complete, loadable one; else what is wrong."""
    from atr_node.calibration.model import PerformanceModel
    from atr_node.config import load_settings
    from atr_node.errors import AtrError
    from atr_node.node import state as node_state
    from atr_node.node.pipeline import Pipeline

    if not (state / "CURRENT").exists():
        return None
    folder = node_state.read_current(state)
    if folder is None:
        return f"CURRENT names {(state / 'CURRENT').read_text()!r}, which is not a complete snapshot folder"
    pipe = Pipeline(load_settings(cfg), model=PerformanceModel.shipped(), workers=0)
    try:
        meta = node_state.load(state, pipe)
    except (AtrError, OSError, ValueError, KeyError) as exc:
        return f"{folder.name}: does not load: {type(exc).__name__}: {exc}"
    finally:
        pipe.close()
    if meta is None or int(meta["position"]) < 0:
        return f"{folder.name}: no position"
    return None


def run_rounds(log: Path, cfg: Path, work: Path, *, kills: int, seed: int, workers: int = 1, online: str = "off",
               max_rounds: int = 1000, progress=None) -> tuple[KillStats, float]:
    """The reference run, then rounds of random kills until ``kills`` kills are done."""
    import random

    rng = random.Random(seed)
    st = KillStats()
    ref_out = work / "ref.jsonl"
    t0 = time.monotonic()
    r = subprocess.run(replay_cmd(log, cfg, ref_out, work / "ref_state", workers=workers, online=online),
                       capture_output=True, text=True, timeout=3600)
    ref_wall = time.monotonic() - t0
    if r.returncode != 0:
        raise SystemExit(f"kill_restart: the reference run failed ({r.returncode}): {r.stderr[-2000:]}")
    ref = ref_out.read_text()
    while st.kills < kills and st.rounds < max_rounds:
        st.rounds += 1
        state, out = work / f"state-{st.rounds}", work / f"out-{st.rounds}.jsonl"
        killed_before = False
        while True:
            t1 = time.monotonic()
            proc = subprocess.Popen(replay_cmd(log, cfg, out, state, workers=workers, online=online),
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            if killed_before:
                st.restarts += 1
            delay = rng.uniform(0.0, ref_wall) if st.kills < kills else None
            try:
                proc.wait(timeout=delay)
            except subprocess.TimeoutExpired:
                proc.send_signal(signal.SIGKILL)
                proc.wait(timeout=60)
                st.kills += 1
                killed_before = True
                has = (state / "CURRENT").exists()
                st.kills_with_snapshot += has
                why = verify_snapshot(state, cfg)
                if why is not None:
                    st.snapshots_corrupted += 1
                    st.failures.append(f"round {st.rounds}, kill {st.kills} at {delay:.2f} s: {why}")
                elif has:
                    st.snapshots_verified += 1
                if progress is not None:
                    progress(f"round {st.rounds}: kill {st.kills}/{kills} after {delay:.2f} s "
                             f"({'snapshot ok' if has and why is None else why or 'no snapshot yet'})")
                continue
            st.run_s.append(time.monotonic() - t1)
            err = proc.stderr.read() if proc.stderr else ""
            if proc.returncode != 0:
                st.failures.append(f"round {st.rounds}: the run ended with status {proc.returncode}: {err[-500:]}")
                break
            equal = out.read_text() == ref
            st.rounds_equal += equal
            if not equal:
                st.failures.append(f"round {st.rounds}: final contacts differ from the uninterrupted run")
            break
        shutil.rmtree(state, ignore_errors=True)
    return st, ref_wall


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kills", type=int, default=30, help="SIGKILLs in all (default 30)")
    ap.add_argument("--quick", action="store_true", help="3 kills on a 2-leg mission, no worker process")
    ap.add_argument("--legs", type=int, default=3, help="legs of the generated mission (default 3)")
    ap.add_argument("--every", type=int, default=4, help="node.snapshot_every_tiles of the generated config")
    ap.add_argument("--log", type=Path, help="replay this .atrlog instead of a generated mission (needs --config)")
    ap.add_argument("--config", type=Path, help="settings for --log")
    ap.add_argument("--workers", type=int, choices=(0, 1), default=1, help="detection worker process (default 1)")
    ap.add_argument("--online-calibration", choices=("on", "off"), default="off")
    ap.add_argument("--seed", type=int, default=0, help="seed of the kill delays and of the mission")
    ap.add_argument("--workdir", type=Path, help="keep everything here (default: a temporary folder)")
    ap.add_argument("--json", metavar="FILE", help="write the counts as JSON")
    args = ap.parse_args(argv)
    if args.quick:
        args.kills, args.legs, args.workers = min(args.kills, 3), 2, 0
    work = args.workdir or Path(tempfile.mkdtemp(prefix="atr-kill-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        if args.log:
            if not args.config:
                ap.error("--log needs --config")
            log, cfg = args.log, args.config
        else:
            import tomllib

            from atr_node.config import settings_from_dict
            from atr_node.simulation.mission import generate_mission

            cfg = work / "mission.toml"
            cfg.write_text(MISSION.format(legs=args.legs, every=args.every))
            settings = settings_from_dict(tomllib.loads(cfg.read_text()), path=str(cfg))
            log = generate_mission(settings, work / "mission", seed=args.seed).atrlog
        st, ref_wall = run_rounds(log, cfg, work, kills=args.kills, seed=args.seed, workers=args.workers,
                                  online=args.online_calibration, progress=lambda s: print(s, file=sys.stderr))
    finally:
        if args.workdir is None:
            shutil.rmtree(work, ignore_errors=True)
    ok = not st.failures and st.rounds_equal == st.rounds
    print(f"kill_restart: seed {args.seed}, workers {args.workers}, machine load {os.getloadavg()[0]:.1f} "
          f"(2 cores, shared)")
    print(f"| {'item':<46} | {'value':>8} |\n|{'-' * 48}|{'-' * 10}|")
    for k, v in [("reference run wall time (s)", f"{ref_wall:.1f}"), ("SIGKILLs", st.kills),
                 ("kills after the first snapshot", st.kills_with_snapshot),
                 ("snapshots verified after a kill (load ok)", st.snapshots_verified),
                 ("corrupted snapshots", st.snapshots_corrupted), ("restarts survived", st.restarts),
                 ("rounds (fresh state to end of log)", st.rounds),
                 ("rounds with contacts equal to the reference", st.rounds_equal)]:
        print(f"| {k:<46} | {v!s:>8} |")
    for f in st.failures[:10]:
        print(f"!! {f}")
    print("result:", "OK, no accepted evidence lost, no corrupted snapshot" if ok else "FAILED")
    if args.json:
        Path(args.json).write_text(json.dumps({**vars(st), "ref_wall_s": ref_wall}, indent=1))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
