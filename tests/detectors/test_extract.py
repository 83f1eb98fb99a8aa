"""Detection extraction (SPEC 3): exact tiny cases, a planted target, a long shadow band."""

from __future__ import annotations

import numpy as np
import pytest

from atr_node.config import DetectorSettings, TemplateSettings
from atr_node.detectors import Detection, find_detections, score_maps, window_geometry
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
