"""The detectors on real SAS seabed textures (SASSED crops, 8-bit display amplitude)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from atr_node.config import DetectorSettings, TemplateSettings
from atr_node.detectors import DETECTORS, score_maps
from tests.detectors.reference import reference_scores
from tests.detectors.scenes import GEOM, SMALL
from tests.detectors.test_reference import assert_scores_match


def texture(real_data, index: int) -> np.ndarray:
    path = real_data / "sas_textures" / f"image_{index}_original_crop.png"
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        pytest.skip(f"cannot read {path}")
    return img.astype(np.float32)


@pytest.mark.parametrize("index", [0, 12])
def test_real_texture_crop_matches_reference(real_data, index):
    img = texture(real_data, index)[100:140, 200:270].copy()
    img[img == 0] = np.nan  # as Tile does for integer wire data: 0 = no data
    got = score_maps(img, template=SMALL, detectors=DetectorSettings(), **GEOM)
    ref = reference_scores(img, template=SMALL, detectors=DetectorSettings(), **GEOM)
    for d in DETECTORS:
        assert_scores_match(got[d], ref[d], 1e-6)


def test_whole_texture_scores_are_finite_inside(real_data):
    img = texture(real_data, 5)
    maps = score_maps(img, range0_m=20.0, dr_m=0.05, dx_m=0.05, altitude_m=14.0,
                      template=TemplateSettings(), detectors=DetectorSettings())
    for d, g in maps.items():
        assert g.shape == img.shape and not np.isinf(g).any(), d
        assert np.isfinite(g[40:-40, 60:-200]).all(), d  # away from the edges every window is full
