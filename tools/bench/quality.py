"""Held-out quality benchmark (issue 17): the node's contacts on scenes it was never tuned on.

Scenes come from ``atr_node.evaluation.heldout``, a generator written independently of the
node's own simulator (which also makes the calibration's signatures), on three seabeds (sand,
ripples, the SASSED textures) and seeds that never chose a setting: tune on other seeds.
Each scene is replayed once through the node's pipeline (default settings, on-line calibration
as the node does it); every method then works on the same detections:

- **DS look**: the node's default (SPEC 6.1: one piece per look, prior per area);
- **DS paper**: per-detector evidence, detectors independent, prior 0.1 (the paper);
- **AND-3**: AND of the three best detectors (ranked on this scene's own ROCs: favours it);
- **OR**: any of the four; **vote**: at least 2 of the 4 detectors within the gate.

Per scene: Pd max; false alarms at Pd 0.8, 0.9 and at the max; the operating point (the
contacts the node publishes, Bel >= report_bel); the share of contacts at Bel >= 0.999; a
reliability table (Bel bin -> share of contacts that are targets); one-leg objects above
report_bel, all of them and those another look covered at Pd >= 0.8 as the node saw it
(:func:`covering_legs`; the issue's criterion counts these); targets seen on >= 2 looks above
report_bel; contacts without a detection; DS look's false alarms on its ROC at each baseline's
own Pd (``fa_at_pd_of``: the issue's "fewer false alarms at equal Pd", :func:`checks`); what
each DS form's false alarms lie on, at Pd 0.8 on its ROC and at the operating point
(``fa_anatomy``: a second contact on a target, a one-leg object, a target-like rock, another
rock, the seabed; :func:`atr_node.evaluation.scoring.fa_anatomy`, the generator's rocks as the
clutter); how well the look P(y) predicts the looks' detections (``look_pd``: log loss and
Brier per range band over every target and leg whose look covered it, :func:`look_pd_pairs`).

Then the shared real side-scan recordings (``--recordings``; they have no ground truth): per
method the contacts it publishes, the objects read by eye it finds (the marks of
``tools/figures/real_recordings.py``) and the contacts on the Iver2 wreck; for DS the share at
Bel >= 0.999 and the contacts without a detection.

    python tools/bench/quality.py                      # 3 seabeds x 3 seeds, ~4 min
    python tools/bench/quality.py --quick              # 1 small scene (smoke)
    python tools/bench/quality.py --json out.json --out /tmp/quality
    atr-node bench quality

Scenes are kept in ``--out`` and reused by later runs when their ``scene.json`` says the same
generator version, seabed, seed and size; anything else there (an older generator's scene, one
a run was interrupted in) is generated again. One run at a time per ``--out``: a second run on
a folder in use stops at once with one line (two runs on one folder once scored each other's
half-written scenes).

Exit codes: 0 ok, 1 a scene failed, 2 usage (including ``--out`` in use by another run).
"""

from __future__ import annotations

import argparse
import functools
import csv
import fcntl
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
sys.path.insert(0, str(Path(__file__).resolve().parent))
import harness  # noqa: E402  (tools/bench/harness.py: repeats, warm-up, statistics, JSON)
from atr_node.evaluation.scoring import FA_KINDS, near_any  # noqa: E402

BEL_BINS = (0.0, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99, 0.999, 1.0 + 1e-12)
SEEDS = (101, 102, 103)
"""Held-out seeds: reported, never used to choose a setting (tuning uses other seeds)."""


def _vote(records, gate_m: float, k: int):
    """Contacts where at least ``k`` distinct detectors fired within the gate."""
    from atr_node.fusion.baselines import group_detections

    n, labels = group_detections(records, gate_m=gate_m)
    out = []
    for g in range(n):
        idx = np.flatnonzero(labels == g)
        if len({records[i].detector for i in idx}) >= k:
            w = np.array([max(records[i].confidence, 1e-12) for i in idx])
            e = float(np.sum(w * [records[i].east_m for i in idx]) / w.sum())
            nn = float(np.sum(w * [records[i].north_m for i in idx]) / w.sum())
            out.append((e, nn))
    return np.array(out).reshape(-1, 2)


def _read_points(path: Path, frame) -> tuple[np.ndarray, list[dict]]:
    if not path.is_file():
        return np.zeros((0, 2)), []
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        return np.zeros((0, 2)), []
    lat = np.array([float(r["lat_deg"]) for r in rows])
    lon = np.array([float(r["lon_deg"]) for r in rows])
    return np.column_stack(frame.to_frame(lat, lon)), rows


_near = near_any
"""Per point, whether another lies within 3 m (:func:`atr_node.evaluation.scoring.near_any`)."""


ONE_LEG_PD = 0.8
"""Issue 17: the one-leg objects judged are those another look covered at Pd >= this."""


def covering_legs(run, point_en, detectors, *, pd_min: float = ONE_LEG_PD, max_off_m: float = 1.0) -> set[int]:
    """Legs whose look covered ``point_en`` (east, north in ``run.frame``) with its look P(y) >=
    ``pd_min``, as the node saw it (:func:`covering_pd`)."""
    return {leg for leg, pd in covering_pd(run, point_en, detectors, max_off_m=max_off_m).items() if pd >= pd_min}


def covering_pd(run, point_en, detectors, *, max_off_m: float = 1.0) -> dict[int, float]:
    """Leg -> the look's P(y) at ``point_en`` for every leg whose look covered it, as the node saw
    it: a unit of the leg has a ping whose beam passes within ``max_off_m`` of the point on the
    unit's side, the point lies in the swath, a detector covered the pixel there (its score is
    not NaN: not in the nadir gap, the first-return band or a dropped ping); the P(y) is the
    unit's model's look ``Pd(r)`` at that range (the per-detector maximum for a model without
    look tables), the largest over the leg's units that cover the point."""
    legs: dict[int, float] = {}
    for u, _r, pd in _covering_units(run, point_en, detectors, max_off_m):
        legs[u.leg] = max(pd, legs.get(u.leg, -math.inf))
    return legs


def _covering_units(run, point_en, detectors, max_off_m: float):
    """(unit, ground range, look P(y) there) for every unit whose look covered ``point_en``
    (:func:`covering_pd`'s rule)."""
    pe, pn = (float(v) for v in point_en)
    for u in run.units:
        i, r, off = u.geometry.locate(pe, pn)
        ranges = np.asarray(u.ranges_m, dtype=np.float64)
        if off > max_off_m or not ranges[0] <= r <= ranges[-1]:
            continue
        j = int(np.argmin(np.abs(ranges - r)))
        if not any(u.result.covered(d)[i, j] for d in detectors):
            continue
        table = u.model.look(detectors)
        yield u, float(r), (float(table.pd_at(r)) if table is not None
                            else max(float(u.model.pd(d, r)) for d in detectors))


PD_BANDS_M = ((0.0, 15.0), (15.0, 50.0), (50.0, math.inf))
"""Ground-range bands of the look P(y) fidelity: near the nadir, mid-swath, the swath's end."""


def look_pd_pairs(run, targets_en, detectors, *, gate_m: float = 3.0, max_off_m: float = 1.0
                  ) -> list[tuple[float, float, bool]]:
    """(ground range, look P(y), detected) per target and leg whose look covered it: the P(y) the
    node used for that look (:func:`covering_pd`: the largest over the leg's units, at the range
    of the unit that gave it) and whether a detection of that leg within ``gate_m`` of the
    target made a look detection under its unit's look table (fired, ``z`` past the table's
    threshold: :meth:`~atr_node.calibration.model.DetectorPerformance.detects`). A calibrated
    P(y) predicts the share detected (docs/calibration.md, "P(y) at the swath's end")."""
    out = []
    for pe, pn in np.asarray(targets_en, dtype=np.float64).reshape(-1, 2):
        legs: dict[int, list] = {}
        for u, r, pd in _covering_units(run, (pe, pn), detectors, max_off_m):
            if u.leg not in legs or pd > legs[u.leg][1]:
                legs[u.leg] = [r, pd, False]
        for u in run.units:
            if u.leg not in legs or legs[u.leg][2]:
                continue
            table = u.model.look(detectors)
            for d in detectors:
                for x in u.result.detections.get(d, ()):
                    xe, xn = u.geometry.world(x.row, x.col)
                    if math.hypot(float(xe) - pe, float(xn) - pn) > gate_m:
                        continue
                    if table is None:  # no look tables: any detection detects
                        legs[u.leg][2] = True
                        continue
                    joint = dict(x.joint) if x.joint is not None else {d: x.gamma}
                    z = u.model.look_score({k: np.float64(v) for k, v in joint.items()}, detectors,
                                           headroom_db=x.headroom_db)
                    legs[u.leg][2] |= bool(table.detects(z))
        out += [tuple(v) for v in legs.values()]
    return out


def pd_fidelity(pairs) -> dict:
    """Log loss and Brier score of the look P(y) against the looks' detections (P(y) clipped to
    [1e-3, 1 - 1e-3] for the log), overall and per :data:`PD_BANDS_M` band."""
    a = np.asarray([(r, pd, float(det)) for r, pd, det in pairs], dtype=np.float64).reshape(-1, 3)

    def figs(m) -> dict:
        p, y = np.clip(a[m, 1], 1e-3, 1 - 1e-3), a[m, 2]
        n = int(m.sum())
        if n == 0:
            return {"pairs": 0}
        ll = -np.where(y > 0, np.log(p), np.log1p(-p))
        return {"pairs": n, "log_loss": round(float(ll.mean()), 4), "brier": round(float(((p - y) ** 2).mean()), 4),
                "model_pd": round(float(a[m, 1].mean()), 3), "detected": round(float(y.mean()), 3)}

    out = figs(np.ones(len(a), dtype=bool))
    out["bands"] = [{"range_m": [lo, hi if math.isfinite(hi) else None], **figs((a[:, 0] >= lo) & (a[:, 0] < hi))}
                    for lo, hi in PD_BANDS_M]
    return out


def _threshold_at_pd(curve, pd: float) -> float | None:
    """The score threshold of the curve's point with the fewest false alarms at Pd >= ``pd``
    (the point ``fa_at_pd`` reads; None when the curve never reaches it)."""
    pts = [p for p in curve.points if p.pd >= pd - 1e-12 and math.isfinite(p.threshold)]
    return min(pts, key=lambda p: (p.false_alarms, -p.threshold)).threshold if pts else None


def _en(contacts) -> np.ndarray:
    return np.array([(c.east_m, c.north_m) for c in contacts], dtype=np.float64).reshape(-1, 2)


def _reliability(contacts, truth_en: np.ndarray) -> list[dict]:
    """Per Bel bin: contacts and the share within 3 m of a target (each contact judged on its
    own: several contacts on one target all count as on a target)."""
    if not contacts:
        return []
    bel = np.array([x.bel for x in contacts])
    on = _near(_en(contacts), truth_en)
    rows = []
    for lo, hi in zip(BEL_BINS[:-1], BEL_BINS[1:]):
        k = (bel >= lo) & (bel < hi)
        if k.any():
            rows.append({"bel": f"[{lo:g}, {min(hi, 1.0):g}{']' if hi > 1 else ')'}", "contacts": int(k.sum()),
                         "targets": round(float(on[k].mean()), 3), "on_target": int(on[k].sum())})
    return rows


def pooled_reliability(results: list[dict]) -> dict[str, dict]:
    """DS look's reliability tables summed over the scenes of each variant ("base", "byte", ...):
    per Bel bin the contacts, those on a target, the share and its 95 % Wilson interval, and
    whether the shares rise (each at least the one below less 0.05, over bins of 3 or more
    contacts: the per-scene check's rule). A scene's bins hold 1-30 contacts, where one contact
    moves a share by 3-100 %; pooled over a variant's 9 scenes they hold 30-400."""
    from atr_node.calibration.stats import wilson_interval

    out: dict[str, dict] = {}
    for r in results:
        group = out.setdefault(r.get("variant", "base"), {"scenes": 0, "bins": {}})
        group["scenes"] += 1
        for row in r["methods"]["DS look (default)"]["reliability"]:
            b = group["bins"].setdefault(row["bel"], [0, 0])
            b[0] += row["contacts"]
            b[1] += row.get("on_target", round(row["contacts"] * row["targets"]))
    for group in out.values():
        rows = []
        for lo, hi in zip(BEL_BINS[:-1], BEL_BINS[1:]):
            label = f"[{lo:g}, {min(hi, 1.0):g}{']' if hi > 1 else ')'}"
            if label not in group["bins"]:
                continue
            n, k = group["bins"][label]
            low, high = wilson_interval(k, n)
            rows.append({"bel": label, "contacts": n, "on_target": k, "share": round(k / n, 3),
                         "low": round(float(low), 3), "high": round(float(high), 3)})
        shares = [x["share"] for x in rows if x["contacts"] >= 3]
        group["bins"] = rows
        group["rises"] = bool(all(b >= a - 0.05 for a, b in zip(shares, shares[1:])))
    return out


def pooled_pd_fidelity(results: list[dict]) -> dict[str, dict]:
    """:func:`pd_fidelity` of every scene's look P(y) pairs pooled, per variant (as
    :func:`pooled_reliability` names them)."""
    groups: dict[str, list] = {}
    for r in results:
        if "look_pd" in r:
            groups.setdefault(r.get("variant", "base"), []).extend(r["look_pd"]["rows"])
    return {name: pd_fidelity(pairs) for name, pairs in groups.items()}


def pooled_fa_anatomy(results: list[dict]) -> dict[str, dict]:
    """:func:`fa_anatomy` summed over the scenes of each variant, per DS form and point:
    ``{"base / DS look (default)": {"Pd 0.8": {...}, "op": {...}}, ...}`` (a scene whose ROC
    never reaches Pd 0.8 adds nothing there)."""
    out: dict[str, dict] = {}
    for r in results:
        for name, f in r["methods"].items():
            for at, a in f.get("fa_anatomy", {}).items():
                g = out.setdefault(f"{r.get('variant', 'base')} / {name}", {}).setdefault(
                    "Pd 0.8" if at == "0.8" else "op", dict.fromkeys(("false_alarms",) + FA_KINDS, 0))
                for k in g:
                    g[k] += int(a[k])
    return out


def pooled_checks(results: list[dict]) -> dict[str, dict]:
    """The done-means of :func:`checks` with each scene's counts summed over the scenes of a
    variant (as :func:`pooled_reliability` names them). A scene holds 13-14 multi-look targets
    and 3-6 covered one-leg objects, so one look more or less decides its check; pooled, the
    shares get a 95 % Wilson interval. This is a reading aid beside the per-scene checks, not
    a replacement: the issue asks them per scene.

    Per variant: ``targets``; ``pd_max`` (targets on a DS look contact at any Bel, and on OR's);
    ``fewer`` (per baseline, DS look's false alarms on its ROC at the baseline's own Pd, summed,
    against the baseline's; at Pd 0.8 and 0.9 against DS paper, over the scenes where both
    reach it); ``op`` (false alarms at the operating point against the ROC's at the same Pd);
    ``no_detection``; ``one_leg`` (covered one-leg objects below ``report_bel``) and
    ``multi_look`` (multi-look targets above it), each ``[k, n, share, low, high]``;
    ``reliability_rises`` (:func:`pooled_reliability`); ``scenes_passing`` per check."""
    from atr_node.calibration.stats import wilson_interval

    def share(k: int, n: int) -> list:
        low, high = wilson_interval(k, n)
        return [k, n, round(k / n, 3) if n else None, round(float(low), 3), round(float(high), 3)]

    rel = pooled_reliability(results)
    out: dict[str, dict] = {}
    for r in results:
        name = r.get("variant", "base")
        g = out.setdefault(name, {"scenes": 0, "targets": 0, "pd_max": {"DS look": 0, "OR": 0}, "fewer": {},
                                  "op": {"false_alarms": 0, "roc_at_op_pd": 0.0}, "no_detection": 0,
                                  "_one_leg": [0, 0], "_multi": [0, 0], "scenes_passing": {}})
        m = r["methods"]
        ds, paper = m["DS look (default)"], m["DS paper (prior 0.1)"]
        g["scenes"] += 1
        g["targets"] += int(r["targets"])
        g["pd_max"]["DS look"] += int(round(ds["pd_max"] * r["targets"]))
        g["pd_max"]["OR"] += int(round(m["OR"]["pd_max"] * r["targets"]))
        for base, ds_fa in ds.get("fa_at_pd_of", {}).items():
            kind = base.split(" (")[0]  # "AND-3 (mf+z+lac)": the best three differ by scene
            if math.isfinite(ds_fa) and math.isfinite(m[base]["op_fa"]):
                f = g["fewer"].setdefault(kind, {"scenes": 0, "DS look": 0.0, kind: 0.0})
                f["scenes"] += 1
                f["DS look"] += ds_fa
                f[kind] += m[base]["op_fa"]
        for p in ("0.8", "0.9"):
            a, b = ds.get(f"fa_at_{p}", math.inf), paper.get(f"fa_at_{p}", math.inf)
            if math.isfinite(a) and math.isfinite(b):
                f = g["fewer"].setdefault(f"DS paper at Pd {p}", {"scenes": 0, "DS look": 0.0, "DS paper": 0.0})
                f["scenes"] += 1
                f["DS look"] += a
                f["DS paper"] += b
        g["op"]["false_alarms"] += int(ds["op_fa"])
        g["op"]["roc_at_op_pd"] += float(ds["roc_fa_at_op_pd"])
        g["no_detection"] += int(ds["no_detection"])
        n1, a1 = int(ds["one_leg_covered_objects"]), int(ds["one_leg_covered_above_report"])
        g["_one_leg"][0] += n1 - a1
        g["_one_leg"][1] += n1
        g["_multi"][0] += int(ds["multi_look_above_report"])
        g["_multi"][1] += int(ds["multi_look_targets"])
        for k, v in r.get("checks", {}).items():
            g["scenes_passing"][k] = g["scenes_passing"].get(k, 0) + bool(v)
    for name, g in out.items():
        g["one_leg"] = share(*g.pop("_one_leg"))
        g["multi_look"] = share(*g.pop("_multi"))
        g["reliability_rises"] = bool(rel.get(name, {}).get("rises", False))
    return out


def _pct(share: list) -> str:
    """A :func:`pooled_checks` share ``[k, n, share, low, high]`` in per cent with its interval."""
    return "-" if share[2] is None else f"{100 * share[2]:.1f} % [{100 * share[3]:.1f}, {100 * share[4]:.1f}]"


def pooled_checks_markdown(pooled: dict[str, dict]) -> list[str]:
    """:func:`pooled_checks` as Markdown lines, one block per variant."""
    lines = []
    for name, g in pooled.items():
        ol, ml = g["one_leg"], g["multi_look"]
        # each "fewer" entry holds DS look's sum and the baseline's under the baseline's name
        # ("DS paper" for the two Pd points read against the paper's ROC)
        fewer = "; ".join(f"{k} {v['DS look']:g} against {v['DS paper' if k.startswith('DS paper') else k]:g}"
                          f" ({v['scenes']} of {g['scenes']} scenes)" for k, v in g["fewer"].items())
        passing = ", ".join(f"{k} {v}" for k, v in g["scenes_passing"].items())
        lines += [f"- {name} ({g['scenes']} scenes, {g['targets']} targets):",
                  f"  - targets on a contact at any Bel: DS look {g['pd_max']['DS look']}, OR {g['pd_max']['OR']}",
                  f"  - false alarms at equal Pd, DS look against each: {fewer}",
                  f"  - operating point: {g['op']['false_alarms']} false alarms, the ROC's at the same Pd "
                  f"{g['op']['roc_at_op_pd']:g} (ratio {g['op']['false_alarms'] / max(g['op']['roc_at_op_pd'], 1):.2f})",
                  f"  - contacts without a detection: {g['no_detection']}",
                  f"  - covered one-leg objects below report_bel: {ol[0]} of {ol[1]}, {_pct(ol)}",
                  f"  - multi-look targets above report_bel: {ml[0]} of {ml[1]}, {_pct(ml)}",
                  f"  - pooled reliability rises: {'yes' if g['reliability_rises'] else 'NO'}",
                  f"  - scenes passing each check: {passing}"]
    return lines


def _curve_figures(curve) -> dict:
    pdmax = curve.best_pd()
    f = {"pd_max": round(pdmax, 3), "fa_at_max": curve.fa_at_pd(pdmax) if pdmax > 0 else 0.0}
    for p in (0.8, 0.9):
        f[f"fa_at_{p}"] = curve.fa_at_pd(p)
    return f


DS_METHODS = (("DS look (default)", {"evidence": "look"}),
              ("DS paper (prior 0.1)", {"evidence": "paper", "prior_target": 0.1}))
"""The two Dempster-Shafer forms every scene and recording is scored with (fusion options)."""


def _share_999(contacts) -> float:
    """Share of ``contacts`` at Bel >= 0.999 (0 without contacts)."""
    return round(float(np.mean([c.bel >= 0.999 for c in contacts])) if contacts else 0.0, 3)


def score_scene(scene_dir: Path, settings, *, online: str, progress=None) -> dict:
    """Every method's figures on one scene (see the module docstring)."""
    from atr_node.commands.replay import build_model
    from atr_node.evaluation.methods import Comparison, fuse, node_like_contacts, _records
    from atr_node.evaluation.scoring import fa_anatomy, operating_point, read_clutter, read_truth
    from atr_node.io.atrlog import AtrLogReader

    model, calibrator = build_model(settings, None, online, deterministic=True)
    from atr_node.evaluation.methods import run_pipeline

    t0 = time.monotonic()
    run = run_pipeline(settings, AtrLogReader(scene_dir / "mission.atrlog"), model=model, online=calibrator)
    truth = read_truth(scene_dir / "truth.csv")
    comp = Comparison(run, np.array([(t.lat_deg, t.lon_deg) for t in truth]).reshape(-1, 2))
    en = tuple(settings.detectors.enabled)
    report = settings.fusion.report_bel
    singles = {d: comp.single(d) for d in en}
    best3 = comp.ranking(singles)[:3]
    out: dict = {"scene": scene_dir.name, "targets": len(truth), "methods": {}}
    one_leg, one_leg_rows = _read_points(scene_dir / "one_leg.csv", run.frame)
    # issue 17 judges the one-leg objects that another look covered at Pd >= 0.8: the
    # generator's covered_by_legs counts 5-60 m, where the node may see nothing (first return)
    judged = np.array([bool(covering_legs(run, p, en) - {int(r["shown_on_leg"])}) for p, r in zip(one_leg, one_leg_rows)],
                      dtype=bool).reshape(-1)
    rocks, _ = _read_points(scene_dir / "clutter.csv", run.frame)
    rock_like = (read_clutter(scene_dir / "clutter.csv").target_like if (scene_dir / "clutter.csv").is_file()
                 else np.zeros(0, dtype=bool))
    t_en, t_rows = _read_points(scene_dir / "truth.csv", run.frame)
    multi = np.array([int(r.get("looks") or 0) >= 2 for r in t_rows], dtype=bool)
    ds_curve = None
    for name, kw in DS_METHODS:
        contacts, grid = fuse(run, en, **kw)
        curve = comp._roc(name, contacts)
        if ds_curve is None:
            ds_curve = curve  # DS default's ROC: its false alarms at each baseline's Pd (checks)
        live = node_like_contacts(run, grid)
        at_node = [c for c in live if c.bel >= report]
        at_en = _en(at_node)
        on_one_leg = _near(one_leg, at_en)
        op = operating_point(name, at_en, comp.truth_en)
        p = op.points[0]
        fig = _curve_figures(curve)
        anatomy = {}
        for label, thr in (("0.8", _threshold_at_pd(curve, 0.8)), ("op", report)):
            if thr is not None:
                src = contacts if label != "op" else at_node
                anatomy[label] = fa_anatomy(_en(src), [c.bel for c in src], comp.truth_en, threshold=thr,
                                            clutter_en=rocks, clutter_target_like=rock_like, one_leg_en=one_leg)
        fig["fa_anatomy"] = anatomy
        fig.update({"op_pd": round(p.pd, 3), "op_fa": p.false_alarms,
                    "roc_fa_at_op_pd": curve.fa_at_pd(p.pd) if p.pd > 0 else 0.0,
                    "share_bel_999": _share_999(at_node),
                    "reliability": _reliability(contacts, comp.truth_en),
                    "one_leg_objects": int(len(one_leg)),
                    "one_leg_above_report": int(on_one_leg.sum()),
                    "one_leg_covered_objects": int(judged.sum()),
                    "one_leg_covered_above_report": int((on_one_leg & judged).sum()),
                    "multi_look_targets": int(multi.sum()),
                    "multi_look_above_report": int(_near(t_en[multi], at_en).sum()),
                    "no_detection": int(sum(1 for c in live if c.detections == 0))})
        out["methods"][name] = fig
    recs = [r for d in en for r in _records(run, d, None)]
    for name, curve in ((f"AND-3 ({'+'.join(best3)})", comp.logical("and", best3)),
                        ("OR", comp.logical("or", en)),
                        ("vote 2 of 4", operating_point("vote", _vote(recs, comp.gate_m, 2), comp.truth_en))):
        p = curve.points[0]
        out["methods"][name] = {"pd_max": round(p.pd, 3), "fa_at_max": p.false_alarms, "op_pd": round(p.pd, 3),
                                "op_fa": p.false_alarms}
        # "at equal Pd": DS default's ROC read at this method's own Pd (unrounded), not at the
        # next of the few points recorded above it
        out["methods"][DS_METHODS[0][0]].setdefault("fa_at_pd_of", {})[name] = (
            ds_curve.fa_at_pd(p.pd) if p.pd > 0 else 0.0)
    pairs = look_pd_pairs(run, t_en, en)
    out["look_pd"] = {**pd_fidelity(pairs), "rows": [[round(r, 2), round(pd, 4), bool(det)] for r, pd, det in pairs]}
    out["leg_shifts"] = leg_shift_figures(scene_dir, run)
    out["seconds"] = round(time.monotonic() - t0, 1)
    out["checks"] = checks(out, settings)
    return out


def leg_shift_figures(scene_dir: Path, run) -> list[dict]:
    """Per pair of legs, the node's measured shift (:mod:`atr_node.fusion.navcheck`, from
    ``run.stats``) against the generator's truth (:func:`~atr_node.evaluation.heldout.leg_shift_truth`
    over the scene's targets and rocks both legs image; empty without a ``scene.json``)."""
    from atr_node.evaluation.heldout import leg_shift_truth

    info_path = scene_dir / "scene.json"
    if not info_path.is_file():
        return []
    info = json.loads(info_path.read_text())
    pts = []
    for name in ("truth.csv", "clutter.csv", "one_leg.csv"):
        if (scene_dir / name).is_file():
            with open(scene_dir / name, newline="") as fh:
                pts += [(float(r["east_m"]), float(r["north_m"])) for r in csv.DictReader(fh)]
    out = []
    for x in run.stats.get("leg_shifts", ()):
        t = leg_shift_truth(info, x["leg_a"], x["leg_b"], np.array(pts))
        out.append({**x, "truth_east_m": None if t is None else round(float(t[0]), 3),
                    "truth_north_m": None if t is None else round(float(t[1]), 3),
                    "truth_distance_m": None if t is None else round(float(np.hypot(*t)), 3),
                    "error_m": (None if t is None
                                else round(float(np.hypot(x["east_m"] - t[0], x["north_m"] - t[1])), 3))})
    return out


def pooled_leg_shifts(results: list[dict]) -> dict[str, dict]:
    """Per variant: pairs of legs whose shift the check believes (the rule it flags by,
    :func:`atr_node.fusion.navcheck.believed`), their error against the truth (median, 90th
    percentile, largest), pairs flagged beyond the gate, and the largest true shift among them."""
    from atr_node.fusion.navcheck import believed

    groups: dict[str, list[dict]] = {}
    for r in results:
        groups.setdefault(r.get("variant", "base"), []).extend(
            x for x in r.get("leg_shifts", ())
            if believed(x["support"], x.get("chance", 0.0)) and x["error_m"] is not None)
    out = {}
    for name, xs in groups.items():
        if not xs:
            continue
        err = np.array([x["error_m"] for x in xs])
        out[name] = {"pairs": len(xs), "error_median_m": round(float(np.median(err)), 2),
                     "error_p90_m": round(float(np.percentile(err, 90)), 2), "error_max_m": round(float(err.max()), 2),
                     "flagged": sum(1 for x in xs if x["flagged"]),
                     "truth_distance_max_m": round(max(x["truth_distance_m"] for x in xs), 2)}
    return out


@functools.lru_cache(maxsize=1)
def _variant_names() -> list[str]:
    from atr_node.evaluation.heldout import VARIANTS

    return list(VARIANTS)


def _real_tool():
    """tools/figures/real_recordings.py: the objects read by eye on the shared recordings and
    how a contact is matched to them (one definition for the figures and this benchmark)."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "figures" / "real_recordings.py"
    spec = importlib.util.spec_from_file_location("real_recordings", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def score_recording(path: Path, settings, *, online: str) -> dict:
    """Every method on one real recording without ground truth: the contacts each publishes,
    how many of the objects read by eye it finds (within 3 m on the waterfall, or in the
    wreck's box), and for DS the share at Bel >= 0.999 and the contacts without a detection.
    AND-3 here is the AND of every detector but the one with the most detections (no truth to
    rank them on)."""
    from atr_node.commands.replay import build_model
    from atr_node.evaluation.methods import _gate, _records, fuse, node_like_contacts, run_pipeline
    from atr_node.errors import AtrError
    from atr_node.evaluation.waterfall import locate_contacts
    from atr_node.fusion.baselines import and_contacts, or_contacts
    from atr_node.io.recording import open_recording
    from atr_node.records.tile import Tile

    rr = _real_tool()
    t0 = time.monotonic()
    rec = settings.recording
    records = list(open_recording(path, crs=rec.crs, altitude=rec.altitude, frequency=rec.frequency))
    tiles = [Tile.from_map(r.msg) for r in records if r.link == "sonar"]
    if not any(t.nav is not None for t in tiles):
        raise AtrError(f"{path}: no ping has a position: no contact can be placed on its waterfall")
    model, calibrator = build_model(settings, None, online, deterministic=True)
    run = run_pipeline(settings, records, model=model, online=calibrator)
    pings, frame, dx = rr.recording_pings(tiles, settings)
    en = tuple(settings.detectors.enabled)
    gate = _gate(settings)
    recs = {d: _records(run, d, None) for d in en}
    noisiest = max(en, key=lambda d: len(recs[d]))
    and3 = tuple(d for d in en if d != noisiest) if len(en) > 3 else en
    report = settings.fusion.report_bel

    def figures(east_north: np.ndarray) -> dict:
        lat, lon = run.frame.to_latlon(east_north[:, 0], east_north[:, 1]) if len(east_north) else ((), ())
        cs = [{"id": i, "lat_deg": float(a), "lon_deg": float(b)} for i, (a, b) in enumerate(zip(np.ravel(lat), np.ravel(lon)))]
        places = locate_contacts(pings, cs, frame)
        found, wreck = rr.match_marks(path.stem, places, dx)
        return {"contacts": len(cs), "placed": len(places), "marks": len(found),
                "marks_found": sum(1 for _, ids in found if ids), "found": {label: bool(ids) for label, ids in found},
                "wreck_contacts": None if wreck is None else len(wreck)}

    out: dict = {"recording": path.name, "methods": {}}
    for name, kw in DS_METHODS:
        _, grid = fuse(run, en, **kw)
        live = node_like_contacts(run, grid)
        at = [c for c in live if c.bel >= report]
        fig = figures(_en(at))
        fig["share_bel_999"] = _share_999(at)
        fig["no_detection"] = int(sum(1 for c in live if c.detections == 0))
        out["methods"][name] = fig
    all_recs = [r for d in en for r in recs[d]]
    for name, cs in ((f"AND-3 ({'+'.join(and3)})", and_contacts(all_recs, gate_m=gate, detectors=and3)),
                     ("OR", or_contacts(all_recs, gate_m=gate))):
        out["methods"][name] = figures(_en(cs))
    out["methods"]["vote 2 of 4"] = figures(_vote(all_recs, gate, 2))
    out["seconds"] = round(time.monotonic() - t0, 1)
    return out


def recordings_markdown(results: list[dict]) -> str:
    lines = ["| recording | method | contacts | objects read by eye found | wreck: contacts on it | Bel>=0.999 | no det |",
             "|---|---|---:|---:|---:|---:|---:|"]
    for r in results:
        for name, f in r["methods"].items():
            wreck = "-" if f["wreck_contacts"] is None else str(f["wreck_contacts"])
            lines.append(f"| {r['recording']} | {name} | {f['contacts']} | {f['marks_found']} of {f['marks']} | {wreck} "
                         f"| {f.get('share_bel_999', '-')} | {f.get('no_detection', '-')} |")
    return "\n".join(lines)


def checks(scene: dict, settings) -> dict:
    """The issue's done-means on one scene (True / False)."""
    m = scene["methods"]
    ds = m["DS look (default)"]
    paper = m["DS paper (prior 0.1)"]
    or_ = m["OR"]
    out = {}
    fewer = True
    for name, v in m.items():
        if name.startswith("DS look"):
            continue
        pd = v["op_pd"] if not name.startswith("DS paper") else None
        if pd is not None and pd > 0:
            at = ds.get("fa_at_pd_of", {})
            ds_fa = at[name] if name in at else _fa_at(ds, pd, scene)
            fewer &= ds_fa < v["op_fa"] or (ds_fa == 0 and v["op_fa"] == 0)
    for p in ("0.8", "0.9"):
        a, b = ds.get(f"fa_at_{p}", math.inf), paper.get(f"fa_at_{p}", math.inf)
        if math.isfinite(b):
            fewer &= a <= b
    out["ds_fewer_false_alarms"] = bool(fewer)
    out["pd_max_095_where_or_does"] = bool(or_["op_pd"] < 0.95 or ds["pd_max"] >= 0.95)
    out["op_within_2x_roc"] = bool(ds["op_fa"] <= 2 * ds["roc_fa_at_op_pd"] or ds["op_fa"] <= 2)
    out["no_contact_without_detection"] = ds["no_detection"] == 0
    n1 = ds["one_leg_covered_objects"]  # those another look covered at Pd >= 0.8
    a1 = ds["one_leg_covered_above_report"]
    out["one_leg_below_report_95pct"] = bool(n1 == 0 or (n1 - a1) / n1 >= 0.95)
    nm = ds["multi_look_targets"]
    out["multi_look_above_report_95pct"] = bool(nm == 0 or ds["multi_look_above_report"] / nm >= 0.95)
    rel = [r["targets"] for r in ds["reliability"] if r["contacts"] >= 3]
    out["reliability_rises"] = bool(all(b >= a - 0.05 for a, b in zip(rel, rel[1:])))
    return out


def _fa_at(fig: dict, pd: float, scene: dict) -> float:
    """DS's fewest false alarms at Pd >= pd, from the recorded points (pd_max, 0.8, 0.9): for a
    JSON written before ``fa_at_pd_of`` (it overstates DS at a baseline's Pd between them)."""
    cands = [(fig["pd_max"], fig["fa_at_max"])]
    for p in (0.8, 0.9):
        if math.isfinite(fig.get(f"fa_at_{p}", math.inf)):
            cands.append((p, fig[f"fa_at_{p}"]))
    ok = [fa for q, fa in cands if q >= pd - 1e-12]
    return min(ok) if ok else math.inf


def markdown(results: list[dict]) -> str:
    lines = ["| scene | method | Pd max | FA@0.8 | FA@0.9 | FA@max | op Pd | op FA | Bel>=0.999 | one-leg above | multi-look above | no det |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in results:
        for name, f in r["methods"].items():
            def g(k):
                v = f.get(k, "")
                return "-" if v == "" else ("inf" if isinstance(v, float) and math.isinf(v) else f"{v:g}" if isinstance(v, float) else str(v))
            ol = (f"{f['one_leg_above_report']}/{f['one_leg_objects']} (covered at Pd 0.8: "
                  f"{f['one_leg_covered_above_report']}/{f['one_leg_covered_objects']})" if "one_leg_objects" in f else "")
            ml = f"{f['multi_look_above_report']}/{f['multi_look_targets']}" if "multi_look_targets" in f else ""
            lines.append(f"| {r['scene']} | {name} | {g('pd_max')} | {g('fa_at_0.8')} | {g('fa_at_0.9')} | {g('fa_at_max')} "
                         f"| {g('op_pd')} | {g('op_fa')} | {g('share_bel_999')} | {ol} | {ml} | {g('no_detection')} |")
    lines.append("")
    lines.append("| scene | " + " | ".join(results[0]["checks"]) + " |" if results else "")
    if results:
        lines.append("|---|" + "---|" * len(results[0]["checks"]))
        for r in results:
            lines.append(f"| {r['scene']} | " + " | ".join("yes" if v else "NO" for v in r["checks"].values()) + " |")
        lines.append("")
        lines.append("Reliability (DS look, contacts down to Bel 0.02): Bel bin -> contacts, share on a target")
        for r in results:
            rel = r["methods"]["DS look (default)"]["reliability"]
            lines.append(f"- {r['scene']}: " + "; ".join(f"{x['bel']} {x['contacts']}, {x['targets']:.2f}" for x in rel))
        lines.append("")
        lines.append("What the false alarms lie on (within 3 m; the generator's truth, its rocks as the clutter): at Pd 0.8 "
                     "on each DS form's ROC, and at the operating point (Bel >= report_bel)")
        lines.append("")
        lines.append("| scene | method | at | false alarms | " + " | ".join(k.replace("_", " ") for k in FA_KINDS) + " |")
        lines.append("|---|---|---|---:|" + "---:|" * len(FA_KINDS))
        for r in results:
            for name, f in r["methods"].items():
                for at, a in f.get("fa_anatomy", {}).items():
                    lines.append(f"| {r['scene']} | {name} | {'Pd 0.8' if at == '0.8' else 'op'} | {a['false_alarms']} | "
                                 + " | ".join(str(a[k]) for k in FA_KINDS) + " |")
        for name, g in pooled_fa_anatomy(results).items():
            lines.append(f"- pooled, {name}: " + "; ".join(
                f"{at}: {a['false_alarms']} false alarms, " + ", ".join(f"{k.replace('_', ' ')} {a[k]}" for k in FA_KINDS)
                for at, a in g.items()))
        lines.append("")
        lines.append("Look P(y) against the looks' detections (target x covering leg; log loss, Brier; per range band: "
                     "pairs, mean model P(y) / share detected, log loss)")
        for name, f in pooled_pd_fidelity(results).items():
            lines.append(f"- {name}: {f['pairs']} pairs, log loss {f.get('log_loss', '-')}, Brier {f.get('brier', '-')}; " + "; ".join(
                f"{b['range_m'][0]:g}-{'' if b['range_m'][1] is None else format(b['range_m'][1], 'g')} m: {b['pairs']}"
                + (f", {b['model_pd']:.2f} / {b['detected']:.2f}, {b['log_loss']}" if b["pairs"] else "")
                for b in f["bands"]))
        lines.append("")
        lines.append("Do the legs agree? (fusion.navcheck: each pair of legs' shift, measured on the objects both see, "
                     "against the generator's nav errors; the pairs whose shift the check believes)")
        for name, g in pooled_leg_shifts(results).items():
            lines.append(f"- {name}: {g['pairs']} pairs, error median {g['error_median_m']} m, 90th percentile "
                         f"{g['error_p90_m']} m, largest {g['error_max_m']} m; flagged beyond the gate {g['flagged']} "
                         f"(largest true shift {g['truth_distance_max_m']} m)")
        lines.append("")
        lines.append("The checks pooled over each variant's scenes (DS look; the counts of every scene summed, the "
                     "shares with a 95 % Wilson interval; the issue asks each check per scene, above)")
        lines += pooled_checks_markdown(pooled_checks(results))
        lines.append("")
        lines.append("Reliability pooled over each variant's scenes (DS look): Bel bin -> contacts, share on a target "
                     "[95 % Wilson interval]")
        for name, g in pooled_reliability(results).items():
            lines.append(f"- {name} ({g['scenes']} scenes, {'rises' if g['rises'] else 'DOES NOT RISE'}): " + "; ".join(
                f"{x['bel']} {x['contacts']}, {x['share']:.2f} [{x['low']:.2f}, {x['high']:.2f}]" for x in g["bins"]))
    return "\n".join(lines)


def main_heldout(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seabeds", default="sand,ripples,sassed", help="comma-separated (sand, ripples, sassed)")
    ap.add_argument("--seeds", default=",".join(map(str, SEEDS)), help="comma-separated held-out seeds")
    ap.add_argument("--variants", default="base", metavar="NAME[,NAME]",
                    help="scene variants (atr_node.evaluation.heldout.VARIANTS): base (default, the benchmark), or "
                         "stress variants of the same seeds: " + ", ".join(v for v in _variant_names() if v != "base")
                         + "; 'all' = every one")
    ap.add_argument("--legs", type=int, default=5)
    ap.add_argument("--leg-length", type=float, default=200.0, help="metres")
    ap.add_argument("--config", default=None, help="node settings (TOML; default built-in)")
    ap.add_argument("--online-calibration", choices=("on", "off"), default="on")
    ap.add_argument("--out", default="/tmp/atr-quality", help="folder for the scenes and the report")
    ap.add_argument("--json", default=None, help="write the figures as JSON here")
    ap.add_argument("--quick", action="store_true", help="one small sand scene (a smoke run)")
    ap.add_argument("--recordings", default=None, metavar="FILE[,FILE]",
                    help="real recordings to score too (default: the shared side-scan XTF files when present, "
                         "not with --quick; 'none' = no recording)")
    args = ap.parse_args(argv)
    from atr_node.config import load_settings
    from atr_node.errors import AtrError
    from atr_node.evaluation.heldout import SEABEDS, VARIANTS

    try:
        settings = load_settings(args.config)
    except AtrError as exc:
        print(f"bench_quality: {exc}", file=sys.stderr)
        return 1
    seabeds = [s for s in args.seabeds.split(",") if s]
    bad = [s for s in seabeds if s not in SEABEDS]
    if bad:
        print(f"bench_quality: unknown seabed(s) {bad}; expected some of {list(SEABEDS)}", file=sys.stderr)
        return 2
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s]
    except ValueError:
        print(f"bench_quality: --seeds {args.seeds!r}: expected comma-separated integers", file=sys.stderr)
        return 2
    variants = list(VARIANTS) if args.variants == "all" else [v for v in args.variants.split(",") if v]
    bad = [v for v in variants if v not in VARIANTS]
    if bad or not variants:
        print(f"bench_quality: --variants {args.variants!r}: expected 'all' or some of {list(VARIANTS)}", file=sys.stderr)
        return 2
    legs, length = args.legs, args.leg_length
    if args.quick:
        seabeds, seeds, legs, length = ["sand"], [seeds[0]], 3, 80.0
    out = Path(args.out)
    try:
        lock = _lock_folder(out)
    except OSError as exc:
        print(f"bench_quality: {exc}", file=sys.stderr)
        return 2
    with lock:
        return _heldout_run(args, out, settings, seabeds, seeds, legs, length, argv, variants)


def _lock_folder(out: Path):
    """An exclusive lock on ``out/.lock`` (held while the returned file is open): one run per
    folder. OSError naming the folder (and the other run's pid) when another run holds it."""
    out.mkdir(parents=True, exist_ok=True)
    fh = open(out / ".lock", "a+")
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        fh.seek(0)
        pid = fh.read().strip() or "?"
        fh.close()
        raise OSError(f"{out} is in use by another run (pid {pid}): wait for it, or give another --out") from None
    except BaseException:
        fh.close()
        raise
    fh.seek(0)
    fh.truncate()
    fh.write(f"{os.getpid()}\n")
    fh.flush()
    return fh


def _reusable(d: Path, seabed: str, seed: int, legs: int, length: float, variant: str = "base") -> bool:
    """A scene folder a finished run of this generator made for these parameters."""
    from atr_node.evaluation.heldout import GENERATOR_VERSION, SCENE_FILES, VARIANTS

    try:
        scene = json.loads((d / "scene.json").read_text())
        same = (scene["generator_version"] == GENERATOR_VERSION and scene["seed"] == seed and scene["legs"] == legs
                and math.isclose(float(scene["leg_length_m"]), length) and scene["seabed"]["kind"] == seabed
                and scene.get("variant", VARIANTS["base"].info()) == VARIANTS[variant].info())
    except (OSError, ValueError, TypeError, KeyError):
        return False
    return same and all((d / f).is_file() for f in SCENE_FILES)


def _write_whole(path: Path, text: str) -> None:
    """``text`` into ``path``, never half-written (:func:`atr_node.io.atomic.atomic_open`)."""
    from atr_node.io.atomic import atomic_open

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path) as fh:
        fh.write(text)


def _heldout_run(args, out: Path, settings, seabeds, seeds, legs, length, argv, variants=("base",)) -> int:
    from atr_node.errors import AtrError
    from atr_node.evaluation.heldout import SCENE_FILES, generate_scene
    from atr_node.io.atomic import leftover_temporaries

    results = []
    for variant, sb, seed in ((v, sb, seed) for v in variants for sb in seabeds for seed in seeds):
        d = out / (f"{sb}-{seed}-{legs}x{length:g}" + ("" if variant == "base" else f"-{variant}"))
        for f in SCENE_FILES:  # a killed generation's temporary files (this run holds the folder)
            for left in leftover_temporaries(d / f):
                left.unlink(missing_ok=True)
        if not _reusable(d, sb, seed, legs, length, variant):
            try:
                generate_scene(d, seabed=sb, seed=seed, legs=legs, leg_length_m=length, variant=variant)
            except (ValueError, OSError) as exc:
                print(f"bench_quality: {d.name}: {exc}", file=sys.stderr)
                return 1
        print(f"{d.name}: scoring ...", file=sys.stderr, flush=True)
        try:
            results.append({**score_scene(d, settings, online=args.online_calibration), "variant": variant})
        except AtrError as exc:
            print(f"bench_quality: {d.name}: {exc}", file=sys.stderr)
            return 1
        print(f"{d.name}: {results[-1]['seconds']} s", file=sys.stderr, flush=True)
        harness.record(f"scene {d.name}: replay and scoring", [float(results[-1]["seconds"])], clock="wall")
        ds = results[-1]["methods"].get("DS look (default)", {})
        harness.value(f"{d.name} DS look pd_max", ds.get("pd_max"))
    if args.recordings is None:
        rr = _real_tool()
        paths = [] if args.quick else [p for p in (rr.SHARED / name for name in rr.DEFAULT_FILES) if p.is_file()]
    else:
        paths = [Path(p) for p in args.recordings.split(",") if p and p != "none"]
    recordings = []
    for p in paths:
        print(f"{p.name}: scoring ...", file=sys.stderr, flush=True)
        try:
            recordings.append(score_recording(p, settings, online=args.online_calibration))
        except (AtrError, OSError) as exc:
            print(f"bench_quality: {p}: {exc}", file=sys.stderr)
            return 1
        harness.record(f"recording {p.name}: replay and scoring", [float(recordings[-1]["seconds"])], clock="wall")
    text = markdown(results) + ("\n\n" + recordings_markdown(recordings) if recordings else "")
    print(text)
    try:
        _write_whole(out / "quality.md", text + "\n")
        if args.json:
            _write_whole(Path(args.json), json.dumps({"command": "python tools/bench/quality.py "
                                                      + " ".join(argv or sys.argv[1:]),
                                                      "scenes": results, "pooled_reliability": pooled_reliability(results),
                                                      "pooled_fa_anatomy": pooled_fa_anatomy(results),
                                                      "pooled_leg_shifts": pooled_leg_shifts(results),
                                                      "pooled_checks": pooled_checks(results),
                                                      "recordings": recordings},
                                                     indent=1, default=float) + "\n")
    except OSError as exc:
        print(f"bench_quality: cannot write the report: {exc}", file=sys.stderr)
        return 1
    return 0




# ================================================================================================
# Part "speed-options" (was tools/bench/quality.py speed-options)
# ================================================================================================

SPEED_OPTIONS_DOC = """Error against run time for every speed option of the product, in one table (issue 8).

One generated mission (default: the demo's sand mission) is run through the node and scored
(`atr_node.evaluation.evaluate_log`, the paper's comparisons) once with the default settings
and once per speed option. For each option the table gives the run time (node pass with
on-line calibration plus the comparison pass), the change in Pd and false alarms of the
node's fusion (Dempster-Shafer with missed-detection evidence, three best detectors, at
Bel(T) >= report_bel) against the default, and the error in the number the option
approximates:

- detector precision (float32 tables) and decimation (2, 4): the scores, max |difference| /
  std of the full-precision scores over the mission's first tile;
- sub-rays (k = 1, 4 against 2), the strips signature engine (k = 2, against rays) and
  calibration size (early stop at convergence; on-line iterations 3, 20 against 10):
  the calibrated P(y) curves, mean |difference| over detectors and range bins, and the
  thresholds, max relative difference;
- grid cell size (0.25 m, 1.0 m against 0.5 m): the positions, median distance from each
  matched target to its contact;
- on-line calibration off (the shipped model): P(y) and thresholds as above.

    python tools/bench/quality.py speed-options                 # writes the table (Markdown) to stdout
    python tools/bench/quality.py speed-options --quick         # a small mission: a smoke run
"""


import dataclasses
import tempfile



def options(base):
    """(name, settings, online) of every speed option; the first is the default."""
    d, sim, cal, fus = base.detectors, base.simulation, base.calibration, base.fusion
    rep = base.replace
    return [
        ("default (float64, decimation 1, k = 2, rays, 10 iterations, 0.5 m cells, on-line)", base, True),
        ("detectors: float32 tables", rep(detectors=dataclasses.replace(d, precision="float32")), True),
        ("detectors: decimation 2", rep(detectors=dataclasses.replace(d, decimation=2)), True),
        ("detectors: decimation 4", rep(detectors=dataclasses.replace(d, decimation=4)), True),
        ("simulation: 1 x 1 sub-rays", rep(simulation=dataclasses.replace(sim, subrays=1)), True),
        ("simulation: 4 x 4 sub-rays", rep(simulation=dataclasses.replace(sim, subrays=4)), True),
        ("simulation: strips engine, k = 2", rep(simulation=dataclasses.replace(sim, engine="strips")), True),
        ("calibration: early stop at convergence (converge_pd 0.02)",
         rep(calibration=dataclasses.replace(cal, converge_pd=0.02)), True),
        ("calibration: early stop at convergence (converge_pd 0.015)",
         rep(calibration=dataclasses.replace(cal, converge_pd=0.015)), True),
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


def main_speed_options(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=SPEED_OPTIONS_DOC, formatter_class=argparse.RawDescriptionHelpFormatter)
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
            harness.record(f"speed option {name}: node and comparison passes", [wall], clock="wall")
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


def main_rock_cue(argv: list[str] | None = None) -> int:
    """Part "rock-cue" (tools/bench/rock_cue.py): a cue against rocks, on development seeds."""
    import rock_cue

    return rock_cue.main(argv)


PARTS = {"heldout": main_heldout, "speed-options": main_speed_options, "rock-cue": main_rock_cue}


def main(argv: list[str] | None = None) -> int:  # a part, every part, or the first with options
    return harness.subject_main(__doc__, PARTS, argv)


if __name__ == "__main__":
    raise SystemExit(main())
