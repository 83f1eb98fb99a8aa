"""Logical AND / OR fusion baselines over the same detections (SPEC section 6, paper section 6).

Detections of every detector and leg (as deposited in the grid,
``EvidenceGrid.detections``) are grouped by single linkage within the association gate: two
detections closer than ``gate_m`` belong to the same group. Then

- **OR**: every group is a contact (any one detector fired);
- **AND**: a group is a contact when every detector of the chosen set fired in it at least once.

A group's position is the mean of its detections. These are operating points, not curves:
the paper compares them with the ROC of the Dempster-Shafer belief.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
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


def group_detections(records: Sequence[DetectionRecord], *, gate_m: float) -> tuple[int, np.ndarray]:
    """Single-linkage groups of detections within ``gate_m``: (n_groups, labels (D,))."""
    k = len(records)
    if k == 0:
        return 0, np.zeros(0, dtype=np.int64)
    xy = np.array([(r.east_m, r.north_m) for r in records], dtype=np.float64)
    pairs = cKDTree(xy).query_pairs(r=gate_m, output_type="ndarray")
    s = np.concatenate([np.arange(k), pairs[:, 0]]) if pairs.size else np.arange(k)
    d = np.concatenate([np.arange(k), pairs[:, 1]]) if pairs.size else np.arange(k)
    n, labels = connected_components(coo_matrix((np.ones(s.size, dtype=np.int8), (s, d)), shape=(k, k)),
                                     directed=False)
    return int(n), labels.astype(np.int64)


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
