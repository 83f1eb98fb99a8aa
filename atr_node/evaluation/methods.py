"""The comparisons of the paper's figure 6, on the same detections.

One pass of the node's pipeline over a recording keeps, per strip unit, each detector's
coverage and detections (at the model's thresholds and at a ladder of further thresholds).
From that one pass, without scoring again:

- **each detector alone**: at every threshold of the ladder, its detections grouped across
  legs within the association gate are the contacts (one ROC point per threshold);
- **AND** of a detector set (the three best, all four) and **OR** of all four, at the
  model's thresholds (operating points; ``atr_node.fusion.baselines``);
- **Dempster-Shafer** fusion (a fresh evidence grid fed the same observations) without
  missed-detection evidence (Pd set to 0), with it, and with it plus the weakest detector;
  the ROC sweeps the threshold on Bel(T).

"Best" and "weakest" are ranked by each detector's own ROC: at the highest Pd every detector
reaches, the fewest false alarms.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from ..calibration.model import PerformanceModel
from ..config import Settings
from ..fusion import ContactTracker, EvidenceGrid, Observation
from ..fusion.baselines import and_contacts, group_detections, or_contacts
from ..fusion.grid import DetectionRecord
from ..geo import MissionFrame, TileGeometry, tile_geometry
from ..io.atrlog import LogRecord
from ..node.detect import DetectResult
from ..node.evidence import evidence_layers, unit_observations
from ..node.pipeline import Pipeline
from ..node.strip import StripUnit
from .scoring import OperatingPoint, RocCurve, match, operating_point, roc

SWEEP_FACTORS = (0.7, 0.85, 1.0, 1.25, 1.6, 2.0, 3.0, 5.0, 10.0)
"""Thresholds of each detector's ROC, as factors of its model threshold."""
EVAL_BEL_FLOOR = 0.02
"""Fusion ROCs consider belief regions down to this Bel(T)."""


@dataclass(frozen=True, eq=False)
class UnitRecord:
    leg: int
    t: float
    geometry: TileGeometry
    ranges_m: np.ndarray
    result: DetectResult
    model: PerformanceModel


@dataclass
class EvaluationRun:
    """What one pipeline pass over a recording leaves for the comparisons."""

    settings: Settings
    frame: MissionFrame
    units: list[UnitRecord]
    node_contacts: list[dict[str, Any]]
    model: PerformanceModel
    """The model in use at the end (the on-line one when it took over)."""
    sweep: dict[str, tuple[float, ...]]
    stats: dict[str, Any] = field(default_factory=dict)
    covered_km2: float = 0.0


def run_pipeline(settings: Settings, records: Iterable[LogRecord], *, model: PerformanceModel, online: Any = None,
                 workers: int = 1, progress: Callable[[int, int], None] | None = None,
                 sweep_factors: Sequence[float] = SWEEP_FACTORS,
                 keep_pixels: Callable[[np.ndarray, TileGeometry], None] | None = None,
                 log_nav: bool = True) -> EvaluationRun:
    """Replay ``records`` through the node's pipeline, keeping every unit's detect result
    (and handing each core's pixels with their geometry to ``keep_pixels``, for a mosaic).
    ``log_nav`` False: the navigation check measures and reports but logs no pair (a second
    pass over a recording whose first pass logged them)."""
    pipe = Pipeline(settings, model=model, workers=workers, mode="replay", online=online)
    pipe.navcheck.log_pairs = log_nav
    units: list[UnitRecord] = []
    sweeps: dict[str, tuple[float, ...]] = {}

    def keep(unit: StripUnit, m: PerformanceModel, res: DetectResult) -> None:
        core = unit.core_tile()
        geometry = tile_geometry(core, pipe.frame)
        units.append(UnitRecord(unit.leg, float(unit.ping_time[unit.core][-1]), geometry, core.ranges_m, res, m))
        if keep_pixels is not None:
            keep_pixels(core.pixels, geometry)

    pipe.on_fused = keep
    try:
        n = 0
        ladder_of = None
        for rec in records:
            if pipe.model is not ladder_of:
                # the ladder follows the model in use (it changes when the on-line model takes over)
                ladder_of = pipe.model
                taus = {d: float(pipe.model.tau.get(d, getattr(settings.detectors.threshold, d)))
                        for d in pipe.enabled}
                sweeps = {d: tuple(sorted(set(round(f * taus[d], 9) for f in sweep_factors))) for d in pipe.enabled}
                pipe.sweep = sweeps if sweep_factors else None
            pipe.feed(rec)
            n += 1
            if progress is not None and rec.link == "sonar":
                progress(pipe.stats.tiles_in, n)
        pipe.finish()
        cell_km2 = (settings.fusion.cell_m ** 2) / 1e6
        return EvaluationRun(settings, pipe.frame, units, pipe.contacts, pipe.model, sweeps,
                             stats={"tiles": pipe.stats.tiles_in, "units": pipe.stats.units,
                                    "pixels": pipe.stats.pixels, "detect_s": pipe.stats.detect_s,
                                    "online_switched_at": getattr(pipe.online, "switched_at", None),
                                    # fusion.navcheck: each pair of legs' shift, and one line on them
                                    "leg_shifts": pipe.navcheck.figures(),
                                    "navigation_report": pipe.navcheck.report()},
                             covered_km2=pipe.grid.covered_cells() * cell_km2)
    finally:
        pipe.close()


def _records(run: EvaluationRun, detector: str, tau: float | None) -> list[DetectionRecord]:
    """Every detection of one detector (at the model threshold, or at a sweep threshold)."""
    out = []
    for u in run.units:
        dets = u.result.detections[detector] if tau is None else u.result.sweep[detector].get(tau, [])
        for x in dets:
            e, n = u.geometry.world(x.row, x.col)
            out.append(DetectionRecord(u.leg, detector, float(e), float(n), u.t,
                                       float(u.model.confidence(detector, x.gamma)), float(x.gamma)))
    return out


class Comparison:
    """All the paper's comparisons for one run against one truth list."""

    def __init__(self, run: EvaluationRun, truth_latlon: np.ndarray) -> None:
        self.run = run
        self.gate_m = _gate(run.settings)
        f = run.frame
        tl = np.asarray(truth_latlon, dtype=np.float64).reshape(-1, 2)
        self.truth_en = np.column_stack(f.to_frame(tl[:, 0], tl[:, 1])) if tl.size else np.zeros((0, 2))
        self.detectors = tuple(run.settings.detectors.enabled)

    # -- methods --------------------------------------------------------------------------
    def single(self, detector: str) -> RocCurve:
        """ROC of one detector alone, piecewise from its threshold ladder.

        At each ladder threshold tau_k the detections (extracted at tau_k, size filter
        included) grouped across legs within the gate are the contacts; between tau_k and the
        next rung, the groups of rung k are kept while their largest gamma reaches the swept
        threshold. At the rungs this is exact; between them it stands for extraction at the
        swept threshold.
        """
        ladder = sorted(self.run.sweep[detector])
        n_t = len(self.truth_en)
        pts = [OperatingPoint(math.inf, 0.0, 0, 0, 0)]
        for k, tau in enumerate(ladder):
            upper = ladder[k + 1] if k + 1 < len(ladder) else math.inf
            recs = _records(self.run, detector, tau)
            n, labels = group_detections(recs, gate_m=self.gate_m)
            if n == 0:
                pts.append(OperatingPoint(tau, 0.0, 0, 0, 0))
                continue
            gam = np.array([r.gamma for r in recs])
            en = np.array([(r.east_m, r.north_m) for r in recs])
            score = np.full(n, -np.inf)
            np.maximum.at(score, labels, gam)
            order = np.lexsort((gam, labels))
            last = np.flatnonzero(np.r_[labels[order][1:] != labels[order][:-1], True])
            pos = np.zeros((n, 2))
            pos[labels[order][last]] = en[order][last]  # a group sits at its strongest detection
            levels = [tau] + sorted({float(x) for x in score if tau < x < upper})
            for thr in levels:
                keep = score >= thr
                m = match(pos[keep], self.truth_en)
                c = int(keep.sum())
                pts.append(OperatingPoint(float(thr), len(m) / max(n_t, 1), c - len(m), c, len(m)))
        return RocCurve(detector.upper(), tuple(pts), n_t)

    def logical(self, kind: str, detectors: Sequence[str]) -> RocCurve:
        recs = [r for d in detectors for r in _records(self.run, d, None)]
        if kind == "and":
            cs = and_contacts(recs, gate_m=self.gate_m, detectors=detectors)
        else:
            cs = or_contacts(recs, gate_m=self.gate_m)
        en = np.array([(c.east_m, c.north_m) for c in cs]).reshape(-1, 2)
        name = f"{kind.upper()} ({', '.join(d.upper() for d in detectors)})"
        return operating_point(name, en, self.truth_en)

    def fusion(self, detectors: Sequence[str], *, missed: bool, name: str | None = None, evidence: str | None = None,
               prior_target: float | None = None) -> "FusionResult":
        """Dempster-Shafer fusion of a detector subset: its ROC and its operating point.

        The ROC sweeps Bel(T) over contacts extracted from regions down to
        :data:`EVAL_BEL_FLOOR`; the operating point takes the contacts the node itself would
        publish from the same grid (regions down to ``fusion.withdraw_bel``). The two differ
        by design: a region's extent decides which detections make each contact, hence its
        position, so one segmentation at the floor is not the node's contact list at
        ``report_bel`` (on the demo's hard mission it gave 395 false alarms at Bel >= 0.5
        where the node published 304, and Pd 0.94 against 0.88).
        """
        contacts, grid = fuse(self.run, detectors, missed=missed, evidence=evidence, prior_target=prior_target)
        label = name or f"DS ({', '.join(d.upper() for d in detectors)}){'' if missed else ', no missed-detection evidence'}"
        at_node = node_like_contacts(self.run, grid, evidence=evidence)
        return FusionResult(self._roc(label, contacts), self._roc(label, at_node), at_node, grid)

    def _roc(self, label: str, contacts: Sequence[Any]) -> RocCurve:
        en = np.array([(c.east_m, c.north_m) for c in contacts]).reshape(-1, 2)
        return roc(label, en, [c.bel for c in contacts], self.truth_en)

    def ranking(self, singles: dict[str, RocCurve]) -> list[str]:
        """Detectors from best to weakest by their ROC: at the highest Pd that every detector
        reaches, the fewest false alarms (then the higher best Pd)."""
        common = min(c.best_pd() for c in singles.values())
        return sorted(singles, key=lambda d: (singles[d].fa_at_pd(common), -singles[d].best_pd(), d))


def _gate(settings: Settings) -> float:
    from ..fusion import association_gate_m

    return association_gate_m(settings.fusion, settings.template)


def fuse(run: EvaluationRun, detectors: Sequence[str], *, missed: bool = True,
         bel_floor: float = EVAL_BEL_FLOOR, evidence: str | None = None,
         prior_target: float | None = None) -> tuple[list, EvidenceGrid]:
    """Dempster-Shafer fusion of the run's observations for a detector subset (SPEC 6-7).

    ``evidence``: ``"look"`` or ``"paper"`` (default the run's ``fusion.evidence``);
    ``prior_target``: read every confidence table under this P(T) per cell instead of the
    model's (:meth:`PerformanceModel.with_prior`; e.g. the paper's 0.1).
    """
    s = run.settings
    evidence = evidence or s.fusion.evidence
    fusion = dataclasses.replace(s.fusion, report_bel=max(bel_floor, 1e-6), withdraw_bel=max(bel_floor, 1e-6),
                                 evidence=evidence)
    gate = _gate(s)
    models: dict[int, PerformanceModel] = {}

    def model_of(u: UnitRecord) -> PerformanceModel:
        if prior_target is None:
            return u.model
        if id(u.model) not in models:
            models[id(u.model)] = u.model.with_prior(prior_target)
        return models[id(u.model)]

    layers = evidence_layers(evidence, run.model, tuple(detectors))
    grid = EvidenceGrid(fusion, gate_m=gate, detectors=tuple(detectors), layers=layers)
    tracker = ContactTracker(fusion, run.frame, gate_m=gate)
    t_last = 0.0
    for u in run.units:
        obs = unit_observations(model_of(u), u.result.detections, u.result.covered, u.ranges_m, tuple(detectors),
                                layers, missed=missed, geometry=u.geometry, object_m=s.template.length_m)
        grid.add_observation(Observation(u.leg, u.t, u.geometry, obs))
        t_last = max(t_last, u.t)
    grid.close_all()
    tracker.update(grid, t_last)
    return list(tracker.live.values()), grid


def node_like_contacts(run: EvaluationRun, grid: EvidenceGrid, *, evidence: str | None = None) -> list:
    """The live contacts the node extracts from ``grid`` with its own ``fusion`` settings
    (regions down to ``withdraw_bel``, born at ``report_bel``), at the end of the run.

    One extraction at the end, where the node extracts after every unit: at Bel(T) >=
    ``report_bel`` the two agree (a component's position and belief depend on the final grid
    only; the history decides ids, and keeps alive contacts between ``withdraw_bel`` and
    ``report_bel``), which ``tests/evaluation`` checks against the node's published contacts.
    """
    fusion = run.settings.fusion if evidence is None else dataclasses.replace(run.settings.fusion, evidence=evidence)
    tracker = ContactTracker(fusion, run.frame, gate_m=_gate(run.settings))
    tracker.update(grid, max((u.t for u in run.units), default=0.0))
    return list(tracker.live.values())


@dataclass(frozen=True, eq=False)
class FusionResult:
    """One Dempster-Shafer fusion of the comparison pass (:meth:`Comparison.fusion`)."""

    curve: RocCurve
    """ROC sweeping Bel(T), regions down to :data:`EVAL_BEL_FLOOR`."""
    at_node: RocCurve
    """The same fusion's contacts as the node extracts them: the operating point."""
    contacts: list
    """Those contacts (live, Bel(T) >= ``withdraw_bel``)."""
    grid: EvidenceGrid

    @property
    def name(self) -> str:
        return self.curve.name


def group_count(records: Sequence[DetectionRecord], gate_m: float) -> int:
    return group_detections(records, gate_m=gate_m)[0]
