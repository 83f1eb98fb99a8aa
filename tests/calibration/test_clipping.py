"""Recordings that clip (an 8-bit file's 255): the tile's saturation, the injected echo cut at it,
the headroom of each place, and the clipped places' own likelihood ratios (docs/fusion.md,
"Clipped recordings")."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from atr_node.calibration.estimate import estimate_model
from atr_node.calibration.looks import MIN_STRATUM_TARGETS, clipped, headroom_db, lr_table
from atr_node.calibration.model import PerformanceModel, _digest
from atr_node.calibration.responses import CalibrationImage, Responses, cell_edges, collect_image
from atr_node.config import CalibrationSettings, Settings, ThresholdSettings, load_settings
from atr_node.detectors.background import column_mean
from atr_node.detectors.windows import window_geometry
from atr_node.errors import ModelFileError
from atr_node.records.tile import Tile, TileNav

DETS = ("mf", "lac", "smf", "z")


def _tile(pixels, *, kind="amplitude", wire="uint8", **kw) -> Tile:
    rows = pixels.shape[0]
    return Tile("m", 0, "port", 0, np.asarray(pixels, dtype=np.float32), kind, 10.0, 0.1, 0.1, False,
                np.arange(rows, dtype=np.float64), wire_dtype=wire, **kw)


# -- the tile's saturation ----------------------------------------------------------------------

@pytest.mark.parametrize("wire, kind, expect, intensity", [
    ("uint8", "amplitude", 255.0, 255.0 ** 2),
    ("uint16", "amplitude", 65535.0, 65535.0 ** 2),
    ("uint16", "intensity", 65535.0, 65535.0),
    ("float32", "amplitude", None, None),
    ("float32", "intensity", None, None),
])
def test_saturation_is_the_integer_samples_full_scale_and_squares_into_intensity(wire, kind, expect, intensity):
    t = _tile(np.full((4, 5), 7.0), kind=kind, wire=wire)
    assert t.saturation == expect
    i = t.as_intensity()
    assert i.kind == "intensity" and i.saturation == intensity
    if kind == "amplitude":
        np.testing.assert_array_equal(i.pixels, np.float32(49.0))


def test_a_given_full_scale_wins_and_ground_range_keeps_it():
    t = _tile(np.full((4, 5), 3.0), wire="uint16", full_scale=4095.0)  # 12-bit samples in 16-bit words
    assert t.saturation == 4095.0 and t.as_intensity().saturation == 4095.0 ** 2
    slant = dataclasses.replace(_tile(np.full((3, 200), 9.0)), slant=True, range0_m=0.0)
    g = slant.ground_range(2.0)
    assert not g.slant and g.wire_dtype == "float32" and g.saturation == 255.0
    assert g.as_intensity().saturation == 255.0 ** 2


@pytest.mark.parametrize("wire, top, clip", [("uint16", 32767.0, True), ("uint8", 255.0, True),
                                              ("uint16", 32767.0, False), ("uint8", 200.0, False)])
def test_the_clip_level_is_where_integer_samples_pile_up(wire, top, clip):
    """A recorder that clips below its word's range (the Iver2 file's 16-bit samples stop at
    32767): the level where the samples pile up is the saturation. Unclipped speckle thins out
    towards its largest sample, so the word's largest value stays the (conservative) one."""
    rng = np.random.default_rng(5)
    a = rng.rayleigh(top * (0.3 if clip else 0.12), size=(200, 300))
    px = np.maximum(np.round(np.minimum(a, top)), 1.0).astype(np.float32)
    px[:5] = np.nan  # dropped pings
    t = _tile(px, wire=wire)
    full = float(np.iinfo(np.uint16 if wire == "uint16" else np.uint8).max)
    if clip:
        assert t.clip_level == top and t.saturation == top
        assert t.as_intensity().saturation == top * top
    else:
        assert t.clip_level is None and t.saturation == full
    assert _tile(px, wire="float32").clip_level is None


def test_the_iver2_file_clips_at_32767(real_data):
    from atr_node.io.recording import open_recording

    tiles = [Tile.from_map(r.msg) for r in open_recording(real_data / "xtf" / "scotsman-iver2.xtf")
             if r.link == "sonar"]
    assert tiles and all(t.wire_dtype == "uint16" and t.saturation == 32767.0 for t in tiles)


def test_a_strip_keeps_the_lowest_clip_level_of_its_tiles():
    """A strip's full scale is the recorder's: a tile that never reached it (no pile-up, so only its
    word's range) does not raise the level the other tiles showed."""
    from atr_node.node.strip import StripAssembler

    rng = np.random.default_rng(2)
    clipped = np.maximum(np.round(np.minimum(rng.rayleigh(12000.0, size=(64, 300)), 32767.0)), 1.0)
    dark = np.maximum(np.round(rng.rayleigh(2000.0, size=(64, 300))), 1.0)
    asm = StripAssembler(4)
    for seq, px in enumerate((clipped, dark)):
        t = Tile("m", 0, "port", seq, px.astype(np.float32), "amplitude", 10.0, 0.1, 0.1, False,
                 seq * 64 + np.arange(64, dtype=np.float64), wire_dtype="uint16",
                 nav=TileNav(np.full(64, 42.0), np.full(64, -70.0) + 1e-6 * (seq * 64 + np.arange(64)),
                             np.zeros(64), np.full(64, 8.0)))
        asm.push(t.as_intensity())
    assert asm._legs["port"].full_scale == 32767.0 ** 2


# -- headroom ------------------------------------------------------------------------------------

def test_headroom_closed_form_and_extremes():
    """10 log10(full scale / background); inf where either is unknown; 0 and below at and over
    full scale (a saturated seabed, SPEC 8)."""
    b = np.array([10.0, 100.0, 1000.0, 2000.0, 0.0, np.nan, -1.0, 1e-300])
    h = headroom_db(1000.0, b)
    np.testing.assert_allclose(h[:4], [20.0, 10.0, 0.0, 10.0 * math.log10(0.5)], rtol=1e-12)
    assert np.all(np.isinf(h[4:7])) and h[7] > 3000.0
    assert np.all(np.isinf(headroom_db(None, b))) and np.all(np.isinf(headroom_db(math.inf, b)))
    np.testing.assert_array_equal(clipped(h, 10.0), [False, False, True, True, False, False, False, False])
    assert not clipped(h, None).any()


# -- injection into a clipping image -------------------------------------------------------------

def _image(full_scale, *, seed=3, rows=400, cols=500) -> CalibrationImage:
    """Speckle of mean 1 as a recorder clipping at 4 would have stored it (6 dB of headroom:
    its brightest 2 % at 4), told its full scale or not."""
    rng = np.random.default_rng(seed)
    px = np.minimum(rng.exponential(1.0, size=(rows, cols)), 4.0).astype(np.float32)
    return CalibrationImage(px, 8.0, 0.05, 0.05, 8.0, name="speckle", full_scale=full_scale)


def test_injected_echoes_are_cut_at_the_images_full_scale_and_headroom_is_recorded():
    s = Settings()
    free = collect_image(_image(None), settings=s, iterations=2, targets_per_image=10, rng=np.random.default_rng(0))
    img = _image(4.0)
    cut = collect_image(img, settings=s, iterations=2, targets_per_image=10, rng=np.random.default_rng(0))
    # the same placements (same draws) and clean cells: only the injected echoes differ
    np.testing.assert_array_equal(free.target_range_m, cut.target_range_m)
    for d in DETS:
        np.testing.assert_array_equal(free.nontarget[d], cut.nontarget[d])
    # the highlight detectors see less of a target whose echo is cut; the shadow detector the same shadow
    assert np.nanmean(cut.target["mf"]) < 0.8 * np.nanmean(free.target["mf"])
    assert np.nanmean(cut.target["z"]) < 0.8 * np.nanmean(free.target["z"])
    np.testing.assert_allclose(np.nanmedian(cut.target["smf"]), np.nanmedian(free.target["smf"]), rtol=0.2)
    # headroom per cell (its first column) and per target, from a direct float64 computation
    b = np.mean(img.pixels.astype(np.float64), axis=0)
    np.testing.assert_allclose(column_mean(img.pixels), b, rtol=1e-5)
    geom = window_geometry(img.ranges_m, template=s.template, dr_m=img.dr_m, dx_m=img.dx_m, altitude_m=img.altitude_m)
    edges = cell_edges(geom.shadow_px, geom.echo_px)
    want = np.tile(10.0 * np.log10(4.0 / b[edges[:-1]]), img.pixels.shape[0] // geom.length_px)
    np.testing.assert_allclose(cut.nontarget_headroom_db, want, atol=1e-4)
    assert cut.nontarget_headroom_db.size == cut.nontarget["mf"].size
    h_t = cut.target_traits["headroom_db"]
    assert h_t.shape == cut.target_range_m.shape and np.all(np.abs(h_t - 10.0 * math.log10(4.0 / 0.98)) < 0.5)
    assert np.all(np.isinf(free.target_traits["headroom_db"])) and np.all(np.isinf(free.nontarget_headroom_db))
    # pooled and cut short, the headroom goes along
    both = Responses.concat([free, cut])
    assert both.nontarget_headroom_db.size == both.nontarget["mf"].size
    assert both.head(5).nontarget_headroom_db is both.nontarget_headroom_db


def test_a_picture_clips_at_white(tmp_path):
    import cv2

    from atr_node.calibration.sources import image_from_picture

    p = tmp_path / "t.png"
    cv2.imwrite(str(p), np.full((20, 30), 255, dtype=np.uint8))
    img = image_from_picture(p, pixel_m=0.05, range0_m=5.0, altitude_m=8.0)
    assert img.full_scale == 1.0 and float(img.pixels.max()) == 1.0


# -- the clipped places' own likelihood ratios ---------------------------------------------------

def clipping_responses(rng, *, m=2000, k=20000, clipped_share=0.5) -> Responses:
    """Independent detectors; on clipped seabed (headroom 5 dB) the highlight detectors (mf, lac,
    z) see a target weakly (shift 1) and the background as elsewhere; elsewhere (30 dB) a target
    stands out (shift 3). The shadow detector (smf) sees both alike."""
    r = rng.uniform(10.0, 60.0, size=m)
    c_t, c_n = rng.random(m) < clipped_share, rng.random(k) < clipped_share
    target = {d: rng.normal(size=m) + np.where(c_t & (d != "smf"), 1.0, 3.0) for d in DETS}
    nontarget = {d: rng.normal(size=k) for d in DETS}
    traits = {"headroom_db": np.where(c_t, 5.0, 30.0)}
    return Responses(DETS, target, nontarget, r, ("cylinder",) * m, {"cell_area_m2": 5.0}, traits,
                     np.where(c_n, 5.0, 30.0))


def test_clipped_places_get_their_own_likelihood_ratios(rng, tmp_path):
    resp = clipping_responses(rng)
    cal = CalibrationSettings()
    model = estimate_model(resp, calibration=cal, thresholds=ThresholdSettings())
    looks = model.looks
    assert looks.lrs_clipped is not None and looks.clip_headroom_db == cal.clip_headroom_db == 10.0
    assert "clipped" in looks.info
    c_t = resp.target_traits["headroom_db"] < 10.0
    c_n = resp.nontarget_headroom_db < 10.0
    # each stratum's table is lr_table of its own targets and cells (an independent build)
    for d in DETS:
        g = np.linspace(-1.0, 4.0, 11)
        ref_c = lr_table(resp.target[d][c_t], resp.nontarget[d][c_n])
        ref_f = lr_table(resp.target[d][~c_t], resp.nontarget[d][~c_n])
        np.testing.assert_allclose(looks.lrs_clipped[d].l, ref_c.l)
        np.testing.assert_allclose(looks.lrs[d].l, ref_f.l)
        np.testing.assert_allclose(looks.lrs_clipped[d](g) - looks.lrs[d](g), ref_c(g) - ref_f(g), atol=1e-12)
    # a weak highlight (1.5 on every highlight detector, a clear shadow) says more where the
    # recording clips: the clipped table scores it higher than the free one, and the model's
    # score picks the table by the place's headroom
    x = {"mf": 1.5, "lac": 1.5, "z": 1.5, "smf": 2.5}
    z_clip = float(model.look_score(x, DETS, headroom_db=6.0))
    z_free = float(model.look_score(x, DETS, headroom_db=25.0))
    assert z_clip > z_free + 2.0
    assert float(model.look_score(x, DETS)) == z_free  # unknown headroom: the free table
    # closed form: with independent normals the log ratio of the clipped targets is
    # shift * g - shift^2 / 2 (shift 1), of the free ones 3 g - 4.5; at g = 1.5 it is 1.0 and 0.0
    for d in ("mf", "lac", "z"):
        assert abs(float(looks.lrs_clipped[d](1.5)) - 1.0) < 0.25
        assert abs(float(looks.lrs[d](1.5)) - 0.0) < 0.35
    # the model file keeps both, and refuses a clipped table without its limit
    back = PerformanceModel.load(model.save(tmp_path / "m.json"))
    assert back.looks.clip_headroom_db == 10.0
    assert float(back.look_score(x, DETS, headroom_db=6.0)) == z_clip
    body = json.loads((tmp_path / "m.json").read_text())
    del body["looks"]["clip_headroom_db"]
    body["sha256"] = _digest({k: v for k, v in body.items() if k != "sha256"})
    (tmp_path / "bad.json").write_text(json.dumps(body))
    with pytest.raises(ModelFileError, match=r"looks\.clip_headroom_db"):
        PerformanceModel.load(tmp_path / "bad.json")


@pytest.mark.parametrize("case", ["none clipped", "too few clipped", "no headroom recorded"])
def test_one_table_for_all_without_enough_clipped_places(rng, case):
    """Float data (no full scale: every headroom inf), a handful of clipped targets, or responses
    made before headroom was recorded: one table, the same as before the clipped tables."""
    share = {"none clipped": 0.0, "too few clipped": (MIN_STRATUM_TARGETS - 10) / 2000}.get(case, 0.5)
    resp = clipping_responses(rng, clipped_share=share)
    if case == "no headroom recorded":
        resp = dataclasses.replace(resp, target_traits={}, nontarget_headroom_db=None)
    model = estimate_model(resp, calibration=CalibrationSettings(), thresholds=ThresholdSettings())
    assert model.looks.lrs_clipped is None and model.looks.clip_headroom_db is None
    for d in DETS:
        np.testing.assert_allclose(model.looks.lrs[d].l, lr_table(resp.target[d], resp.nontarget[d]).l)
    x = {"mf": 1.5, "lac": 1.5, "z": 1.5, "smf": 2.5}
    assert float(model.look_score(x, DETS, headroom_db=0.0)) == float(model.look_score(x, DETS))


def test_clip_headroom_setting_is_read(tmp_path):
    """(A bad value is refused in tests/foundation/test_config_cli.py's table.)"""
    p = tmp_path / "c.toml"
    p.write_text("[calibration]\nclip_headroom_db = 6.0\n")
    assert load_settings(p).calibration.clip_headroom_db == 6.0
