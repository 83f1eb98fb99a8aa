"""One footprint for T and notT; no contact without a detection; position from detections
(SPEC 6.1 third bullet, SPEC 7; issue 18: contacts with ``detections: 0`` at the ends of legs)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from atr_node.config import FusionSettings
from atr_node.fusion import ContactTracker, EvidenceGrid
from atr_node.fusion.contacts import detection_position
from atr_node.fusion.grid import DetectionRecord
from atr_node.fusion.mass import closed_form
from atr_node.fusion.observation import gate_cells

from .conftest import observe, pixel_of, step_pd, track_geometry

CONF = {"lac": 0.8, "smf": 0.7, "z": 0.6}
END = (50.0, 19.8)
"""A target 0.2 m before the end of leg 1's coverage (its last ping is at north 19.9 m)."""


def end_of_leg(frame, *, tiles: int = 1):
    """Leg 1 northbound from north -20 m to 19.9 m (cut into ``tiles`` tile cores), detecting
    ``END`` with three detectors; leg 2 southbound over the same stretch, Pd 0.95 there, no
    detection (as a lawnmower's legs all end on one line)."""
    rows = 400 // tiles
    out = []
    for k in range(tiles):
        g = track_geometry(frame, east0_m=0.0, north0_m=-20.0 + k * rows * 0.1, heading_deg=0.0, rows=rows,
                           cols=700, leg=1)
        r, c = pixel_of(g, *END)
        hit = np.hypot(*(np.array(g.world(r, c)) - END)) < 0.1
        out.append(observe(g, 1, 1.0 + k, {d: (None, step_pd(g.ranges_m), [(r, c, conf)] if hit else [])
                                           for d, conf in CONF.items()}))
    g2 = track_geometry(frame, east0_m=100.0, north0_m=19.9, heading_deg=180.0, rows=400, cols=700, leg=2)
    out.append(observe(g2, 2, 10.0, {d: (None, step_pd(g2.ranges_m), []) for d in CONF}))
    return out


def all_cells(grid: EvidenceGrid):
    """(iy, ix, L_T, L_N) of every allocated cell, open legs included."""
    keys = grid.chunk_keys()
    acc = grid.chunk_accumulators(keys)
    n = grid.n
    cy = np.repeat([k[0] for k in keys], grid.nn)
    cx = np.repeat([k[1] for k in keys], grid.nn)
    cell = np.tile(np.arange(grid.nn), len(keys))
    return cy * n + cell // n, cx * n + cell % n, acc[:, 0].ravel(), acc[:, 1].ravel()


def test_gate_at_the_end_of_a_leg_puts_no_belief_beyond_the_leg(frame):
    obs = end_of_leg(frame)
    grid = EvidenceGrid(FusionSettings(), gate_m=3.0)
    gy, gx = gate_cells(*END, gate_m=3.0, cell_m=grid.cell_m)
    beyond = gy >= 40  # north >= 20 m: leg 1 never covered these cells
    assert beyond.sum() > 20 and (~beyond).sum() > 20  # the gate reaches past the leg's end
    grid.add_observation(obs[0])
    for closed in (False, True):
        if closed:
            grid.close_leg(1)
        la, _ = grid.accumulators(gy, gx)
        # T on the gate's covered cells, once per detector; nothing past the end of the leg
        assert np.all(la[~beyond] == math.fsum(math.log1p(-c) for c in CONF.values()))
        assert np.all(la[beyond] == 0.0)
        assert np.all(grid.masses_at(*grid.cell_centre(gy[beyond], gx[beyond])).m_t == 0.0)
        assert all(grid.legs_at(int(y), int(x)) == [] for y, x in zip(gy[beyond], gx[beyond]))
    grid.add_observation(obs[1])
    grid.close_all()
    iy, ix, la, ln = all_cells(grid)
    bel = closed_form(la, ln).m_t
    # every cell with belief was covered by a leg (no T mass where notT could never reach)
    held = np.flatnonzero(bel > 0.0)
    assert held.size and all(grid.legs_at(int(iy[i]), int(ix[i])) for i in held)
    assert float(bel.max()) < FusionSettings().withdraw_bel  # leg 2's miss (Pd 0.95) outweighs


def test_end_of_leg_gives_no_contact_without_a_detection(frame):
    """Before the footprint rule, leg 1's gate past its end kept Bel 0.976 there after leg 2
    cleared the detection's own cells: a contact with ``detections: 0``."""
    fusion = FusionSettings()
    grid = EvidenceGrid(fusion, gate_m=3.0)
    inc = ContactTracker(fusion, frame, gate_m=3.0)
    full = ContactTracker(fusion, frame, gate_m=3.0, incremental=False)
    msgs = []
    for o in end_of_leg(frame, tiles=4):
        grid.add_observation(o)
        a = [c.to_message() for c in inc.update(grid, o.t)]
        assert a == [c.to_message() for c in full.update(grid, o.t)]
        msgs += a
    grid.close_all()
    a = [c.to_message() for c in inc.update(grid, 99.0)]
    assert a == [c.to_message() for c in full.update(grid, 99.0)]
    msgs += a
    assert msgs and all(m["detections"] > 0 for m in msgs if m["state"] != "withdrawn")
    assert msgs[0]["state"] == "new" and msgs[-1]["state"] == "withdrawn" and inc.live == {}
    assert {m["id"] for m in msgs} == {1}


def test_a_gate_across_a_tile_cut_or_a_merge_is_clipped_to_the_leg_not_the_tile(frame):
    """The footprint is the leg's: a gate reaching into the next tile core of the same leg
    counts there once that core arrives, whatever the cut, the order or a merge of the two
    halves held open in two grids (bit for bit)."""
    fusion = FusionSettings(commit_after_obs=0)
    g = track_geometry(frame, east0_m=0.0, north0_m=-20.0, heading_deg=0.0, rows=400, cols=700, leg=1)
    r, c = pixel_of(g, 50.0, 0.05)  # on the cut at row 200: the gate reaches 3 m into both halves
    pd = step_pd(g.ranges_m)
    whole = EvidenceGrid(fusion, gate_m=3.0)
    whole.add_observation(observe(g, 1, 1.0, {"z": (None, pd, [(r, c, 0.9)])}))
    whole.close_all()
    halves = []
    for rows in (slice(0, 200), slice(200, 400)):
        gi = track_geometry(frame, east0_m=0.0, north0_m=-20.0 + rows.start * 0.1, heading_deg=0.0, rows=200,
                            cols=700, leg=1)
        hits = [(r - rows.start, c, 0.9)] if rows.start <= r < rows.stop else []
        halves.append(observe(gi, 1, 1.0, {"z": (None, pd, hits)}))
    keys = sorted(whole.chunk_keys())
    for order in ((0, 1), (1, 0)):
        cut = EvidenceGrid(fusion, gate_m=3.0)
        for k in order:
            cut.add_observation(halves[k])
        cut.close_all()
        assert np.array_equal(cut.chunk_accumulators(keys), whole.chunk_accumulators(keys))
    # the half with the detection alone: its gate stops at its own coverage
    alone = EvidenceGrid(fusion, gate_m=3.0)
    alone.add_observation(halves[0] if r < 200 else halves[1])
    other = EvidenceGrid(fusion, gate_m=3.0)
    other.add_observation(halves[1] if r < 200 else halves[0])
    gy, gx = gate_cells(*g.world(r, c), gate_m=3.0, cell_m=whole.cell_m)
    la_alone = alone.accumulators(gy, gx)[0]
    assert (la_alone == 0.0).sum() > 10 and (whole.accumulators(gy, gx)[0] < 0.0).all()
    alone.merge(other)  # both halves of the open leg: the layers combine by maximum
    alone.close_all()
    assert np.array_equal(alone.chunk_accumulators(keys), whole.chunk_accumulators(keys))


def test_a_region_without_a_detection_is_never_a_contact(frame):
    """Neither born (T mass with no detection record) nor kept alive (a later look clears the
    detection's cell, the rest of its region stays above ``withdraw_bel``); both extractions."""
    fusion = FusionSettings()
    grid = EvidenceGrid(fusion, gate_m=3.0)
    inc = ContactTracker(fusion, frame, gate_m=3.0)
    full = ContactTracker(fusion, frame, gate_m=3.0, incremental=False)

    def step(t):
        a = [c.to_message() for c in inc.update(grid, t)]
        assert a == [c.to_message() for c in full.update(grid, t)]
        return a

    iy, ix = np.meshgrid(np.arange(100, 105), np.arange(100, 105), indexing="ij")
    grid.deposit(1, "mf", 1.0, iy, ix, m_t=0.9)  # Bel 0.9 over 25 cells, no detection
    assert step(1.0) == [] and inc.live == {}
    iy2, ix2 = iy + 40, ix
    grid.detections.append(DetectionRecord(2, "mf", 51.25, 71.25, 2.0, 0.9, 3.0))  # cell (142, 102)
    assert tuple(int(v) for v in grid.cell_of(51.25, 71.25)) == (142, 102)
    grid.deposit(2, "mf", 2.0, iy2, ix2, m_t=0.9)
    (born,) = step(2.0)
    assert born["state"] == "new" and born["detections"] == 1
    assert (born["east_m"], born["north_m"]) == (51.25, 71.25)
    # leg 3 misses at the detection's cell only: Bel there 0.9*0.01/(0.1+0.01-0.001) < 0.4,
    # the 24 cells around it stay at 0.9 (a ring, one 8-connected region) without a detection
    grid.deposit(3, "mf", 3.0, np.array([142]), np.array([102]), m_n=0.99)
    (gone,) = step(3.0)
    assert gone["state"] == "withdrawn" and gone["id"] == born["id"] and inc.live == {}
    assert float(grid.masses_at(50.75, 70.75).m_t) == pytest.approx(0.9, abs=1e-12)  # the ring holds
    assert step(4.0) == []


def test_contact_position_is_the_confidence_weighted_mean_of_its_detections(frame):
    """Four legs over one target, detections scattered about it with their confidences: the
    contact sits at their confidence-weighted mean (an independent float64 sum), ``sigma_m``
    is their spread plus the navigation sigma, lat/lon follow."""
    fusion = FusionSettings(nav_sigma_m=0.7)
    target = (50.0, 0.0)
    rng = np.random.default_rng(11)
    grid = EvidenceGrid(fusion, gate_m=3.0)
    inc = ContactTracker(fusion, frame, gate_m=3.0)
    full = ContactTracker(fusion, frame, gate_m=3.0, incremental=False)
    last = {}
    for leg, east0, heading in ((1, 0.0, 0.0), (2, 100.0, 180.0), (3, 10.0, 0.0), (4, 90.0, 180.0)):
        g = track_geometry(frame, east0_m=east0, north0_m=-20.0 if heading == 0.0 else 19.9, heading_deg=heading,
                           rows=400, cols=700, leg=leg)
        r, c = pixel_of(g, *target)
        views = {}
        for d in ("mf", "lac", "smf", "z"):
            dr, dc = (int(v) for v in rng.integers(-6, 7, size=2))
            views[d] = (None, np.full(700, 0.2), [(r + dr, c + dc, float(rng.uniform(0.3, 0.95)))])
        grid.add_observation(observe(g, leg, float(leg), views))
        a = inc.update(grid, float(leg))
        assert [x.to_message() for x in a] == [x.to_message() for x in full.update(grid, float(leg))]
        last.update({x.id: x for x in a})
    (contact,) = last.values()
    dets = grid.detections
    assert contact.detections == len(dets) == 16
    # independent reference: plain float64 sums in Python, the formula of docs/fusion.md
    sw = sum(x.confidence for x in dets)
    e = sum(x.confidence * x.east_m for x in dets) / sw
    n = sum(x.confidence * x.north_m for x in dets) / sw
    var = sum(x.confidence * ((x.east_m - e) ** 2 + (x.north_m - n) ** 2) for x in dets) / sw
    assert contact.east_m == pytest.approx(e, abs=1e-9) and contact.north_m == pytest.approx(n, abs=1e-9)
    assert contact.sigma_m == pytest.approx(math.sqrt(0.5 * var + 0.7 ** 2), rel=1e-12)
    assert math.sqrt(0.5 * var) > 0.1  # the detections do scatter
    lat, lon = frame.to_latlon(contact.east_m, contact.north_m)
    assert (contact.lat_deg, contact.lon_deg) == (float(lat), float(lon))


def test_detection_position_extremes():
    """Confidence 0 everywhere (equal weights), 0 and 1 mixed, 10^5 detections (SPEC 8)."""
    rec = lambda e, n, c: DetectionRecord(1, "mf", e, n, 0.0, c, 1.0)  # noqa: E731
    dets = [rec(10.0, 20.0, 0.0), rec(14.0, 26.0, 0.0)]
    assert detection_position(dets, [0, 1], nav_sigma_m=0.0) == (12.0, 23.0, math.sqrt(0.5 * (4 + 9 + 4 + 9) / 2))
    dets.append(rec(100.0, 200.0, 1.0))
    assert detection_position(dets, [0, 1, 2], nav_sigma_m=1.0) == (100.0, 200.0, 1.0)
    rng = np.random.default_rng(8)
    e = 512683.0 + rng.normal(0.0, 2.0, 100_000)
    n = 5365842.0 + rng.normal(0.0, 2.0, 100_000)
    c = rng.uniform(0.0, 1.0, 100_000)
    many = [rec(float(a), float(b), float(w)) for a, b, w in zip(e, n, c)]
    ge, gn, gs = detection_position(many, range(len(many)), nav_sigma_m=1.0)
    # reference in extended precision: exact products and sums of the float64 inputs
    sw = math.fsum(c)
    assert ge == pytest.approx(math.fsum(c * e) / sw, abs=1e-9) and gn == pytest.approx(math.fsum(c * n) / sw, abs=1e-9)
    order = rng.permutation(len(many)).tolist()  # the order of the detections does not matter
    assert detection_position(many, order, nav_sigma_m=1.0) == (ge, gn, gs)
    assert gs == pytest.approx(math.sqrt(2.0 ** 2 + 1.0), rel=1e-2)


def test_footprint_extremes_confidence_one_and_pd_one(frame):
    """Confidence 1 (clamped to 1 - eps) against Pd 1 (clamped too): finite, counted, and
    still no mass past the end of the detecting leg."""
    obs = end_of_leg(frame)
    for o in obs:
        for d in o.detectors:
            object.__setattr__(d, "detections", tuple(type(x)(x.row, x.col, x.gamma, x.range_m, 1.0)
                                                     for x in d.detections))
            d.pd[:] = 1.0
    grid = EvidenceGrid(FusionSettings(), gate_m=3.0)
    for o in obs:
        grid.add_observation(o)
    grid.close_all()
    iy, ix, la, ln = all_cells(grid)
    m = closed_form(la, ln)
    assert np.all(np.isfinite(m.m_t)) and grid.n_clamped > 0
    gy, gx = gate_cells(*END, gate_m=3.0, cell_m=grid.cell_m)
    assert np.all(grid.accumulators(gy[gy >= 40], gx[gy >= 40])[0] == 0.0)
    inside = grid.masses_at(*END)
    assert float(inside.m_t) == pytest.approx(0.5, abs=1e-6)  # 1 - eps against 1 - eps, three each
