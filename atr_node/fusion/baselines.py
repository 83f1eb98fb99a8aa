"""Logical AND / OR fusion baselines over the same detections (SPEC section 6, paper section 6).

Detections of every detector and leg (as deposited in the grid,
``EvidenceGrid.detections``) are grouped within the association gate of the strongest
detection of each group (greedy leader clustering: no chaining across a dense field). Then

- **OR**: every group is a contact (any one detector fired);
- **AND**: a group is a contact when every detector of the chosen set fired in it at least once.

A group's position is the mean of its detections. These are operating points, not curves:
the paper compares them with the ROC of the Dempster-Shafer belief.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .grid import DetectionRecord


@dataclass(frozen=True)
class LogicalContact:
    """A contact of a logical baseline."""

    east_m: float
    north_m: float
    detectors: tuple[str, ...]
    """Detectors that fired in the group (sorted)."""
    detections: int
    legs: tuple[int, ...]
    max_confidence: float


def leader_groups(xy: np.ndarray, weight: np.ndarray, *, radius_m: float) -> tuple[int, np.ndarray]:
    """Greedy leader clustering: the strongest point not yet grouped leads a group and takes
    every ungrouped point within ``radius_m`` of it; repeat. Unlike single linkage it cannot
    chain a dense field of detections into one group spanning tens of metres. Ties are broken
    by input order, so the grouping is deterministic. Returns (n_groups, labels (K,))."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    k = xy.shape[0]
    labels = np.full(k, -1, dtype=np.int64)
    if k == 0:
        return 0, labels
    tree = cKDTree(xy)
    order = np.lexsort((np.arange(k), -np.asarray(weight, dtype=np.float64)))
    n = 0
    for i in order:
        if labels[i] >= 0:
            continue
        near = np.asarray(tree.query_ball_point(xy[i], r=radius_m), dtype=np.int64)
        near = near[labels[near] < 0]
        labels[near] = n
        labels[i] = n
        n += 1
    return n, labels


def group_detections(records: Sequence[DetectionRecord], *, gate_m: float) -> tuple[int, np.ndarray]:
    """Groups of detections within ``gate_m`` of their strongest (highest confidence, then
    gamma) member: (n_groups, labels (D,)). See :func:`leader_groups`."""
    if not records:
        return 0, np.zeros(0, dtype=np.int64)
    xy = np.array([(r.east_m, r.north_m) for r in records], dtype=np.float64)
    conf = np.array([r.confidence for r in records], dtype=np.float64)
    return leader_groups(xy, conf, radius_m=gate_m)


def _contacts(records: Sequence[DetectionRecord], gate_m: float, required: frozenset[str] | None) -> list[LogicalContact]:
    n, labels = group_detections(records, gate_m=gate_m)
    out = []
    for g in range(n):
        members = [records[i] for i in np.flatnonzero(labels == g)]
        fired = frozenset(r.detector for r in members)
        if required is not None and not required <= fired:
            continue
        out.append(LogicalContact(east_m=float(np.mean([r.east_m for r in members])),
                                  north_m=float(np.mean([r.north_m for r in members])),
                                  detectors=tuple(sorted(fired)), detections=len(members),
                                  legs=tuple(sorted({r.leg for r in members})),
                                  max_confidence=max(r.confidence for r in members)))
    return out


def or_contacts(records: Sequence[DetectionRecord], *, gate_m: float) -> list[LogicalContact]:
    """OR baseline: every group of detections is a contact."""
    return _contacts(records, gate_m, None)


def and_contacts(records: Sequence[DetectionRecord], *, gate_m: float, detectors: Iterable[str]) -> list[LogicalContact]:
    """AND baseline: groups in which every detector of ``detectors`` fired at least once."""
    required = frozenset(detectors)
    if not required:
        raise ValueError("and_contacts needs at least one detector")
    return _contacts([r for r in records if r.detector in required], gate_m, required)
