"""Tiles with margins score like the uncut strip; SPEC section 8 extremes stay finite or NaN."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from atr_node.config import TemplateSettings
from atr_node.detectors import (DETECTORS, column_mean, column_median, required_margin, score_maps,
                                score_strip, window_geometry)
from atr_node.errors import AtrError
from tests.detectors.reference import reference_scores
from tests.detectors.scenes import GEOM, SMALL, rayleigh, structured
from tests.detectors.test_reference import assert_scores_match


def cut_and_score(strip, core, margin, settings, b, m):
    rows = strip.shape[0]
    parts = {d: [] for d in DETECTORS}
    for c0 in range(0, rows, core):
        c1 = min(rows, c0 + core)
        t0, t1 = max(0, c0 - margin), min(rows, c1 + margin)
        got = score_strip(strip[t0:t1], core_rows=(c0 - t0, c1 - t0), template=SMALL, detectors=settings,
                          background=b, median=m, **GEOM)
        for d in DETECTORS:
            parts[d].append(got[d])
    return {d: np.concatenate(p) for d, p in parts.items()}


@pytest.mark.parametrize("holes", ["drop-outs", "whole columns"])
def test_tiles_with_margins_equal_the_whole_strip(holes, rng, settings):
    strip = np.concatenate([structured(rng, 40, 60) for _ in range(3)])
    if holes == "whole columns":  # the separable-mask path
        strip = rayleigh(rng, 120, 60)
        strip[:, :3] = np.nan
    b, m = column_mean(strip), column_median(strip)
    whole = score_maps(strip, template=SMALL, detectors=settings, background=b, median=m, **GEOM)
    geom = window_geometry(GEOM["range0_m"] + 0.1 * np.arange(60), dr_m=0.1, dx_m=0.1,
                           altitude_m=GEOM["altitude_m"], template=SMALL)
    margin = required_margin(geom)[0]
    for core in (7, 25, 50):
        tiled = cut_and_score(strip, core, margin, settings, b, m)
        for d in DETECTORS:
            np.testing.assert_array_equal(np.isnan(tiled[d]), np.isnan(whole[d]))
            np.testing.assert_allclose(tiled[d], whole[d], rtol=1e-9, atol=1e-12)
    # Without the margin the cores differ near the cuts: the test above has teeth.
    short = cut_and_score(strip, 25, margin - 2, settings, b, m)
    assert not all(np.allclose(short[d], whole[d], equal_nan=True) for d in DETECTORS)


def test_score_strip_rejects_a_core_outside_the_tile(settings):
    with pytest.raises(AtrError, match="core_rows"):
        score_strip(np.ones((10, 10), np.float32), core_rows=(5, 11), template=SMALL, detectors=settings, **GEOM)


def assert_finite_or_nan(maps):
    for d, g in maps.items():
        assert not np.isinf(g).any(), f"{d} has inf"


def scores(img, settings, template=SMALL, **geom):
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no division by zero or overflow on the way
        return score_maps(img, template=template, detectors=settings, **{**GEOM, **geom})


def interior(g):
    return g[8:-8, 12:-12]


@pytest.mark.parametrize("value", [0.0, 1.0, 37.5, 1e6])
def test_constant_and_zero_tiles_score_zero(value, settings):
    maps = scores(np.full((40, 60), value, np.float32), settings)
    for d, g in maps.items():
        assert np.isfinite(interior(g)).all(), d
        # Constant: no echo, no shadow, no variance; Z's numerator is a rounding residue.
        np.testing.assert_allclose(interior(g), 0.0, atol=1e-9 if d != "z" else 1e-6)


def test_all_nan_tile_scores_nan(settings):
    maps = scores(np.full((30, 40), np.nan, np.float32), settings)
    assert all(np.isnan(g).all() for g in maps.values())


@pytest.mark.parametrize("template", [SMALL, TemplateSettings(length_m=0.1, echo_width_m=0.1, height_m=0.1,
                                                               shadow_min_m=0.1, shadow_max_m=0.1,
                                                               context_factor=1.0)])
def test_single_pixel_tile(template, settings):
    maps = scores(np.array([[3.0]], np.float32), settings, template=template)
    for g in maps.values():
        assert g.shape == (1, 1) and not np.isinf(g).any()
    if template is SMALL:  # every window is more than half off the tile: NaN
        assert all(np.isnan(g).all() for g in maps.values())
    else:  # the shadow zone is the pixel itself (variance 0); the echo zone is off the tile
        assert maps["lac"][0, 0] == 0.0
        assert np.isnan(maps["mf"]).all() and np.isnan(maps["z"]).all() and np.isnan(maps["smf"]).all()


def test_dynamic_range_1e_minus6_to_1e6_matches_reference(rng, settings):
    img = (10.0 ** rng.uniform(-6, 6, size=(40, 60))).astype(np.float32)
    img[10:20, 20:40] = 1e-6
    maps = scores(img, settings)
    ref = reference_scores(img, template=SMALL, detectors=settings, **GEOM)
    assert_finite_or_nan(maps)
    for d in DETECTORS:
        assert_scores_match(maps[d], ref[d], 1e-6)


def test_saturated_region_and_exact_zero_shadow(rng, settings):
    img = rayleigh(rng, 40, 60) * 100
    img[5:15, 10:30] = 255.0          # clipped highlight
    img[20:30, 30:45] = 0.0           # shadow of exact zeros behind...
    img[20:30, 27:30] = 255.0         # ...a saturated echo
    maps = scores(img, settings)
    assert_finite_or_nan(maps)
    ref = reference_scores(img, template=SMALL, detectors=settings, **GEOM)
    for d in DETECTORS:
        assert_scores_match(maps[d], ref[d], 1e-6)
    # Zero shadow: lacunarity 0 / floor = 0; the mean test divides by its floor, finite and large.
    assert maps["lac"][25, 35] == 0.0
    assert 1e3 < maps["z"][25, 30] < 1e5


@pytest.mark.parametrize("geom", [dict(altitude_m=0.5), dict(altitude_m=0.1), dict(altitude_m=-1.0),
                                  dict(range0_m=0.0), dict(range0_m=-2.0)])
def test_sonar_below_target_top_and_zero_range(geom, rng, settings):
    img = rayleigh(rng, 40, 60)
    maps = scores(img, settings, **geom)
    assert_finite_or_nan(maps)
    ref = reference_scores(img, template=SMALL, detectors=settings, **{**GEOM, **geom})
    for d in DETECTORS:
        assert_scores_match(maps[d], ref[d], 1e-6)


def test_bad_inputs_are_clear_errors(settings):
    with pytest.raises(AtrError, match="2-D"):
        score_maps(np.ones(5), template=SMALL, detectors=settings, **GEOM)
    with pytest.raises(AtrError, match="unknown detector"):
        score_maps(np.ones((5, 5)), template=SMALL, detectors=settings, enabled=("mf", "cfar"), **GEOM)
    with pytest.raises(AtrError, match="background has 3 values"):
        score_maps(np.ones((5, 5)), template=SMALL, detectors=settings, background=np.ones(3), **GEOM)


def test_float32_precision_on_extremes_stays_finite(rng, settings):
    img = (10.0 ** rng.uniform(-6, 6, size=(40, 60))).astype(np.float32)
    img[:, 20:30] = 0.0
    maps = scores(img, dataclasses.replace(settings, precision="float32"))
    assert_finite_or_nan(maps)
