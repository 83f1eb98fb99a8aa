"""The mission's metric frame: UTM of the mission origin, or a local tangent plane.

``utm``: the UTM zone (WGS84) that holds the origin; east/north are UTM easting and northing
in metres, as an MCM engineer reads them off a chart. ``ltp``: an azimuthal equidistant
projection centred on the origin (a local tangent plane whose distances from the origin are
exact); east/north are metres from the origin. Both go through pyproj, the maintained binding
of PROJ, rather than our own series expansions.

UTM is defined from 80 deg S to 84 deg N (:data:`UTM_LAT_RANGE_DEG`); a mission whose origin
lies outside asks for ``utm`` in vain, and :meth:`MissionFrame.from_settings` gives it the local
tangent plane instead (valid at any latitude, the poles included), saying so once at INFO.

Without a configured origin, the node takes the origin from the first fixes, robustly
(:func:`robust_origin`, :class:`OriginEstimator`): one wild first fix does not set the frame.

Headings are true (clockwise from true north); in the frame, grid north differs from true
north by the meridian convergence, and lengths by the scale factor. :meth:`grid_factors`
returns both per point so that georeferencing (``georef``) stays exact to millimetres.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from pyproj import CRS, Proj, Transformer

from ..errors import GeometryError

log = logging.getLogger(__name__)

UTM_LAT_RANGE_DEG = (-80.0, 84.0)
"""Latitudes where UTM is defined (beyond them: UPS; the node uses its local tangent plane)."""

ORIGIN_FIXES = 5
"""Plausible fixes the frame origin is the median of (:class:`OriginEstimator`)."""


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
        if not (math.isfinite(self.origin_lat_deg) and abs(self.origin_lat_deg) <= 90.0):
            raise GeometryError(f"origin latitude {self.origin_lat_deg!r} outside [-90, 90]")
        lo, hi = UTM_LAT_RANGE_DEG
        if self.kind == "utm" and not lo <= self.origin_lat_deg <= hi:
            raise GeometryError(f"origin latitude {self.origin_lat_deg!r} outside UTM's [{lo:g}, {hi:g}]: "
                                "use the local tangent plane (frame 'ltp')")
        if not math.isfinite(self.origin_lon_deg):
            raise GeometryError(f"origin longitude {self.origin_lon_deg!r} is not finite")
        crs = CRS.from_proj4(self.proj4)
        object.__setattr__(self, "_proj", Proj(crs))
        object.__setattr__(self, "_fwd", Transformer.from_crs("EPSG:4326", crs, always_xy=True))
        object.__setattr__(self, "_inv", Transformer.from_crs(crs, "EPSG:4326", always_xy=True))

    @classmethod
    def from_settings(cls, mission: Any, first_fix: tuple[float, float] | None = None) -> "MissionFrame":
        """From ``MissionSettings``; without an origin there, ``first_fix`` (lat, lon): the
        node passes the robust estimate of :class:`OriginEstimator`.

        ``utm`` asked for where UTM is not defined (beyond 84 deg N or 80 deg S) gives the
        local tangent plane, with one INFO line saying so: a polar mission runs."""
        if mission.origin_lat_deg is not None:
            lat, lon = float(mission.origin_lat_deg), float(mission.origin_lon_deg)
        elif first_fix is None:
            raise GeometryError("the mission frame needs an origin: set mission.origin_lat_deg/lon_deg "
                                "or wait for a fix")
        else:
            lat, lon = float(first_fix[0]), float(first_fix[1])
        kind = mission.frame
        lo, hi = UTM_LAT_RANGE_DEG
        if kind == "utm" and math.isfinite(lat) and not lo <= lat <= hi:
            kind = "ltp"
            log.info("mission origin %.6f, %.6f is outside UTM's latitudes [%g, %g]: the mission frame is "
                     "the local tangent plane at the origin", lat, lon, lo, hi)
        return cls(kind, lat, lon)

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


def plausible_fix(lat_deg: float, lon_deg: float) -> bool:
    """A fix that may enter the origin estimate: finite, on the globe, and not (0, 0) (a
    recorder's "no fix", as the nav merge treats it)."""
    return (math.isfinite(lat_deg) and math.isfinite(lon_deg) and abs(lat_deg) <= 90.0
            and -180.0 <= lon_deg <= 360.0 and not (lat_deg == 0.0 and lon_deg == 0.0))


def robust_origin(lat_deg: Any, lon_deg: Any) -> tuple[float, float]:
    """(lat_deg, lon_deg): the median position of fixes, robust to a minority of outliers.

    The component-wise median of the fixes' unit vectors, normalised back to a direction: it
    ignores any one wild fix among three or more (the median of each component comes from the
    others), and needs no care at the antimeridian or near a pole, where a median of
    longitudes would be meaningless. Latitudes are geodetic, taken as the angles of the unit
    vector both ways, so one fix gives itself back.

    Parameters
    ----------
    lat_deg, lon_deg : array_like, shape (n,)
        The fixes, n >= 1, each finite.

    Returns
    -------
    tuple of float
        The origin, longitude in [-180, 180).
    """
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64).ravel())
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64).ravel())
    if lat.size == 0 or lat.size != lon.size:
        raise GeometryError(f"robust_origin: {lat.size} latitudes and {lon.size} longitudes, "
                            "expected n >= 1 of each")
    xyz = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    x, y, z = np.median(xyz, axis=1)
    if math.hypot(x, y, z) == 0.0:  # fixes spread evenly round the globe: no median direction
        raise GeometryError("robust_origin: the fixes have no median direction")
    o_lat = math.degrees(math.atan2(z, math.hypot(x, y)))
    o_lon = math.degrees(math.atan2(y, x))
    if len(lat) == 1:  # exactly the fix (atan2 round trips to ~1e-14 deg otherwise)
        o_lat, o_lon = float(np.degrees(lat[0])), float(np.degrees(lon[0]))
    return o_lat, (o_lon + 180.0) % 360.0 - 180.0


class OriginEstimator:
    """Gathers the first plausible fixes of a mission for its frame origin (:func:`robust_origin`).

    The node fixes its frame once :attr:`ready` (``n`` fixes), or at its first tile with what
    it has then (the tile's own pings added): both points depend only on the record sequence,
    so a replay fixes the same origin every time. One outlier first fix (a GNSS fix before
    convergence, a recorder's stale position) then costs nothing: the median of ``n`` = 5
    fixes ignores up to two.
    """

    def __init__(self, n: int = ORIGIN_FIXES) -> None:
        if n < 1:
            raise GeometryError(f"OriginEstimator: n must be >= 1, got {n}")
        self.n = n
        self.fixes: list[tuple[float, float]] = []
        self.implausible = 0
        """Fixes left out (not finite, off the globe, or (0, 0))."""

    def add(self, lat_deg: float, lon_deg: float) -> bool:
        """Offer one fix; True once :attr:`ready`."""
        if len(self.fixes) < self.n:
            if plausible_fix(lat_deg, lon_deg):
                self.fixes.append((float(lat_deg), float(lon_deg)))
            else:
                self.implausible += 1
        return self.ready

    def add_track(self, lat_deg: Any, lon_deg: Any) -> None:
        """Offer a tile's pings: ``n`` of them spread over the tile (its first pings alone
        would be one position ``n`` times; a tile spans tens of metres at most)."""
        lat = np.asarray(lat_deg, dtype=np.float64).ravel()
        lon = np.asarray(lon_deg, dtype=np.float64).ravel()
        if lat.size == 0:
            return
        for i in np.unique(np.linspace(0, lat.size - 1, self.n).round().astype(int)):
            self.add(float(lat[i]), float(lon[i]))

    @property
    def ready(self) -> bool:
        return len(self.fixes) >= self.n

    def estimate(self) -> tuple[float, float] | None:
        """The robust origin of the fixes so far (None: none yet)."""
        if not self.fixes:
            return None
        lat, lon = zip(*self.fixes)
        return robust_origin(lat, lon)
