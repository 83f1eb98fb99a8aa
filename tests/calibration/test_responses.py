"""Responses by injection on real detectors and the real simulator: cell maxima against a
loop reference, crop scoring equal to whole-image scoring, and the Pd agreement of SPEC 5 on
a fresh, independent set of injected targets."""

from __future__ import annotations

import numpy as np
import pytest

from atr_node.calibration.estimate import estimate_model
from atr_node.calibration.responses import (CalibrationImage, cell_edges, cell_maxima, collect_image,
                                            collect_responses, window_max)
from atr_node.calibration.sources import synthetic_images, synthetic_seabed
from atr_node.config import CalibrationSettings, DetectorSettings, Settings
from atr_node.detectors.background import column_mean, column_median
from atr_node.detectors.engine import score_maps
from atr_node.detectors.windows import window_geometry
from atr_node.simulation.inject import inject_targets


def test_cell_maxima_match_a_loop(rng):
    score = rng.normal(size=(47, 60))
    score[:, 10:14] = np.nan  # a no-data band: all-NaN cells stay NaN
    shadow = rng.integers(1, 9, size=60)
    got = cell_maxima(score, length_px=5, echo_px=3, shadow_px=shadow)
    edges = cell_edges(shadow, 3)
    ref = []
    for r in range(0, 45, 5):
        for c0, c1 in zip(edges[:-1], edges[1:]):
            w = score[r:r + 5, c0:c1]
            ref.append(np.nan if np.all(np.isnan(w)) else np.nanmax(w))
    np.testing.assert_array_equal(got, np.array(ref))
    assert edges[0] == 0 and edges[-1] == 60
    assert np.all(np.diff(edges)[:-1] == 3 + shadow[edges[:-2]])
    assert cell_maxima(score[:3], length_px=5, echo_px=3, shadow_px=shadow).size == 0


def test_window_max_clips_and_reports_no_data():
    s = np.arange(20.0).reshape(4, 5)
    assert window_max(s, 1, 2, row0=-1, length_px=2, echo_px=1, shadow_px=2) == 8.0  # rows 0-1, cols 1-3
    assert window_max(s, 0, 0, row0=-3, length_px=10, echo_px=4, shadow_px=10) == 19.0
    assert np.isnan(window_max(np.full((4, 5), np.nan), 1, 2, row0=-1, length_px=2, echo_px=1, shadow_px=2))
    assert np.isnan(window_max(s, 10, 2, row0=-1, length_px=2, echo_px=1, shadow_px=2))


@pytest.fixture(scope="module")
def seabed_image() -> CalibrationImage:
    s = Settings()
    px = synthetic_seabed(320, 700, range0_m=30.0, dr_m=0.1, dx_m=0.1, seabed="sand",
                          rng=np.random.default_rng(3))
    px[:, 640:] = np.nan  # past maximum range
    return CalibrationImage(px, 30.0, 0.1, 0.1, s.sensor.altitude_m, name="test")


def test_crop_scoring_equals_whole_image_scoring(seabed_image):
    """The lazy crops give exactly what scoring the whole injected image gives."""
    s = Settings()
    im = seabed_image
    resp = collect_image(im, settings=s, iterations=1, targets_per_image=6, rng=np.random.default_rng(11))
    assert resp.n_targets >= 3
    injected, placed = inject_targets(im.pixels, range0_m=im.range0_m, dr_m=im.dr_m, dx_m=im.dx_m,
                                      altitude_m=im.altitude_m, n_targets=6, rng=np.random.default_rng(11),
                                      sensor=s.sensor, simulation=s.simulation, template=s.template,
                                      population=s.calibration.population, swath_end=True)
    b, m = column_mean(im.pixels), column_median(im.pixels)
    full = score_maps(injected, range0_m=im.range0_m, dr_m=im.dr_m, dx_m=im.dx_m, altitude_m=im.altitude_m,
                      template=s.template, detectors=s.detectors, background=b, median=m)
    geom = window_geometry(im.ranges_m, dr_m=im.dr_m, dx_m=im.dx_m, altitude_m=im.altitude_m, template=s.template)
    assert [t.range_m for t in placed] == resp.target_range_m.tolist()
    for d in s.detectors.enabled:
        ref = [window_max(full[d], t.row, t.col, row0=geom.row0, length_px=geom.length_px,
                          echo_px=geom.echo_px, shadow_px=int(geom.shadow_px[t.col])) for t in placed]
        np.testing.assert_allclose(resp.target[d], ref, rtol=1e-9, atol=1e-12)
        # targets stand out of the seabed for every detector
        assert np.nanmedian(resp.target[d]) > np.nanpercentile(resp.nontarget[d], 90)
    # non-target cells: of the clean image, NaN-free past the no-data band is not required
    assert resp.nontarget["mf"].size == (320 // geom.length_px) * (cell_edges(geom.shadow_px, geom.echo_px).size - 1)


def test_targets_cut_by_the_swath_end_are_recorded():
    """An image whose data run to its last column (the swath's end): a target there keeps its
    place, its shadow cut, and the trait ``whole`` says which (docs/calibration.md)."""
    s = Settings()
    px = synthetic_seabed(320, 300, range0_m=30.0, dr_m=0.1, dx_m=0.1, seabed="sand", rng=np.random.default_rng(4))
    im = CalibrationImage(px, 30.0, 0.1, 0.1, s.sensor.altitude_m, name="edge")
    cut = 0
    for seed in range(6):
        resp = collect_image(im, settings=s, iterations=1, targets_per_image=8, rng=np.random.default_rng(seed))
        _, placed = inject_targets(im.pixels, range0_m=im.range0_m, dr_m=im.dr_m, dx_m=im.dx_m,
                                   altitude_m=im.altitude_m, n_targets=8, rng=np.random.default_rng(seed),
                                   sensor=s.sensor, simulation=s.simulation, template=s.template,
                                   population=s.calibration.population, swath_end=True)
        assert [t.range_m for t in placed] == resp.target_range_m.tolist()
        want = [float(t.footprint[3] <= px.shape[1] - 1) for t in placed]
        assert resp.target_traits["whole"].tolist() == want
        np.testing.assert_array_equal(resp.whole, np.asarray(want) > 0)
        cut += want.count(0.0)
    assert cut > 0  # some did reach the swath's end


def test_image_from_a_slant_tile_is_on_ground_range():
    from atr_node.records.tile import Tile

    px = np.random.default_rng(0).exponential(1.0, size=(50, 300)).astype(np.float32)
    tile = Tile("m", 0, "port", 3, px, "intensity", 10.0, 0.1, 0.1, True, 1e9 + np.arange(50) * 0.1)
    im = CalibrationImage.from_tile(tile, altitude_m=14.0)
    ref = tile.ground_range(14.0)
    np.testing.assert_array_equal(im.pixels, ref.pixels)
    assert im.range0_m == ref.range0_m and im.altitude_m == 14.0 and im.name == tile.ident


def test_image_from_an_amplitude_tile_is_its_intensity():
    """Calibration images are what the node scores: an amplitude tile squared (Tile.as_intensity)."""
    from atr_node.records.tile import Tile

    amp = np.random.default_rng(1).rayleigh(1.0, size=(40, 120)).astype(np.float32)
    tile = Tile("m", 0, "stbd", 0, amp, "amplitude", 5.0, 0.1, 0.1, False, 1e9 + np.arange(40) * 0.1)
    im = CalibrationImage.from_tile(tile, altitude_m=10.0)
    np.testing.assert_allclose(im.pixels, amp.astype(np.float64) ** 2, rtol=1e-7)


def test_collect_is_deterministic_and_pools_images():
    s = Settings(detectors=DetectorSettings(enabled=("mf", "z")))
    ims = synthetic_images(2, settings=s, rows=200, cols=400, seed=5, seabed="silt")
    calls = []
    a = collect_responses(ims, settings=s, iterations=2, targets_per_image=3, seed=9,
                          progress=lambda d, t: calls.append((d, t)))
    b = collect_responses(ims, settings=s, iterations=2, targets_per_image=3, seed=9)
    assert a.detectors == ("mf", "z") and calls[-1] == (4, 4)
    for d in a.detectors:
        np.testing.assert_array_equal(a.target[d], b.target[d])
        np.testing.assert_array_equal(a.nontarget[d], b.nontarget[d])
    assert a.provenance["n_images"] == 2 and a.provenance["seed"] == 9 and len(a.provenance["images"]) == 2


def test_pd_agrees_with_a_fresh_independent_injected_set():
    """Done criterion of issue 6: on synthetic seabeds the model's Pd(r) agrees with the Pd
    measured on fresh, independent targets (another image of the same seabed, another seed)
    within the Wilson interval in at least 90 % of range bins (four detectors pooled).

    Two measurements with finite samples agree when their Wilson 95 % intervals overlap; that
    is the check on 90 % of the bins. A stricter check guards against an interval that is
    too narrow: the fresh Pd itself must lie inside the model's interval in at least 80 % of
    the bins. (For a correctly calibrated 95 % interval this fraction is about 93 % with these
    sample sizes, the fresh set's own noise included; an interval half as wide as it should be
    gives about 65 %. `tools/bench/calibration.py --agreement N` shows the spread over seeds.)
    A Pd target of 0.8 keeps Pd(r) away from 1, where the check has teeth."""
    from atr_node.calibration.stats import wilson_interval

    s = Settings(calibration=CalibrationSettings(pd_target=0.8, range_bin_m=10.0))
    rows, cols = 1024, 800  # ranges 28-108 m: 9 bins of 10 m
    cal_im = synthetic_images(1, settings=s, rows=rows, cols=cols, seed=1, seabed="sand")
    fresh_im = synthetic_images(1, settings=s, rows=rows, cols=cols, seed=2, seabed="sand")
    cal = collect_responses(cal_im, settings=s, iterations=6, targets_per_image=40, seed=1)
    fresh = collect_responses(fresh_im, settings=s, iterations=30, targets_per_image=40, seed=2)
    model = estimate_model(cal, calibration=s.calibration)
    overlap = inside = total = 0
    for d in s.detectors.enabled:
        p = model.detectors[d]
        y = p.pyr
        x = fresh.target[d]
        r = fresh.target_range_m
        ok = np.isfinite(x)
        for b in range(y.edges_m.size - 1):
            sel = ok & (r >= y.edges_m[b]) & (r < y.edges_m[b + 1])
            if y.injected[b] < 5 or sel.sum() < 20:
                continue
            k = int(np.sum(x[sel] > p.tau))
            lo, hi = wilson_interval(k, int(sel.sum()))
            total += 1
            overlap += int(lo <= y.high[b] and y.low[b] <= hi)
            inside += int(y.low[b] <= k / sel.sum() <= y.high[b])
        assert 0.5 < p.pd_at_tau < 0.95  # Pd target 0.8: intermediate Pd, not saturated
    assert total >= 30
    assert overlap / total >= 0.9, f"{overlap}/{total} bins agree"
    assert inside / total >= 0.8, f"fresh Pd inside the model's interval in only {inside}/{total} bins"


def test_calibration_on_a_real_sas_texture(real_data):
    """Real seabed (SASSED crop, rock and ripples): the responses and model are defined, targets
    stand out of the real clutter, and clutter does reach the thresholds there, so the
    confidence at tau is well below its synthetic-speckle value for some detector."""
    from atr_node.calibration.sources import image_from_picture

    s = Settings()
    im = image_from_picture(real_data / "sas_textures" / "image_5_original_crop.png", pixel_m=0.1, range0_m=30.0,
                            altitude_m=14.0)
    resp = collect_responses([im], settings=s, iterations=4, targets_per_image=4, seed=0)
    assert resp.n_targets >= 8
    model = estimate_model(resp, calibration=s.calibration)
    c_tau = []
    for d in s.detectors.enabled:
        assert np.nanmedian(resp.target[d]) > np.nanpercentile(resp.nontarget[d], 90)
        c = model.confidence(d, np.linspace(model.tau[d], 2 * abs(model.tau[d]) + 1, 20))
        assert np.all((c > 0) & (c < 1)) and np.all(np.diff(c) >= 0)
        c_tau.append(float(c[0]))
    assert min(c_tau) < 0.9


def test_images_without_room_for_a_target_are_refused():
    from atr_node.errors import AtrError

    s = Settings()
    tiny = CalibrationImage(np.ones((5, 400), np.float32), 30.0, 0.1, 0.1, 14.0, name="tiny")
    empty = CalibrationImage(np.full((400, 400), np.nan, np.float32), 30.0, 0.1, 0.1, 14.0, name="all-nan")
    with pytest.raises(AtrError, match="no image has room"):
        collect_responses([tiny, empty], settings=s, iterations=1, targets_per_image=2, seed=0)


def test_whole_image_scoring_gives_the_crops_responses(seabed_image):
    """A small image crowded with targets: scoring the injected image once per iteration (what
    ``scoring="auto"`` picks when the crops cover more than the image) gives each target the
    response its crop gives, to rounding; the same draws, so the same targets and traits."""
    s = Settings()
    im = seabed_image
    kw = dict(settings=s, iterations=2, targets_per_image=12)
    crops = collect_image(im, rng=np.random.default_rng(5), scoring="crops", **kw)
    whole = collect_image(im, rng=np.random.default_rng(5), scoring="whole", **kw)
    auto = collect_image(im, rng=np.random.default_rng(5), **kw)
    assert crops.n_targets >= 6
    np.testing.assert_array_equal(crops.target_range_m, whole.target_range_m)
    assert crops.target_shape == whole.target_shape == auto.target_shape
    for k in crops.target_traits:
        np.testing.assert_array_equal(crops.target_traits[k], whole.target_traits[k])
    for d in s.detectors.enabled:
        # rounding: the whole image's summed-area tables hold larger sums than a crop's, and
        # lacunarity's variance E[x^2] - E[x]^2 cancels them (a +10 dB target of the varied
        # population: 2.5e-9 relative)
        np.testing.assert_allclose(whole.target[d], crops.target[d], rtol=1e-8, atol=1e-12)
        assert np.array_equal(auto.target[d], whole.target[d], equal_nan=True) or \
            np.array_equal(auto.target[d], crops.target[d], equal_nan=True)
    with pytest.raises(ValueError, match="scoring"):
        collect_image(im, rng=np.random.default_rng(5), scoring="sometimes", **kw)
