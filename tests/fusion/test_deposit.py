"""The per-cell Pd reduction and the grid's deposit (SPEC section 7) against per-pixel references.

The fast path (``atr_node.fusion.deposit.PdReducer``: dense box per sub-block, vertical runs
folded, coverage per column) must give bit for bit what a direct per-pixel maximum gives; the
grid built from it must equal, bit for bit, a grid fed pixel by pixel through the low-level
``EvidenceGrid.deposit``.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from atr_node.config import FusionSettings
from atr_node.fusion import EvidenceGrid
from atr_node.fusion.chunks import layer_terms, layer_terms_covered
from atr_node.fusion.deposit import PdReducer
from atr_node.fusion.observation import gate_cells, pixel_cells
from atr_node.geo import TileGeometry

from .conftest import observe, track_geometry


def straight(rows: int, cols: int, *, heading_deg: float, east0: float = 3.3, north0: float = -7.1,
             range0: float = 5.0, dr: float = 0.1, jump_row: int | None = None) -> TileGeometry:
    """A straight track directly in the metric frame; ``jump_row``: a 5 km nav jump from there."""
    h = np.radians(heading_deg)
    i = np.arange(rows, dtype=np.float64)
    e, n = east0 + 0.1 * i * np.sin(h), north0 + 0.1 * i * np.cos(h)
    if jump_row is not None:
        e[jump_row:] += 5000.0
    ue, un = np.full(rows, np.cos(h)), np.full(rows, -np.sin(h))  # starboard
    return TileGeometry(e, n, ue, un, range0 + dr * np.arange(cols), np.full(rows, h))


def coverage(rng: np.random.Generator, rows: int, cols: int, kind: str) -> np.ndarray:
    cov = np.zeros((rows, cols), bool)
    if kind == "window":  # the valid window: constant down each column
        cov[:, int(rng.integers(0, cols // 4 + 1)):cols - int(rng.integers(0, cols // 4 + 1))] = True
    elif kind == "strip_start":  # a window, and the first rows of a strip not covered
        cov[int(rng.integers(0, rows)):, 10:cols - 10] = True
    elif kind == "holes":
        cov = rng.uniform(size=(rows, cols)) < 0.7
    elif kind == "all":
        cov[:] = True
    elif kind == "columns":  # a window, coverage changing down a few columns only
        cov[:, 2:cols - 2] = True
        for c in rng.integers(0, cols, size=max(1, cols // 20)):
            cov[int(rng.integers(0, rows)):, c] = False
    return cov  # "none": nothing covered


def reference(geom: TileGeometry, covs: list[np.ndarray], pds: list[np.ndarray], cell_m: float
              ) -> dict[tuple[int, int], list[float]]:
    """Per cell, per detector, the maximum Pd over covered pixels: a direct per-pixel loop
    over the cells of :func:`pixel_cells` (float64 throughout)."""
    rows, cols = covs[0].shape
    iy, ix = pixel_cells(geom, slice(0, rows), cell_m=cell_m)
    out: dict[tuple[int, int], list[float]] = {}
    for j, (cov, pd) in enumerate(zip(covs, pds)):
        for r, c in zip(*np.nonzero(cov)):
            v = out.setdefault((int(iy[r, c]), int(ix[r, c])), [-1.0] * len(covs))
            v[j] = max(v[j], float(pd[c]))
    return out


def reduced(reducer: PdReducer, geom: TileGeometry, covs, pds, rows: slice, cols: slice) -> dict:
    iy, ix, vmax = reducer.reduce(geom, covs, pds, rows, cols)
    out: dict[tuple[int, int], list[float]] = {}
    for k, key in enumerate(zip(iy.tolist(), ix.tolist())):  # sub-blocks may repeat a cell
        v = out.setdefault(key, [-1.0] * len(covs))
        for j in range(len(covs)):
            v[j] = max(v[j], float(vmax[j, k]))
    return out


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), heading=st.sampled_from([0.0, 90.0, 180.0, 45.0, 33.7, -121.0]),
       kinds=st.lists(st.sampled_from(["window", "strip_start", "holes", "all", "none", "columns"]), min_size=1,
                     max_size=4),
       sub=st.sampled_from([1 << 18, 997, 64]), cell_m=st.sampled_from([0.5, 0.75, 1.0]))
def test_reduction_equals_a_per_pixel_maximum(seed, heading, kinds, sub, cell_m):
    rng = np.random.default_rng(seed)
    rows, cols = int(rng.integers(1, 60)), int(rng.integers(1, 90))
    geom = straight(rows, cols, heading_deg=heading, range0=float(rng.uniform(0, 30)))
    covs = [coverage(rng, rows, cols, k) for k in kinds]
    # Pd with repeated values, 0 and 1 (exact ties and the extremes), and -0.0
    pds = [rng.choice([0.0, -0.0, 1.0, 0.25, 0.5, *rng.uniform(size=4)], size=cols) for _ in kinds]
    got = reduced(PdReducer(cell_m, sub_pixels=sub), geom, covs, pds, slice(0, rows), slice(0, cols))
    ref = reference(geom, covs, pds, cell_m)
    assert got == ref  # exact: same cells, same maxima (no cell without a covered pixel)


@pytest.mark.parametrize("u_scale", [1.0, 1e-310, 0.0])
@pytest.mark.parametrize("cell_m", [0.5, 0.3])
def test_cell_planes_scaled_path_and_its_fallback_are_exact(u_scale, cell_m):
    """Cells of the scaled path (cell_m a power of two: one pass less) and of the direct
    expression (other cell sizes, subnormal direction components) against pixel_cells."""
    rng = np.random.default_rng(4)
    rows, cols = 37, 53
    geom = straight(rows, cols, heading_deg=float(rng.uniform(0, 360)), east0=-0.0, north0=0.0, range0=0.0)
    geom = TileGeometry(geom.east_m, geom.north_m, geom.ue * u_scale, geom.un, geom.ranges_m, geom.heading_grid_rad)
    red = PdReducer(cell_m)
    assert (red._scale is not None) == (cell_m == 0.5)
    assert red.scaled(geom) == (cell_m == 0.5 and u_scale != 1e-310)  # the path taken
    fy, fx = np.empty((rows, cols)), np.empty((rows, cols))
    red._cell_planes(geom, slice(0, rows), slice(0, cols), fy, fx)
    iy, ix = pixel_cells(geom, slice(0, rows), cell_m=cell_m)
    assert np.array_equal(fy, iy) and np.array_equal(fx, ix)
    covs = [coverage(rng, rows, cols, "columns"), coverage(rng, rows, cols, "window")]
    pds = [rng.uniform(size=cols), rng.uniform(size=cols)]
    assert reduced(red, geom, covs, pds, slice(0, rows), slice(0, cols)) == reference(geom, covs, pds, cell_m)


def test_a_nav_jump_takes_the_sparse_path_and_a_sub_window_is_exact():
    rng = np.random.default_rng(1)
    rows, cols = 40, 50
    geom = straight(rows, cols, heading_deg=20.0, jump_row=17)  # box far wider than the block
    covs = [coverage(rng, rows, cols, "holes"), coverage(rng, rows, cols, "window")]
    pds = [rng.uniform(size=cols), rng.uniform(size=cols)]
    got = reduced(PdReducer(0.5), geom, covs, pds, slice(0, rows), slice(0, cols))
    assert got == reference(geom, covs, pds, 0.5)
    # rows and columns of a block only (the grid skips never-covered columns)
    sub_geom = TileGeometry(geom.east_m[5:30], geom.north_m[5:30], geom.ue[5:30], geom.un[5:30],
                            geom.ranges_m[7:41], geom.heading_grid_rad[5:30])
    want = reference(sub_geom, [c[5:30, 7:41] for c in covs], [p[7:41] for p in pds], 0.5)
    assert reduced(PdReducer(0.5, sub_pixels=100), geom, covs, pds, slice(5, 30), slice(7, 41)) == want


def per_pixel_grid(obs_list, fusion: FusionSettings, gate_m: float) -> EvidenceGrid:
    """Reference grid: every covered pixel and every gate cell through the low-level
    ``deposit`` (a per-pixel maximum), the way add_observation deposited before issue 7;
    gate cells only where the same (leg, detector) covered a pixel (one footprint, SPEC
    6.1: here a set of the leg's covered cells, found pixel by pixel beforehand)."""
    grid = EvidenceGrid(fusion, gate_m=gate_m)
    footprint: dict[tuple[int, str], set[tuple[int, int]]] = {}
    for obs in obs_list:
        rows, _ = obs.shape
        iy, ix = pixel_cells(obs.geometry, slice(0, rows), cell_m=grid.cell_m)
        for d in obs.detectors:
            footprint.setdefault((obs.leg, d.detector), set()).update(
                zip(iy[d.covered].tolist(), ix[d.covered].tolist()))
    for obs in obs_list:
        rows, cols = obs.shape
        iy, ix = pixel_cells(obs.geometry, slice(0, rows), cell_m=grid.cell_m)
        for d in obs.detectors:
            cov = d.covered
            if cov.any():
                grid.deposit(obs.leg, d.detector, obs.t, iy[cov], ix[cov], m_n=np.broadcast_to(d.pd, cov.shape)[cov])
            seen = footprint[(obs.leg, d.detector)]
            for det in d.detections:
                e, n = obs.geometry.world(det.row, det.col)
                gy, gx = gate_cells(float(e), float(n), gate_m=gate_m, cell_m=grid.cell_m)
                inside = np.array([(a, b) in seen for a, b in zip(gy.tolist(), gx.tolist())], dtype=bool)
                if inside.any():
                    grid.deposit(obs.leg, d.detector, obs.t, gy[inside], gx[inside], m_t=det.confidence)
    grid.close_all()
    return grid


def test_grid_equals_a_per_pixel_deposit_bit_for_bit(frame):
    from .conftest import mission_observations
    obs = mission_observations(frame, tiles_per_leg=3, rows=300)
    rng = np.random.default_rng(3)
    # holes in some coverage (no longer constant down the columns), and a detector blind in a tile
    for o in obs[::2]:
        for d in o.detectors[:2]:
            d.covered[rng.uniform(size=d.covered.shape) < 0.2] = False
    obs[1].detectors[3].covered[:] = False
    fusion = FusionSettings(commit_after_obs=0)
    fast = EvidenceGrid(fusion, gate_m=3.0)
    for o in obs:
        fast.add_observation(o)
    fast.close_all()
    ref = per_pixel_grid(obs, fusion, 3.0)
    assert fast._spare is not None and len({o.leg for o in obs}) > 2  # later legs reused a layer array
    keys = sorted(ref.chunk_keys())
    assert sorted(fast.chunk_keys()) == keys
    assert fast.chunk_accumulators(keys).tobytes() == ref.chunk_accumulators(keys).tobytes()
    assert fast.covered_cells() == ref.covered_cells()


@pytest.mark.parametrize("k, case", [(1, "mixed"), (7, "mixed"), (5, "no_t"), (5, "no_n"), (5, "sparse_t"),
                                     (5, "nothing"), (3, "dense_n")])
def test_layer_terms_without_per_detector_terms_are_the_same_sums(k, case):
    rng = np.random.default_rng(k)
    p = rng.choice([-1.0, 0.0, -0.0, 0.3, 0.999, 1.0, 1.0 - 1e-12], size=(k, 4, 2, 64))
    if case in ("no_t", "sparse_t", "dense_n", "nothing"):
        p[:, :, 0] = -1.0
    if case == "sparse_t":  # T evidence in one chunk only (the usual case: near detections)
        p[k // 2, 1, 0, 5:9] = [0.7, -0.0, 1.0, 0.2]
    if case in ("no_n", "nothing"):
        p[:, :, 1] = -1.0
    if case == "dense_n":
        p[:, :, 1] = rng.choice([0.0, -0.0, 0.4, 1.0], size=p[:, :, 1].shape)
    d_lt, d_ln, n_cl, per = layer_terms(p, 1e-9)
    d_lt2, d_ln2, n_cl2, none = layer_terms(p, 1e-9, per_detector=False)
    assert none is None and n_cl2 == n_cl
    assert d_lt2.tobytes() == d_lt.tobytes() and d_ln2.tobytes() == d_ln.tobytes()
    # independent reference, element by element in float64 (signed zeros included)
    top = 1.0 - 1e-9
    c, q = p[:, :, 0], p[:, :, 1]
    # one footprint (SPEC 6.1): T only where the same detector covered the cell (q >= 0)
    has_t, has_n = (c >= 0) & (q >= 0), (q >= 0) & (c < 0)
    ref_t = np.where(has_t, np.log1p(-np.minimum(np.abs(c), top)), 0.0)
    ref_n = np.where(has_n, np.log1p(-np.minimum(np.abs(q), top)), 0.0)
    assert per[:, :, 0].tobytes() == ref_t.tobytes() and per[:, :, 1].tobytes() == ref_n.tobytes()
    assert d_ln.tobytes() == (((ref_n[:, 0] + ref_n[:, 1]) + ref_n[:, 2]) + ref_n[:, 3]).tobytes()
    assert d_lt.tobytes() == (((ref_t[:, 0] + ref_t[:, 1]) + ref_t[:, 2]) + ref_t[:, 3]).tobytes()
    assert n_cl == int(np.count_nonzero(has_t & (c > top)) + np.count_nonzero(has_n & (q > top)))
    covered = layer_terms_covered(p, 1e-9, per_detector=False)[4]
    assert np.array_equal(covered, (q >= 0.0).any(axis=1))  # a gate alone covers nothing
    if case == "mixed":
        assert ((c >= 0) & (q < 0)).any()  # the clip was exercised


def test_open_layer_read_out_matches_commit_after_the_deposit(frame, make_grid):
    g = track_geometry(frame, east0_m=0.0, north0_m=0.0, heading_deg=30.0, rows=200, cols=400)
    pd = np.linspace(0.9, 0.1, 400)
    o = observe(g, 1, 1.0, {"z": (None, pd, [(100, 200, 0.7)]), "mf": (None, pd[::-1].copy(), [])})
    grid = make_grid()
    grid.add_observation(o)
    keys = sorted(grid.chunk_keys())
    before = grid.chunk_accumulators(keys)
    grid.close_all()
    assert grid.chunk_accumulators(keys).tobytes() == before.tobytes()


def test_a_pickled_grid_drops_the_spare_layer_array_and_goes_on_the_same(frame):
    import pickle

    from .conftest import mission_observations
    obs = mission_observations(frame, tiles_per_leg=2, rows=200)
    grid = EvidenceGrid(FusionSettings(), gate_m=3.0)
    cut = next(i for i, o in enumerate(obs) if o.leg != obs[0].leg)
    for o in obs[:cut]:
        grid.add_observation(o)
    grid.close_leg(obs[0].leg)
    assert grid._spare is not None  # the closed leg's layer array, for the next leg
    copy = pickle.loads(pickle.dumps(grid))
    assert copy._spare is None
    for g in (grid, copy):
        for o in obs[cut:]:
            g.add_observation(o)
        g.close_all()
    keys = grid.chunk_keys()
    assert copy.chunk_keys() == keys
    assert copy.chunk_accumulators(keys).tobytes() == grid.chunk_accumulators(keys).tobytes()
