"""Window geometry (SPEC 1) and column statistics (SPEC 2) against closed forms and numpy."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st

from atr_node.config import TemplateSettings
from atr_node.detectors import (BackgroundTracker, column_mean, column_median, required_margin,
                                shadow_length_m, window_geometry)
from atr_node.errors import AtrError, GeometryError

T = TemplateSettings()  # L 2 m, W 0.6 m, h 0.5 m, S in [0.5, 8] m, context x3


def test_shadow_length_closed_form():
    r = np.array([0.0, 10.0, 27.0, 100.0, 1000.0])
    # h r / (H - h) with H = 14: 27 m -> 1 m exactly; clipped to [0.5, 8].
    np.testing.assert_allclose(shadow_length_m(r, altitude_m=14.0, template=T),
                               [0.5, 0.5, 1.0, 100 / 27, 8.0])


@pytest.mark.parametrize("altitude", [0.5, 0.2, 0.0, -3.0])
def test_sonar_not_above_target_top_gives_longest_shadow(altitude):
    s = shadow_length_m(np.array([0.0, 5.0, 50.0]), altitude_m=altitude, template=T)
    np.testing.assert_array_equal(s, T.shadow_max_m)


def test_range_to_zero_and_negative_stay_finite():
    g = window_geometry(np.array([-1.0, 0.0, 1e-12, np.nan]), dr_m=0.1, dx_m=0.1, altitude_m=14.0, template=T)
    np.testing.assert_array_equal(g.shadow_px, 5)  # shadow_min 0.5 m = 5 px


def test_pixel_sizes_and_context():
    g = window_geometry(np.array([27.0, 216.0]), dr_m=0.1, dx_m=0.05, altitude_m=14.0, template=T)
    assert (g.echo_px, g.length_px) == (6, 40)
    np.testing.assert_array_equal(g.shadow_px, [10, 80])
    assert (g.row0, g.row1) == (-20, 20)
    assert (g.ctx_row0, g.ctx_row1) == (-60, 60)          # 3 x 40 rows centred on the template
    np.testing.assert_array_equal(g.ctx_col1 - g.ctx_col0, [48, 258])   # 3 x (6 + S)
    np.testing.assert_array_equal(g.ctx_col0, [-6 - 16, -6 - 86])       # centred: (3-1)(6+S)/2 each side
    # Farthest reach: context rows -60..59, columns -92..165 around the anchor.
    assert required_margin(g) == (60, 165)


def test_bad_spacing_is_a_geometry_error():
    with pytest.raises(GeometryError, match="dr_m"):
        window_geometry(np.zeros(3), dr_m=0.0, dx_m=0.1, altitude_m=14.0, template=T)
    with pytest.raises(GeometryError, match="altitude"):
        window_geometry(np.zeros(3), dr_m=0.1, dx_m=0.1, altitude_m=np.nan, template=T)


@hsettings(max_examples=60, deadline=None)
@given(rows=st.integers(1, 9), cols=st.integers(1, 6), seed=st.integers(0, 2**31 - 1),
       nan_p=st.sampled_from([0.0, 0.3, 0.7, 1.0]))
def test_column_median_equals_nanmedian(rows, cols, seed, nan_p):
    rng = np.random.default_rng(seed)
    x = rng.integers(0, 4, size=(rows, cols)).astype(np.float32)  # ties on purpose
    x[rng.random(x.shape) < nan_p] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ref = np.nanmedian(x.astype(np.float64), axis=0)
        mean = np.nanmean(x.astype(np.float64), axis=0)
    np.testing.assert_array_equal(column_median(x), ref)
    np.testing.assert_allclose(column_mean(x), mean, rtol=1e-12)


def test_column_median_large_tile_with_infinities(rng):
    x = rng.exponential(size=(301, 50)).astype(np.float32)
    x[rng.random(x.shape) < 0.2] = np.nan
    x[5, 7] = np.inf  # non-finite pixels are no data
    ref_in = x.astype(np.float64)
    ref_in[~np.isfinite(ref_in)] = np.nan
    np.testing.assert_array_equal(column_median(x), np.nanmedian(ref_in, axis=0))


@pytest.mark.parametrize("scattered", [0.0, 0.05])
def test_column_median_with_dropped_pings_equals_nanmedian(rng, monkeypatch, scattered):
    """Rows without any valid pixel (dropped pings) are left out before the partition: the
    same medians, even and odd counts, with empty columns and scattered no-data pixels, in
    blocks of one and of several columns."""
    from atr_node.detectors import background

    x = rng.integers(0, 6, size=(97, 40)).astype(np.float32)  # ties on purpose
    x[rng.random(x.shape) < scattered] = np.nan
    x[[0, 3, 4, 50, 96]] = np.nan  # dropped pings, the first and the last included
    x[:, 7] = np.nan  # a column without data
    x[:60, 11] = np.inf  # non-finite is no data
    ref = x.astype(np.float64)
    ref[~np.isfinite(ref)] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ref_even = np.nanmedian(ref[:-1], axis=0)
        ref = np.nanmedian(ref, axis=0)
    np.testing.assert_array_equal(column_median(x), ref)
    np.testing.assert_array_equal(column_median(x[:-1]), ref_even)
    monkeypatch.setattr(background, "_MEDIAN_BLOCK_BYTES", 4 * 97 * 3)
    np.testing.assert_array_equal(column_median(x), ref)
    assert np.isnan(column_median(np.full((5, 3), np.nan, np.float32))).all()


def test_column_median_by_blocks_of_columns_equals_nanmedian(rng, monkeypatch):
    """Blocks of 1 and of 7 columns (the last one short), partly and wholly empty columns."""
    from atr_node.detectors import background

    x = rng.integers(0, 5, size=(64, 45)).astype(np.float32)
    x[rng.random(x.shape) < 0.3] = np.nan
    x[:, 3] = np.nan
    x[:40, 10] = np.nan
    ref = x.astype(np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ref = np.nanmedian(ref, axis=0)
    for cols_per_block in (1, 7):
        monkeypatch.setattr(background, "_MEDIAN_BLOCK_BYTES", 4 * 64 * cols_per_block)
        np.testing.assert_array_equal(column_median(x), ref)


def test_tracker_forgets_exponentially():
    tr = BackgroundTracker(0.8)
    a = np.full((4, 3), 2.0, np.float32)
    a[:, 2] = np.nan
    b = np.full((4, 3), 7.0, np.float32)
    np.testing.assert_array_equal(tr.update(a), [2.0, 2.0, np.nan])
    # b <- 0.8 b + 0.2 b_tile; a column seen for the first time takes the tile's value.
    np.testing.assert_allclose(tr.update(b), [3.0, 3.0, 7.0])
    np.testing.assert_allclose(tr.update(a), [2.8, 2.8, 7.0])
    with pytest.raises(AtrError, match="columns"):
        tr.update(np.ones((2, 5), np.float32))
    np.testing.assert_allclose(tr.background, [2.8, 2.8, 7.0])  # unchanged by the bad tile
    tr.reset()
    assert tr.background is None
    with pytest.raises(AtrError, match="forgetting"):
        BackgroundTracker(1.0)
