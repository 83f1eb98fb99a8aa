"""Navigation records and their interpolation at ping times.

The INS links deliver position, heading and altitude in separate sentences or frames at their
own rates; a :class:`NavTrack` keeps one time series per quantity and interpolates each at
the ping times of a tile. Headings are interpolated along the short way round (359 deg ->
1 deg passes through 0, not 180), and so are longitudes across the antimeridian.

Interpolation never extrapolates past ``max_gap_s`` nor bridges a gap wider than that
between two fixes: such pings are reported invalid, so a tile is never georeferenced with
stale navigation (ICD section 2; the node holds or flags such tiles). A fix whose implied
speed from its neighbour exceeds ``max_speed_m_s`` is a nav jump: pings between the two are
invalid too. Duplicated timestamps keep the last value received.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .tile import TileNav

Quantity = Literal["position", "heading", "altitude", "depth", "speed"]
EARTH_RADIUS_M = 6371008.8
_isfinite = math.isfinite


def wrap180(a: np.ndarray | float) -> np.ndarray:
    """Angle difference wrapped to [-180, 180) degrees."""
    return (np.asarray(a, dtype=np.float64) + 180.0) % 360.0 - 180.0


@dataclass(frozen=True)
class NavFix:
    """One navigation record from a link; absent quantities are None."""

    t: float
    """UNIX seconds of validity."""
    lat_deg: float | None = None
    lon_deg: float | None = None
    heading_deg: float | None = None
    altitude_m: float | None = None
    depth_m: float | None = None
    speed_m_s: float | None = None
    source: str = ""
    """Which link and message produced it, e.g. ``nmea:GGA``."""


_new_object = object.__new__


def make_fix(t: float, lat_deg: float | None = None, lon_deg: float | None = None,
             heading_deg: float | None = None, altitude_m: float | None = None,
             depth_m: float | None = None, speed_m_s: float | None = None, source: str = "") -> NavFix:
    """``NavFix(...)`` for the link decoders' hot path, about 3x cheaper.

    A frozen dataclass's ``__init__`` sets each of its 8 fields through
    ``object.__setattr__``; this fills the instance ``__dict__`` directly. The result is the
    same object in every respect (``==``, ``hash``, ``repr``, still frozen); the values are
    stored as given, exactly as ``NavFix`` does (tests compare both constructions).
    """
    fix = _new_object(NavFix)
    d = fix.__dict__
    d["t"] = t
    d["lat_deg"] = lat_deg
    d["lon_deg"] = lon_deg
    d["heading_deg"] = heading_deg
    d["altitude_m"] = altitude_m
    d["depth_m"] = depth_m
    d["speed_m_s"] = speed_m_s
    d["source"] = source
    return fix


class _Series:
    """A time-sorted series of one or two float64 columns, grown by doubling.

    ``last`` mirrors ``t[n - 1]`` as a Python float (-inf when empty), so the common case,
    a fix newer than every other, is decided without reading a numpy scalar.
    """

    def __init__(self, width: int) -> None:
        self.t = np.empty(64)
        self.v = np.empty((64, width))
        self.n = 0
        self.last = -math.inf

    def add(self, t: float, v0: float, v1: float | None = None) -> None:
        """Insert a sample at time ``t``: ``v0`` (and ``v1`` for a two-column series)."""
        n = self.n
        if t > self.last:  # in order (or first): append
            if n == self.t.size:
                self._grow()
            # element stores: about half the cost of assigning a tuple to a numpy row
            self.t[n] = t
            v = self.v
            v[n, 0] = v0
            if v1 is not None:
                v[n, 1] = v1
            self.n = n + 1
            self.last = t
            return
        # out of order or repeated: the new time is <= t[n - 1], so ``last`` does not change
        values = (v0,) if v1 is None else (v0, v1)
        k = int(np.searchsorted(self.t[:n], t))
        if k < n and self.t[k] == t:  # duplicated timestamp: the last received wins
            self.v[k] = values
            return
        self._grow()
        self.t[k + 1:n + 1] = self.t[k:n]
        self.v[k + 1:n + 1] = self.v[k:n]
        self.t[k] = t
        self.v[k] = values
        self.n += 1

    def _grow(self) -> None:
        if self.n == self.t.size:
            self.t = np.concatenate([self.t, np.empty_like(self.t)])
            self.v = np.concatenate([self.v, np.empty_like(self.v)])

    def drop_before(self, t: float) -> None:
        """Forget samples older than ``t`` but the last one before it."""
        k = max(int(np.searchsorted(self.t[:self.n], t)) - 1, 0)
        if k > 0:
            self.t[:self.n - k] = self.t[k:self.n]
            self.v[:self.n - k] = self.v[k:self.n]
            self.n -= k

    @property
    def times(self) -> np.ndarray:
        return self.t[:self.n]

    @property
    def values(self) -> np.ndarray:
        return self.v[:self.n]


@dataclass
class NavSample:
    """Navigation interpolated at a set of times, with a validity mask per time."""

    nav: TileNav
    valid: np.ndarray
    """True where every quantity was interpolated between fresh fixes."""
    reason: list[str] = field(default_factory=list)
    """Why some times are invalid (empty when all are valid)."""


class NavTrack:
    """Time series of position, heading and altitude from the INS links.

    Parameters
    ----------
    max_gap_s
        Widest gap between fixes that interpolation bridges, and the furthest it reaches
        beyond the first or last fix.
    max_speed_m_s
        Two position fixes closer in time than their distance allows at this speed are a
        nav jump; pings between them are invalid.
    default_altitude_m
        Altitude used when no altitude source exists at all (None: altitude is required).
    """

    def __init__(self, *, max_gap_s: float = 2.0, max_speed_m_s: float = 15.0,
                 default_altitude_m: float | None = None) -> None:
        self.max_gap_s = float(max_gap_s)
        self.max_speed_m_s = float(max_speed_m_s)
        self.default_altitude_m = default_altitude_m
        self._pos = _Series(2)
        self._hdg = _Series(1)
        self._alt = _Series(1)
        self.fixes = 0
        self.jumps = 0

    def add(self, fix: NavFix) -> None:
        """Take a fix; quantities that are None are not touched."""
        t = fix.t
        if not _isfinite(t):
            return
        self.fixes += 1
        lat, lon = fix.lat_deg, fix.lon_deg
        if lat is not None and lon is not None:
            if _isfinite(lat) and _isfinite(lon) and abs(lat) <= 90:
                self._pos.add(t, lat, lon)
        h = fix.heading_deg
        if h is not None and _isfinite(h):
            self._hdg.add(t, h % 360.0)
        a = fix.altitude_m
        if a is not None and _isfinite(a) and a >= 0:
            self._alt.add(t, a)

    def extend(self, fixes) -> None:
        for f in fixes:
            self.add(f)

    def forget_before(self, t: float) -> None:
        """Drop fixes older than ``t`` (keeping one before it), to bound memory on long missions."""
        for s in (self._pos, self._hdg, self._alt):
            s.drop_before(t)

    def state(self) -> dict:
        """Plain arrays for a snapshot."""
        return {"pos_t": self._pos.times.copy(), "pos_v": self._pos.values.copy(),
                "hdg_t": self._hdg.times.copy(), "hdg_v": self._hdg.values.copy(),
                "alt_t": self._alt.times.copy(), "alt_v": self._alt.values.copy(),
                "fixes": self.fixes, "jumps": self.jumps}

    def restore(self, state: dict) -> None:
        for name, series in (("pos", self._pos), ("hdg", self._hdg), ("alt", self._alt)):
            t = np.asarray(state[f"{name}_t"], dtype=np.float64)
            # explicit width: reshape(0, -1) fails, so a snapshot taken before any INS fix
            # could not be restored and the node could not start again (found by a kill test)
            v = np.asarray(state[f"{name}_v"], dtype=np.float64).reshape(t.size, series.v.shape[1])
            cap = max(64, 1 << int(np.ceil(np.log2(max(t.size, 1)))))
            series.t = np.empty(cap)
            series.v = np.empty((cap, series.v.shape[1]))
            series.t[:t.size], series.v[:t.size] = t, v
            series.n = t.size
            series.last = float(t[-1]) if t.size else -math.inf
        self.fixes, self.jumps = int(state["fixes"]), int(state["jumps"])

    @property
    def span(self) -> tuple[float, float] | None:
        """First and last position fix time."""
        p = self._pos
        if p.n == 0:
            return None
        # the node asks on every record while a tile waits for nav: no array slicing here
        return float(p.t[0]), float(p.last)

    def _interp(self, s: _Series, t: np.ndarray, angular: tuple[bool, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Interpolate every column of ``s`` at ``t``; angular columns take the short way."""
        n = s.n
        out = np.full((t.size, s.v.shape[1]), np.nan)
        ok = np.zeros(t.size, dtype=bool)
        if n == 0:
            return out, ok
        ts, vs = s.times, s.values
        if n == 1:
            near = np.abs(t - ts[0]) <= self.max_gap_s
            out[near] = vs[0]
            return out, near
        k = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, n - 2)
        t0, t1 = ts[k], ts[k + 1]
        f = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
        for c, ang in enumerate(angular):
            v0, v1 = vs[k, c], vs[k + 1, c]
            d = wrap180(v1 - v0) if ang else v1 - v0
            out[:, c] = v0 + f * d
        inside = (t >= t0) & (t <= t1) & (t1 - t0 <= self.max_gap_s)
        before = (t < ts[0]) & (ts[0] - t <= self.max_gap_s)
        after = (t > ts[-1]) & (t - ts[-1] <= self.max_gap_s)
        ok = inside | before | after
        return out, ok

    def interpolate(self, times: np.ndarray) -> NavSample:
        """Navigation at ``times`` (UNIX seconds), with validity per time."""
        t = np.asarray(times, dtype=np.float64)
        reasons: list[str] = []
        pos, ok_pos = self._interp(self._pos, t, (False, True))
        if not ok_pos.all():
            reasons.append("no fresh position fix")
        # nav jumps: the segment bracketing each time implies an impossible speed
        if self._pos.n >= 2:
            ts, vs = self._pos.times, self._pos.values
            k = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, self._pos.n - 2)
            dist = _haversine_m(vs[k, 0], vs[k, 1], vs[k + 1, 0], vs[k + 1, 1])
            dt = ts[k + 1] - ts[k]
            jump = dist > self.max_speed_m_s * np.maximum(dt, 1e-3)
            jump &= (t >= ts[k]) & (t <= ts[k + 1])
            if jump.any():
                reasons.append("nav jump")
                ok_pos &= ~jump
        hdg, ok_hdg = self._interp(self._hdg, t, (True,))
        if not ok_hdg.all():
            reasons.append("no fresh heading")
        if self._alt.n == 0 and self.default_altitude_m is not None:
            alt = np.full((t.size, 1), float(self.default_altitude_m))
            ok_alt = np.ones(t.size, dtype=bool)
        else:
            alt, ok_alt = self._interp(self._alt, t, (False,))
            if not ok_alt.all():
                reasons.append("no fresh altitude")
        lon = (pos[:, 1] + 180.0) % 360.0 - 180.0
        nav = TileNav(lat_deg=pos[:, 0], lon_deg=lon, heading_deg=hdg[:, 0] % 360.0, altitude_m=alt[:, 0])
        return NavSample(nav=nav, valid=ok_pos & ok_hdg & ok_alt, reason=reasons)


def _haversine_m(lat0, lon0, lat1, lon1) -> np.ndarray:
    p0, p1 = np.radians(lat0), np.radians(lat1)
    dp = p1 - p0
    dl = np.radians(wrap180(np.asarray(lon1) - np.asarray(lon0)))
    a = np.sin(dp / 2) ** 2 + np.cos(p0) * np.cos(p1) * np.sin(dl / 2) ** 2
    return 2 * EARTH_RADIUS_M * np.arcsin(np.minimum(np.sqrt(a), 1.0))


def nav_jumps(nav: TileNav, ping_time: np.ndarray, *, max_speed_m_s: float = 15.0) -> np.ndarray:
    """Indices i where the step from ping i to i+1 is faster than ``max_speed_m_s``."""
    if len(nav) < 2:
        return np.empty(0, dtype=np.int64)
    d = _haversine_m(nav.lat_deg[:-1], nav.lon_deg[:-1], nav.lat_deg[1:], nav.lon_deg[1:])
    dt = np.diff(ping_time)
    return np.flatnonzero(d > max_speed_m_s * np.maximum(dt, 1e-3))
