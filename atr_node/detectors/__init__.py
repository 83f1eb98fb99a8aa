"""The four detectors of SPEC section 2 and detection extraction (SPEC sections 1-3).

- :mod:`.windows`: range-adaptive windows around the anchor pixel (SPEC 1).
- :mod:`.background`: per-range background b(j), median m(j), the leg's tracker.
- :mod:`.sat`: the summed-area engine (padded tables, box sums by slices and gathers).
- :mod:`.formulas`: matched filter, lacunarity, segmented matched filter, mean test.
- :mod:`.engine`: :func:`score_maps` and :func:`score_strip` (tiles with margins).
- :mod:`.extract`: :class:`Detection`, :func:`find_detections` (SPEC 3) and
  :func:`place_at_peak` (``detectors.relocate``).
"""

from __future__ import annotations

from ..config import DETECTOR_NAMES
from .background import BackgroundTracker, column_mean, column_median
from .engine import score_maps, score_strip
from .extract import Detection, find_detections, place_at_peak
from .sat import Workspace
from .windows import WindowGeometry, required_margin, shadow_length_m, window_geometry

DETECTORS: tuple[str, ...] = DETECTOR_NAMES
"""Detector names: matched filter, lacunarity, segmented matched filter, mean (Z) test."""

__all__ = [
    "DETECTORS", "BackgroundTracker", "Detection", "WindowGeometry", "column_mean", "column_median",
    "find_detections", "place_at_peak", "required_margin", "score_maps", "score_strip", "shadow_length_m",
    "window_geometry", "Workspace",
]
