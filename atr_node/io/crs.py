"""The coordinate reference system of a recorded file's positions: ``--crs`` (ICD v1.1 section 6).

Some recorders store positions as projected metres (XTF ``NavUnits`` 0: easting in the X
fields, northing in the Y fields) and do not say in which projection. The user names it with
``--crs`` (or the ``recording.crs`` key), e.g. ``EPSG:32610`` (UTM 10N); positions are turned
into WGS 84 latitude and longitude with pyproj at reading, so everything downstream sees
degrees as from any other file. A geographic CRS is accepted too (``EPSG:4326``: the file's
positions are degrees whatever its header says, a quirk of writers that leave ``NavUnits`` 0;
another datum, e.g. ``EPSG:4267`` NAD27, is shifted to WGS 84).

:func:`projection` validates a CRS string once (an unknown CRS, or one that is not a 2-D
horizontal one, is one :class:`~atr_node.errors.ConfigError` line naming the option and the
value) and returns a :class:`Projection` that converts both ways, on scalars or arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from ..errors import ConfigError

__all__ = ["EXAMPLE_CRS", "Projection", "projection"]

EXAMPLE_CRS = "EPSG:32610"
"""The example every message gives (UTM zone 10 north, WGS 84)."""


@dataclass(frozen=True)
class Projection:
    """A file's CRS and its transformers to and from WGS 84 lat/lon (``always_xy``: x =
    easting or longitude, y = northing or latitude)."""

    crs: str
    """As the user gave it (e.g. ``EPSG:32610``)."""
    name: str
    """pyproj's name of the CRS (e.g. ``WGS 84 / UTM zone 10N``), for messages."""
    _to_lonlat: Any
    _from_lonlat: Any

    projected: bool
    """True for map projections (metres), False for geographic CRSs (degrees)."""

    def to_latlon(self, x: Any, y: Any) -> tuple[Any, Any]:
        """(lat_deg, lon_deg) of the file's (x, y) positions (scalars or arrays): easting and
        northing in metres, or longitude and latitude in degrees; NaN where the CRS has no
        answer (pyproj gives inf there)."""
        lon, lat = self._to_lonlat.transform(x, y)
        lat, lon = np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64)
        bad = ~(np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90.0) & (np.abs(lon) <= 180.0))
        lat, lon = np.where(bad, np.nan, lat), np.where(bad, np.nan, lon)
        if lat.ndim == 0:
            return float(lat), float(lon)
        return lat, lon

    def from_latlon(self, lat_deg: Any, lon_deg: Any) -> tuple[Any, Any]:
        """(x, y) in this CRS of WGS 84 positions (scalars or arrays): (east_m, north_m) for a
        projection, (lon, lat) for a geographic CRS."""
        return self._from_lonlat.transform(lon_deg, lat_deg)


@lru_cache(maxsize=16)
def projection(crs: str, *, option: str = "--crs") -> Projection:
    """The :class:`Projection` of a CRS string, validated.

    Parameters
    ----------
    crs
        Anything pyproj takes: ``EPSG:32610``, a PROJ string, WKT.
    option
        Where the value came from, for messages (``--crs`` or ``recording.crs``).

    Raises
    ------
    ConfigError
        Unknown to pyproj, or neither a projected nor a 2-D geographic CRS (a geocentric,
        vertical or 3-D CRS does not say what a pair of horizontal coordinates is).
    """
    from pyproj import CRS, Transformer
    from pyproj.exceptions import CRSError

    if not crs or not crs.strip():
        raise ConfigError(f"{option} is empty; expected a projected CRS such as {EXAMPLE_CRS}")
    try:
        c = CRS.from_user_input(crs)
    except CRSError as exc:
        why = str(exc).split(": (", 1)[-1].rstrip(")") if ": (" in str(exc) else str(exc)
        raise ConfigError(f"{option} {crs!r}: not a coordinate reference system pyproj knows ({why}); "
                          f"expected a projected CRS such as {EXAMPLE_CRS}") from None
    if not (c.is_projected or (c.is_geographic and len(c.axis_info) == 2)):
        raise ConfigError(f"{option} {crs!r} is a {c.type_name} ({c.name}): expected the 2-D CRS of the "
                          f"file's horizontal positions, a projection such as {EXAMPLE_CRS}")
    return Projection(crs=crs, name=c.name, projected=bool(c.is_projected),
                      _to_lonlat=Transformer.from_crs(c, "EPSG:4326", always_xy=True),
                      _from_lonlat=Transformer.from_crs("EPSG:4326", c, always_xy=True))
