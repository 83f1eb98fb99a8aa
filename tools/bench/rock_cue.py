"""A cue against rocks, measured on the held-out generator's development seeds (issue 17).

At Pd 0.8 almost every false alarm of the node lies on one of the generator's rocks
(``fa_anatomy``, docs/evaluation.md), and the four detectors' responses cannot tell those
rocks from targets. This part measures one image cue that might, **highlight peakedness**:
in a window of +-1.5 m along-track and +-2 m in range about a place, the mean of its 5
brightest pixels over the mean of its 50 brightest (a flat face or a cylinder returns a few
specular pixels, a rounded rock spreads its echo; the ratio needs no background level).
Nothing in the node uses it (docs/fusion.md, "Next: a cue against rocks" says what building it
would take). Per scene it reports:

- the cue's AUC between the contacts on a target and those on a rock at Bel >= 0.8, and the
  median cue of the targets, of those rocks, of injected targets (the calibration's own
  tracer and population, injected into the scene's units), of seabed cells, and of the false
  alarms at Bel >= 0.5 on no object (the seabed's texture, on SASSED real SAS imagery);
- the false alarms on the ROC at Pd 0.8 and 0.9 when contacts are ranked by Bel, and by Bel
  times a likelihood ratio of the cue that uses no truth, as the node could form it: a Gaussian
  in log cue fitted to the injected targets against one fitted to the mission's own contacts
  at Bel >= 0.3 (mostly clutter);
- with more than one seabed, an upper bound: a logistic model on (logit Bel, log cue) trained
  with the truth of the other seabeds' scenes and ranked on this one.

The cue of a contact is the largest over the units that image its position. Use development
seeds (the default, 201-204) only: this measures an idea, it must not choose a setting on the
held-out seeds.

    python tools/bench/quality.py rock-cue [--seeds 201,202,203,204] [--variants base] [--json F]
    python tools/bench/quality.py rock-cue --quick      # one small scene (smoke)
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

DEV_SEEDS = (201, 202, 203, 204)
WINDOW_ALONG_M = 1.5
WINDOW_RANGE_M = 2.0
TOP_FEW, TOP_MANY = 5, 50
LR_CAP = math.log(1000.0)
CLIPPED_SHARE = 1e-3
"""A unit clips when more than this share of its pixels sit at its largest value."""


def peakedness(pixels: np.ndarray, row: int, col: int, *, dx_m: float, dr_m: float) -> float:
    """Highlight peakedness about pixel (row, col): the mean of the ``TOP_FEW`` brightest
    finite pixels of the window over the mean of the ``TOP_MANY`` brightest (NaN where the
    window holds fewer than ``TOP_MANY`` finite pixels or no positive one)."""
    h = max(1, int(round(WINDOW_ALONG_M / dx_m)))
    w = max(1, int(round(WINDOW_RANGE_M / dr_m)))
    win = np.asarray(pixels[max(row - h, 0):row + h + 1, max(col - w, 0):col + w + 1], dtype=np.float64).ravel()
    win = win[np.isfinite(win)]
    if win.size < TOP_MANY:
        return math.nan
    top = -np.sort(-np.partition(win, win.size - TOP_MANY)[-TOP_MANY:])
    many = top.mean()
    return float(top[:TOP_FEW].mean() / many) if many > 0 else math.nan


def _views(units, point) -> list[tuple[int, int, int]]:
    """(unit index, row, column) of every unit whose ping passes within 0.3 m of ``point``
    with the point inside its swath."""
    out = []
    for k, (pix, g) in enumerate(units):
        i, r, off = g.locate(*point)
        if off <= 0.3 and g.ranges_m[0] <= r <= g.ranges_m[-1]:
            out.append((k, i, int(np.argmin(np.abs(g.ranges_m - r)))))
    return out


def _cue_at(units, point, dx_m: float) -> float:
    vals = []
    for k, i, j in _views(units, point):
        pix, g = units[k]
        vals.append(peakedness(pix, i, j, dx_m=dx_m, dr_m=float(np.median(np.diff(g.ranges_m)))))
    vals = [v for v in vals if math.isfinite(v)]
    return max(vals) if vals else math.nan


def _auc(pos, neg) -> float:
    a, b = np.asarray(pos, dtype=np.float64), np.asarray(neg, dtype=np.float64)
    if not a.size or not b.size:
        return math.nan
    return float((a[:, None] > b[None, :]).mean() + 0.5 * (a[:, None] == b[None, :]).mean())


def _gauss_llr(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """log N(x; a) - log N(x; b), each a Gaussian fitted to its sample, capped at +-ln 1000."""
    ma, sa = float(np.mean(a)), float(np.std(a)) + 1e-9
    mb, sb = float(np.mean(b)), float(np.std(b)) + 1e-9
    llr = (-0.5 * ((x - ma) / sa) ** 2 - math.log(sa)) - (-0.5 * ((x - mb) / sb) ** 2 - math.log(sb))
    return np.clip(llr, -LR_CAP, LR_CAP)


def _logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(np.asarray(p, dtype=np.float64), 1e-9, 1 - 1e-9)
    return np.log(p / (1 - p))


def _fit_logistic(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    from scipy.optimize import minimize

    a = np.column_stack([np.ones(len(y)), x])

    def nll(w):
        z = a @ w
        return float(np.sum(np.logaddexp(0.0, z) - y * z) + 1e-3 * w @ w)

    return minimize(nll, np.zeros(a.shape[1]), method="BFGS").x


def measure_scene(scene_dir: Path, settings, *, online: str, rng: np.random.Generator) -> dict:
    """The cue's figures on one scene (module docstring), and the arrays the upper bound needs."""
    from atr_node.commands.replay import build_model
    from atr_node.evaluation.methods import Comparison, fuse, run_pipeline
    from atr_node.evaluation.scoring import near_any, read_truth, roc
    from atr_node.io.atrlog import AtrLogReader
    from atr_node.simulation.inject import inject_targets
    import quality as Q

    scene = json.loads((scene_dir / "scene.json").read_text())
    dx = float(scene["dx_m"])
    units: list = []
    model, calibrator = build_model(settings, None, online, deterministic=True)
    run = run_pipeline(settings, AtrLogReader(scene_dir / "mission.atrlog"), model=model, online=calibrator,
                       keep_pixels=lambda px, g: units.append((np.array(px, dtype=np.float32), g)))
    truth = read_truth(scene_dir / "truth.csv")
    comp = Comparison(run, np.array([(t.lat_deg, t.lon_deg) for t in truth]).reshape(-1, 2))
    rocks, _ = Q._read_points(scene_dir / "clutter.csv", run.frame)
    one_leg, _ = Q._read_points(scene_dir / "one_leg.csv", run.frame)
    contacts, _ = fuse(run, tuple(settings.detectors.enabled), evidence="look")
    en = np.array([(c.east_m, c.north_m) for c in contacts], dtype=np.float64).reshape(-1, 2)
    bel = np.array([c.bel for c in contacts], dtype=np.float64)
    cue = np.array([_cue_at(units, p, dx) for p in en], dtype=np.float64)
    on_t = near_any(en, comp.truth_en)
    on_rock = near_any(en, rocks) & ~on_t
    # the calibration's own targets, injected into every third unit, and seabed cells
    injected, seabed = [], []
    pop = settings.calibration.population
    for pix, g in units[::3]:
        rows, cols = pix.shape
        dr = float(np.median(np.diff(g.ranges_m)))
        margin_r, margin_c = int(round(WINDOW_ALONG_M / dx)) + 1, int(round(WINDOW_RANGE_M / dr)) + 1
        if rows < 4 * margin_r or cols < 4 * margin_c:
            continue
        host = np.nan_to_num(pix, nan=0.0).astype(np.float64)
        img, placed = inject_targets(host, range0_m=float(g.ranges_m[0]), dr_m=dr, dx_m=dx,
                                     altitude_m=float(scene["altitude_m"]), n_targets=4, rng=rng,
                                     sensor=settings.sensor, simulation=settings.simulation,
                                     template=settings.template, population=pop,
                                     range_span_m=(float(g.ranges_m[0]) + 3.0, float(g.ranges_m[-1]) - 3.0))
        top = float(np.nanmax(pix)) if np.isfinite(pix).any() else math.nan
        if math.isfinite(top) and np.mean(pix == top) > CLIPPED_SHARE:
            # the recording clips (its full scale holds a plateau of pixels): the injected echo
            # is cut there too, as the calibration cuts it at the tile's full scale
            np.minimum(img, top, out=img)
        for t in placed:
            j = int(np.argmin(np.abs(g.ranges_m - t.range_m)))
            if margin_r <= t.row < rows - margin_r:
                injected.append(peakedness(img, int(t.row), j, dx_m=dx, dr_m=dr))
        for _ in range(4):
            seabed.append(peakedness(pix, int(rng.integers(margin_r, rows - margin_r)),
                                     int(rng.integers(margin_c, cols - margin_c)), dx_m=dx, dr_m=dr))
    injected = np.array([v for v in injected if math.isfinite(v)])
    seabed_v = np.array([v for v in seabed if math.isfinite(v)])
    ok = np.isfinite(cue)
    fa_rock = on_rock & (bel >= 0.8) & ok
    # published false alarms on no object at all: the seabed's texture (real SAS imagery on
    # the SASSED seabed), ripple crests, speckle
    fa_seabed = (bel >= 0.5) & ok & ~on_t & ~near_any(en, rocks) & ~near_any(en, one_leg)
    out = {"scene": scene_dir.name, "contacts": int(len(contacts)),
           "auc_targets_vs_rocks_bel08": round(_auc(cue[on_t & ok], cue[fa_rock]), 3),
           "median_cue": {"targets": _median(cue[on_t & ok]), "rocks_bel08": _median(cue[fa_rock]),
                          "injected": _median(injected), "seabed": _median(seabed_v),
                          "seabed_false_alarms_bel05": _median(cue[fa_seabed])},
           "n": {"targets": int((on_t & ok).sum()), "rocks_bel08": int(fa_rock.sum()), "injected": int(injected.size),
                 "seabed_false_alarms_bel05": int(fa_seabed.sum())}}
    r0 = roc("Bel", en, bel, comp.truth_en)
    out["bel"] = [r0.fa_at_pd(0.8), r0.fa_at_pd(0.9)]
    clutter = np.log(cue[(bel >= 0.3) & ok])
    if injected.size >= 5 and clutter.size >= 5:
        x = np.log(np.where(ok, cue, math.exp(float(np.median(clutter)))))
        o = np.exp(_logit(bel) + _gauss_llr(x, np.log(injected), clutter))
        r1 = roc("Bel x cue", en, o / (1 + o), comp.truth_en)
        out["bel_times_cue"] = [r1.fa_at_pd(0.8), r1.fa_at_pd(0.9)]
    return out, {"en": en, "bel": bel, "cue": cue, "truth_en": comp.truth_en, "on_t": on_t}


def _median(v) -> float | None:
    v = np.asarray(v, dtype=np.float64)
    return round(float(np.median(v)), 3) if v.size else None


def upper_bound(results: list[dict], arrays: list[dict]) -> None:
    """Add ``upper_bound`` (FA at Pd 0.8 / 0.9) to each scene: a logistic model on (logit Bel,
    log cue) trained with the truth of the other seabeds' scenes (contacts at Bel >= 0.3)."""
    from atr_node.evaluation.scoring import roc

    seabed = [r["scene"].split("-")[0] for r in results]
    for k, (r, a) in enumerate(zip(results, arrays)):
        train = [i for i in range(len(results)) if seabed[i] != seabed[k]]
        if not train:
            continue
        xs, ys = [], []
        for i in train:
            b = arrays[i]
            keep = (b["bel"] >= 0.3) & np.isfinite(b["cue"])
            xs.append(np.column_stack([_logit(b["bel"][keep]), np.log(b["cue"][keep])]))
            ys.append(b["on_t"][keep].astype(np.float64))
        x, y = np.vstack(xs), np.concatenate(ys)
        mu, sd = x.mean(axis=0), x.std(axis=0) + 1e-9
        w = _fit_logistic((x - mu) / sd, y)
        cue = np.where(np.isfinite(a["cue"]), a["cue"], np.exp(np.nanmedian(np.log(a["cue"]))))
        z = (np.column_stack([_logit(a["bel"]), np.log(cue)]) - mu) / sd
        score = 1.0 / (1.0 + np.exp(-(w[0] + z @ w[1:])))
        c = roc("upper bound", a["en"], score, a["truth_en"])
        r["upper_bound"] = [c.fa_at_pd(0.8), c.fa_at_pd(0.9)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="quality.py rock-cue", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seabeds", default="sand,ripples,sassed")
    ap.add_argument("--seeds", default=",".join(map(str, DEV_SEEDS)), help="development seeds (default 201-204)")
    ap.add_argument("--variants", default="base", help="scene variants (atr_node.evaluation.heldout.VARIANTS)")
    ap.add_argument("--config", default=None, help="node settings (TOML; default built-in)")
    ap.add_argument("--online-calibration", choices=("on", "off"), default="on")
    ap.add_argument("--out", default="/tmp/atr-rock-cue", help="folder for the scenes")
    ap.add_argument("--json", default=None, help="write the figures as JSON here")
    ap.add_argument("--quick", action="store_true", help="one small sand scene (a smoke run)")
    args = ap.parse_args(argv)
    import quality as Q
    from atr_node.config import load_settings
    from atr_node.errors import AtrError
    from atr_node.evaluation.heldout import SEABEDS, VARIANTS, generate_scene

    try:
        settings = load_settings(args.config)
        seeds = [int(s) for s in args.seeds.split(",") if s]
    except (AtrError, ValueError) as exc:
        print(f"rock-cue: {exc}", file=sys.stderr)
        return 2
    seabeds = [s for s in args.seabeds.split(",") if s]
    variants = [v for v in args.variants.split(",") if v]
    if [s for s in seabeds if s not in SEABEDS] or [v for v in variants if v not in VARIANTS] or not seabeds:
        print(f"rock-cue: expected seabeds of {list(SEABEDS)} and variants of {list(VARIANTS)}", file=sys.stderr)
        return 2
    if set(seeds) & set(Q.SEEDS):
        print(f"rock-cue: seeds {sorted(set(seeds) & set(Q.SEEDS))} are the held-out ones: measure on others",
              file=sys.stderr)
        return 2
    legs, length = 5, 200.0
    if args.quick:
        seabeds, seeds, variants, legs, length = ["sand"], [seeds[0]], variants[:1], 2, 60.0
    out = Path(args.out)
    try:
        lock = Q._lock_folder(out)
    except OSError as exc:
        print(f"rock-cue: {exc}", file=sys.stderr)
        return 2
    rng = np.random.default_rng(5)
    results, arrays = [], []
    with lock:
        for variant in variants:
            for sb in seabeds:
                for seed in seeds:
                    d = out / (f"{sb}-{seed}-{legs}x{length:g}" + ("" if variant == "base" else f"-{variant}"))
                    if not Q._reusable(d, sb, seed, legs, length, variant):
                        generate_scene(d, seabed=sb, seed=seed, legs=legs, leg_length_m=length, variant=variant)
                    print(f"{d.name}: measuring ...", file=sys.stderr, flush=True)
                    r, a = measure_scene(d, settings, online=args.online_calibration, rng=rng)
                    results.append(r)
                    arrays.append(a)
    upper_bound(results, arrays)
    print("| scene | AUC cue (targets vs rocks at Bel >= 0.8) | median cue: targets / rocks / injected / seabed cells "
          "/ false alarms on the seabed at Bel >= 0.5 (how many) | FA at Pd 0.8, 0.9: Bel | Bel x cue (no truth) "
          "| upper bound (truth of other seabeds) |")
    print("|---|---:|---|---|---|---|")
    tot = {k: [0.0, 0.0] for k in ("bel", "bel_times_cue", "upper_bound")}
    for r in results:
        m = r["median_cue"]
        print(f"| {r['scene']} | {r['auc_targets_vs_rocks_bel08']} | {m['targets']} / {m['rocks_bel08']} / "
              f"{m['injected']} / {m['seabed']} / {m['seabed_false_alarms_bel05']} ({r['n']['seabed_false_alarms_bel05']}) "
              f"| {r['bel']} | {r.get('bel_times_cue', '-')} | {r.get('upper_bound', '-')} |")
        for k in tot:
            if k in r:
                tot[k] = [a + b for a, b in zip(tot[k], r[k])]
    print("\ntotals, FA at Pd 0.8 / 0.9: " + "; ".join(f"{k} {v[0]:g} / {v[1]:g}" for k, v in tot.items()))
    if args.json:
        Q._write_whole(Path(args.json), json.dumps({"command": "python tools/bench/quality.py rock-cue "
                                                    + " ".join(argv or []), "scenes": results, "totals": tot},
                                                   indent=1, default=float) + "\n")
    return 0
