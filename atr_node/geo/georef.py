"""Georeferencing of tile pixels (SPEC section 0).

Pixel (i, j) of a ground-range tile lies at horizontal distance ``r_j = range0_m + j*dr_m``
from the position of ping i, perpendicular to the heading: to starboard (heading + 90 deg) on
the ``stbd`` side, to port (heading - 90 deg) on the ``port`` side. In the mission frame the
true heading becomes a grid heading (minus the meridian convergence) and the distance is
scaled by the projection's scale factor, both evaluated at the ping, so positions agree with
a geodesic computation to millimetres over a swath.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import GeometryError
from ..records.tile import Tile, TileNav
from .frame import MissionFrame


@dataclass(frozen=True, eq=False)
class TileGeometry:
    """Per-ping position and across-track unit vector of a tile in the mission frame.

    ``world(i, j) = (east[i], north[i]) + ranges_m[j] * (ue[i], un[i])``
    """

    east_m: np.ndarray
    """(rows,) ping positions."""
    north_m: np.ndarray
    ue: np.ndarray
    """(rows,) east component of the across-track direction, scaled by the grid scale factor."""
    un: np.ndarray
    ranges_m: np.ndarray
    """(cols,) ground range of each column."""
    heading_grid_rad: np.ndarray
    """(rows,) grid heading (clockwise from grid north)."""

    def world(self, rows: np.ndarray | int, cols: np.ndarray | int | float) -> tuple[np.ndarray, np.ndarray]:
        """(east_m, north_m) of pixels; ``cols`` may be fractional (sub-pixel positions)."""
        i = np.asarray(rows)
        c = np.asarray(cols, dtype=np.float64)
        r = self.ranges_m[0] + c * (self.ranges_m[1] - self.ranges_m[0]) if self.ranges_m.size > 1 else \
            np.full(c.shape, self.ranges_m[0])
        return self.east_m[i] + r * self.ue[i], self.north_m[i] + r * self.un[i]

    def locate(self, east_m: float, north_m: float) -> tuple[int, float, float]:
        """The inverse of :meth:`world` for one point: ``(row, range_m, off_m)``, the ping whose
        across-track line passes nearest the point, the ground range along that line (not
        clipped to the swath: compare with ``ranges_m``) and the point's distance from the line,
        metres in the frame. The across-track vector carries the grid scale factor ``k``, so the
        range is the dot product over ``k^2``."""
        de, dn = float(east_m) - self.east_m, float(north_m) - self.north_m
        across = (de * self.ue + dn * self.un) / (self.ue * self.ue + self.un * self.un)
        off = np.hypot(de - across * self.ue, dn - across * self.un)
        i = int(np.argmin(off))
        return i, float(across[i]), float(off[i])

    def world_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """(east_m, north_m) of every pixel, each (rows, cols) float64."""
        e = self.east_m[:, None] + self.ranges_m[None, :] * self.ue[:, None]
        n = self.north_m[:, None] + self.ranges_m[None, :] * self.un[:, None]
        return e, n


def across_track_unit(heading_deg: np.ndarray, side: str) -> tuple[np.ndarray, np.ndarray]:
    """(east, north) unit vector perpendicular to a heading, to the given side."""
    h = np.radians(np.asarray(heading_deg, dtype=np.float64))
    if side == "stbd":  # heading + 90 deg
        return np.cos(h), -np.sin(h)
    if side == "port":  # heading - 90 deg
        return -np.cos(h), np.sin(h)
    raise GeometryError(f"side must be 'port' or 'stbd', got {side!r}")


def tile_geometry(tile: Tile, frame: MissionFrame, nav: TileNav | None = None) -> TileGeometry:
    """Geometry of a ground-range tile in ``frame`` from its nav (or ``nav`` if given)."""
    if tile.slant:
        raise GeometryError(f"{tile.ident}: georeferencing needs ground range; call ground_range() first")
    nav = nav if nav is not None else tile.nav
    if nav is None:
        raise GeometryError(f"{tile.ident}: no nav in the tile and none given")
    if len(nav) != tile.rows:
        raise GeometryError(f"{tile.ident}: nav has {len(nav)} rows, tile has {tile.rows}")
    e, n, ue, un, hg = ping_frame(nav, tile.side, frame)
    return TileGeometry(east_m=e, north_m=n, ue=ue, un=un, ranges_m=tile.ranges_m, heading_grid_rad=hg)


def ping_frame(nav: TileNav, side: str, frame: MissionFrame
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per ping: (east_m, north_m) in ``frame``, the across-track direction to ``side``
    scaled by the grid scale factor (ue, un), and the grid heading in radians; each (rows,)."""
    e, n = frame.to_frame(nav.lat_deg, nav.lon_deg)
    conv, scale = frame.grid_factors(nav.lat_deg, nav.lon_deg)
    hg = nav.heading_deg - conv
    ue, un = across_track_unit(hg, side)
    return (np.asarray(e, dtype=np.float64).reshape(-1), np.asarray(n, dtype=np.float64).reshape(-1),
            (ue * scale).reshape(-1), (un * scale).reshape(-1), np.radians(hg).reshape(-1))


def pixel_latlon(tile: Tile, frame: MissionFrame, rows, cols) -> tuple[np.ndarray, np.ndarray]:
    """WGS84 (lat_deg, lon_deg) of pixels of a ground-range tile."""
    e, n = tile_geometry(tile, frame).world(rows, cols)
    return frame.to_latlon(e, n)
