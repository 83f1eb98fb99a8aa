"""Sonar tiles: the record of ICD section 1, parsed, validated and written back.

A :class:`Tile` is one side of a contiguous run of pings of one leg (SPEC section 0): rows are
pings (time increases with row), columns are range bins increasing away from the sonar.
Pixels are held as float32 with NaN for no data, whatever the wire dtype: uint16 and uint8
zeros become NaN, and are written back as zeros (the conversion is exact both ways).

The wire form is a msgpack map (``msgpack.packb(tile.to_map(), use_bin_type=True)``)::

    type "tile", v 1, mission str, leg int, side "port"|"stbd", seq int,
    shape [rows, cols], dtype "float32"|"uint16"|"uint8", data bin (little-endian, row-major),
    kind "intensity"|"amplitude", range0_m, dr_m, dx_m float, slant bool,
    ping_time bin (float64 LE, one per row),
    nav (optional) {lat_deg, lon_deg, heading_deg, altitude_m: bin float64 LE per row},
    sensor (optional) {frequency_hz, bandwidth_hz, tx_length_m, rx_length_m, n_rx, sas}
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Literal, Mapping

import msgpack
import numpy as np

from ..errors import GeometryError, TileError

Side = Literal["port", "stbd"]
Kind = Literal["intensity", "amplitude"]

TILE_VERSION = 1
SPACING_LIMITS_M = (1e-3, 100.0)
"""Plausible dr_m and dx_m: outside, window sizes and range axes overflow (found by fuzzing)."""
MAX_RANGE_M = 1e5
MAX_PIXELS = 1 << 28
"""Most pixels the wire format lets a tile declare (the node's own limit is lower:
``node.max_tile_pixels``)."""
"""Farthest plausible range of a tile's last column."""
WIRE_DTYPES: dict[str, np.dtype] = {
    "float32": np.dtype("<f4"),
    "uint16": np.dtype("<u2"),
    "uint8": np.dtype("u1"),
}
NAV_KEYS = ("lat_deg", "lon_deg", "heading_deg", "altitude_m")
SENSOR_KEYS = ("frequency_hz", "bandwidth_hz", "tx_length_m", "rx_length_m", "n_rx", "sas")
REQUIRED_KEYS = ("type", "v", "mission", "leg", "side", "seq", "shape", "dtype", "data", "kind",
                 "range0_m", "dr_m", "dx_m", "slant", "ping_time")
CLIP_MIN_PIXELS = 8
"""Fewest samples at an integer tile's largest value for it to be the recorder's clip level
(:attr:`Tile.clip_level`)."""
CLIP_MIN_SHARE = 1e-3
"""... and at least this share of the tile's valid samples (the shared files: 0.6-16 %)."""
CLIP_BAND = 0.02
"""... and more of them than in the levels within this fraction below it."""


@dataclass(frozen=True, eq=False)
class TileNav:
    """Per-ping navigation of a tile: float64 arrays of one value per row."""

    lat_deg: np.ndarray
    lon_deg: np.ndarray
    heading_deg: np.ndarray
    """True heading, clockwise from north, degrees."""
    altitude_m: np.ndarray
    """Sonar altitude above the seabed, metres."""

    def __post_init__(self) -> None:
        n = None
        for k in NAV_KEYS:
            a = np.ascontiguousarray(getattr(self, k), dtype=np.float64)
            if a.ndim != 1 or (n is not None and a.size != n):
                raise ValueError(f"nav.{k}: expected one float64 value per row")
            n = a.size
            object.__setattr__(self, k, a)

    def __len__(self) -> int:
        return int(self.lat_deg.size)

    def slice(self, rows: slice) -> "TileNav":
        return TileNav(*(getattr(self, k)[rows] for k in NAV_KEYS))

    def equals(self, other: "TileNav | None") -> bool:
        return other is not None and all(np.array_equal(getattr(self, k), getattr(other, k)) for k in NAV_KEYS)


@dataclass(frozen=True)
class SensorInfo:
    """The ``sensor`` map of a tile."""

    frequency_hz: float
    bandwidth_hz: float
    tx_length_m: float
    rx_length_m: float
    n_rx: int
    sas: bool

    def wavelength_m(self, sound_speed_m_s: float = 1500.0) -> float:
        return sound_speed_m_s / self.frequency_hz


@dataclass(frozen=True, eq=False)
class Tile:
    """One side of a contiguous run of pings (ICD section 1), pixels as float32 with NaN."""

    mission: str
    leg: int
    side: Side
    seq: int
    pixels: np.ndarray
    """float32 (rows, cols); NaN = no data."""
    kind: Kind
    range0_m: float
    dr_m: float
    dx_m: float
    slant: bool
    ping_time: np.ndarray
    """float64 (rows,), UNIX seconds."""
    nav: TileNav | None = None
    sensor: SensorInfo | None = None
    wire_dtype: str = "float32"
    """dtype of ``data`` on the wire; :meth:`to_map` writes it back in this dtype."""
    full_scale: float | None = None
    """The largest value the sensor records, in this tile's ``kind``: where the echo is
    stronger, the pixel is clipped to it. None: read off the samples when asked
    (:attr:`saturation`); a float tile's is unknown. :meth:`as_intensity` and
    :meth:`ground_range` set it, so the node reads an integer tile's samples for it once."""

    # -- axes ---------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        return self.pixels.shape  # type: ignore[return-value]

    @property
    def rows(self) -> int:
        return int(self.pixels.shape[0])

    @property
    def cols(self) -> int:
        return int(self.pixels.shape[1])

    @property
    def ranges_m(self) -> np.ndarray:
        """Range of each column's centre (slant or ground, as ``slant`` says), float64."""
        return self.range0_m + self.dr_m * np.arange(self.cols, dtype=np.float64)

    @property
    def ident(self) -> str:
        return tile_ident(self.mission, self.side, self.seq)

    @property
    def valid(self) -> np.ndarray:
        """Boolean (rows, cols): True where there is data."""
        return ~np.isnan(self.pixels)

    def replace(self, **changes: Any) -> "Tile":
        return dataclasses.replace(self, **changes)

    @property
    def saturation(self) -> float | None:
        """The level at which this tile's pixels clip (:attr:`full_scale`, in its ``kind``): the
        one given, else for integer samples the level where they pile up (:attr:`clip_level`: a
        recorder may clip below its word's range, the Iver2 file's 16-bit samples at 32767),
        else the integer wire dtype's largest value (255 for uint8 samples: clipping there
        cannot be ruled out), else None (a float tile: unknown)."""
        if self.full_scale is not None:
            return float(self.full_scale)
        dt = WIRE_DTYPES[self.wire_dtype]
        if dt.kind not in "ui":
            return None
        seen = self.clip_level
        return float(np.iinfo(dt).max) if seen is None else seen

    @property
    def clip_level(self) -> float | None:
        """Where an integer tile's samples pile up at their largest value: that value, when it
        holds at least :data:`CLIP_MIN_PIXELS` samples and :data:`CLIP_MIN_SHARE` of the valid
        ones, and more samples than the 2 % of levels below it together (a clipped tail lands
        on one level; an unclipped one thins out towards its largest sample), and no more than
        half of them (a constant tile is not a clipped tail). None: no pile-up (or float
        samples)."""
        if WIRE_DTYPES[self.wire_dtype].kind not in "ui":
            return None
        v = self.pixels[np.isfinite(self.pixels)]
        if v.size == 0:
            return None
        top = float(v.max())
        at = int(np.count_nonzero(v == top))
        below = int(np.count_nonzero((v >= top * (1.0 - CLIP_BAND)) & (v < top)))
        # at most half of them: a constant or blank tile is not a clipped tail
        if max(CLIP_MIN_PIXELS, CLIP_MIN_SHARE * v.size) <= at <= 0.5 * v.size and at > below:
            return top
        return None

    def as_intensity(self) -> "Tile":
        """This tile in linear intensity, the quantity the detectors' formulas and levels are
        written for (SPEC sections 0 and 2: a shadow at 0.3 of the median, lacunarity's
        ``var / mean^2``): itself when it is, else its pixels squared (float32; NaN stays NaN),
        its :attr:`saturation` squared with them (an 8-bit sample clips at 255, so its
        intensity at 255^2)."""
        if self.kind == "intensity":
            if self.full_scale is not None or WIRE_DTYPES[self.wire_dtype].kind == "f":
                return self
            return self.replace(full_scale=self.saturation)  # integer samples: read their clip level once
        sat = self.saturation
        return self.replace(pixels=np.square(self.pixels, dtype=np.float32), kind="intensity", wire_dtype="float32",
                            full_scale=None if sat is None else sat * sat)

    def equals(self, other: "Tile") -> bool:
        """Exact equality of every field and pixel (NaN equal to NaN)."""
        if not isinstance(other, Tile):
            return False
        for f in dataclasses.fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, np.ndarray):
                if not (isinstance(b, np.ndarray) and a.shape == b.shape and a.dtype == b.dtype
                        and np.array_equal(a, b, equal_nan=True)):
                    return False
            elif isinstance(a, TileNav):
                if not a.equals(b):
                    return False
            elif a != b:
                return False
        return True

    # -- wire ---------------------------------------------------------------------------
    def to_map(self) -> dict[str, Any]:
        """The ICD section 1 map of this tile (pixels in ``wire_dtype``)."""
        dt = WIRE_DTYPES[self.wire_dtype]
        if dt.kind == "f":
            data = np.ascontiguousarray(self.pixels, dtype=dt).tobytes()
        else:
            info = np.iinfo(dt)
            px = np.nan_to_num(self.pixels, nan=0.0)
            data = np.clip(np.rint(px), info.min, info.max).astype(dt).tobytes()
        m: dict[str, Any] = {
            "type": "tile", "v": TILE_VERSION, "mission": self.mission, "leg": int(self.leg),
            "side": self.side, "seq": int(self.seq), "shape": [self.rows, self.cols],
            "dtype": self.wire_dtype, "data": data, "kind": self.kind,
            "range0_m": float(self.range0_m), "dr_m": float(self.dr_m), "dx_m": float(self.dx_m),
            "slant": bool(self.slant),
            "ping_time": np.ascontiguousarray(self.ping_time, dtype="<f8").tobytes(),
        }
        if self.nav is not None:
            m["nav"] = {k: np.ascontiguousarray(getattr(self.nav, k), dtype="<f8").tobytes() for k in NAV_KEYS}
        if self.sensor is not None:
            m["sensor"] = dataclasses.asdict(self.sensor)
        return m

    def pack(self) -> bytes:
        """msgpack bytes of :meth:`to_map`."""
        return msgpack.packb(self.to_map(), use_bin_type=True)

    @classmethod
    def from_map(cls, m: Any, *, max_pixels: int | None = None) -> "Tile":
        """Parse and validate an ICD section 1 map; raise :class:`TileError` naming the field
        (``max_pixels``: see :func:`parse_tile`)."""
        return parse_tile(m, max_pixels=max_pixels)

    @classmethod
    def unpack(cls, payload: bytes) -> "Tile":
        """Parse msgpack bytes of a tile map."""
        try:
            m = msgpack.unpackb(payload, raw=False, strict_map_key=False)
        except Exception as exc:  # msgpack raises several unrelated types
            raise TileError(f"not a msgpack map: {exc}", tile="tile ?") from None
        return parse_tile(m)

    # -- geometry -----------------------------------------------------------------------
    def with_nav(self, nav: TileNav) -> "Tile":
        if len(nav) != self.rows:
            raise TileError(f"nav has {len(nav)} rows, tile has {self.rows}", tile=self.ident, field="nav")
        return self.replace(nav=nav)

    def altitude_m(self) -> np.ndarray:
        if self.nav is None:
            raise GeometryError(f"{self.ident}: no nav, so no altitude (interpolate the INS first)")
        return self.nav.altitude_m

    def ground_range(self, altitude_m: np.ndarray | float | None = None, *, range0_m: float | None = None,
                     cols: int | None = None, first_return_band_m: float = 0.0) -> "Tile":
        """This tile on a ground-range axis (SPEC section 0): ``r = sqrt(R^2 - H^2)``.

        The ground axis keeps the spacing ``dr_m``. By default it starts at the ground range
        of column 0 at the highest altitude (rounded down to a multiple of ``dr_m``) and ends
        at the farthest ground range; ``range0_m`` and ``cols`` fix it instead (the node
        keeps one axis per leg so that tiles join into a strip). Samples from the water
        column (R < H) are dropped and ground ranges with no slant sample are NaN. Pixels are
        interpolated linearly in slant range, row by row. A ground-range tile is returned
        unchanged.

        ``first_return_band_m``: ground ranges whose slant range lies within this far beyond
        the first bottom return (``H <= R < H + band``: the bright nadir return and its
        ringing, stretched over the first metres of ground range) are NaN too: no data, so no
        detector sees them and no evidence lands there.
        """
        if not self.slant:
            return self
        if altitude_m is None:
            alt = self.altitude_m()
        else:
            alt = np.broadcast_to(np.asarray(altitude_m, dtype=np.float64), (self.rows,))
        if not np.all(np.isfinite(alt)) or np.any(alt < 0):
            raise GeometryError(f"{self.ident}: altitude must be finite and >= 0")
        r_slant_max = self.range0_m + self.dr_m * (self.cols - 1)
        hmax = float(alt.max())
        if range0_m is None:
            g0 = math.sqrt(max(self.range0_m ** 2 - hmax ** 2, 0.0))
            g0 = math.floor(g0 / self.dr_m) * self.dr_m
        else:
            g0 = float(range0_m)
        if cols is None:
            gmax = math.sqrt(max(r_slant_max ** 2 - float(alt.min()) ** 2, 0.0))
            ncols = max(int(math.floor((gmax - g0) / self.dr_m + 1e-9)) + 1, 1)
        else:
            ncols = int(cols)
        g = g0 + self.dr_m * np.arange(ncols, dtype=np.float64)
        slant_r = np.sqrt(g[None, :] ** 2 + alt[:, None] ** 2)
        f = (slant_r - self.range0_m) / self.dr_m
        inside = (f >= 0.0) & (f <= self.cols - 1)
        i0 = np.clip(np.floor(f).astype(np.int64), 0, self.cols - 1)
        i1 = np.minimum(i0 + 1, self.cols - 1)
        w = (f - i0).astype(np.float32)
        src = self.pixels
        a0 = np.take_along_axis(src, i0, axis=1)
        a1 = np.take_along_axis(src, i1, axis=1)
        # Exact sample where the weight vanishes, so a NaN neighbour does not spread.
        out = np.where(w == 0, a0, a0 * (1 - w) + a1 * w).astype(np.float32)
        out[~inside] = np.nan
        if first_return_band_m > 0:
            out[slant_r < alt[:, None] + first_return_band_m] = np.nan
        return self.replace(pixels=out, range0_m=float(g0), slant=False, wire_dtype="float32",
                            full_scale=self.saturation)


def tile_ident(mission: Any, side: Any, seq: Any) -> str:
    """How errors name a tile: ``tile <mission>/<side>/seq <seq>``."""
    return f"tile {mission if isinstance(mission, str) else '?'}/{side if isinstance(side, str) else '?'}/seq {seq if isinstance(seq, int) else '?'}"


# ----------------------------------------------------------------------------------------
# Parsing


def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _is_num(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _f64_bin(value: Any, n: int, where: str, fld: str) -> np.ndarray:
    if not isinstance(value, (bytes, bytearray, memoryview)):
        raise TileError(f"expected bin of {n} little-endian float64, got {type(value).__name__}", tile=where, field=fld)
    if len(value) != 8 * n:
        raise TileError(f"expected {8 * n} bytes ({n} float64, one per row), got {len(value)}", tile=where, field=fld)
    return np.frombuffer(value, dtype="<f8").astype(np.float64)


def parse_tile(m: Any, *, max_pixels: int | None = None) -> Tile:
    """Validate a decoded ICD section 1 map and build a :class:`Tile`.

    ``max_pixels``: refuse a tile of more pixels (the node's memory budget,
    ``node.max_tile_pixels``), checked before its pixels are converted; None: the wire
    format's limit (:data:`MAX_PIXELS`) only.

    Raises
    ------
    TileError
        Naming the tile (``mission/side/seq`` as far as known) and the field that breaks
        the ICD table, with what was expected.
    """
    if not isinstance(m, Mapping):
        raise TileError(f"expected a msgpack map, got {type(m).__name__}", tile="tile ?")
    where = tile_ident(m.get("mission"), m.get("side"), m.get("seq"))
    for k in REQUIRED_KEYS:
        if k not in m:
            raise TileError("missing key", tile=where, field=k)
    if m["type"] != "tile":
        raise TileError(f"expected \"tile\", got {m['type']!r}", tile=where, field="type")
    if not _is_int(m["v"]) or m["v"] != TILE_VERSION:
        raise TileError(f"unknown version {m['v']!r}; this node reads v{TILE_VERSION}", tile=where, field="v")
    if not isinstance(m["mission"], str) or not m["mission"]:
        raise TileError("expected a non-empty string", tile=where, field="mission")
    if not _is_int(m["leg"]) or not 0 <= m["leg"] < 1 << 63:  # int64 arrays hold it (fuzzing: 2^64 - 1 crashed)
        raise TileError(f"expected an integer in [0, 2^63), got {m['leg']!r}", tile=where, field="leg")
    if m["side"] not in ("port", "stbd"):
        raise TileError(f"expected \"port\" or \"stbd\", got {m['side']!r}", tile=where, field="side")
    if not _is_int(m["seq"]) or not 0 <= m["seq"] < 1 << 63:
        raise TileError(f"expected an integer in [0, 2^63), got {m['seq']!r}", tile=where, field="seq")
    shape = m["shape"]
    if (not isinstance(shape, (list, tuple)) or len(shape) != 2 or not all(_is_int(s) for s in shape)
            or shape[0] < 1 or shape[1] < 1):
        raise TileError(f"expected [rows, cols] of positive integers, got {shape!r}", tile=where, field="shape")
    rows, cols = int(shape[0]), int(shape[1])
    if rows * cols > MAX_PIXELS:
        raise TileError(f"{rows} x {cols} pixels is more than the 2^28 a tile may hold", tile=where, field="shape")
    if max_pixels is not None and rows * cols > max_pixels:
        # before any pixel is converted: detection needs ~80 B per pixel (node.max_tile_pixels)
        raise TileError(f"{rows} x {cols} = {rows * cols} pixels is more than node.max_tile_pixels = {max_pixels}",
                        tile=where, field="shape")
    if not isinstance(m["dtype"], str) or m["dtype"] not in WIRE_DTYPES:  # a list or map is unhashable
        raise TileError(f"expected one of {list(WIRE_DTYPES)}, got {m['dtype']!r}", tile=where, field="dtype")
    dt = WIRE_DTYPES[m["dtype"]]
    data = m["data"]
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise TileError(f"expected bin, got {type(data).__name__}", tile=where, field="data")
    expected = rows * cols * dt.itemsize
    if len(data) != expected:
        raise TileError(f"expected {expected} bytes for {rows} x {cols} {m['dtype']}, got {len(data)}",
                        tile=where, field="data")
    if m["kind"] not in ("intensity", "amplitude"):
        raise TileError(f"expected \"intensity\" or \"amplitude\", got {m['kind']!r}", tile=where, field="kind")
    for k in ("range0_m", "dr_m", "dx_m"):
        v = m[k]
        if not _is_num(v) or not math.isfinite(v):
            raise TileError(f"expected a finite number, got {v!r}", tile=where, field=k)
    if m["range0_m"] < 0:
        raise TileError(f"expected >= 0, got {m['range0_m']!r}", tile=where, field="range0_m")
    for k in ("dr_m", "dx_m"):
        if m[k] <= 0:
            raise TileError(f"expected > 0, got {m[k]!r}", tile=where, field=k)
        if not SPACING_LIMITS_M[0] <= m[k] <= SPACING_LIMITS_M[1]:
            raise TileError(f"{m[k]!r} m is not a plausible spacing: expected {SPACING_LIMITS_M[0]} to "
                            f"{SPACING_LIMITS_M[1]} m", tile=where, field=k)
    if m["range0_m"] + m["dr_m"] * cols > MAX_RANGE_M:
        raise TileError(f"the last column is at {m['range0_m'] + m['dr_m'] * (cols - 1)!r} m: expected at most "
                        f"{MAX_RANGE_M:g} m", tile=where, field="range0_m")
    if not isinstance(m["slant"], bool):
        raise TileError(f"expected true or false, got {m['slant']!r}", tile=where, field="slant")
    ping_time = _f64_bin(m["ping_time"], rows, where, "ping_time")
    if not np.all(np.isfinite(ping_time)):
        raise TileError("contains a non-finite time", tile=where, field="ping_time")
    if rows > 1 and np.any(np.diff(ping_time) < 0):
        i = int(np.argmax(np.diff(ping_time) < 0))
        raise TileError(f"not monotonic: row {i + 1} ({ping_time[i + 1]!r}) is before row {i} ({ping_time[i]!r})",
                        tile=where, field="ping_time")

    raw = np.frombuffer(data, dtype=dt).reshape(rows, cols)
    if dt.kind == "f":
        # float32 on the wire: the tile's pixels are the record's bytes, read-only (records are
        # never modified after they are made; the strip copies them into units), not a copy
        pixels = raw if raw.dtype == np.float32 else raw.astype(np.float32)
        lo = np.fmin.reduce(pixels, axis=None)
        hi = np.fmax.reduce(pixels, axis=None)
        if np.isinf(lo) or np.isinf(hi):
            raise TileError("contains an infinite pixel (no data is NaN)", tile=where, field="data")
        if lo < 0:
            raise TileError(f"contains a negative pixel ({lo!r}): pixels are linear intensity or amplitude, never dB",
                            tile=where, field="data")
    else:
        pixels = raw.astype(np.float32)
        pixels[raw == 0] = np.nan

    nav = None
    if m.get("nav") is not None:
        nm = m["nav"]
        if not isinstance(nm, Mapping):
            raise TileError(f"expected a map, got {type(nm).__name__}", tile=where, field="nav")
        arrays = {}
        for k in NAV_KEYS:
            if k not in nm:
                raise TileError("missing key", tile=where, field=f"nav.{k}")
            a = _f64_bin(nm[k], rows, where, f"nav.{k}")
            if not np.all(np.isfinite(a)):
                raise TileError("contains a non-finite value", tile=where, field=f"nav.{k}")
            arrays[k] = a
        if np.any(np.abs(arrays["lat_deg"]) > 90):
            raise TileError("latitude outside [-90, 90]", tile=where, field="nav.lat_deg")
        if np.any((arrays["lon_deg"] < -180) | (arrays["lon_deg"] > 360)):
            raise TileError("longitude outside [-180, 360]", tile=where, field="nav.lon_deg")
        if np.any(arrays["altitude_m"] < 0):
            raise TileError("negative altitude", tile=where, field="nav.altitude_m")
        nav = TileNav(**arrays)

    sensor = None
    if m.get("sensor") is not None:
        sm = m["sensor"]
        if not isinstance(sm, Mapping):
            raise TileError(f"expected a map, got {type(sm).__name__}", tile=where, field="sensor")
        vals: dict[str, Any] = {}
        for k in SENSOR_KEYS:
            if k not in sm:
                raise TileError("missing key", tile=where, field=f"sensor.{k}")
            v = sm[k]
            if k == "sas":
                if not isinstance(v, bool):
                    raise TileError(f"expected true or false, got {v!r}", tile=where, field="sensor.sas")
            elif k == "n_rx":
                if not _is_int(v) or v < 1:
                    raise TileError(f"expected an integer >= 1, got {v!r}", tile=where, field="sensor.n_rx")
            elif not _is_num(v) or not math.isfinite(v) or v <= 0:
                raise TileError(f"expected a finite number > 0, got {v!r}", tile=where, field=f"sensor.{k}")
            vals[k] = float(v) if k not in ("n_rx", "sas") else v
        sensor = SensorInfo(**vals)

    return Tile(mission=m["mission"], leg=int(m["leg"]), side=m["side"], seq=int(m["seq"]), pixels=pixels,
                kind=m["kind"], range0_m=float(m["range0_m"]), dr_m=float(m["dr_m"]), dx_m=float(m["dx_m"]),
                slant=m["slant"], ping_time=ping_time, nav=nav, sensor=sensor, wire_dtype=m["dtype"])
