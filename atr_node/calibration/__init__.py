"""Detector performance estimates by target injection (SPEC section 5).

- :mod:`.stats`: survival functions, confidence (paper eq. 6), isotonic fit, Wilson interval,
  P(y) per range bin, Dobeck thresholds; pure functions defined for empty and single samples.
- :mod:`.model`: :class:`PerformanceModel` and its versioned, self-describing file.
- :mod:`.responses`: target and non-target responses collected by injection.
- :mod:`.estimate`: responses -> model.
- :mod:`.sources`: images to calibrate on (recordings, pictures, synthetic seabeds).
- :mod:`.online`: the on-line calibration worker process of the node.
- :mod:`.plots`: the paper's figures 3 (confidence) and 4 (P(y)); matplotlib imported lazily.
"""

from .estimate import estimate_model
from .model import FORMAT_VERSION, DetectorPerformance, PerformanceModel
from .responses import CalibrationImage, Responses, collect_responses

__all__ = ["FORMAT_VERSION", "CalibrationImage", "DetectorPerformance", "PerformanceModel", "Responses",
           "collect_responses", "estimate_model"]
