"""Each detector against the direct float64 reference, window by window (SPEC sections 1-2)."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from atr_node.detectors import DETECTORS, score_maps
from tests.detectors.reference import reference_scores
from tests.detectors.scenes import GEOM, rayleigh, structured


def assert_scores_match(got: np.ndarray, ref: np.ndarray, rtol: float) -> None:
    """Same NaN pattern; elsewhere |got - ref| <= rtol * max(|ref|, 1)."""
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    ok = ~np.isnan(ref)
    assert ok.sum() > 0.3 * ref.size, "too few scored pixels for a meaningful comparison"
    err = np.abs(got[ok] - ref[ok]) / np.maximum(np.abs(ref[ok]), 1.0)
    assert err.max() <= rtol, f"max relative error {err.max():.3g}"


def nan_columns(rng: np.random.Generator) -> np.ndarray:
    """No data in whole columns only (nadir gap, past maximum range): the separable-mask path."""
    img = rayleigh(rng, 40, 60)
    img[:, :4] = np.nan
    img[:, 30:33] = np.nan
    img[:, 55:] = np.nan
    return img


def nan_rows_and_columns(rng: np.random.Generator) -> np.ndarray:
    """No data in whole columns and whole rows (nadir gap, ping drop-outs): still separable."""
    img = nan_columns(rng)
    img[[0, 7, 8, 9, 21, 39], :] = np.nan
    return img


def quantized(rng: np.random.Generator) -> np.ndarray:
    """Integer gray levels (as from a uint8 tile): pixels hit 0.3m, 0.6m, 2m and 4m exactly."""
    img = rng.integers(0, 41, size=(40, 60)).astype(np.float32)
    img[:, ::2] = rng.choice([0.0, 3.0, 6.0, 10.0, 20.0, 40.0], size=(40, 30))  # median 10 there
    img[rng.random(img.shape) < 0.02] = np.inf  # non-finite pixels are no data too
    return img


def inf_rows_and_columns(rng: np.random.Generator) -> np.ndarray:
    """Whole columns and rows of +inf / -inf (a separable mask of no data that compares as a
    segment hit unless masked)."""
    img = structured(rng)
    img[:, [3, 4, 30]] = np.inf
    img[[12, 25], :] = -np.inf
    img[:, 50] = np.nan
    return img


SCENES = {"random": lambda rng: rayleigh(rng, 40, 60), "structured": structured, "nan_columns": nan_columns,
          "nan_rows_and_columns": nan_rows_and_columns, "quantized": quantized,
          "inf_rows_and_columns": inf_rows_and_columns}


@pytest.mark.parametrize("scene", sorted(SCENES))
def test_float64_matches_reference(scene, rng, template, settings):
    img = SCENES[scene](rng)
    got = score_maps(img, template=template, detectors=settings, **GEOM)
    ref = reference_scores(img, template=template, detectors=settings, **GEOM)
    assert set(got) == set(DETECTORS)
    for d in DETECTORS:
        assert got[d].shape == img.shape
        assert_scores_match(got[d], ref[d], 1e-6)


def test_window_grows_with_range_and_hits_both_clips(template):
    # The structured scene's columns span S from shadow_min (3 px) to shadow_max (10 px).
    from atr_node.detectors import window_geometry
    g = window_geometry(GEOM["range0_m"] + 0.1 * np.arange(60), dr_m=0.1, dx_m=0.1,
                        altitude_m=GEOM["altitude_m"], template=template)
    assert g.shadow_px[0] == 3 and g.shadow_px[-1] == 10
    assert len(np.unique(g.shadow_px)) == 8


@pytest.mark.parametrize("scene", ["structured", "nan_columns", "nan_rows_and_columns"])
def test_given_background_and_median_are_used(scene, rng, template, settings):
    img = SCENES[scene](rng)
    if scene == "structured":
        img[:, :3] = 1.0  # no all-NaN column here: every column has a background and a median
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns
        b = np.nanmean(img.astype(np.float64), axis=0) * rng.uniform(0.5, 2.0, img.shape[1])
        m = np.nanmedian(img.astype(np.float64), axis=0) * rng.uniform(0.5, 2.0, img.shape[1])
    got = score_maps(img, template=template, detectors=settings, background=b, median=m, **GEOM)
    ref = reference_scores(img, template=template, detectors=settings, background=b, median=m, **GEOM)
    for d in DETECTORS:
        assert_scores_match(got[d], ref[d], 1e-6)


def test_float32_tables_stay_close(rng, template, settings):
    # float32 tables lose digits where a deep shadow has a tiny variance (E[p^2] - E[p]^2);
    # the benchmark reports the error on full-size tiles.
    img = structured(rng)
    got = score_maps(img, template=template, detectors=dataclasses.replace(settings, precision="float32"), **GEOM)
    ref = reference_scores(img, template=template, detectors=settings, **GEOM)
    for d in DETECTORS:
        assert got[d].dtype == np.float32
        assert_scores_match(got[d], ref[d], 1e-3)


@pytest.mark.parametrize("step", [2, 4])
def test_decimation_scores_every_nth_pixel_exactly(step, rng, template, settings):
    img = structured(rng, 43, 61)
    full = score_maps(img, template=template, detectors=settings, **GEOM)
    dec = score_maps(img, template=template, detectors=dataclasses.replace(settings, decimation=step), **GEOM)
    for d in DETECTORS:
        assert dec[d].shape == img.shape
        np.testing.assert_allclose(dec[d][::step, ::step], full[d][::step, ::step], rtol=1e-12, atol=1e-12)
        # Each scored pixel stands for its step x step block.
        np.testing.assert_array_equal(dec[d][1::step, ::step], dec[d][0:-1:step, ::step][:dec[d][1::step].shape[0]])


def test_switched_off_detectors_are_not_returned(rng, template, settings):
    img = rayleigh(rng, 30, 40)
    only = score_maps(img, template=template, detectors=settings, enabled=("lac",), **GEOM)
    both = score_maps(img, template=template, detectors=settings, **GEOM)
    assert list(only) == ["lac"]
    np.testing.assert_array_equal(only["lac"], both["lac"])
    assert score_maps(img, template=template, detectors=settings, enabled=(), **GEOM) == {}


def test_workspace_reuse_leaves_nothing_behind(rng, template, settings):
    from atr_node.detectors import Workspace
    ws = Workspace()
    scenes = [structured(rng), nan_columns(rng), quantized(rng), rayleigh(rng, 25, 70), structured(rng)]
    for img in scenes:  # shapes and no-data patterns change from call to call
        for prec in ("float64", "float32"):
            s = dataclasses.replace(settings, precision=prec)
            fresh = score_maps(img, template=template, detectors=s, **GEOM)
            reused = score_maps(img, template=template, detectors=s, workspace=ws, **GEOM)
            for d in DETECTORS:
                np.testing.assert_array_equal(reused[d], fresh[d])


@pytest.mark.parametrize("scene", ["structured", "nan_columns", "nan_rows_and_columns", "quantized"])
@pytest.mark.parametrize("step", [1, 2])
def test_slices_where_offsets_stay_constant_give_the_gathered_scores(scene, step, rng, template, settings,
                                                                     monkeypatch):
    # The structured scene reaches shadow_max (constant offsets) over its last columns; with a
    # short enough run length those columns are read as slices, bit for bit as the gathers.
    from atr_node.detectors import sat
    img = np.concatenate([SCENES[scene](rng)] * 2, axis=1)  # 120 columns, 55+ past the clip
    s = dataclasses.replace(settings, decimation=step)
    monkeypatch.setattr(sat, "MIN_SLICE_RUN", 10 ** 9)
    gathered = score_maps(img, template=template, detectors=s, **GEOM)
    monkeypatch.setattr(sat, "MIN_SLICE_RUN", 4)
    sliced = score_maps(img, template=template, detectors=s, **GEOM)
    for d in DETECTORS:
        np.testing.assert_array_equal(sliced[d], gathered[d])
    if step == 1:
        ref = reference_scores(img, template=template, detectors=settings, **GEOM)
        for d in DETECTORS:
            assert_scores_match(sliced[d], ref[d], 1e-6)
