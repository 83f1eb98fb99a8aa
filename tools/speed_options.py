#!/usr/bin/env python3
"""Error against run time for every speed option of the product, in one table (issue 8).

One generated mission (default: the demo's sand mission) is run through the node and scored
(`atr_node.evaluation.evaluate_log`, the paper's comparisons) once with the default settings
and once per speed option. For each option the table gives the run time (node pass with
on-line calibration plus the comparison pass), the change in Pd and false alarms of the
node's fusion (Dempster-Shafer with missed-detection evidence, three best detectors, at
Bel(T) >= report_bel) against the default, and the error in the number the option
approximates:

- detector precision (float32 tables) and decimation (2, 4): the scores, max |difference| /
  std of the full-precision scores over the mission's first tile;
- sub-rays (k = 1, 4 against 2) and calibration size (on-line iterations 3, 20 against 10):
  the calibrated P(y) curves, mean |difference| over detectors and range bins, and the
  thresholds, max relative difference;
- grid cell size (0.25 m, 1.0 m against 0.5 m): the positions, median distance from each
  matched target to its contact;
- on-line calibration off (the shipped model): P(y) and thresholds as above.

    python tools/speed_options.py                 # writes the table (Markdown) to stdout
    python tools/speed_options.py --quick         # a small mission: a smoke run
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def options(base):
    """(name, settings, online) of every speed option; the first is the default."""
    d, sim, cal, fus = base.detectors, base.simulation, base.calibration, base.fusion
    rep = base.replace
    return [
        ("default (float64, decimation 1, k = 2, 10 iterations, 0.5 m cells, on-line)", base, True),
        ("detectors: float32 tables", rep(detectors=dataclasses.replace(d, precision="float32")), True),
        ("detectors: decimation 2", rep(detectors=dataclasses.replace(d, decimation=2)), True),
        ("detectors: decimation 4", rep(detectors=dataclasses.replace(d, decimation=4)), True),
        ("simulation: 1 x 1 sub-rays", rep(simulation=dataclasses.replace(sim, subrays=1)), True),
        ("simulation: 4 x 4 sub-rays", rep(simulation=dataclasses.replace(sim, subrays=4)), True),
        ("calibration: 3 iterations per tile", rep(calibration=dataclasses.replace(cal, online_iterations=3)), True),
        ("calibration: 20 iterations per tile", rep(calibration=dataclasses.replace(cal, online_iterations=20)), True),
        ("grid: 0.25 m cells", rep(fusion=dataclasses.replace(fus, cell_m=0.25)), True),
        ("grid: 1.0 m cells", rep(fusion=dataclasses.replace(fus, cell_m=1.0)), True),
        ("on-line calibration off (shipped model)", base, False),
    ]


def score_error(base, variant, tile) -> float:
    from atr_node.detectors import score_maps

    kw = dict(range0_m=tile.range0_m, dr_m=tile.dr_m, dx_m=tile.dx_m, altitude_m=float(np.median(tile.nav.altitude_m)),
              template=base.template)
    ref = score_maps(tile.pixels, detectors=base.detectors, **kw)
    got = score_maps(tile.pixels, detectors=variant.detectors, **kw)
    err = 0.0
    for k in ref:
        ok = np.isfinite(ref[k]) & np.isfinite(got[k])
        sd = float(np.std(ref[k][ok])) or 1.0
        err = max(err, float(np.max(np.abs(got[k][ok].astype(np.float64) - ref[k][ok]))) / sd)
    return err


def model_error(ref, got) -> tuple[float, float]:
    """(mean |dPd| over detectors and range bins, max relative tau difference)."""
    dpd, dtau = [], []
    for d in ref.detectors:
        r = np.arange(2.5, 60, 5.0)
        dpd.append(np.mean(np.abs(ref.pd(d, r) - got.pd(d, r))))
        dtau.append(abs(got.tau[d] - ref.tau[d]) / max(abs(ref.tau[d]), 1e-12))
    return float(np.mean(dpd)), float(max(dtau))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="a small mission and three options: a smoke run")
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--seabed", default="sand")
    ap.add_argument("--json", metavar="FILE", help="also write the rows as JSON")
    args = ap.parse_args(argv)

    from atr_node.calibration.model import PerformanceModel
    from atr_node.calibration.online import OnlineCalibrator
    from atr_node.config import Settings
    from atr_node.evaluation.evaluate import NODE_SOURCE, evaluate_log
    from atr_node.evaluation.scoring import match, read_truth
    from atr_node.io.atrlog import read_atrlog
    from atr_node.records.tile import Tile
    from atr_node.simulation.mission import generate_mission

    base = Settings()
    base = base.replace(simulation=dataclasses.replace(base.simulation, seabed=args.seabed))
    if args.quick:
        base = base.replace(simulation=dataclasses.replace(base.simulation, mission_legs=3, mission_leg_length_m=70.0,
                                                           mission_swath_m=30.0, mission_targets=5,
                                                           mission_tile_pings=128),
                            calibration=dataclasses.replace(base.calibration, online_tiles=2, online_iterations=2,
                                                            targets_per_image=10))
    opts = options(base)
    if args.quick:
        opts = [opts[0], opts[2], opts[-1]]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        files = generate_mission(base, Path(tmp) / "mission", seed=args.seed, name="speed-options")
        first_tile = next(Tile.from_map(r.msg) for r in read_atrlog(files.atrlog) if r.link == "sonar")
        truth = read_truth(files.truth)
        ref = None
        for name, s, online in opts:
            sys.stderr.write(f"  {name} ...\n")
            shipped = PerformanceModel.shipped()
            cal = OnlineCalibrator(s, shipped, deterministic=True) if online else None
            t0 = time.perf_counter()
            res = evaluate_log(s, files.atrlog, files.truth, Path(tmp) / "eval", model=shipped, online=cal,
                               name=name, figures=False)
            wall = time.perf_counter() - t0
            run = res.run
            ds = next(r for r in res.rows if r.method.startswith("DS") and "no missed" not in r.method
                      and "weakest" not in r.method and r.source != NODE_SOURCE)  # DS of the 3 best
            cmp_ = res.comparison
            contacts = [c for c in run.node_contacts if c["state"] != "withdrawn" and c["bel"] >= s.fusion.report_bel]
            en = np.array([(c["east_m"], c["north_m"]) for c in contacts]).reshape(-1, 2)
            pairs = match(en, cmp_.truth_en)
            pos = float(np.median([np.hypot(*(en[i] - cmp_.truth_en[k])) for i, k in pairs])) if pairs else float("nan")
            row = {"option": name, "wall_s": wall, "pd": ds.pd, "fa": ds.false_alarms, "position_m": pos,
                   "model": run.model}
            if ref is None:
                ref = row
                row["error"] = "reference"
            elif name.startswith("detectors"):
                row["error"] = f"scores: max {score_error(base, s, first_tile):.2g} std"
            elif name.startswith("grid"):
                row["error"] = f"position: median {pos:.2f} m (default {ref['position_m']:.2f} m)"
            else:
                dpd, dtau = model_error(ref["model"], run.model)
                row["error"] = f"P(y): mean abs diff {dpd:.3f}; tau: max rel. diff {dtau:.2f}"
            rows.append(row)
    print(f"Speed options on one generated mission ({args.seabed}, seed {args.seed}, {len(truth)} targets); fusion of "
          f"the three best detectors with missed-detection evidence at Bel >= {base.fusion.report_bel:g}.\n")
    print("| option | run time (s) | Pd | dPd | false alarms | dFA | error in what it approximates |")
    print("|---|---:|---:|---:|---:|---:|---|")
    for r in rows:
        print(f"| {r['option']} | {r['wall_s']:.1f} | {r['pd']:.2f} | {r['pd'] - ref['pd']:+.2f} | {r['fa']:g} | "
              f"{r['fa'] - ref['fa']:+g} | {r['error']} |")
    if args.json:
        Path(args.json).write_text(json.dumps([{k: v for k, v in r.items() if k != "model"} for r in rows], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
