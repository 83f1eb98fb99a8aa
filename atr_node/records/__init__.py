"""Typed records: sonar tiles (ICD section 1) and navigation."""

from .nav import NavFix, NavSample, NavTrack, nav_jumps, wrap180
from .tile import SensorInfo, Tile, TileNav, parse_tile, tile_ident

__all__ = ["NavFix", "NavSample", "NavTrack", "SensorInfo", "Tile", "TileNav", "nav_jumps", "parse_tile",
           "tile_ident", "wrap180"]
