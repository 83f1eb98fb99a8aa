"""One mission evaluated: the node run on a recording, every method scored, figures written,
and the paper's claims checked (issue "evaluation and demo").

The first row scores the contacts the node published (final state of each, as
``--contacts-out`` writes them; written to ``contacts.jsonl``) with
:func:`~atr_node.evaluation.scoring.score_contacts`, the function ``atr-node evaluate
--contacts`` calls. The other rows are the *comparison pass*: every method recomputed from
the node's detections (one pass with the model the node ended with). Its Dempster-Shafer
operating points take the contacts as the node extracts them, so its DS row of every detector
is the node's row whenever one model served every tile (``_node_agreement`` says so, or why
not); its ROC curves re-segment the belief map down to Bel 0.02
(:meth:`~atr_node.evaluation.methods.Comparison.fusion`).

Claims of the paper's figure 6, checked on each mission and reported as holding or not:

1. Dempster-Shafer fusion with missed-detection evidence reaches the highest Pd of any method
   (each detector alone at its threshold, AND, OR, fusion without missed detections);
2. at the Pd of AND of the three best detectors, it has fewer false alarms than that AND;
3. OR of all four has far more false alarms: at least twice those fusion needs to reach OR's Pd
   (or the highest Pd fusion reaches, when that is lower);
4. adding the weakest detector does not degrade fusion: the same or higher best Pd, and at
   the three-detector fusion's best Pd no more false alarms (one allowed for ties).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..calibration.model import PerformanceModel
from ..config import Settings
from ..node.service import write_contacts
from .methods import SWEEP_FACTORS, Comparison, EvaluationRun, FusionResult, run_pipeline
from .report import Mosaic, plot_belief, plot_mosaic, plot_roc
from .scoring import Clutter, RocCurve, read_truth, score_contacts


NODE_SOURCE = "node's contacts"
"""``Row.source`` of the row scoring what the node published."""
COMPARISON_SOURCE = "comparison pass, recomputed from the node's detections"
"""``Row.source`` of every method of the paper's figure 6 recomputed on the same detections."""


@dataclass
class Row:
    method: str
    pd: float
    false_alarms: float
    fa_per_km2: float
    note: str = ""
    source: str = COMPARISON_SOURCE


@dataclass
class MissionResult:
    name: str
    rows: list[Row]
    claims: dict[str, tuple[bool, str]]
    figures: dict[str, str]
    covered_km2: float
    targets: int
    stats: dict[str, Any] = field(default_factory=dict)
    run: Any = field(default=None, repr=False)
    """The :class:`EvaluationRun` (detections, model), for further analysis; not saved."""
    comparison: Any = field(default=None, repr=False)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "targets": self.targets, "covered_km2": self.covered_km2,
                "rows": [vars(r) for r in self.rows],
                "claims": {k: {"holds": v[0], "why": v[1]} for k, v in self.claims.items()},
                "figures": self.figures, "stats": self.stats}


def evaluate_log(settings: Settings, log_path: str | Path, truth_path: str | Path, out_dir: str | Path, *,
                 model: PerformanceModel, online: Any = None, name: str = "mission",
                 progress: Callable[[int, int], None] | None = None, figures: bool = True,
                 clutter: Clutter | None = None) -> MissionResult:
    """``clutter``: known objects that are not targets (:func:`~.scoring.read_clutter`); the
    node row then says what its false alarms lie on (``stats["node_false_alarm_anatomy"]``),
    and the mosaic shows them."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    truth = read_truth(truth_path)
    mosaic = Mosaic() if figures else None
    node_contacts, online_stats = None, {}
    if online is not None:
        # pass 1: the node as aboard, calibrating on-line from the mission's first tiles; the
        # comparisons then run on one pass with the model it ended with, so that every method
        # sees the same detections at the same thresholds
        first = _run(settings, log_path, model=model, online=online, mosaic=None, progress=progress, sweep=False)
        node_contacts, model = first.node_contacts, first.model
        online_stats = {"online_switched_at": first.stats.get("online_switched_at"),
                        "node_pass_detect_s": first.stats.get("detect_s"),
                        # do the legs agree: as the node saw it (the second pass logs nothing again)
                        **{k: first.stats.get(k) for k in ("leg_shifts", "navigation_report")}}
    run = _run(settings, log_path, model=model, online=None, mosaic=mosaic, progress=progress, sweep=True,
               log_nav=online is None)
    if node_contacts is not None:
        run.node_contacts = node_contacts
        run.stats.update(online_stats)
    tl = np.array([(t.lat_deg, t.lon_deg) for t in truth]).reshape(-1, 2)
    cmp = Comparison(run, tl)
    km2 = max(run.covered_km2, 1e-12)
    singles = {d: cmp.single(d) for d in cmp.detectors}
    rank = cmp.ranking(singles)
    best3, weakest = rank[:3], rank[-1]
    and3 = cmp.logical("and", best3)
    and4 = cmp.logical("and", rank)
    or4 = cmp.logical("or", rank)
    f_nomiss = cmp.fusion(best3, missed=False)
    f_miss = cmp.fusion(best3, missed=True)
    f_all = cmp.fusion(rank, missed=True, name=f"DS ({', '.join(d.upper() for d in rank)}), "
                                              f"with {weakest.upper()} (weakest)")
    # SPEC 6.1: the paper's per-detector form (detectors independent, prior 0.1) in every evaluation
    f_paper = cmp.fusion(rank, missed=True, evidence="paper", prior_target=0.1,
                         name=f"DS ({', '.join(d.upper() for d in rank)}) as in the paper: per detector, prior 0.1")
    ds_nomiss, ds_miss, ds_all = f_nomiss.curve, f_miss.curve, f_all.curve
    report_bel = settings.fusion.report_bel

    # first what the node published, scored as `atr-node evaluate --contacts` scores it
    node = score_contacts(run.node_contacts, truth, bel=report_bel, name=NODE_SOURCE, clutter=clutter)
    nb = node.curve.best_pd()
    rows = [Row(f"DS ({', '.join(d.upper() for d in settings.detectors.enabled)}): the node, as published",
                node.point.pd, node.point.false_alarms, node.point.false_alarms / km2,
                f"at Bel >= {report_bel:g}; {node.contacts} live contacts; best Pd {nb:.2f} with "
                f"{node.curve.fa_at_pd(nb):g} FA (contacts down to Bel {settings.fusion.withdraw_bel:g})",
                source=NODE_SOURCE)]
    for d in rank:
        tau = min(run.sweep[d], key=lambda t: abs(t - run.model.tau.get(d, t)))
        p = singles[d].at_threshold(tau)
        rows.append(Row(f"{d.upper()} alone", p.pd, p.false_alarms, p.false_alarms / km2, f"tau = {tau:.3g}"))
    for c in (and3, and4, or4):
        p = c.points[0]
        rows.append(Row(c.name, p.pd, p.false_alarms, p.false_alarms / km2))
    for f in (f_paper, f_nomiss, f_miss, f_all):
        # the operating point from the contacts as the node extracts them; the sweep's best Pd
        # from regions down to EVAL_BEL_FLOOR (methods.Comparison.fusion says why they differ)
        p = f.at_node.at_threshold(report_bel)
        best = f.curve.best_pd()
        rows.append(Row(f.name, p.pd, p.false_alarms, p.false_alarms / km2,
                        f"at Bel >= {report_bel:g}; ROC: best Pd {best:.2f} with {f.curve.fa_at_pd(best):g} FA"))
    agree = _node_agreement(rows[0], rows[-1], f_all, run)

    claims = check_claims(singles, run, and3=and3, or4=or4, ds_nomiss=ds_nomiss, ds_miss=ds_miss, ds_all=ds_all,
                          and4=and4)
    figs: dict[str, str] = {}
    if figures:
        truth_en = cmp.truth_en
        figs["roc"] = plot_roc(list(singles.values()) + [ds_nomiss, ds_miss, ds_all, f_paper.curve], [and3, and4, or4],
                               out / "roc.png", covered_km2=km2, title=f"{name}: ROC (paper figure 6)",
                               fused=[node.curve]).name
        clutter_en = None
        if clutter is not None and clutter.objects:
            clutter_en = np.column_stack(run.frame.to_frame(np.array([o.lat_deg for o in clutter.objects]),
                                                            np.array([o.lon_deg for o in clutter.objects])))
        figs["mosaic"] = plot_mosaic(mosaic, out / "mosaic.png", truth_en=truth_en, contacts=run.node_contacts,
                                     title=f"{name}: mosaic, truth and the node's contacts",
                                     report_bel=report_bel, clutter_en=clutter_en).name
        # Bel(T) of all the detectors with missed detections: f_all's grid (the same evidence
        # as the node's, in another detector order)
        figs["belief"] = plot_belief(f_all.grid, out / "belief.png", truth_en=truth_en,
                                     title=f"{name}: Bel(T), all detectors with missed-detection evidence").name
        try:
            from ..calibration.plots import plot_pyr

            figs["pyr"] = plot_pyr(run.model, out / "pyr.png").name
        except Exception as exc:  # plotting must not lose the evaluation
            figs["pyr_error"] = str(exc)
    # what the node published, as `atr-node replay --contacts-out` writes it: the node row can
    # be reproduced with `atr-node evaluate --contacts contacts.jsonl --truth ...`
    write_contacts(out / "contacts.jsonl", run.node_contacts)
    result = MissionResult(name, rows, claims, figs, km2, len(truth),
                           stats={**run.stats, "ranking": rank, "node_contacts": len(run.node_contacts),
                                  "node_live_contacts": node.contacts, "node_vs_comparison": agree,
                                  **({"node_false_alarm_anatomy": node.summary()["false_alarm_anatomy"],
                                      "node_false_alarm_anatomy_text": node.anatomy_line()}
                                     if node.anatomy is not None else {})},
                           run=run, comparison=cmp)
    (out / "result.json").write_text(json.dumps(result.to_dict(), indent=2, default=str))
    return result


def _node_agreement(node_row: Row, ds_row: Row, f_all: FusionResult, run: EvaluationRun) -> str:
    """Whether the comparison pass's DS of every detector, at the operating point, is the
    node's published result, and if not why; for the report.

    It is by construction when one model served every tile (replay, on-line calibration or
    not: the node holds the first tiles until its on-line model is ready, and the comparison
    pass runs with the model it ended with). A node that changed model mid-run (a live node
    switching to the on-line model) fused its first tiles with the other model.
    """
    if (node_row.pd, node_row.false_alarms) == (ds_row.pd, ds_row.false_alarms):
        return "agree"
    models = {id(u.model) for u in run.units}
    why = ("the comparison pass used several models" if len(models) > 1 else
           "the node's pass and the comparison pass fused different detections or models")
    return (f"differ: the node Pd {node_row.pd:.2f} with {node_row.false_alarms:g} FA, the comparison pass's "
            f"{f_all.name} Pd {ds_row.pd:.2f} with {ds_row.false_alarms:g} FA ({why})")


def _run(settings, log_path, *, model, online, mosaic, progress, sweep: bool, log_nav: bool = True) -> EvaluationRun:
    from ..io.recording import open_recording

    rec = settings.recording
    records = open_recording(log_path, crs=rec.crs, altitude=rec.altitude, frequency=rec.frequency)
    return run_pipeline(settings, records, model=model, online=online, progress=progress,
                        keep_pixels=mosaic.add if mosaic is not None else None,
                        sweep_factors=SWEEP_FACTORS if sweep else (), log_nav=log_nav)


def check_claims(singles: dict[str, RocCurve], run: EvaluationRun, *, and3: RocCurve, and4: RocCurve, or4: RocCurve,
                 ds_nomiss: RocCurve, ds_miss: RocCurve, ds_all: RocCurve) -> dict[str, tuple[bool, str]]:
    out: dict[str, tuple[bool, str]] = {}
    others = {f"{d.upper()} alone": singles[d].at_threshold(
        min(run.sweep[d], key=lambda t: abs(t - run.model.tau.get(d, t)))).pd for d in singles}
    others.update({and3.name: and3.points[0].pd, and4.name: and4.points[0].pd, or4.name: or4.points[0].pd,
                   ds_nomiss.name: ds_nomiss.best_pd()})
    best_other = max(others.values())
    pd_miss = max(ds_miss.best_pd(), ds_all.best_pd())
    out["1 highest Pd"] = (pd_miss >= best_other - 1e-12,
                           f"fusion with missed detections reaches Pd {pd_miss:.2f}; best other method "
                           f"{max(others, key=others.get)} {best_other:.2f}")
    p_and = and3.points[0]
    fa_ds = ds_miss.fa_at_pd(p_and.pd)
    out["2 fewer FA than AND of 3 best"] = (fa_ds < p_and.false_alarms or (fa_ds == p_and.false_alarms == 0),
                                            f"at Pd {p_and.pd:.2f}: fusion {fa_ds:g} FA, {and3.name} "
                                            f"{p_and.false_alarms} FA")
    p_or = or4.points[0]
    p_cmp = min(p_or.pd, ds_all.best_pd())  # OR's Pd, or the highest fusion reaches if lower
    fa_ds_or = ds_all.fa_at_pd(p_cmp)
    out["3 OR far worse"] = (p_or.false_alarms >= 2 * fa_ds_or,
                             f"OR: Pd {p_or.pd:.2f} with {p_or.false_alarms} FA; fusion (all four) at Pd "
                             f"{p_cmp:.2f}: {fa_ds_or:g} FA")
    p3 = ds_miss.best_pd()
    fa3, fa4 = ds_miss.fa_at_pd(p3), ds_all.fa_at_pd(p3)
    out["4 weakest does not degrade"] = (ds_all.best_pd() >= p3 - 1e-12 and fa4 <= fa3 + 1,
                                         f"best Pd 3 detectors {p3:.2f} ({fa3:g} FA), with the weakest "
                                         f"{ds_all.best_pd():.2f} ({fa4:g} FA at Pd {p3:.2f})")
    return out


def rows_markdown(rows: list[Row]) -> str:
    """The rows as a Markdown table; the source column tells the node's published result
    from the comparison pass."""
    lines = ["| method | source | Pd | false alarms | FA / km² | note |", "|---|---|---:|---:|---:|---|"]
    for r in rows:
        lines.append(f"| {r.method} | {r.source} | {r.pd:.2f} | {r.false_alarms:g} | {r.fa_per_km2:.0f} | {r.note} |")
    return "\n".join(lines)
