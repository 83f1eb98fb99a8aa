"""Evidence grid scenarios (SPEC section 7) against the general Dempster rule as reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from atr_node.config import FusionSettings, TemplateSettings
from atr_node.errors import FusionError
from atr_node.fusion import EvidenceGrid, association_gate_m
from atr_node.fusion.mass import NOT_T, T, combine_all, simple_support

from .conftest import observe, pixel_of, step_pd, track_geometry

TARGET = (50.0, 0.0)  # east, north of the target in the mission frame
CONF = {"lac": 0.8, "smf": 0.7, "z": 0.6}


def leg1(frame, t=1.0):
    """Northbound at east = 0: the target at 50 m to starboard, detected by 3 detectors."""
    g = track_geometry(frame, east0_m=0.0, north0_m=-20.0, heading_deg=0.0, rows=400, cols=700)
    r, c = pixel_of(g, *TARGET)
    pd = step_pd(g.ranges_m)
    return g, observe(g, 1, t, {d: (None, pd, [(r, c, conf)]) for d, conf in CONF.items()})


def leg2(frame, east0_m, t=2.0):
    """Southbound at ``east0_m``: the target to starboard (west), no detection."""
    g = track_geometry(frame, east0_m=east0_m, north0_m=20.0, heading_deg=180.0, rows=400, cols=700, leg=2)
    pd = step_pd(g.ranges_m)
    return g, observe(g, 2, t, {d: (None, pd, []) for d in CONF})


def ref_bel(cs, qs):
    m = combine_all([simple_support(T, c) for c in cs] + [simple_support(NOT_T, q) for q in qs])
    return m.get(frozenset({T}), 0.0), m.get(frozenset({NOT_T}), 0.0)


def test_gate_from_settings():
    assert association_gate_m(FusionSettings(nav_sigma_m=1.0, gate_sigmas=2.0), TemplateSettings(length_m=2.0)) == 3.0


def test_detected_then_missed_where_pd_is_high_ends_low(frame, make_grid):
    grid = make_grid()
    grid.add_observation(leg1(frame)[1])
    bel1 = float(grid.masses_at(*TARGET).m_t)
    assert bel1 == pytest.approx(ref_bel(CONF.values(), [])[0], abs=1e-12)
    grid.add_observation(leg2(frame, east0_m=100.0)[1])  # range 50 m: Pd 0.95
    grid.close_all()
    m = grid.masses_at(*TARGET)
    exp_t, exp_n = ref_bel(CONF.values(), [0.95] * 3)
    assert float(m.m_t) == pytest.approx(exp_t, abs=1e-12)
    assert float(m.m_n) == pytest.approx(exp_n, abs=1e-12)
    assert float(m.m_t) < 0.05 < bel1
    assert grid.legs_at(*map(int, grid.cell_of(*TARGET))) == [1, 2]


def test_missed_where_pd_is_low_leaves_belief_nearly_unchanged(frame, make_grid):
    grid = make_grid()
    grid.add_observation(leg1(frame)[1])
    bel1 = float(grid.masses_at(*TARGET).m_t)
    grid.add_observation(leg2(frame, east0_m=125.0)[1])  # range 75 m: Pd 0.1
    grid.close_all()
    m = grid.masses_at(*TARGET)
    assert float(m.m_t) == pytest.approx(ref_bel(CONF.values(), [0.1] * 3)[0], abs=1e-12)
    assert abs(float(m.m_t) - bel1) < 0.01 and float(m.m_t) > 0.95


def test_cell_never_covered_has_no_evidence(frame, make_grid):
    grid = make_grid()
    grid.add_observation(leg1(frame)[1])
    grid.close_all()
    for e, n in ((-30.0, 0.0), (50.0, 500.0), (10.0, 0.0)):  # port side, far north, nadir gap (< 20 m)
        m = grid.masses_at(e, n)
        assert (float(m.m_t), float(m.m_n), float(m.m_theta)) == (0.0, 0.0, 1.0)
        assert grid.legs_at(*map(int, grid.cell_of(e, n))) == []
    la, ln = grid.accumulators(*grid.cell_of(-30.0, 0.0))
    assert float(la) == 0.0 and float(ln) == 0.0


def test_one_piece_per_leg_and_detector_per_cell(frame, make_grid):
    grid = make_grid()
    g = track_geometry(frame, east0_m=0.0, north0_m=-20.0, heading_deg=0.0, rows=400, cols=700)
    pd = np.linspace(0.2, 0.9, g.ranges_m.size)  # Pd varies inside a cell: the max is kept
    grid.add_observation(observe(g, 1, 1.0, {"lac": (None, pd, []), "z": (None, pd * 0.5, [])}))
    grid.close_all()
    # a cell away from the track edges: 25 pixels of 0.1 m in a 0.5 m cell, one piece each
    iy, ix = grid.cell_of(40.2, 0.2)
    la, ln = grid.accumulators(iy, ix)
    e, _ = g.world_grid()
    cols_in = np.flatnonzero((np.floor(e[0] / 0.5) == ix))
    q = pd[cols_in].max()
    assert float(la) == 0.0
    assert float(ln) == math.log1p(-q) + math.log1p(-q * 0.5)


def test_cell_straddling_two_tile_cores_counts_once(frame, make_grid):
    g = track_geometry(frame, east0_m=0.0, north0_m=-20.0, heading_deg=0.0, rows=400, cols=700)
    r, c = pixel_of(g, *TARGET)
    pd = step_pd(g.ranges_m)
    whole = make_grid()
    whole.add_observation(observe(g, 1, 1.0, {"lac": (None, pd, [(r, c, 0.8)]), "z": (None, pd, [])}))
    whole.close_all()
    split = make_grid()
    cut = 203  # row 203 is 0.3 m into a 0.5 m cell: cells on the cut get pixels from both tiles
    for rows, t in ((slice(0, cut), 0.5), (slice(cut, 400), 1.0)):
        gi = track_geometry(frame, east0_m=0.0, north0_m=-20.0 + rows.start * 0.1, heading_deg=0.0,
                            rows=rows.stop - rows.start, cols=700)
        hits = [(r - rows.start, c, 0.8)] if rows.start <= r < rows.stop else []
        split.add_observation(observe(gi, 1, t, {"lac": (None, pd, hits), "z": (None, pd, [])}))
    split.close_all()
    keys = sorted(whole.chunk_keys())
    assert keys == sorted(split.chunk_keys())
    # max-combination makes the result independent of the cut: bit for bit
    assert np.array_equal(whole.chunk_accumulators(keys), split.chunk_accumulators(keys))
    # the cut line itself got exactly one notT piece per detector
    iy, ix = whole.cell_of(30.0, cut * 0.1 - 20.0)
    assert float(whole.accumulators(iy, ix)[1]) == 2 * math.log1p(-0.95)


def test_two_detections_in_one_gate_give_the_maximum_not_the_sum(frame, make_grid):
    grid = make_grid()
    g = track_geometry(frame, east0_m=0.0, north0_m=-20.0, heading_deg=0.0, rows=400, cols=700)
    r, c = pixel_of(g, *TARGET)
    pd = step_pd(g.ranges_m)
    grid.add_observation(observe(g, 1, 1.0, {"lac": (None, pd, [(r, c, 0.6), (r + 3, c + 2, 0.9)])}))
    grid.close_all()
    assert float(grid.accumulators(*grid.cell_of(*TARGET))[0]) == math.log1p(-0.9)


def test_open_leg_is_visible_and_commit_is_identical(frame, make_grid):
    grid = make_grid()
    grid.add_observation(leg1(frame)[1])
    live = grid.masses_at(*TARGET)
    assert float(grid.masses_at(*TARGET, include_open=False).m_t) == 0.0
    grid.close_all()
    assert float(grid.masses_at(*TARGET).m_t) == float(live.m_t)


def test_low_level_deposit_and_exchange(make_grid):
    grid = make_grid()
    iy = np.array([0, 0, 5, -200])
    ix = np.array([0, 1, 5, 300])
    grid.deposit(7, "mf", 1.0, iy, ix, m_n=np.array([0.5, 0.2, 0.9, 0.3]))
    grid.deposit(7, "mf", 1.0, iy[:1], ix[:1], m_n=0.7)  # same leg and detector: max
    grid.deposit(7, "smf", 1.0, iy[2:3], ix[2:3], m_t=1.0)  # clamped
    grid.close_leg(7)
    la, ln = grid.accumulators(iy, ix)
    assert ln.tolist() == [math.log1p(-0.7), math.log1p(-0.2), math.log1p(-0.9), math.log1p(-0.3)]
    assert la[2] == math.log1p(-(1 - 1e-9)) and grid.n_clamped == 1
    grid.add_accumulators(iy[:2], ix[:2], -1.0, 0.0, t=2.0)
    assert grid.accumulators(iy[:2], ix[:2])[0].tolist() == [-1.0, -1.0]


def test_bad_input_is_rejected_whole_and_loses_nothing(frame, make_grid):
    grid = make_grid()
    grid.add_observation(leg1(frame)[1])
    before = grid.chunk_accumulators(sorted(grid.chunk_keys()))
    g = track_geometry(frame, east0_m=0.0, north0_m=30.0, heading_deg=0.0, rows=50, cols=700)
    pd = step_pd(g.ranges_m)
    with pytest.raises(FusionError, match="unknown detector 'xx'"):
        grid.add_observation(observe(g, 1, 3.0, {"lac": (None, pd, []), "xx": (None, pd, [])}))
    with pytest.raises(FusionError, match="pd"):
        observe(g, 1, 3.0, {"lac": (None, pd[:-1], [])})
    with pytest.raises(FusionError, match="confidence"):
        observe(g, 1, 3.0, {"lac": (None, pd, [(1, 1, 1.5)])})
    with pytest.raises(FusionError, match="outside the core"):
        observe(g, 1, 3.0, {"lac": (None, pd, [(50, 1, 0.5)])})
    with pytest.raises(FusionError, match="covered"):
        observe(g, 1, 3.0, {"lac": (np.ones((40, 700), bool), pd, [])})
    assert np.array_equal(grid.chunk_accumulators(sorted(grid.chunk_keys())), before)
    grid.add_observation(leg2(frame, 100.0)[1])  # closes leg 1
    with pytest.raises(FusionError, match="leg 1 is already closed"):
        grid.add_observation(leg1(frame)[1])


def test_nan_coverage_deposits_nothing(frame, make_grid):
    grid = make_grid()
    g = track_geometry(frame, east0_m=0.0, north0_m=-20.0, heading_deg=0.0, rows=100, cols=700)
    cov = np.zeros((100, 700), bool)
    grid.add_observation(observe(g, 1, 1.0, {"lac": (cov, step_pd(g.ranges_m), [])}))
    grid.close_all()
    assert grid.chunk_keys() == [] and grid.covered_cells() == 0


def test_diagnostics_keep_per_detector_terms(frame):
    grid = EvidenceGrid(FusionSettings(diagnostics=True), gate_m=3.0)
    grid.add_observation(leg1(frame)[1])
    grid.close_all()
    total = grid.chunk_accumulators(grid.chunk_keys())
    per = grid.detector_accumulators(grid.chunk_keys())
    assert np.allclose(per.sum(axis=1), total, rtol=0, atol=1e-12)
    assert grid.nbytes()["diagnostics"] == len(grid.chunk_keys()) * 4 * 2 * grid.nn * 8
    # L_N in every chunk, L_T only in the chunks the detection gates reached
    from atr_node.fusion.observation import gate_cells
    g, _ = leg1(frame)
    r, c = pixel_of(g, *TARGET)
    e, n = g.world(r, c)
    iy, ix = gate_cells(float(e), float(n), gate_m=3.0, cell_m=0.5)
    t_chunks = set(zip((iy // grid.n).tolist(), (ix // grid.n).tolist()))  # chunks the gate reaches
    assert len(t_chunks) < len(grid.chunk_keys())
    assert grid.nbytes()["accumulators"] == (len(grid.chunk_keys()) + len(t_chunks)) * grid.nn * 8


def test_early_commit_behind_the_vehicle_is_exact_and_bounds_memory(frame, make_grid):
    from .conftest import mission_observations
    obs = mission_observations(frame, tiles_per_leg=10, rows=1000)  # 10 tiles of 10 m per leg
    results, peaks = [], []
    for after in (0, 2):
        grid = make_grid(commit_after_obs=after)
        peak = 0
        for o in obs:
            grid.add_observation(o)
            peak = max(peak, grid.nbytes()["open_layers"])
        grid.close_all()
        results.append(grid)
        peaks.append(peak)
    whole, early = results
    keys = sorted(whole.chunk_keys())
    assert sorted(early.chunk_keys()) == keys
    assert np.array_equal(early.chunk_accumulators(keys), whole.chunk_accumulators(keys))
    assert early.covered_cells() == whole.covered_cells() and early.n_reopened == 0
    assert peaks[1] < peaks[0]


def test_a_leg_back_over_its_own_committed_ground_is_counted(frame, make_grid):
    grid = make_grid(commit_after_obs=1)
    g = track_geometry(frame, east0_m=0.0, north0_m=-20.0, heading_deg=0.0, rows=100, cols=700)
    far = track_geometry(frame, east0_m=0.0, north0_m=500.0, heading_deg=0.0, rows=100, cols=700)
    pd = step_pd(g.ranges_m)
    grid.add_observation(observe(g, 1, 1.0, {"z": (None, pd, [])}))
    grid.add_observation(observe(far, 1, 2.0, {"z": (None, pd, [])}))  # first tile's chunks committed
    assert grid.n_reopened == 0
    grid.add_observation(observe(g, 1, 3.0, {"z": (None, pd, [])}))   # the same ground again
    assert grid.n_reopened > 0


def test_grid_extremes_many_pieces_and_infinite_accumulators(make_grid):
    from atr_node.fusion.mass import closed_form, log_complement
    grid = make_grid()
    rng = np.random.default_rng(4)
    c = rng.uniform(0.0, 0.2, 100_000)
    cell = np.zeros(100_000, dtype=np.int64)
    grid.add_accumulators(cell, cell, log_complement(c), 0.0, t=1.0)  # 1e5 pieces on cell (0, 0)
    la, ln = grid.accumulators(np.array([0]), np.array([0]))
    assert float(la[0]) == pytest.approx(math.fsum(np.log1p(-c)), rel=1e-12)
    m = grid.masses_at(0.1, 0.1)
    assert float(m.m_t) == 1.0 and float(m.m_theta) == 0.0 and np.isfinite(float(la[0]))
    # -inf accumulators: certainty, exact; both -inf: total conflict flagged, finite
    grid.add_accumulators(np.array([3, 5]), np.array([3, 5]), np.array([-np.inf, -np.inf]), np.array([0.0, -np.inf]),
                          t=2.0)
    m = closed_form(*grid.accumulators(np.array([3, 5]), np.array([3, 5])))
    assert m.m_t.tolist() == [1.0, 0.5] and m.conflict.tolist() == [False, True]
    with pytest.raises(FusionError, match="deltas <= 0"):
        grid.add_accumulators(np.array([1]), np.array([1]), np.array([0.5]), np.array([0.0]), t=3.0)


def test_nav_jump_inside_a_tile_and_non_finite_geometry(frame, make_grid):
    from atr_node.geo import TileGeometry
    g = track_geometry(frame, east0_m=0.0, north0_m=-20.0, heading_deg=0.0, rows=100, cols=700)
    north = g.north_m.copy()
    north[50:] += 1.0e8  # absurd jump: a chunk span too wide for dense codes (the unique path)
    jumped = TileGeometry(g.east_m, north, g.ue, g.un, g.ranges_m, g.heading_grid_rad)
    grid = make_grid()
    grid.add_observation(observe(jumped, 1, 1.0, {"z": (None, step_pd(g.ranges_m), [])}))
    grid.close_all()
    ref = make_grid()
    for rows in (slice(0, 50), slice(50, 100)):
        part = TileGeometry(g.east_m[rows], north[rows], g.ue[rows], g.un[rows], g.ranges_m,
                            g.heading_grid_rad[rows])
        ref.add_observation(observe(part, 1, 1.0, {"z": (None, step_pd(g.ranges_m), [])}))
    ref.close_all()
    keys = sorted(ref.chunk_keys())
    assert sorted(grid.chunk_keys()) == keys
    assert np.array_equal(grid.chunk_accumulators(keys), ref.chunk_accumulators(keys))
    bad = north.copy()
    bad[3] = np.nan
    with pytest.raises(FusionError, match="north_m is not finite"):
        observe(TileGeometry(g.east_m, bad, g.ue, g.un, g.ranges_m, g.heading_grid_rad), 1, 1.0,
                {"z": (None, step_pd(g.ranges_m), [])})


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_grid_does_not_depend_on_order_or_grouping(seed):
    """Deposits in any order within a leg give the same layer bit for bit (maximum); legs in
    any order or merged in any grouping give the same belief to rounding; both equal the
    general rule over the pieces the one-per-(leg, detector, cell) rule keeps."""
    rng = np.random.default_rng(seed)
    pieces = []  # (leg, detector, iy, ix, kind, mass)
    for leg in range(1, 5):
        for det in ("mf", "z"):
            for _ in range(int(rng.integers(1, 6))):
                iy, ix = rng.integers(-3, 3, size=2)
                pieces.append((leg, det, int(iy), int(ix), "m_t" if rng.uniform() < 0.3 else "m_n",
                               float(rng.uniform(0, 1))))

    def run(order, groups):
        grids = []
        for group in groups:
            g = EvidenceGrid(FusionSettings(), gate_m=1.0, auto_close=False)
            for k in order:
                leg, det, iy, ix, kind, m = pieces[k]
                if leg in group:
                    g.deposit(leg, det, float(leg), np.array([iy]), np.array([ix]), **{kind: m})
            g.close_all()
            grids.append(g)
        for g in grids[1:]:
            grids[0].merge(g)
        return grids[0]

    iy, ix = np.mgrid[-3:3, -3:3]
    a = run(range(len(pieces)), [{1, 2, 3, 4}])
    b = run(rng.permutation(len(pieces)), [{1, 2, 3, 4}])
    c = run(rng.permutation(len(pieces)), [{3}, {1, 4}, {2}])
    acc_a = np.array(a.accumulators(iy, ix))
    assert np.array_equal(acc_a, np.array(b.accumulators(iy, ix)))
    assert np.allclose(acc_a, np.array(c.accumulators(iy, ix)), rtol=1e-12, atol=0)
    # reference: per (leg, detector, cell) keep the max T mass if any, else the max Pd
    for y, x in [(-3, -3), (0, 0), (2, 2)]:
        kept = []
        for leg in range(1, 5):
            for det in ("mf", "z"):
                here = [p for p in pieces if p[:4] == (leg, det, y, x)]
                ts = [m for *_, kind, m in here if kind == "m_t"]
                ns = [m for *_, kind, m in here if kind == "m_n"]
                if ts:
                    kept.append(simple_support(T, min(max(ts), 1 - 1e-9)))
                elif ns:
                    kept.append(simple_support(NOT_T, min(max(ns), 1 - 1e-9)))
        m = a.masses_at((x + 0.5) * 0.5, (y + 0.5) * 0.5)
        ref = combine_all(kept) if kept else {frozenset({T, NOT_T}): 1.0}
        assert float(m.m_t) == pytest.approx(ref.get(frozenset({T}), 0.0), abs=1e-12)
        assert float(m.m_n) == pytest.approx(ref.get(frozenset({NOT_T}), 0.0), abs=1e-12)


def test_reserved_memory_changes_nothing_and_is_grown_into_without_copies(frame, make_grid):
    from .conftest import mission_observations
    obs = mission_observations(frame, tiles_per_leg=4, rows=1000)
    plain, reserved = make_grid(commit_after_obs=2), make_grid(commit_after_obs=2)
    reserved.reserve(400)
    arrays = set()
    for o in obs:
        plain.add_observation(o)
        reserved.add_observation(o)
        for layer in reserved.open.values():
            arrays.add(id(layer.chunks.arr))
            assert layer.chunks.high <= 400  # the test is about growth inside the reserve
    plain.close_all()
    reserved.close_all()
    assert len(arrays) == 1  # every leg's layer grew inside the one reserved array
    keys = sorted(plain.chunk_keys())
    assert sorted(reserved.chunk_keys()) == keys
    assert np.array_equal(reserved.chunk_accumulators(keys), plain.chunk_accumulators(keys))
    assert reserved.covered_cells() == plain.covered_cells()


def test_chunk_stack_reserve_keeps_slots_and_fills_new_ones():
    from atr_node.fusion.chunks import ChunkStack
    s = ChunkStack((3,), -1.0)
    for k in range(5):
        slot = s.get((k, 0))  # get() may replace arr
        s.arr[slot] = k
    before = s.gather()
    s.reserve(64)
    arr = s.arr
    assert arr.shape[0] == 64 and np.array_equal(s.gather(), before)
    assert (arr[s.high:] == -1.0).all()
    for k in range(5, 64):
        slot = s.get((k, 0))
        assert (s.arr[slot] == -1.0).all()
    assert s.arr is arr  # no growth copy up to the reserve
    s.reserve(10)  # smaller than held: nothing lost
    assert s.arr is arr and np.array_equal(s.gather()[:5], before)
