"""Contacts: extraction, stable ids, new / update / withdrawn, the ICD message (SPEC 7, ICD 3)."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from atr_node.config import FusionSettings
from atr_node.fusion import Contact, ContactTracker, EvidenceGrid, and_contacts, or_contacts
from atr_node.fusion.contacts import label_cells, label_graph
from atr_node.fusion.grid import DetectionRecord

from .conftest import DETS, TARGETS, mission_observations
from .test_grid import TARGET, leg1, leg2

ICD_KEYS = {"type", "v", "id", "state", "t", "lat_deg", "lon_deg", "east_m", "north_m", "sigma_m", "bel", "pl",
            "m_theta", "looks", "detections", "detectors", "legs"}


def test_label_cells_against_brute_force():
    rng = np.random.default_rng(2)
    mask = rng.uniform(size=(30, 40)) < 0.35
    iy, ix = np.nonzero(mask)
    iy, ix = iy - 15, ix - 7  # negative indices too
    n, lab = label_cells(iy.astype(np.int64), ix.astype(np.int64))
    from scipy import ndimage
    ref, nref = ndimage.label(mask, structure=np.ones((3, 3)))
    assert n == nref
    ref_lab = ref[mask]
    # the same partition: a bijection between labels
    pairs = set(zip(lab.tolist(), ref_lab.tolist()))
    assert len(pairs) == n


@pytest.mark.parametrize("spread", [1, 5000, 10**9])
def test_label_cells_numbering_equals_the_graph_path(spread):
    """The raster path (a compact bounding box) labels and numbers components exactly as the
    neighbour graph (numbered by first cell in the given order: new contact ids follow it)."""
    rng = np.random.default_rng(spread)
    mask = rng.uniform(size=(60, 80)) < 0.3
    iy, ix = np.nonzero(mask)
    iy, ix = iy.astype(np.int64) - 31, ix.astype(np.int64) * spread - 40  # 10**9: no raster
    order = rng.permutation(iy.size)  # any cell order (the tracker's: by chunk)
    iy, ix = iy[order], ix[order]
    n, lab = label_cells(iy, ix)
    n_ref, lab_ref = label_graph(iy, ix)
    assert n == n_ref and np.array_equal(lab, lab_ref)
    assert np.array_equal(np.unique(lab, return_index=True)[1], np.sort(np.unique(lab, return_index=True)[1]))


def test_mission_contacts_have_stable_ids_and_icd_messages(frame):
    fusion = FusionSettings()
    grid = EvidenceGrid(fusion, gate_m=3.0)
    tracker = ContactTracker(fusion, frame, gate_m=3.0)
    seen: dict[int, list[Contact]] = {}
    for o in mission_observations(frame):
        grid.add_observation(o)
        for c in tracker.update(grid, o.t):
            seen.setdefault(c.id, []).append(c)
            assert c.t == o.t
    assert len(seen) == len(TARGETS)
    for cid, msgs in seen.items():
        assert msgs[0].state == "new" and all(m.state == "update" for m in msgs[1:])
        last = msgs[-1]
        # the id stays on one target all along
        dists = [min(np.hypot(m.east_m - te, m.north_m - tn) for te, tn in TARGETS) for m in msgs]
        assert max(dists) < 0.5
        assert last.looks == len(last.legs) >= 2 and last.bel >= fusion.report_bel
        assert last.pl >= last.bel and abs(last.bel + (1 - last.pl) + last.m_theta - 1) < 1e-12
        assert set(last.detectors) <= set(DETS) and last.detections >= 2
        lat, lon = frame.to_latlon(last.east_m, last.north_m)
        assert (last.lat_deg, last.lon_deg) == (float(lat), float(lon))
        msg = last.to_message()
        assert set(msg) == ICD_KEYS and msg["type"] == "contact" and msg["v"] == 1
        wire = msgpack.unpackb(msgpack.packb(msg, use_bin_type=True), raw=False)
        assert Contact.from_message(wire) == last
    # nothing changed: nothing to publish
    assert tracker.update(grid, 9999.0) == []


def test_contact_is_withdrawn_after_a_miss_where_pd_is_high(frame):
    fusion = FusionSettings()
    grid = EvidenceGrid(fusion, gate_m=3.0)
    tracker = ContactTracker(fusion, frame, gate_m=3.0)
    grid.add_observation(leg1(frame)[1])
    (c,) = tracker.update(grid, 1.0)
    assert c.state == "new" and c.id == 1 and c.legs == (1,)
    assert np.hypot(c.east_m - TARGET[0], c.north_m - TARGET[1]) < 0.3
    grid.add_observation(leg2(frame, east0_m=100.0)[1])
    (w,) = tracker.update(grid, 2.0)
    assert w.state == "withdrawn" and w.id == 1 and w.bel < fusion.withdraw_bel
    assert float(grid.masses_at(w.east_m, w.north_m).m_t) == w.bel
    assert tracker.live == {} and tracker.history[1].state == "withdrawn"


def test_hysteresis_between_report_and_withdraw(frame):
    fusion = FusionSettings(report_bel=0.7, withdraw_bel=0.3)
    grid = EvidenceGrid(fusion, gate_m=1.0)
    tracker = ContactTracker(fusion, frame, gate_m=1.0)
    iy, ix = grid.cell_of(10.0, 10.0)
    grid.detections.append(DetectionRecord(1, "mf", 10.0, 10.0, 1.0, 0.5, 3.0))  # contacts need one (SPEC 7)
    grid.deposit(1, "mf", 1.0, iy, ix, m_t=0.5)  # Bel 0.5: between the thresholds, not born
    assert tracker.update(grid, 1.0) == []
    grid.deposit(2, "mf", 2.0, iy, ix, m_t=0.6)  # Bel 0.8: born
    assert [c.state for c in tracker.update(grid, 2.0)] == ["new"]
    grid.deposit(3, "mf", 3.0, iy, ix, m_n=0.8)  # Bel 0.8*0.2/(0.2+0.2-0.04) = 0.44: lives on
    (u,) = tracker.update(grid, 3.0)
    assert u.state == "update" and u.bel == pytest.approx(0.8 * 0.2 / 0.36, abs=1e-12)


def test_and_or_baselines(frame):
    grid = EvidenceGrid(FusionSettings(), gate_m=3.0)
    for o in mission_observations(frame):
        grid.add_observation(o)
    ors = or_contacts(grid.detections, gate_m=3.0)
    ands = and_contacts(grid.detections, gate_m=3.0, detectors=DETS)
    # every target is an OR contact and, with 4 legs at Pd 0.8 each, an AND contact
    for te, tn in TARGETS:
        assert min(np.hypot(c.east_m - te, c.north_m - tn) for c in ors) < 1.0
        assert min(np.hypot(c.east_m - te, c.north_m - tn) for c in ands) < 1.0
    assert len(ands) == len(TARGETS) < len(ors)
    assert sum(c.detections for c in ors) == len(grid.detections)
    three = and_contacts(grid.detections, gate_m=3.0, detectors=("lac", "smf"))
    assert all(set(c.detectors) == {"lac", "smf"} for c in three)


def test_cached_extraction_equals_a_full_recompute_every_update(frame):
    """The tracker reuses per-chunk cells and per-region detection groupings between updates;
    a tracker that drops every cache before each update (as after a restore) must publish
    exactly the same messages, in the same order, with the same ids."""
    fusion = FusionSettings()
    grid = EvidenceGrid(fusion, gate_m=3.0)
    cached, fresh = ContactTracker(fusion, frame, gate_m=3.0), ContactTracker(fusion, frame, gate_m=3.0)
    obs = mission_observations(frame, tiles_per_leg=3, rows=600)
    # two more objects 4 m apart: one region holding two detection groups (the split path)
    from .conftest import observe, track_geometry
    g = track_geometry(frame, east0_m=0.0, north0_m=60.0, heading_deg=0.0, rows=300, cols=700, leg=9)
    pd = np.full(700, 0.5)
    hits = [(100, 400, 0.9), (102, 401, 0.8), (100, 440, 0.85)]
    obs.append(observe(g, 9, 9000.0, {d: (None, pd, hits) for d in DETS}))
    a, b = [], []
    for o in obs:
        grid.add_observation(o)
        a += [c.to_message() for c in cached.update(grid, o.t)]
        fresh.restore(fresh.state())  # drops the cell cache and the groupings
        b += [c.to_message() for c in fresh.update(grid, o.t)]
    grid.close_all()
    a += [c.to_message() for c in cached.update(grid, 1e4)]
    fresh.restore(fresh.state())
    b += [c.to_message() for c in fresh.update(grid, 1e4)]
    assert a == b and len(a) > len(TARGETS)
    assert len(cached._groups) > 0  # the cache was used


def test_chunks_flagged_without_t_evidence_have_no_t_evidence(frame):
    """The tracker skips chunks ``has_t_evidence`` rules out: they must have L_T = 0 (open
    legs included), and chunks near detections must be flagged."""
    grid = EvidenceGrid(FusionSettings(), gate_m=3.0)
    obs = mission_observations(frame, tiles_per_leg=2)
    for o in obs[:-1]:  # the last leg stays open: its layer counts too
        grid.add_observation(o)
    keys = grid.chunk_keys()
    flags = grid.has_t_evidence(keys)
    acc = grid.chunk_accumulators(keys)
    assert any(flags) and not all(flags)
    for f, a in zip(flags, acc):
        if not f:
            assert not (a[0] != 0.0).any()
    for r in grid.detections:
        iy, ix = grid.cell_of(r.east_m, r.north_m)
        key = (int(iy) // grid.n, int(ix) // grid.n)
        assert flags[keys.index(key)]


def _many_targets(frame, *, seed: int, n_targets: int = 30, legs: int = 6, tiles_per_leg: int = 4):
    """A lawnmower of overlapping legs over many objects (some a few metres apart: split
    regions), with missed looks (contacts withdrawn when later legs see nothing) and false
    alarms: every path of the tracker."""
    from .conftest import observe, track_geometry

    rng = np.random.default_rng(seed)
    targets = [(float(rng.uniform(25.0, 140.0)), float(rng.uniform(-15.0, 45.0))) for _ in range(n_targets)]
    targets += [(targets[0][0] + 3.0, targets[0][1] + 1.0), (targets[1][0] - 2.5, targets[1][1])]
    rows, cols = 280, 600
    out = []
    for leg in range(1, legs + 1):
        heading = 0.0 if leg % 2 else 180.0
        east0 = 10.0 + 15.0 * (leg - 1) if heading == 0.0 else 80.0 + 15.0 * (leg - 1)
        for k in range(tiles_per_leg):
            north0 = (-20.0 + k * rows * 0.1) if heading == 0.0 else (50.0 - k * rows * 0.1)
            g = track_geometry(frame, east0_m=east0, north0_m=north0, heading_deg=heading, rows=rows, cols=cols,
                               leg=leg, t0=1.7e9 + 100.0 * leg + k)
            e, n = g.world_grid()
            views = {}
            for d in DETS:
                hits = []
                for te, tn in targets:
                    dist = (e - te) ** 2 + (n - tn) ** 2
                    idx = int(np.argmin(dist))
                    if dist.flat[idx] < 0.05 and rng.uniform() < 0.6:
                        r, c = divmod(idx, cols)
                        hits.append((r, c, float(rng.uniform(0.4, 0.95))))
                for _ in range(int(rng.integers(0, 3))):
                    hits.append((int(rng.integers(0, rows)), int(rng.integers(0, cols)), float(rng.uniform(0.2, 0.6))))
                cov = np.ones((rows, cols), bool)
                cov[:, :4] = False
                views[d] = (cov, np.full(cols, float(rng.uniform(0.3, 0.95))), hits)
            out.append(observe(g, leg, 1000.0 * leg + k, views))
    return out


@pytest.mark.parametrize("scene", ["mission", "split", "many-1", "many-2"])
def test_incremental_update_publishes_what_a_full_extraction_does(frame, scene):
    """The tracker re-labels only the regions near changed chunks (``incremental``); the full
    extraction re-labels every region at every update. Both must publish the same messages,
    in the same order, with the same ids, update after update, across a restore and the
    legs' commits."""
    fusion = FusionSettings()
    if scene == "mission":
        obs = mission_observations(frame, tiles_per_leg=3, rows=600)
    elif scene == "split":
        from .conftest import observe, track_geometry
        obs = mission_observations(frame, seed=9, tiles_per_leg=2)
        g = track_geometry(frame, east0_m=0.0, north0_m=60.0, heading_deg=0.0, rows=300, cols=700, leg=9)
        hits = [(100, 400, 0.9), (102, 401, 0.8), (100, 440, 0.85)]
        obs.append(observe(g, 9, 9000.0, {d: (None, np.full(700, 0.5), hits) for d in DETS}))
    else:
        obs = _many_targets(frame, seed=int(scene[-1]))
    grid = EvidenceGrid(fusion, gate_m=3.0)
    inc = ContactTracker(fusion, frame, gate_m=3.0)
    full = ContactTracker(fusion, frame, gate_m=3.0, incremental=False)
    assert inc.incremental and not full.incremental
    a = []
    for i, o in enumerate(obs):
        grid.add_observation(o)
        ma = [c.to_message() for c in inc.update(grid, o.t)]
        mb = [c.to_message() for c in full.update(grid, o.t)]
        assert ma == mb, f"update {i}"
        a += ma
        if i == len(obs) // 2:  # a node restarting from its snapshot: caches rebuilt from the grid
            inc.restore(inc.state())
    grid.close_all()
    assert [c.to_message() for c in inc.update(grid, 1e5)] == [c.to_message() for c in full.update(grid, 1e5)]
    states = {m["state"] for m in a}
    assert {"new", "update"} <= states
    if scene.startswith("many"):
        assert "withdrawn" in states and len({m["id"] for m in a}) > 10


def test_incremental_update_keeps_regions_away_from_the_changes(frame):
    """Evidence far from a contact leaves its region as it was: not labelled again."""
    from .conftest import observe, track_geometry

    fusion = FusionSettings()
    grid = EvidenceGrid(fusion, gate_m=3.0)
    tracker = ContactTracker(fusion, frame, gate_m=3.0)
    g1 = track_geometry(frame, east0_m=0.0, north0_m=0.0, heading_deg=0.0, rows=300, cols=300, leg=1)
    grid.add_observation(observe(g1, 1, 1.0, {d: (None, np.full(300, 0.2), [(150, 150, 0.9)]) for d in DETS}))
    assert [c.state for c in tracker.update(grid, 1.0)] == ["new"]
    (region,) = tracker._regions.values()
    g2 = track_geometry(frame, east0_m=500.0, north0_m=0.0, heading_deg=0.0, rows=300, cols=300, leg=1)
    grid.add_observation(observe(g2, 1, 2.0, {d: (None, np.full(300, 0.2), [(150, 150, 0.9)]) for d in DETS}))
    assert [c.state for c in tracker.update(grid, 2.0)] == ["new"]
    assert region in tracker._regions.values() and len(tracker._regions) == 2


def test_incremental_update_joins_a_region_across_an_unchanged_chunk_border(frame):
    """New belief in one chunk next to an old region in the neighbouring chunk (which did not
    change) makes one region: the neighbour's region is labelled again with the new cells."""
    fusion = FusionSettings()
    grid = EvidenceGrid(fusion, gate_m=3.0)
    inc = ContactTracker(fusion, frame, gate_m=3.0)
    full = ContactTracker(fusion, frame, gate_m=3.0, incremental=False)
    n = grid.n
    iy, ix = np.meshgrid(np.arange(4), np.arange(n - 3, n), indexing="ij")  # the right edge of chunk (0, 0)
    # the detection behind the region, in chunk (0, 0) (a region without one is no contact)
    grid.detections.append(DetectionRecord(1, "mf", (n - 2 + 0.5) * grid.cell_m, 1.5 * grid.cell_m, 1.0, 0.9, 3.0))
    grid.deposit(1, "mf", 1.0, iy, ix, m_t=0.9)
    assert [c.to_message() for c in inc.update(grid, 1.0)] == [c.to_message() for c in full.update(grid, 1.0)]
    iy, ix = np.meshgrid(np.arange(4), np.arange(n, n + 3), indexing="ij")  # the left edge of chunk (0, 1)
    grid.deposit(1, "mf", 2.0, iy, ix, m_t=0.9)
    assert set(grid.changed_since(1)) == {(0, 1)}  # chunk (0, 0) did not change
    got = [c.to_message() for c in inc.update(grid, 2.0)]
    assert got == [c.to_message() for c in full.update(grid, 2.0)]
    assert len(inc.live) == 1 and len(inc._regions) == 1


def _two_legs(frame, leg_hits, incremental, fusion=None):
    """Legs 1 and 2 over the same ground (one geometry), MF only, Pd 0.9 everywhere; the
    tracker's live contacts (strongest first) and the grid."""
    from .conftest import observe, track_geometry

    fusion = fusion or FusionSettings(evidence="paper")
    grid = EvidenceGrid(fusion, gate_m=3.0, detectors=("mf",))
    tracker = ContactTracker(fusion, frame, gate_m=3.0, incremental=incremental)
    for leg, hits in leg_hits:
        g = track_geometry(frame, east0_m=0.0, north0_m=60.0, heading_deg=0.0, rows=300, cols=700, leg=leg)
        grid.add_observation(observe(g, leg, 1000.0 * leg, {"mf": (None, np.full(700, 0.9), hits)}))
        tracker.update(grid, 1000.0 * leg)
    grid.close_all()
    tracker.update(grid, 3000.0)
    return sorted(tracker.live.values(), key=lambda c: -c.bel), grid


def _own(c1: float, c2: float | None) -> float:
    """Bel on an object's own cell: leg 1's T mass c1; leg 2's c2, or its miss at Pd 0.9."""
    if c2 is None:
        return c1 * (1 - 0.9) / (1 - c1 * 0.9)
    return 1 - (1 - c1) * (1 - c2)


@pytest.mark.parametrize("incremental", [True, False])
def test_a_weaker_object_beside_a_stronger_one_reads_its_own_belief(frame, incremental):
    """Two objects 4 m apart share one belief region (gates of 3 m); it splits into two groups.
    The one-leg object's cells border the other's, whose gate's T mass reaches them, so at its
    peak cell it read the other's Bel: seen on leg 1 only (leg 2 covered it and missed it) it
    was published at the other's 0.99. Each group now reads its Bel at its own position."""
    # the object at column 440 seen by leg 1 only, at 0.9: reported after leg 1, then Bel 0.47
    # on its own cell, between withdraw_bel and report_bel: still live (hysteresis), at 0.47
    live, grid = _two_legs(frame, [(1, [(100, 400, 0.9), (100, 440, 0.9)]), (2, [(100, 400, 0.9)])], incremental)
    assert FusionSettings().withdraw_bel < _own(0.9, None) < FusionSettings().report_bel
    assert [c.detections for c in live] == [2, 1]
    assert live[0].bel == pytest.approx(_own(0.9, 0.9), rel=1e-9)
    assert live[1].bel == pytest.approx(_own(0.9, None), rel=1e-9)  # not the other's 0.99
    # seen by both legs: two contacts, each at its own cell's Bel
    live, grid = _two_legs(frame, [(1, [(100, 400, 0.9), (100, 440, 0.85)]), (2, [(100, 400, 0.9), (100, 440, 0.85)])],
                           incremental)
    assert [c.detections for c in live] == [2, 2]
    strong, weak = live
    assert np.hypot(strong.east_m - weak.east_m, strong.north_m - weak.north_m) == pytest.approx(4.0, abs=0.05)
    assert weak.bel == pytest.approx(_own(0.85, 0.85), rel=1e-9) and strong.bel == pytest.approx(_own(0.9, 0.9), rel=1e-9)
    assert weak.bel == float(grid.masses_at(weak.east_m, weak.north_m).m_t)


@pytest.mark.parametrize("incremental", [True, False])
def test_the_leading_group_reads_its_own_belief_too(frame, incremental):
    """The group of the most confident detection leads the split; it is not the one with the
    highest Bel. A one-leg object at 0.95 beside a rock seen on both legs at 0.8: the object
    leads, and at its peak it read the rock's Bel, ranking above the rock."""
    live, _ = _two_legs(frame, [(1, [(100, 400, 0.8), (100, 440, 0.95)]), (2, [(100, 400, 0.8)])], incremental)
    rock = [c for c in live if c.detections == 2]
    assert len(rock) == 1 and rock[0].bel == pytest.approx(_own(0.8, 0.8), rel=1e-9)
    one_leg = [c for c in live if c.detections == 1]
    assert all(c.bel == pytest.approx(_own(0.95, None), rel=1e-9) for c in one_leg)
    assert all(c.bel < rock[0].bel for c in one_leg)


@pytest.mark.parametrize("incremental", [True, False])
def test_a_group_without_cells_reads_its_region(frame, incremental):
    """Cells go to the nearest group's position, so a group squeezed between two others can
    get none: it reads the nearest of its region's cells (it once raised on an empty argmin)."""
    a = [(100, 369, 0.9)] + [(100, 398, 0.9)] * 10
    c = [(100, 431, 0.9)] + [(100, 402, 0.9)] * 10
    live, grid = _two_legs(frame, [(1, a + c + [(100, 400, 0.5)]), (2, a + c + [(100, 400, 0.5)])], incremental)
    assert live and all(0.0 <= x.bel <= 1.0 for x in live)
    for x in live:
        assert x.bel == pytest.approx(float(grid.masses_at(x.east_m, x.north_m).m_t), abs=0.05)


@pytest.mark.parametrize("incremental", [True, False])
@pytest.mark.parametrize("cut_m", [1.5, 2.0, 2.5])
def test_an_object_missed_by_a_look_that_covered_it_reads_that_miss(frame, incremental, cut_m):
    """Leg 2 covers the object's place (Pd 0.9) and misses it, but its swath ends ``cut_m``
    beyond it, inside leg 1's gate (3 m). The region's peak then lies past leg 2's swath edge,
    where leg 1's T mass is alone: the contact read leg 1's 0.9 there. It reads the highest
    Bel within its sigma (1 m) of its position: leg 2's miss, in the closed form."""
    from .conftest import observe, track_geometry

    fusion = FusionSettings(evidence="paper")
    grid = EvidenceGrid(fusion, gate_m=3.0, detectors=("mf",))
    tracker = ContactTracker(fusion, frame, gate_m=3.0, incremental=incremental)
    col = 400  # 20 m + 40 m of range: the object at 60 m east of the track
    for leg in (1, 2):
        g = track_geometry(frame, east0_m=0.0, north0_m=60.0, heading_deg=0.0, rows=300, cols=700, leg=leg)
        cov = None
        if leg == 2:
            cov = np.zeros((300, 700), bool)
            cov[:, : col + round(cut_m / 0.1)] = True
        hits = [(100, col, 0.9)] if leg == 1 else []
        grid.add_observation(observe(g, leg, 1000.0 * leg, {"mf": (cov, np.full(700, 0.9), hits)}))
        tracker.update(grid, 1000.0 * leg)
    grid.close_all()
    tracker.update(grid, 3000.0)
    (c,) = tracker.live.values()  # born at 0.9 after leg 1, kept above withdraw_bel
    assert c.bel == pytest.approx(_own(0.9, None), rel=1e-9)
    assert 1.0 - c.pl > 0.0  # notT mass: leg 2's miss reached the cell read
    # the region's peak (past leg 2's swath) still holds leg 1's mass alone
    far = grid.masses_at(c.east_m + cut_m + 0.5, c.north_m)
    assert float(far.m_t) == pytest.approx(0.9, rel=1e-9)


def test_peak_near_reads_within_the_radius_or_the_nearest_cell():
    """``_peak_near``: the highest Bel among the cells within the radius (the last on a tie);
    the nearest cell when none is that close."""
    from atr_node.fusion.contacts import _peak_near

    grid = EvidenceGrid(FusionSettings(), gate_m=3.0, detectors=("mf",))
    iy = np.array([0, 0, 0, 0, 10])
    ix = np.array([0, 1, 2, 3, 10])
    bel = np.array([0.9, 0.6, 0.6, 0.95, 0.99])
    e, n = grid.cell_centre(iy, ix)  # e, n of each cell (whichever axis ix runs along)
    ce, cn = float(e[1]), float(n[1])
    step = float(np.hypot(e[1] - e[0], n[1] - n[0]))
    cells = np.arange(5)
    # within one step of cell 1: cells 0-2; the highest there is cell 0 (0.9)
    assert _peak_near(e, n, bel, cells, ce, cn, 1.01 * step) == 0
    # within two steps: cell 3 (0.95) too; cell 4 (0.99) is far
    assert _peak_near(e, n, bel, cells, ce, cn, 2.01 * step) == 3
    # a tie goes to the last such cell
    assert _peak_near(e, n, np.array([0.5, 0.7, 0.7, 0.1, 0.1]), cells, ce, cn, 1.01 * step) == 2
    # none within the radius: the nearest cell
    far_e, far_n = ce + 1000.0, cn + 1000.0
    d = np.hypot(e - far_e, n - far_n)
    assert _peak_near(e, n, bel, cells, far_e, far_n, 1.0) == int(np.argmin(d))
