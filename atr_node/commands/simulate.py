"""Generate a synthetic multi-leg mission: a lawnmower survey over a synthetic seabed with
ray-traced targets and clutter (SPEC section 4). Writes OUT/mission.atrlog (sonar tiles with
per-ping nav, INS as NMEA and CAN records; ICD section 4), OUT/truth.csv (ICD section 5) and
OUT/clutter.csv (rocks, blocks, debris; not truth).

Examples:
  atr-node simulate --out /tmp/mission --seed 3
  atr-node simulate --out /tmp/hard --seed 4 --hard --seabed sand --legs 6
  atr-node simulate --out /tmp/small --legs 2 --leg-length 60 --swath 30 --targets 4
"""

from __future__ import annotations

import argparse
import dataclasses
import time

from ..config import load_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    parser.add_argument("--config", metavar="FILE", help="TOML settings (default: built-in defaults)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--name", help="mission name in the tiles (default sim-<seed>)")
    parser.add_argument("--hard", action="store_true", help="dense clutter, strong ripples, rougher seabed")
    parser.add_argument("--legs", type=int, help="survey legs (simulation.mission_legs)")
    parser.add_argument("--leg-length", type=float, metavar="M", help="leg length in metres")
    parser.add_argument("--swath", type=float, metavar="M", help="ground swath per side = leg spacing, metres")
    parser.add_argument("--targets", type=int, help="number of targets")
    parser.add_argument("--shapes", help="comma-separated shapes: cylinder, cone, wedge, sphere, box or .stl/.obj files")
    parser.add_argument("--seabed", choices=("mud", "silt", "sand", "gravel", "rock"), help="seabed type")
    parser.add_argument("--tile-pings", type=int, help="pings per tile")
    parser.add_argument("--no-links", action="store_true", help="tiles with nav only: no NMEA or CAN records")


def run(args: argparse.Namespace) -> int:
    from ..simulation.mission import generate_mission

    settings = load_settings(args.config)
    over = {}
    for opt, key in (("legs", "mission_legs"), ("leg_length", "mission_leg_length_m"), ("swath", "mission_swath_m"),
                     ("targets", "mission_targets"), ("seabed", "seabed"), ("tile_pings", "mission_tile_pings")):
        v = getattr(args, opt)
        if v is not None:
            over[key] = v
    if args.shapes:
        over["mission_shapes"] = tuple(s.strip() for s in args.shapes.split(",") if s.strip())
    if over:
        settings = settings.replace(simulation=dataclasses.replace(settings.simulation, **over))
    t0 = time.perf_counter()
    files = generate_mission(settings, args.out, seed=args.seed, name=args.name, hard=args.hard,
                             links=not args.no_links)
    dt = time.perf_counter() - t0
    print(f"mission {files.name}: {files.legs} legs, {files.tiles} tiles, {files.targets} targets, "
          f"{files.clutter_objects} clutter objects, {files.records} records, {files.duration_s:.0f} s of survey")
    print(f"  {files.atrlog}\n  {files.truth}\n  {files.clutter}\n  generated in {dt:.1f} s")
    return 0
