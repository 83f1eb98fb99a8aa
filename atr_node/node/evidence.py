"""A unit's detections and coverage as evidence for the grid: per detector (the paper) or per
look (SPEC 6.1, the default).

- ``paper``: one :class:`~atr_node.fusion.DetectorObservation` per detector, its detections at
  ``c_d(gamma)`` and its misses at ``Pd_d(r)``: four pieces per leg and cell, taken as
  independent.
- ``look``: one observation for the look (layer ``"look"``): every detection of every detector
  at the look confidence ``c(z)`` of its joint responses (``Detection.joint``), and the misses
  at the look's ``Pd(r)`` where any detector covered the cell. One piece per leg and cell: the
  grid keeps the maximum T mass of the look there, and the detection records keep the detector
  that made each detection.

The node (``pipeline._fuse``) and the evaluation (``evaluation.methods.fuse``) both call
:func:`unit_observations`, so what is evaluated is what the node publishes.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..calibration.looks import ranked_confidence, subset_key
from ..fusion import DetectionEvidence, DetectorObservation
from ..fusion.baselines import leader_groups

log = logging.getLogger(__name__)

LOOK_LAYER = "look"


def evidence_layers(evidence: str, model: Any, enabled: Sequence[str]) -> tuple[str, ...]:
    """The grid's evidence layers for ``fusion.evidence`` and a model: ``("look",)`` when look
    evidence is asked for and the model has the look table of ``enabled``, else the detectors
    (with a warning when look evidence was asked for)."""
    if evidence == "look":
        if model.look(enabled) is not None:
            return (LOOK_LAYER,)
        log.warning("fusion.evidence = 'look' but the performance model has no look-level table for %s (a model "
                    "from before SPEC 6.1): per-detector evidence (the paper's form) is used; recalibrate with "
                    "'atr-node calibrate' for look-level evidence", "+".join(enabled))
    return tuple(enabled)


def unit_observations(model: Any, detections: Mapping[str, Sequence[Any]], covered: Callable[[str], np.ndarray],
                      ranges_m: np.ndarray, enabled: Sequence[str], layers: Sequence[str], *,
                      missed: bool = True, geometry: Any = None,
                      object_m: float = 0.0) -> tuple[DetectorObservation, ...]:
    """The observations of one unit's core for a grid with evidence ``layers``.

    Parameters
    ----------
    model : PerformanceModel
        Thresholds' confidences and P(y), per detector and per look.
    detections : mapping detector -> list of Detection
        At the model's thresholds, with ``joint`` responses for look evidence.
    covered : callable
        ``covered(d)``: the detector's covered mask of the core (bool, rows x cols).
    ranges_m : (cols,) float
        Ground range of each column.
    missed : bool
        False: no missed-detection evidence (Pd 0), for the comparison without it.
    geometry : TileGeometry, optional
        The core's georeferencing; with ``object_m`` > 0, look evidence places a look's
        detections of one object at one anchor (:func:`one_anchor_per_object`).
    object_m : float
        Anchors of one look closer than this (metres on the ground) are one object: the
        template's length (the node passes ``template.length_m``); 0 = every anchor stands.
    """
    ranges_m = np.asarray(ranges_m, dtype=np.float64)
    if tuple(layers) != (LOOK_LAYER,):
        out = []
        for d in enabled:
            dets = tuple(DetectionEvidence.from_detection(x, float(model.confidence(d, x.gamma)))
                         for x in _strongest_of_patches(detections[d]))
            pd = _pd(model.pd(d, ranges_m)) if missed else np.zeros(ranges_m.size)
            out.append(DetectorObservation(d, covered(d), pd, dets))
        return tuple(out)
    table = model.look(enabled)
    # canonical detector order: a look's detections carry equal confidences (one z per place),
    # so the order of the records would break ties downstream; the node and the evaluation's
    # comparison pass (which lists detectors by rank) must give the same records
    enabled = subset_key(enabled).split("+")
    cov = None
    for d in enabled:
        c = covered(d)
        cov = c.copy() if cov is None else (cov | c)
    dets = []
    if table is None:
        # a look-layered grid fed by a model without look tables (a later model of another
        # kind): the strongest single detector stands for the look
        for d in enabled:
            dets += [DetectionEvidence.from_detection(x, float(model.confidence(d, x.gamma)), source=d)
                     for x in _strongest_of_patches(detections[d])]
        pd = np.max([_pd(model.pd(d, ranges_m)) for d in enabled], axis=0) if missed else np.zeros(ranges_m.size)
    else:
        scored = []
        for d in enabled:
            for x in detections[d]:
                joint = dict(x.joint) if x.joint is not None else {d: x.gamma}
                scored.append((d, x, float(model.look_score({k: np.float64(v) for k, v in joint.items()}, enabled,
                                                            headroom_db=x.headroom_db))))
        # a look this weak is a miss (calibration.look_pd, look_z_min): no T mass there
        found = [(d, x, z) for d, x, z in scored if table.detects(z)]
        # anchors from every detecting look, then one look per textured patch: thinning a patch
        # (detectors.patch_one_look) drops detections, it never moves the others
        anchor = (one_anchor_per_object([x for _, x, _ in found], [z for _, _, z in found], geometry, object_m)
                  if geometry is not None and object_m > 0 else list(range(len(found))))
        keep = _one_per_patch([x for _, x, _ in found], [z for _, _, z in found])
        for i, ((d, x, z), a) in enumerate(zip(found, anchor)):
            if not keep[i]:
                continue
            # the table's ties (its flat top, its isotonic pools) broken by z: Bel ranks them
            c = float(ranked_confidence(np.clip(table.confidence_at(z), 0.0, 1.0), z))
            ev = DetectionEvidence.from_detection(x, c, source=d)
            if a != i:  # at the anchor of the object's strongest detection in this look
                at = found[a][1]
                ev = dataclasses.replace(ev, row=int(at.row), col=int(at.col), range_m=float(at.range_m))
            dets.append(ev)
        pd = _pd(table.pd_at(ranges_m)) if missed else np.zeros(ranges_m.size)
    if cov is None:
        return ()
    return (DetectorObservation(LOOK_LAYER, cov, pd, tuple(dets)),)


def one_anchor_per_object(found: Sequence[Any], strength: Sequence[float], geometry: Any,
                          radius_m: float) -> list[int]:
    """For each of one look's detections ``found``, the index of the detection whose anchor it
    takes: the strongest (largest ``strength``, the look score z; the first on ties) point
    detection within ``radius_m`` on the ground of it, itself when none is stronger.

    The detectors anchor one object at different places (the echo, the echo/shadow boundary,
    the centre of a window, the strongest speckle of the highlight), up to two or three metres
    apart, and the contact stage, which groups detections within the association gate, split
    such a spread into two or three contacts around one target. Placed at one anchor, a look's
    detections of one object make one contact, its detectors still listed. Extended objects
    (``length_m`` set, ``detectors/objects.py``) keep their own anchors and take no others.
    Greedy from the strongest, as non-maximum suppression: the leader clustering the contact
    stage and the AND/OR baselines use (:func:`~atr_node.fusion.baselines.leader_groups`), so a
    detection within ``radius_m`` of two stronger anchors takes the stronger one's."""
    out = list(range(len(found)))
    idx = [i for i, x in enumerate(found) if getattr(x, "length_m", None) is None]  # point detections
    if len(idx) < 2 or not radius_m > 0:
        return out
    e, n = geometry.world(np.array([found[i].row for i in idx]), np.array([found[i].col for i in idx]))
    w = np.array([float(strength[i]) for i in idx])
    _, labels = leader_groups(np.column_stack([e, n]), w, radius_m=radius_m)
    leader: dict[int, int] = {}
    for k in np.lexsort((np.arange(len(idx)), -w)).tolist():  # leader_groups' order: its leaders come first
        leader.setdefault(int(labels[k]), idx[k])
        out[idx[k]] = leader[int(labels[k])]
    return out


def _one_per_patch(found: Sequence[Any], strength: Sequence[float]) -> list[bool]:
    """Which of ``found`` (detections of one unit) count: all outside textured patches
    (``Detection.patch``, ``detectors/objects.py``); in a patch, those anchored at its strongest
    place (the largest ``strength`` there, the first such on ties), so a rock pile is one look,
    not one per rock."""
    top: dict[int, tuple[float, int, int]] = {}
    for x, v in zip(found, strength):
        if x.patch and (x.patch not in top or v > top[x.patch][0]):
            top[x.patch] = (v, x.row, x.col)
    return [not x.patch or (x.row, x.col) == top[x.patch][1:] for x in found]


def _strongest_of_patches(found: Sequence[Any]) -> list[Any]:
    """One detector's ``found`` with :func:`_one_per_patch` by gamma."""
    return [x for x, k in zip(found, _one_per_patch(found, [x.gamma for x in found])) if k]


def _pd(pd: np.ndarray) -> np.ndarray:
    return np.clip(np.nan_to_num(np.asarray(pd, dtype=np.float64), nan=0.0), 0.0, 1.0)
