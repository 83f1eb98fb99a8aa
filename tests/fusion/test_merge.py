"""Exact merge of grids by adding accumulators (SPEC section 7)."""

from __future__ import annotations

import numpy as np
import pytest

from atr_node.errors import FusionError
from atr_node.fusion import ContactTracker
from atr_node.config import FusionSettings

from .conftest import mission_observations


def run(make_grid, observations, close=True):
    grid = make_grid()
    for o in observations:
        grid.add_observation(o)
    if close:
        grid.close_all()
    return grid


def test_merge_two_half_missions_equals_whole_mission(frame, make_grid):
    obs = mission_observations(frame)
    whole = run(make_grid, obs)
    a = run(make_grid, [o for o in obs if o.leg <= 2])
    b = run(make_grid, [o for o in obs if o.leg > 2])
    keys = sorted(whole.chunk_keys())
    acc_a, acc_b = a.chunk_accumulators(keys), b.chunk_accumulators(keys)
    a.merge(b)
    assert sorted(a.chunk_keys()) == keys
    merged, ref = a.chunk_accumulators(keys), whole.chunk_accumulators(keys)
    # float addition is not associative: (s1 + s2) + (s3 + s4) vs ((s1 + s2) + s3) + s4
    assert np.allclose(merged, ref, rtol=1e-12, atol=0)
    # ...but where only one half holds evidence the merge is bit for bit
    one_side = (acc_a == 0.0) | (acc_b == 0.0)
    assert one_side.any() and np.array_equal(merged[one_side], ref[one_side])
    assert a.covered_cells() == whole.covered_cells()
    assert len(a.detections) == len(whole.detections)
    # the same contacts
    ta = ContactTracker(FusionSettings(), frame, gate_m=3.0)
    tw = ContactTracker(FusionSettings(), frame, gate_m=3.0)
    ca = sorted((c.east_m, c.north_m, c.bel, c.looks, c.legs) for c in ta.update(a, 1.0))
    cw = sorted((c.east_m, c.north_m, c.bel, c.looks, c.legs) for c in tw.update(whole, 1.0))
    assert len(ca) == len(cw) >= 3
    for x, y in zip(ca, cw):
        assert x[0] == pytest.approx(y[0], abs=1e-9) and x[2] == pytest.approx(y[2], abs=1e-12)
        assert x[3:] == y[3:]


def test_merge_mid_leg_is_bit_exact(frame, make_grid):
    obs = mission_observations(frame, tiles_per_leg=4)
    whole = run(make_grid, obs)
    first, second = obs[:2], obs[2:4]  # leg 1 cut in two halves, both left open
    a = run(make_grid, first, close=False)
    b = run(make_grid, second, close=False)
    a.merge(b)
    for o in obs[4:]:
        a.add_observation(o)
    a.close_all()
    keys = sorted(whole.chunk_keys())
    assert np.array_equal(a.chunk_accumulators(keys), whole.chunk_accumulators(keys))


def test_merge_refuses_inconsistent_grids(frame, make_grid):
    obs = mission_observations(frame)
    a = run(make_grid, obs[:2])          # leg 1 committed
    b = run(make_grid, obs[:1], close=False)  # leg 1 open
    with pytest.raises(FusionError, match="open in one grid and committed"):
        a.merge(b)
    with pytest.raises(FusionError, match="cell size"):
        a.merge(make_grid(cell_m=1.0))
