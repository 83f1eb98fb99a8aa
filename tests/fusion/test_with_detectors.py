"""The grid fed as the node feeds it: real detections (atr_node.detectors.find_detections) on a
score map with a planted blob, confidence and Pd from the shipped performance model."""

from __future__ import annotations

import numpy as np
import pytest

from atr_node.calibration import PerformanceModel
from atr_node.config import FusionSettings
from atr_node.detectors import find_detections
from atr_node.fusion import (ContactTracker, DetectionEvidence, DetectorObservation, EvidenceGrid, Observation)
from atr_node.fusion.mass import NOT_T, T, combine_all, simple_support

from .conftest import pixel_of, track_geometry

TARGET = (50.0, 0.0)


def test_planted_blob_becomes_one_contact_with_reference_belief(frame):
    model = PerformanceModel.shipped()
    g = track_geometry(frame, east0_m=0.0, north0_m=-20.0, heading_deg=0.0, rows=400, cols=700)
    r0, c0 = pixel_of(g, *TARGET)
    rows, cols = np.mgrid[0:400, 0:700]
    blob = np.exp(-((rows - r0) ** 2 + (cols - c0) ** 2) / (2 * 4.0 ** 2))
    views, confs = [], {}
    for d in model.tau:
        score = blob * 2.0 * model.tau[d]  # peak at twice the threshold, at the target's anchor
        score[:, :3] = np.nan  # window edge: no score, not covered
        dets = find_detections(score, model.tau[d], detector=d, range0_m=20.0, dr_m=0.1, dx_m=0.1,
                               min_extent_m=0.2, max_extent_m=6.0)
        assert len(dets) == 1 and (dets[0].row, dets[0].col) == (r0, c0)
        confs[d] = float(model.confidence(d, dets[0].gamma))
        ev = tuple(DetectionEvidence.from_detection(x, confs[d]) for x in dets)
        views.append(DetectorObservation(d, ~np.isnan(score), model.pd(d, g.ranges_m), ev))
    fusion = FusionSettings()
    grid = EvidenceGrid(fusion, gate_m=3.0, detectors=tuple(model.tau))
    tracker = ContactTracker(fusion, frame, gate_m=3.0)
    grid.add_observation(Observation(leg=1, t=5.0, geometry=g, detectors=tuple(views)))
    (c,) = tracker.update(grid, 5.0)
    assert c.state == "new" and set(c.detectors) == set(model.tau) and c.detections == 4
    assert np.hypot(c.east_m - TARGET[0], c.north_m - TARGET[1]) < 0.5
    ref = combine_all([simple_support(T, min(x, 1 - 1e-9)) for x in confs.values()])
    assert float(grid.masses_at(*TARGET).m_t) == pytest.approx(ref[frozenset({T})], abs=1e-12)
    # far from the blob, every detector's miss: brute-force reference over the cell's pixels
    e, n = 70.2, 5.2
    ew, nw = g.world_grid()
    iy, ix = grid.cell_of(e, n)
    in_cell = (np.floor(ew / 0.5) == ix) & (np.floor(nw / 0.5) == iy)
    assert in_cell.sum() >= 16  # about 25 pixels of 0.1 m in a 0.5 m cell
    ref_n = combine_all([simple_support(NOT_T, float(model.pd(d, g.ranges_m)[np.nonzero(in_cell)[1]].max()))
                         for d in model.tau])
    assert float(grid.masses_at(e, n).m_n) == pytest.approx(ref_n.get(frozenset({NOT_T}), 0.0), abs=1e-12)
