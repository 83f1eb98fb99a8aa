"""Nav merge: every tile leaves this stage on ground range with per-ping nav, or not at all.

A tile that carries its own ``nav`` map uses it. Otherwise the INS track is interpolated at
its ping times; a tile that arrives before the INS fixes that bracket its last ping is held
until they come. When the INS stays silent past ``max_gap_s`` after a held tile's last ping,
the tile is released with its pings that have no fresh fix set to no data (NaN): they give
no evidence, rather than evidence put in the wrong place. Such pings are counted.

A tile that leaves with no usable nav at all (or whose slant axis no ground-range tile could
hold) is dropped: counted by reason in :attr:`NavMergeStats.dropped` and passed to
``on_drop`` (the pipeline counts it in ``tiles_dropped``). The first drop of each reason is
logged as a warning, the others at debug level: a recording without positions drops every
tile, and one line per tile says nothing more.

Clock: ``now`` is the arrival time of the record being processed (the live wall clock, or the
recorded arrival time in a replay), so replays are deterministic.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..records.nav import NavTrack, nav_jumps
from ..records.tile import Tile

log = logging.getLogger(__name__)


@dataclass
class NavMergeStats:
    tiles_with_own_nav: int = 0
    tiles_interpolated: int = 0
    tiles_held: int = 0
    pings_without_nav: int = 0
    tiles_without_nav: int = 0
    nav_jump_pings: int = 0
    reasons: dict[str, int] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)
    """Tiles dropped here, by reason (:data:`NO_NAV`, :data:`AXIS_TOO_LONG`)."""
    first_return_band_m: dict[str, int] = field(default_factory=dict)
    """Slant tiles by the first-return band they were given (metres, to 0.1 m)."""


NO_NAV = "no usable nav"
"""Drop reason: no ping of the tile has a position (none of its own, no INS fix near it)."""
AXIS_TOO_LONG = "slant range axis too long"
"""Drop reason: the slant axis asks for a ground-range tile no memory could hold."""


class NavMerger:
    """Attach nav to tiles and convert them to ground range.

    Parameters
    ----------
    track
        The INS track the links feed.
    max_gap_s
        How long after a held tile's last ping the INS may stay silent before the tile is
        released with its un-navigated pings blanked.
    max_speed_m_s
        Steps between pings faster than this are nav jumps (in tile nav too).
    default_altitude_m
        Altitude for slant-to-ground conversion when nav has none.
    first_return_band_m
        Slant metres after the first bottom return (R = altitude) that become no data in the
        ground-range tile (:meth:`Tile.ground_range`): the bright nadir return and its ringing
        are not seabed evidence (``sensor.first_return_band_m``). The least band.
    first_return_level, first_return_band_max_m
        With ``first_return_level`` > 0 the band of a slant tile is the longer of
        ``first_return_band_m`` and the rise of its first return to that fraction of the seabed
        level, measured on the tile (:func:`~atr_node.io.xtf_bottom.first_return_length_m`,
        at most ``first_return_band_max_m``; per side, the side's last measured value for a
        tile too short to measure): ``sensor.first_return_level`` and
        ``sensor.first_return_band_max_m``. Counted in ``stats.first_return_band_m``.
    on_drop
        Called with the tile and the reason of every tile dropped here.
    """

    def __init__(self, track: NavTrack, *, max_gap_s: float = 2.0, max_speed_m_s: float = 15.0,
                 default_altitude_m: float = 14.0, max_held: int = 64, first_return_band_m: float = 0.0,
                 first_return_level: float = 0.0, first_return_band_max_m: float = 2.5,
                 on_drop: Callable[[Tile, str], None] | None = None, max_pixels: int = 1 << 28) -> None:
        self.on_drop = on_drop
        self.max_pixels = int(max_pixels)
        """Largest ground-range tile a slant tile may become (``node.max_tile_pixels``)."""
        self.track = track
        self.max_gap_s = float(max_gap_s)
        self.max_speed_m_s = float(max_speed_m_s)
        self.default_altitude_m = float(default_altitude_m)
        self.first_return_band_m = float(first_return_band_m)
        self.first_return_level = float(first_return_level)
        self.first_return_band_max_m = float(first_return_band_max_m)
        self._band_by_side: dict[str, float] = {}
        self.max_held = int(max_held)
        self._held: deque[Tile] = deque()
        self.stats = NavMergeStats()

    @property
    def held(self) -> int:
        return len(self._held)

    def push(self, tile: Tile, now: float) -> list[Tile]:
        """Take a validated tile; return the tiles now ready (in arrival order)."""
        if tile.nav is not None:
            self.stats.tiles_with_own_nav += 1
            if self._held:  # keep arrival order
                self._held.append(tile)
                return self.poll(now)
            done = self._finish(tile, *self._tile_nav_valid(tile))
            return [done] if done is not None else []
        self._held.append(tile)
        self.stats.tiles_held += 1
        return self.poll(now)

    def poll(self, now: float, *, flush: bool = False) -> list[Tile]:
        """Release the held tiles whose nav is complete, or stale (or all, with ``flush``)."""
        out = []
        while self._held:
            tile = self._held[0]
            if tile.nav is not None:
                self._held.popleft()
                done = self._finish(tile, *self._tile_nav_valid(tile))
                if done is not None:
                    out.append(done)
                continue
            last = float(tile.ping_time[-1])
            span = self.track.span
            covered = span is not None and span[1] >= last
            stale = now - last > self.max_gap_s
            if not (covered or stale or flush or len(self._held) > self.max_held):
                break
            self._held.popleft()
            sample = self.track.interpolate(tile.ping_time)
            for r in sample.reason:
                self.stats.reasons[r] = self.stats.reasons.get(r, 0) + 1
            self.stats.tiles_interpolated += 1
            done = self._finish(tile, sample.nav, sample.valid)
            if done is not None:
                out.append(done)
        return out

    @staticmethod
    def _tile_nav_valid(tile: Tile):
        """A tile's own nav, with pings at exactly (0, 0) (a recorder's "no fix") invalid."""
        nav = tile.nav
        return nav, ~((nav.lat_deg == 0.0) & (nav.lon_deg == 0.0))

    def _drop(self, tile: Tile, reason: str, detail: str = "") -> None:
        n = self.stats.dropped.get(reason, 0) + 1
        self.stats.dropped[reason] = n
        log.log(logging.WARNING if n == 1 else logging.DEBUG, "%s: %s%s; dropped%s", tile.ident, reason, detail,
                " (further drops for this reason are counted, not logged)" if n == 1 else "")
        if self.on_drop is not None:
            self.on_drop(tile, reason)

    def _finish(self, tile: Tile, nav, valid: np.ndarray) -> Tile | None:
        valid = valid.copy()
        jumps = nav_jumps(nav, tile.ping_time, max_speed_m_s=self.max_speed_m_s)
        if jumps.size:
            # the rows on both sides of a jump: position between them is unknown
            valid[jumps] = False
            valid[jumps + 1] = False
            self.stats.nav_jump_pings += int(2 * jumps.size)
        if not valid.any():
            # nothing to place it with: dropped here (counted), never georeferenced at a
            # placeholder position
            self.stats.tiles_without_nav += 1
            self.stats.pings_without_nav += tile.rows
            self._drop(tile, NO_NAV, " for any ping")
            return None
        if not valid.all():
            self.stats.pings_without_nav += int((~valid).sum())
        # fill invalid nav rows with a harmless value so geometry stays finite; their pixels are NaN
        nav = _fill_invalid(nav, valid, self.default_altitude_m)
        if tile.slant:
            # the ground axis spans 0 to range0_m + dr_m * cols: refuse one no tile could hold (a
            # range0_m of 1e300 or a dr_m of 1e-300 asks for an impossible array), or one that
            # blows a few columns far out into a huge, empty tile (40 columns at 65 km: 650 000
            # columns, seconds of detection; both found by fuzzing)
            far_cols = (tile.range0_m + tile.dr_m * (tile.cols - 1)) / tile.dr_m + 1
            if (not math.isfinite(far_cols) or far_cols * tile.rows > self.max_pixels
                    or far_cols > max(64 * tile.cols, 1 << 16)):
                key = "slant range axis too long for a ground-range tile"
                self.stats.reasons[key] = self.stats.reasons.get(key, 0) + 1
                self._drop(tile, AXIS_TOO_LONG, f" for a ground-range tile (range0_m {tile.range0_m!r}, "
                                                f"dr_m {tile.dr_m!r})")
                return None
            alt = nav.altitude_m
            # the ground axis of a slant tile: from 0 to the farthest slant range, same spacing
            cols = int(math.floor((tile.range0_m + tile.dr_m * (tile.cols - 1)) / tile.dr_m + 1e-9)) + 1
            # water column (R < H) and first-return band (H <= R < H + band) become no data
            tile = tile.with_nav(nav).ground_range(alt, range0_m=0.0, cols=cols,
                                                   first_return_band_m=self._band_m(tile, alt))
        else:
            tile = tile.with_nav(nav)
        if not valid.all():
            px = tile.pixels.copy()
            px[~valid] = np.nan
            tile = tile.replace(pixels=px)
        return tile


    def _band_m(self, tile: Tile, altitude_m: np.ndarray) -> float:
        """The first-return band of a slant tile (``first_return_level`` in the class docstring)."""
        band = self.first_return_band_m
        if self.first_return_level > 0:
            from ..io.xtf_bottom import first_return_length_m

            rise = first_return_length_m(tile, altitude_m, level=self.first_return_level,
                                         max_m=self.first_return_band_max_m)
            if math.isfinite(rise):
                self._band_by_side[tile.side] = rise
            band = max(band, self._band_by_side.get(tile.side, band))
        key = f"{band:.1f}"
        self.stats.first_return_band_m[key] = self.stats.first_return_band_m.get(key, 0) + 1
        return band


def _fill_invalid(nav, valid: np.ndarray, default_altitude_m: float):
    from ..records.tile import TileNav

    if valid.all():
        return nav
    arrays = []
    for a, fallback in ((nav.lat_deg, 0.0), (nav.lon_deg, 0.0), (nav.heading_deg, 0.0),
                        (nav.altitude_m, default_altitude_m)):
        a = a.copy()
        good = valid & np.isfinite(a)
        if good.any():
            idx = np.flatnonzero(good)
            a[~good] = np.interp(np.flatnonzero(~good), idx, a[idx])
        else:
            a[:] = fallback
        arrays.append(a)
    return TileNav(*arrays)
