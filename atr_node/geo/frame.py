"""The mission's metric frame: UTM of the mission origin, or a local tangent plane.

``utm``: the UTM zone (WGS84) that holds the origin; east/north are UTM easting and northing
in metres, as an MCM engineer reads them off a chart. ``ltp``: an azimuthal equidistant
projection centred on the origin (a local tangent plane whose distances from the origin are
exact); east/north are metres from the origin. Both go through pyproj, the maintained binding
of PROJ, rather than our own series expansions.

Headings are true (clockwise from true north); in the frame, grid north differs from true
north by the meridian convergence, and lengths by the scale factor. :meth:`grid_factors`
returns both per point so that georeferencing (``georef``) stays exact to millimetres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from pyproj import CRS, Proj, Transformer

from ..errors import GeometryError


def utm_zone(lat_deg: float, lon_deg: float) -> tuple[int, bool]:
    """(zone, north) of the UTM zone holding a point, with the Norway and Svalbard exceptions."""
    lon = (lon_deg + 180.0) % 360.0 - 180.0
    zone = int((lon + 180.0) // 6.0) + 1
    if 56.0 <= lat_deg < 64.0 and 3.0 <= lon < 12.0:
        zone = 32
    if 72.0 <= lat_deg < 84.0:
        for lo, hi, z in ((0.0, 9.0, 31), (9.0, 21.0, 33), (21.0, 33.0, 35), (33.0, 42.0, 37)):
            if lo <= lon < hi:
                zone = z
    return min(zone, 60), lat_deg >= 0.0


@dataclass(frozen=True)
class MissionFrame:
    """A metric frame anchored at the mission origin."""

    kind: Literal["utm", "ltp"]
    origin_lat_deg: float
    origin_lon_deg: float
    _proj: Any = field(init=False, repr=False, compare=False)
    _fwd: Any = field(init=False, repr=False, compare=False)
    _inv: Any = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.kind not in ("utm", "ltp"):
            raise GeometryError(f"frame kind must be 'utm' or 'ltp', got {self.kind!r}")
        if not (math.isfinite(self.origin_lat_deg) and abs(self.origin_lat_deg) <= 84.0):
            raise GeometryError(f"origin latitude {self.origin_lat_deg!r} outside [-84, 84]")
        if not math.isfinite(self.origin_lon_deg):
            raise GeometryError(f"origin longitude {self.origin_lon_deg!r} is not finite")
        crs = CRS.from_proj4(self.proj4)
        object.__setattr__(self, "_proj", Proj(crs))
        object.__setattr__(self, "_fwd", Transformer.from_crs("EPSG:4326", crs, always_xy=True))
        object.__setattr__(self, "_inv", Transformer.from_crs(crs, "EPSG:4326", always_xy=True))

    @classmethod
    def from_settings(cls, mission: Any, first_fix: tuple[float, float] | None = None) -> "MissionFrame":
        """From ``MissionSettings``; without an origin there, the first nav fix (lat, lon)."""
        if mission.origin_lat_deg is not None:
            return cls(mission.frame, mission.origin_lat_deg, mission.origin_lon_deg)
        if first_fix is None:
            raise GeometryError("the mission frame needs an origin: set mission.origin_lat_deg/lon_deg or wait for a fix")
        return cls(mission.frame, float(first_fix[0]), float(first_fix[1]))

    @property
    def proj4(self) -> str:
        if self.kind == "utm":
            zone, north = utm_zone(self.origin_lat_deg, self.origin_lon_deg)
            return f"+proj=utm +zone={zone} {'' if north else '+south '}+datum=WGS84 +units=m +no_defs"
        return (f"+proj=aeqd +lat_0={self.origin_lat_deg!r} +lon_0={self.origin_lon_deg!r} "
                "+datum=WGS84 +units=m +no_defs")

    @property
    def name(self) -> str:
        if self.kind == "utm":
            zone, north = utm_zone(self.origin_lat_deg, self.origin_lon_deg)
            return f"UTM {zone}{'N' if north else 'S'} (WGS84)"
        return f"local tangent plane at {self.origin_lat_deg:.6f}, {self.origin_lon_deg:.6f}"

    def to_frame(self, lat_deg: Any, lon_deg: Any) -> tuple[np.ndarray, np.ndarray]:
        """(east_m, north_m) of WGS84 points."""
        e, n = self._fwd.transform(np.asarray(lon_deg, dtype=np.float64), np.asarray(lat_deg, dtype=np.float64))
        return np.asarray(e), np.asarray(n)

    def to_latlon(self, east_m: Any, north_m: Any) -> tuple[np.ndarray, np.ndarray]:
        """(lat_deg, lon_deg) of frame points."""
        lon, lat = self._inv.transform(np.asarray(east_m, dtype=np.float64), np.asarray(north_m, dtype=np.float64))
        return np.asarray(lat), np.asarray(lon)

    def grid_factors(self, lat_deg: Any, lon_deg: Any) -> tuple[np.ndarray, np.ndarray]:
        """(convergence_deg, scale) at points: grid azimuth = true azimuth - convergence;
        frame length = true length * scale (the mean of meridional and parallel scale)."""
        f = self._proj.get_factors(np.asarray(lon_deg, dtype=np.float64), np.asarray(lat_deg, dtype=np.float64))
        conv = np.asarray(f.meridian_convergence, dtype=np.float64)
        scale = 0.5 * (np.asarray(f.meridional_scale, dtype=np.float64) + np.asarray(f.parallel_scale, dtype=np.float64))
        return conv, scale

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "origin_lat_deg": self.origin_lat_deg, "origin_lon_deg": self.origin_lon_deg}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "MissionFrame":
        return cls(d["kind"], float(d["origin_lat_deg"]), float(d["origin_lon_deg"]))
