"""The mission metric frame and georeferencing of sonar pixels (SPEC sections 0 and 7)."""

from .frame import MissionFrame, OriginEstimator, robust_origin, utm_zone
from .georef import TileGeometry, across_track_unit, pixel_latlon, tile_geometry

__all__ = ["MissionFrame", "OriginEstimator", "TileGeometry", "across_track_unit", "pixel_latlon", "robust_origin",
           "tile_geometry", "utm_zone"]
