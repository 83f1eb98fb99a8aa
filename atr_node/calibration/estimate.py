"""From collected responses to a :class:`PerformanceModel` (SPEC section 5).

Per detector: tau by Dobeck's rule at the Pd target on the synthetic targets, the confidence
table c(gamma; tau) (paper eq. 6, isotonic where it dips) and the P(y) table with its Wilson
interval. Pure: the same responses and settings give the same model.
"""

from __future__ import annotations

import datetime as _dt
import itertools
import math
from typing import Any, Mapping

import numpy as np

from .. import __version__
from ..config import CalibrationSettings, ThresholdSettings
from . import looks as _looks
from .looks import area_prior
from .model import DetectorPerformance, PerformanceModel, look_detects
from .responses import Responses, thresholds_on_nominal
from .stats import confidence_curve, dobeck_threshold, pd_curve, range_edges


def estimate_detector(x_t: np.ndarray, x_n: np.ndarray, ranges_m: np.ndarray, *, calibration: CalibrationSettings,
                      default_tau: float, tau: float | None = None, edges_m: np.ndarray | None = None,
                      tau_from: np.ndarray | None = None, prior_target: float | None = None,
                      score_from: np.ndarray | None = None) -> DetectorPerformance:
    """One detector's estimates.

    Parameters
    ----------
    x_t : (m,) float
        Target responses; ``ranges_m`` (m,) their anchors' ground ranges.
    x_n : (k,) float
        Non-target responses.
    default_tau : float
        Threshold used when there is no finite target response (``tau_source = "config"``).
    tau : float, optional
        Force this threshold instead of Dobeck's (``tau_source = "given"``).
    tau_from : (m,) bool, optional
        The target responses Dobeck's rule reads (e.g. the nominal population's); default
        all. The confidence and P(y) always use every target response.
    prior_target : float, optional
        P(T) per cell (default ``calibration.prior_target``).
    score_from : (m,) bool, optional
        The target responses the confidence curve and ``pd_at_tau`` read (the targets clear
        of the swath's end, :attr:`Responses.whole`); default all. P(y) reads every target.
    """
    x_t = np.asarray(x_t, dtype=np.float64)
    x_s = x_t if score_from is None else x_t[np.asarray(score_from, dtype=bool)]
    finite = x_s[np.isfinite(x_s)]
    sel = x_t if tau_from is None else x_t[np.asarray(tau_from, dtype=bool)]
    sel = sel[np.isfinite(sel)]
    if tau is not None:
        source = "given"
    elif sel.size:
        tau, source = dobeck_threshold(sel, calibration.pd_target, default=default_tau), "dobeck"
    else:
        tau, source = float(default_tau), "config"
    conf = confidence_curve(x_s, x_n, tau, prior_target=calibration.prior_target if prior_target is None else prior_target,
                            n_points=calibration.confidence_points, smoothing=calibration.smoothing)
    pyr = pd_curve(ranges_m, x_t, tau, bin_m=calibration.range_bin_m, edges_m=edges_m,
                   smoothing=calibration.smoothing)
    pd_tau = float(np.mean(finite > tau)) if finite.size else float("nan")
    return DetectorPerformance(tau=float(tau), confidence=conf, pyr=pyr, tau_source=source, pd_at_tau=pd_tau)


def estimate_model(responses: Responses, *, calibration: CalibrationSettings,
                   thresholds: ThresholdSettings | None = None, taus: Mapping[str, float] | None = None,
                   provenance: Mapping[str, Any] | None = None) -> PerformanceModel:
    """Estimate every detector of ``responses``; all share one set of range-bin edges.

    ``thresholds`` are the fallbacks for detectors without target responses; ``taus`` forces
    thresholds (e.g. to draw the curves at other operating points). ``provenance`` is merged
    over what the responses record (counts, seed, sensor, seabed, ...).
    """
    thresholds = thresholds or ThresholdSettings()
    edges = range_edges(responses.target_range_m, calibration.range_bin_m)
    # Thresholds on the nominal targets (SPEC 5, Dobeck at pd_target) keep the operating point
    # of a target of the size and echo the detectors were designed for; the varied rest then
    # shows, in P(y), how often the targets users meet reach it (issue 17 item 5).
    # The targets whose shadow the swath's end cut count in P(y) only: the thresholds,
    # confidence curves and look scores describe a whole signature (docs/calibration.md,
    # "P(y) at the swath's end")
    whole = responses.whole
    nominal = responses.nominal & whole
    on_nominal = thresholds_on_nominal(calibration, nominal)
    tau_from = nominal if on_nominal else whole
    prior, prior_info = cell_prior(calibration, responses.provenance)
    dets = {}
    for d in responses.detectors:
        dets[d] = estimate_detector(responses.target[d], responses.nontarget[d], responses.target_range_m,
                                    calibration=calibration, default_tau=getattr(thresholds, d),
                                    tau=None if taus is None else taus.get(d), edges_m=edges, tau_from=tau_from,
                                    prior_target=prior, score_from=whole)
    looks = estimate_looks(responses, {d: p.tau for d, p in dets.items()}, calibration=calibration,
                           prior_target=prior, edges_m=edges)
    prov: dict[str, Any] = {
        "created_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "atr_node_version": __version__,
        "n_target_responses": int(responses.n_targets),
        "n_nontarget_responses": {d: int(np.isfinite(responses.nontarget[d]).sum()) for d in responses.detectors},
    }
    prov.update(dict(responses.provenance))
    prov.update(dict(provenance or {}))
    est = {"prior_target": prior, **prior_info, "pd_target": calibration.pd_target,
           "range_bin_m": calibration.range_bin_m, "smoothing": calibration.smoothing,
           "confidence": "P(T | Gamma >= gamma) among responses above tau (SPEC 5, paper eq. 6)",
           "pd": "detected / injected per range bin, Jeffreys-smoothed, Wilson 95 %; 0 outside the span",
           "threshold_on": ("nominal" if on_nominal else "population"),
           "n_threshold_targets": int(nominal.sum()) if on_nominal else int(responses.n_targets)}
    return PerformanceModel(detectors=dets, provenance=prov, estimation=est, looks=looks)


AUTO_FIT_CLIPPED_CELLS = _looks.MIN_STRATUM_CELLS
"""``calibration.look_weights = "auto"`` fits the look score's weights where at least this many of
the calibration's clean cells lie within ``clip_headroom_db`` of the recording's full scale (the
clean cells the clipped places need for likelihood ratios of their own): the seabed clips, and
the highlight detectors read the same cut pixels. Float data (no full scale) never does."""

DEFAULT_CELL_AREA_M2 = 5.0
"""Area of a template-sized cell when the responses do not record it (L = 2 m by W + S of
about 2.5 m at mid-range)."""


def cell_prior(calibration: CalibrationSettings, provenance: Mapping[str, Any]) -> tuple[float, dict[str, Any]]:
    """P(T) per template-sized cell (SPEC 6.1) and what the model file records about it.

    ``prior = "area"``: ``1 - exp(-rho A)`` with ``rho`` = ``target_density_km2`` and ``A`` the
    mean area of the non-target cells the responses were measured on (``cell_area_m2`` in
    their provenance); ``"fixed"``: ``prior_target``.
    """
    if calibration.prior == "fixed":
        return float(calibration.prior_target), {"prior": "fixed"}
    area = provenance.get("cell_area_m2")
    area = float(area) if isinstance(area, (int, float)) and np.isfinite(area) and area > 0 else DEFAULT_CELL_AREA_M2
    return area_prior(calibration.target_density_km2, area), {
        "prior": "area", "target_density_km2": float(calibration.target_density_km2), "cell_area_m2": area}


def look_tau(z_t: np.ndarray, fired_t: np.ndarray, look_pd: float) -> float:
    """The look's threshold z_tau: the largest z with ``P(fired and z >= z_tau | T) >= look_pd``
    over the covered injected targets (``z_t`` finite); -inf with ``look_pd = 0`` or when the
    fired targets are fewer than that share (every fired look then detects: a detector set
    that misses more than ``1 - look_pd`` of the injected targets on its own, as a single
    detector may, keeps every look it fired).

    A look whose detectors fired only weakly (a lone detector just over its threshold, as
    textured seabed makes them on every pass) is far more often seabed than target: counted as
    a detection it gave its small T mass and blocked that look's miss evidence, so an object
    seen on one leg, or clutter, kept the Bel another pass should have taken away.
    """
    z = np.asarray(z_t, dtype=np.float64)
    covered = np.isfinite(z)
    if look_pd <= 0.0 or not covered.any():
        return -math.inf
    hits = np.sort(z[covered & np.asarray(fired_t, dtype=bool)])[::-1]  # strongest first
    k = math.ceil(look_pd * int(covered.sum()) - 1e-9)  # targets the threshold must keep (as dobeck_threshold)
    if k < 1 or hits.size < k:
        return -math.inf
    return float(hits[k - 1])


def estimate_looks(responses: Any, taus: Mapping[str, float], *, calibration: Any, prior_target: float,
                   edges_m: np.ndarray) -> _looks.LookModel:
    """Look tables for every non-empty subset of ``responses.detectors`` (SPEC 6.1).

    Needs joint non-target responses: the same cells for every detector (as
    :func:`~atr_node.calibration.responses.collect_image` records them); where the detectors'
    non-target arrays differ in length (responses pooled from elsewhere), no table is made.
    """
    dets = tuple(responses.detectors)
    whole = responses.whole  # P(y) reads every target, the rest these (as estimate_model)
    tails = {d: _looks.tail_table(responses.nontarget[d]) for d in dets}
    lrs = ({d: _looks.lr_table(responses.target[d][whole], responses.nontarget[d], tail=tails[d]) for d in dets}
           if calibration.look_score == "lr" else None)
    # places where the recording clips (an 8-bit file's bright seabed): their own likelihood
    # ratios, and the others' from the others, when both have enough targets and cells
    sizes = {np.asarray(responses.nontarget[d]).size for d in dets}
    lrs_clipped, clipped_at, limit = None, None, calibration.clip_headroom_db
    h_t, h_n = responses.target_traits.get("headroom_db"), responses.nontarget_headroom_db
    c_n = _looks.clipped(h_n, limit) if h_n is not None else np.zeros(0, dtype=bool)  # clean cells that clip
    if lrs is not None and h_t is not None and h_n is not None and {c_n.size} == sizes:
        c_t = _looks.clipped(h_t, limit)
        if (min(int((c_t & whole).sum()), int((~c_t & whole).sum())) >= _looks.MIN_STRATUM_TARGETS
                and min(int(c_n.sum()), int((~c_n).sum())) >= _looks.MIN_STRATUM_CELLS):
            lrs = {d: _looks.lr_table(responses.target[d][~c_t & whole], responses.nontarget[d][~c_n], tail=tails[d])
                   for d in dets}
            lrs_clipped = {d: _looks.lr_table(responses.target[d][c_t & whole], responses.nontarget[d][c_n],
                                              tail=tails[d])
                           for d in dets}
            clipped_at = (c_t, c_n)
    terms = tails if lrs is None else lrs
    info: dict[str, Any] = {"score": _looks.LR_SCORE_DEFINITION if lrs is not None else _looks.SCORE_DEFINITION,
                            "fired": "at least one detector of the set above its threshold",
                            "confidence": "P(T | Z >= z, fired), prior per cell as for the detectors",
                            "pd": "share of injected targets on which the set fired with z > tau (tau the float just below "
                                  f"the look's threshold z_tau, look_pd {calibration.look_pd:g}"
                                  + (f"; or look_z_min {calibration.look_z_min:g} itself where that is higher, "
                                     "tau_source look_z" if lrs is not None else "")
                                  + "), per range bin"}
    if clipped_at is not None:
        info["clipped"] = (f"own likelihood ratios where the seabed is within {limit:g} dB of the recording's full scale: "
                           f"{int((clipped_at[0] & whole).sum())} targets, {int(clipped_at[1].sum())} cells there; the "
                           f"others from {int((~clipped_at[0] & whole).sum())} targets, {int((~clipped_at[1]).sum())} cells")
    if lrs is not None:
        # None: no floor (-inf has no JSON form)
        info["look_z_min"] = float(calibration.look_z_min) if math.isfinite(calibration.look_z_min) else None
    if len(sizes) != 1:
        info["skipped"] = "non-target responses of the detectors are not joint (different lengths)"
        return _looks.LookModel(tails, {}, info, lrs, lrs_clipped, None if lrs_clipped is None else float(limit))
    tables = {}
    weights: dict[str, dict[str, float]] = {}
    weights_clipped: dict[str, dict[str, float]] = {}
    fit_weights, why = False, ""
    if lrs is not None and calibration.look_weights == "fit":
        fit_weights = True
    elif lrs is not None and calibration.look_weights == "auto":
        n_clip = int(c_n.sum())
        fit_weights = n_clip >= AUTO_FIT_CLIPPED_CELLS
        why = (f"look_weights auto: {n_clip} of {c_n.size} clean cells within {limit:g} dB of full scale "
               f"(the fit from {AUTO_FIT_CLIPPED_CELLS})")
    if fit_weights:
        info["weights"] = ("per detector set, the weight of each detector's term in z: a class-balanced logistic fit "
                           "(weights >= 0) of the injected targets against the clean cells the set fired on"
                           + (f" ({why})" if why else ""))
    for n in range(1, len(dets) + 1):
        for subset in itertools.combinations(dets, n):
            z_t, f_t, z_n, f_n, w, w_c = _looks.look_scores(responses.target, responses.nontarget, taus, terms,
                                                            subset, clipped_terms=lrs_clipped, clipped_at=clipped_at,
                                                            fit=fit_weights, fit_targets=whole)
            if w:
                weights[_looks.subset_key(subset)] = w
            if w_c:
                weights_clipped[_looks.subset_key(subset)] = w_c
            fired_z = np.concatenate([z_t[f_t & np.isfinite(z_t)], z_n[f_n & np.isfinite(z_n)]])
            # every fired response above a threshold below all of them, the others below it ...
            tau = float(fired_z.min()) - 1e-9 * max(1.0, abs(float(fired_z.min()))) if fired_z.size else 0.0
            below = tau - 1.0
            source = "look"  # every fired look detects
            # ... unless the look's own threshold z_tau applies: a look whose z stays below it
            # counts as a miss. The table keeps the largest float below z_tau, so the looks
            # that detect (z > tau, the k-th target's z_tau included) are exactly the
            # confidence curve's exceedances, and P(y) is measured with the same rule
            z_tau = look_tau(z_t[whole], f_t[whole], calibration.look_pd)
            if z_tau > tau:
                tau, source = float(np.nextafter(z_tau, -np.inf)), "look_pd"
            # ... and, for the likelihood-ratio score, a look whose detectors together say the
            # seabed is at least as likely as a target (z <= look_z_min, 0) is a miss as well
            if lrs is not None and calibration.look_z_min > tau:
                tau, source = float(calibration.look_z_min), "look_z"
            x_t = np.where(f_t, z_t, np.where(np.isfinite(z_t), below, np.nan))
            x_n = np.where(f_n, z_n, np.where(np.isfinite(z_n), below, np.nan))
            conf = confidence_curve(x_t[whole], x_n, tau, prior_target=prior_target,
                                    n_points=calibration.confidence_points, smoothing=calibration.smoothing)
            hit_t = f_t & look_detects(z_t, tau, source)
            det_t = np.where(np.isfinite(z_t), hit_t.astype(np.float64), np.nan)
            pyr = pd_curve(responses.target_range_m, det_t, 0.5, edges_m=edges_m, smoothing=calibration.smoothing)
            covered = np.isfinite(z_t) & whole
            pd_tau = float(np.mean(hit_t[covered])) if covered.any() else math.nan
            tables[_looks.subset_key(subset)] = DetectorPerformance(tau=tau, confidence=conf, pyr=pyr, tau_source=source,
                                                             pd_at_tau=pd_tau)
    return _looks.LookModel(tails, tables, info, lrs, lrs_clipped, None if lrs_clipped is None else float(limit),
                            weights or None, weights_clipped or None)
