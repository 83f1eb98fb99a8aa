"""Detection extraction (SPEC 3): exact tiny cases, a planted target, a long shadow band, and
the fast path against a plain scipy.ndimage reference (random, tied, NaN, border, exact-size
and real score maps; the SPEC 8 extremes)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st
from hypothesis.extra import numpy as hnp
from scipy import ndimage

from atr_node.config import DetectorSettings, TemplateSettings
from atr_node.detectors import Detection, find_detections, score_maps, window_geometry
from atr_node.detectors.extract import collapse_empty
from atr_node.errors import AtrError

KW = dict(range0_m=10.0, dr_m=0.1, dx_m=0.2, min_extent_m=0.2, max_extent_m=1.0)


def test_components_peaks_and_size_filter_exact():
    g = np.zeros((12, 14))
    g[1:3, 1:3] = [[2.0, 3.0], [2.5, 1.5]]      # 2 x 2 px: 0.2 m x 0.4 m, kept
    g[5, 5] = 9.0                                  # 1 px: 0.1 m across, dropped
    g[7:12, 2] = 2.0                               # 5 rows: 1.0 m along, kept (edge of max)
    g[8, 3] = 4.0                                  # 8-connected to the column above
    g[0:6, 10:12] = 5.0                            # 6 rows: 1.2 m along, dropped
    g[3, 7] = np.nan                               # NaN never detects
    dets = find_detections(g, 1.0, detector="mf", **KW)
    assert dets == [
        Detection("mf", 1, 2, 3.0, 10.0 + 0.2, 0.2, 0.4, 4),
        Detection("mf", 8, 3, 4.0, 10.0 + 0.3, 0.2, 1.0, 6),
    ]


def test_ties_go_to_the_first_pixel_and_threshold_is_strict():
    g = np.zeros((4, 4))
    g[1:3, 1:3] = 2.0
    (d,) = find_detections(g, 1.0, detector="z", **KW)
    assert (d.row, d.col, d.n_pixels) == (1, 1, 4)
    assert find_detections(g, 2.0, detector="z", **KW) == []


def test_bad_inputs():
    with pytest.raises(AtrError, match="2-D"):
        find_detections(np.zeros(4), 1.0, detector="mf", **KW)
    with pytest.raises(AtrError, match="finite"):
        find_detections(np.zeros((4, 4)), np.nan, detector="mf", **KW)
    assert find_detections(np.full((3, 3), np.nan), 0.0, detector="mf", **KW) == []
    assert find_detections(np.zeros((0, 5)), 0.0, detector="mf", **KW) == []


# Thresholds well above the Rayleigh background's 99.9th percentile (about 0.17, 0.36, 0.04,
# 0.34 for mf, lac, smf, z at the default template), and below the planted target's peak.
TAU = {"mf": 1.0, "lac": 1.5, "smf": 0.25, "z": 2.0}
T = TemplateSettings()
S = DetectorSettings()
GEO = dict(range0_m=20.0, dr_m=0.1, dx_m=0.1, altitude_m=14.0)


def detect(img):
    maps = score_maps(img, template=T, detectors=S, **GEO)
    return {d: find_detections(g, TAU[d], detector=d, range0_m=20.0, dr_m=0.1, dx_m=0.1,
                               min_extent_m=S.min_extent_m, max_extent_m=S.max_extent_m)
            for d, g in maps.items()}


def test_planted_target_is_detected_by_all_four_at_its_anchor():
    rng = np.random.default_rng(7)
    img = rng.rayleigh(size=(300, 400)).astype(np.float32)
    geom = window_geometry(20.0 + 0.1 * np.arange(400), dr_m=0.1, dx_m=0.1, altitude_m=14.0, template=T)
    row, col = 150, 200
    s, w, ln = int(geom.shadow_px[col]), geom.echo_px, geom.length_px
    img[row - ln // 2:row - ln // 2 + ln, col - w:col] *= 4.0       # echo
    img[row - ln // 2:row - ln // 2 + ln, col:col + s] *= 0.15      # shadow
    for d, dets in detect(img).items():
        assert len(dets) == 1, f"{d}: {dets}"  # the target, and no false alarm on the seabed
        det = dets[0]
        assert abs(det.row - row) <= ln // 2 and abs(det.col - col) <= 1, f"{d}: {det}"
        assert det.range_m == pytest.approx(20.0 + 0.1 * det.col)


def test_a_20_m_shadow_band_is_dropped_by_size():
    rng = np.random.default_rng(8)
    img = rng.rayleigh(size=(400, 400)).astype(np.float32)
    img[100:300, 194:200] *= 4.0     # 20 m of echo along-track...
    img[100:300, 200:215] *= 0.15    # ...and its shadow: a ridge, not a mine
    maps = score_maps(img, template=T, detectors=S, **GEO)
    for d in ("mf", "z"):
        # Unfiltered, the band is one component about 18 m long; the size filter drops it.
        wide = find_detections(maps[d], TAU[d], detector=d, range0_m=20.0, dr_m=0.1, dx_m=0.1,
                               min_extent_m=0.2, max_extent_m=100.0)
        assert any(x.extent_along_m > 15.0 and 190 <= x.col <= 215 for x in wide), d
        kept = find_detections(maps[d], TAU[d], detector=d, range0_m=20.0, dr_m=0.1, dx_m=0.1,
                               min_extent_m=S.min_extent_m, max_extent_m=S.max_extent_m)
        assert not any(100 <= x.row < 300 and 190 <= x.col <= 215 for x in kept), (d, kept)
    # The SMF's context normalisation already keeps the band below threshold.
    assert not find_detections(maps["smf"], TAU["smf"], detector="smf", range0_m=20.0, dr_m=0.1,
                               dx_m=0.1, min_extent_m=0.2, max_extent_m=100.0)


# ----------------------------------------------------------------------------------------
# The fast path against a plain reference: scipy.ndimage.label (8-connected), then one
# component at a time: its pixels in row-major order, bounding box, first maximum.

EIGHT = np.ones((3, 3), dtype=bool)


def reference_detections(g, tau, *, detector, range0_m, dr_m, dx_m, min_extent_m, max_extent_m):
    g = np.asarray(g)
    with np.errstate(invalid="ignore"):
        hot = g > tau
    labels, n = ndimage.label(hot, structure=EIGHT)
    tol = 1e-9 * max_extent_m
    out = []
    for k, box in enumerate(ndimage.find_objects(labels), start=1):
        rr, cc = np.nonzero(labels[box] == k)  # row-major within the box, hence within the map
        rr, cc = rr + box[0].start, cc + box[1].start
        width_m = (cc.max() - cc.min() + 1) * dr_m
        height_m = (rr.max() - rr.min() + 1) * dx_m
        if not (min_extent_m - tol <= width_m <= max_extent_m + tol
                and min_extent_m - tol <= height_m <= max_extent_m + tol):
            continue
        vals = g[rr, cc].astype(np.float64)
        i = int(np.argmax(vals))  # the first maximum
        out.append(Detection(detector, int(rr[i]), int(cc[i]), float(vals[i]), float(range0_m + cc[i] * dr_m),
                             float(width_m), float(height_m), int(rr.size)))
    return sorted(out, key=lambda d: (d.row, d.col))


def both(g, tau, **kw):
    kw = {**KW, "detector": "t", **kw}
    return find_detections(g, tau, **kw), reference_detections(g, tau, **kw)


def test_reference_agrees_on_the_exact_tiny_case():
    g = np.zeros((12, 14))
    g[1:3, 1:3] = [[2.0, 3.0], [2.5, 1.5]]
    g[7:12, 2] = 2.0
    g[8, 3] = 4.0
    fast, ref = both(g, 1.0)
    assert fast == ref and len(ref) == 2


@pytest.mark.parametrize("seed", range(12))
def test_random_maps_with_ties_and_nan_match_the_reference(seed):
    rng = np.random.default_rng(seed)
    rows, cols = rng.integers(1, 90, size=2)
    g = np.round(rng.random((rows, cols)) * 6) / 2  # values 0, 0.5, ... 3: many ties
    g[rng.random((rows, cols)) < 0.1] = np.nan
    for tau in (0.9, 1.9, 2.4):
        for lo, hi in ((0.2, 1.0), (0.1, 100.0), (0.3, 0.6)):
            fast, ref = both(g, tau, min_extent_m=lo, max_extent_m=hi)
            assert fast == ref, (seed, tau, lo, hi)


def test_sparse_clusters_across_empty_rows_and_columns_match_the_reference():
    """Blobs far apart (collapse of empty lines at work), single empty lines between blobs
    (which must not merge), and components on all four borders."""
    rng = np.random.default_rng(3)
    g = np.zeros((300, 500))
    for r, c in rng.integers(0, [300, 500], size=(60, 2)):
        h, w = rng.integers(1, 8, size=2)
        g[r:r + h, c:c + w] = rng.integers(2, 5, size=(min(h, 300 - r), min(w, 500 - c)))
    g[0:3, 0:4] = 3.0                  # top-left corner
    g[297:300, 496:500] = 3.0          # bottom-right corner
    g[100:104, 0] = 2.0                # left border
    g[100:104, 499] = 2.0              # right border
    g[150:153, 200:203] = 2.0          # one empty row and one empty column apart: three components
    g[154:157, 200:203] = 2.0
    g[150:153, 204:207] = 2.0
    g[160, 300] = g[161, 301] = 2.0    # diagonal neighbours: one component
    g[:, 250] = np.nan
    fast, ref = both(g, 1.0, min_extent_m=0.1, max_extent_m=1.0)
    assert fast == ref
    assert {(0, 0), (297, 496), (100, 0), (100, 499), (150, 200), (154, 200), (150, 204), (160, 300)} <= {
        (d.row, d.col) for d in fast}
    assert next(d for d in fast if (d.row, d.col) == (160, 300)).n_pixels == 2


def test_sizes_at_exactly_min_and_max_extent():
    # dr 0.1, dx 0.2: min 0.2 m is 2 columns or 1 row; max 1.0 m is 10 columns or 5 rows
    g = np.zeros((40, 60))
    g[1:2, 1:3] = 2.0      # 2 cols x 1 row: both at the minimum, kept
    g[5:6, 5:6] = 2.0      # 1 col: below, dropped
    g[10:15, 1:11] = 2.0   # 10 cols x 5 rows: both at the maximum, kept
    g[20:26, 1:3] = 2.0    # 6 rows: above, dropped
    g[30:31, 20:31] = 2.0  # 11 cols: above, dropped
    fast, ref = both(g, 1.0)
    assert fast == ref
    assert [(d.row, d.col, d.n_pixels) for d in fast] == [(1, 1, 2), (10, 1, 50)]


@pytest.mark.parametrize("tau_scale", [1.0, 0.3])
def test_real_score_maps_match_the_reference(tau_scale):
    """Score maps of a Rayleigh tile with NaN nadir columns and planted targets, at the test
    thresholds (few components) and at 0.3 of them (many)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools" / "bench"))
    from detectors import make_tile  # tools/bench/detectors.py

    img, truth = make_tile(256, 700, 5, T)
    maps = score_maps(img, template=T, detectors=S, **GEO)
    for d, g in maps.items():
        tau = TAU[d] * tau_scale
        kw = dict(detector=d, range0_m=20.0, dr_m=0.1, dx_m=0.1, min_extent_m=S.min_extent_m,
                  max_extent_m=S.max_extent_m)
        fast = find_detections(g, tau, **kw)
        assert fast == reference_detections(g, tau, **kw), d
        assert len(fast) >= len(truth) // 2, d
        f32 = g.astype(np.float32)  # the compare runs in the map's dtype, as before
        assert find_detections(f32, np.float32(tau), **kw) == reference_detections(f32, np.float32(tau), **kw)


def test_a_strided_view_gives_the_detections_of_its_copy():
    rng = np.random.default_rng(4)
    g = np.round(rng.random((80, 120)) * 4)
    view = g[::2, 1::3]
    assert not view.flags.c_contiguous
    fast, ref = both(view, 2.5, min_extent_m=0.1, max_extent_m=10.0)
    assert fast == ref == find_detections(view.copy(), 2.5, **{**KW, "detector": "t", "min_extent_m": 0.1,
                                                                  "max_extent_m": 10.0})
    assert fast


def test_spec8_extremes_constant_single_pixel_and_wide_dynamic_range():
    kw = dict(min_extent_m=0.1, max_extent_m=100.0)
    # constant above tau: the whole map is one component, its peak the first pixel
    (d,) = find_detections(np.full((7, 9), 3.0), 1.0, detector="t", **{**KW, **kw})
    assert (d.row, d.col, d.n_pixels, d.gamma) == (0, 0, 63, 3.0)
    assert find_detections(np.zeros((7, 9)), 0.0, detector="t", **{**KW, **kw}) == []
    (d,) = find_detections(np.full((1, 1), 5.0), 1.0, detector="t", **{**KW, **kw})
    assert (d.row, d.col, d.n_pixels, d.extent_range_m, d.extent_along_m) == (0, 0, 1, 0.1, 0.2)
    rng = np.random.default_rng(6)
    g = 10.0 ** rng.uniform(-6, 6, size=(64, 64))
    g[rng.random(g.shape) < 0.05] = np.nan
    for tau in (1e-6, 1.0, 1e5):
        fast, ref = both(g, tau, **kw)
        assert fast == ref, tau
    # +inf scores are above any threshold and become the peak
    g = np.zeros((5, 5))
    g[1:4, 1:4] = 2.0
    g[2, 3] = np.inf
    (d,) = find_detections(g, 1.0, detector="t", **KW)
    assert (d.row, d.col, d.gamma) == (2, 3, math.inf)


@hsettings(max_examples=150, deadline=None)
@given(hnp.arrays(np.float64, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=24),
                  elements=st.sampled_from([0.0, 1.0, 2.0, 2.0, 3.0, np.nan])),
       st.sampled_from([0.5, 1.5, 2.5]), st.sampled_from([(0.1, 0.4), (0.2, 1.0), (0.1, 100.0)]))
def test_property_equal_to_the_reference(g, tau, extent):
    fast, ref = both(g, tau, min_extent_m=extent[0], max_extent_m=extent[1])
    assert fast == ref


@hsettings(max_examples=150, deadline=None)
@given(hnp.arrays(np.bool_, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=30),
                  elements=st.sampled_from([False, False, False, True])))
def test_property_collapse_keeps_every_component(mask):
    """Collapsing empty lines keeps the components: count, area and extent of each, matched
    by their first pixel."""
    if not mask.any():
        return
    small, row_of, col_of = collapse_empty(mask)
    assert np.array_equal(np.diff(row_of) > 0, np.ones(row_of.size - 1, bool))
    assert np.array_equal(np.diff(col_of) > 0, np.ones(col_of.size - 1, bool))
    assert np.array_equal(small, mask[np.ix_(row_of, col_of)])  # a separator is an empty line

    def summary(m, rmap, cmap):
        lab, n = ndimage.label(m, structure=EIGHT)
        out = set()
        for k, box in enumerate(ndimage.find_objects(lab), start=1):
            rr, cc = np.nonzero(lab[box] == k)
            rr, cc = rmap[rr + box[0].start], cmap[cc + box[1].start]
            out.add((int(rr[0]), int(cc[0]), rr.size, int(np.ptp(rr)), int(np.ptp(cc))))
        return out

    assert summary(small, row_of, col_of) == summary(mask, np.arange(mask.shape[0]), np.arange(mask.shape[1]))
