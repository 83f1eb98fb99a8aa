"""XTF side-scan recordings as the records of an ``.atrlog`` (ICD sections 1 and 4).

:func:`iter_xtf_records` turns an XTF file into the stream a replay plays, so an ``.xtf``
replays exactly like an ``.atrlog``:

- ``sonar`` records: one tile map (ICD section 1) per side per block of at most
  ``tile_pings`` pings, as recorded: ``slant`` true (false only for channels flagged ground
  range), the file's sample type (``uint16`` for most side-scans; 0 = no data), columns from
  the nadir outwards (the port channel, stored far range first, is reversed), ``range0_m`` the
  centre of sample 0 (``TimeDelay`` x one-way sound speed + dr/2), ``dr_m`` = slant range /
  samples, ``dx_m`` = mean speed (knots in XTF) x median ping interval, per-row ``nav`` from
  the ping headers (altitude: see ``altitude`` of :class:`XtfReader`), ``sensor`` from the
  channel headers where the file has it (the rest from
  :class:`~atr_node.config.SensorSettings`). A block ends early when the channel geometry
  changes (sample count, type, or a range axis that differs by more than 1e-4 relative; pings
  within it are resampled onto the block's first ping's axis), after a pause of more than
  ``max_gap_s``, or when pings start or stop carrying a
  position: pings without one make tiles without ``nav`` (the node then interpolates its INS
  links).
- ``nmea`` records synthesised with :mod:`hw.nmea`: from ping headers GGA (at the position fix
  time when the header has it, height = -depth), HDT, DPT (altitude above the seabed), VTG
  (speed, null course: XTF has none); from navigation packets GGA, from attitude and gyro
  packets HDT; ZDA once a second so decoders know the date. NMEA sentences a serial port
  logged into raw serial packets (type 6) come out as recorded.

Positions in projected metres (``NavUnits`` 0) are converted to lat/lon with the CRS given as
``crs`` (``--crs``); without it the reader refuses such a file at once (:mod:`.xtf_packets`).

Records come in time order: ``t`` is the packet time (a tile's is its last ping), never less
than the record before (a navigation packet stamped earlier than what precedes it in the file
arrives with the previous time; its sentence keeps its own). Pings going back in time are
dropped and counted. Everything met is counted in an :class:`XtfStats`.
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path
from typing import Iterator

import numpy as np

from ..config import SensorSettings, frequency_choice
from ..records.nav import _haversine_m, nav_jumps
from ..records.tile import SensorInfo, Tile, TileNav
from .atrlog import LogRecord
from .nmea_encode import KNOT_M_S, NmeaError, encode_dpt, encode_gga, encode_hdt, encode_zda, format_sentence
from .xtf_bottom import BottomTrack, shares_axis, track_bottom
from .xtf_packets import XtfNav, XtfPing, XtfSerial, iter_xtf_items, note_fields, read_positions
from .xtf_stats import XtfStats

__all__ = ["DEFAULT_TILE_PINGS", "XtfReader", "XtfStats", "iter_xtf_records"]

DEFAULT_TILE_PINGS = 256
ALTITUDE_SOURCES = ("auto", "altimeter", "sonar")
AXIS_RTOL = 1e-4
"""Pings whose sample spacing and first-sample range agree to this (relative) share a tile."""
AXIS_RESAMPLE_SAMPLES = 1e-4
"""A ping whose samples sit farther than this (in samples, anywhere on the swath) from the
tile's axis is resampled onto it; closer, its samples are used as they are."""
ALTITUDE_RTOL = 0.05
"""``auto``: a recorded altitude within this fraction (or 2 samples) of the image's first
return is consistent with it."""
log = logging.getLogger(__name__)
WIRE_DTYPE = {np.dtype("<u2"): "uint16", np.dtype("u1"): "uint8"}


def _nav_valid(nav: XtfNav) -> bool:
    """A ping's nav makes a tile's: a position and a heading. Its altitude may be missing
    (JSF 0 = not filled, a negative or NaN XTF field): :meth:`XtfReader._altitude_m` fills it."""
    return nav.has_position and math.isfinite(nav.heading_deg)


def _block_key(ping: XtfPing) -> tuple:
    """Pings of one tile share this: per side samples, dtype and slant; nav or not.

    The range axis (``range0_m``, ``dr_m``) is compared with a tolerance by :func:`_same_axis`:
    exporters recompute the sample spacing per ping in float32 (SonarWiz drifts by 8e-5
    relative from ping to ping), which is not a change of range scale.
    """
    sides = tuple((s, c.samples.size, c.samples.dtype.str, c.slant) for s, c in sorted(ping.channels.items()))
    return sides, _nav_valid(ping.nav)


def _same_axis(ping: XtfPing, first: XtfPing) -> bool:
    """True when every side of ``ping`` has the range axis of ``first`` to ``AXIS_RTOL``."""
    for side, c in ping.channels.items():
        c0 = first.channels[side]
        if not (abs(c.dr_m - c0.dr_m) <= AXIS_RTOL * abs(c0.dr_m)
                and abs(c.range0_m - c0.range0_m) <= AXIS_RTOL * max(abs(c0.range0_m), abs(c0.dr_m))):
            return False
    return True


def _on_axis(samples: np.ndarray, range0_m: float, dr_m: float, range0_to_m: float,
             dr_to_m: float) -> np.ndarray | None:
    """``samples`` (float) linearly resampled onto the axis ``range0_to_m + dr_to_m * i``, or
    None when no sample moves by more than ``AXIS_RESAMPLE_SAMPLES`` (used as they are).
    NaN (no data) spreads to the neighbouring output samples only."""
    n = samples.size
    shift = (abs(range0_m - range0_to_m) + abs(dr_m - dr_to_m) * (n - 1)) / dr_to_m
    if shift <= AXIS_RESAMPLE_SAMPLES:
        return None
    f = (range0_to_m + dr_to_m * np.arange(n) - range0_m) / dr_m
    f = np.clip(f, 0.0, n - 1)
    i0 = np.floor(f).astype(np.int64)
    i1 = np.minimum(i0 + 1, n - 1)
    w = f - i0
    return np.where(w == 0, samples[i0], samples[i0] * (1 - w) + samples[i1] * w)


class XtfReader:
    """Stream the records of an XTF file (see the module docstring); ``stats`` fills as it goes.

    Parameters
    ----------
    path
        The XTF file.
    tile_pings
        Most pings per tile.
    mission
        Mission name in the tiles; default the file name without suffix.
    leg
        Survey leg number of every tile (one file = one leg).
    seq0
        ``seq`` of the first tile of each side.
    sensor
        Sensor values the file does not hold (tx/rx array lengths, bandwidth), and ``dx_m``
        when neither speed nor positions give it.
    altitude
        ``altimeter``: the tile ``nav.altitude_m`` is the ping header's altitude, as recorded
        (where it is missing, the image's first return); ``sonar``: the sonar's own altitude
        from the first bottom return of the pings (:func:`.xtf_bottom.track_bottom`,
        continuous across tiles), the recorded one where the image shows none; ``auto``
        (default): the recorded altitude where it is plausible (> 0 and within 5 % or 2
        samples of the image's first-return track where it has one), the image's first return
        where it is zero, missing or inconsistent. A ping with a position and a heading but
        neither a recorded altitude nor an image one takes ``sensor.altitude_m`` (counted as
        ``nominal``). Pings per source are counted in ``stats.altitude_source`` and logged
        once per file. DPT sentences always carry the recorded altitude.
    max_gap_s
        A longer pause between two pings starts a new tile (a tile is a contiguous run).
    crs
        Coordinate reference system of the file's positions when they are not degrees (XTF
        ``NavUnits`` 0: projected metres), e.g. ``EPSG:32610``; "" = none (:mod:`.crs`).
    frequency
        Which side-scan channel to read where a side has more than one (a dual-frequency
        sonar): ``high`` (default: the finer resolution an ATR wants), ``low``, or a frequency
        in kHz (within 10 %); :func:`.xtf_packets.pick_channel`. Channels not read are counted
        (``stats.channels_unused``) and said in one line (``stats.frequency_line``).

    Raises
    ------
    LogFormatError
        At construction (the file header is read at once): not an XTF file, positions that
        need a CRS and none given (one line naming ``--crs``), or a frequency in kHz that none
        of the side-scan channels the header lists has (one line naming ``--frequency``).
    ConfigError
        ``crs`` is not a CRS pyproj knows; ``frequency`` is not high, low or a number > 0.
    """

    def __init__(self, path: str | os.PathLike[str], *, tile_pings: int = DEFAULT_TILE_PINGS,
                 mission: str | None = None, leg: int | None = None, seq0: int | None = None,
                 sensor: SensorSettings | None = None, altitude: str = "auto", max_gap_s: float = 2.0,
                 crs: str = "", frequency: str | float = "high") -> None:
        if not max_gap_s > 0:
            raise ValueError(f"max_gap_s must be > 0, got {max_gap_s}")
        self.max_gap_s = float(max_gap_s)
        if altitude not in ALTITUDE_SOURCES:
            raise ValueError(f"altitude must be one of {ALTITUDE_SOURCES}, got {altitude!r}")
        self.altitude = altitude
        if tile_pings < 1:
            raise ValueError(f"tile_pings must be >= 1, got {tile_pings}")
        self.path = Path(path)
        self.tile_pings = int(tile_pings)
        self._args = (mission, leg, seq0)
        self.mission, self.leg, self.seq0 = mission or self.path.stem or "xtf", int(leg or 0), int(seq0 or 0)
        self.sensor = sensor or SensorSettings()
        self.stats = XtfStats(path=str(self.path))
        # what the positions are, and whether the frequency asked is there, is decided from the
        # file header now, so that a file that needs --crs fails before a command writes anything
        self.frequency = frequency_choice(frequency)
        self.positions = self._read_positions(crs)

    def _read_positions(self, crs: str):
        """What the file's positions are, the frequency asked checked on the same header read;
        a hook other formats (JSF) override."""
        return read_positions(self.path, crs, frequency=self.frequency)

    def _use_header(self, header) -> None:
        """Mission, leg and seq written by :mod:`.xtf_write` are the defaults of the arguments."""
        note = note_fields(bytes(header.NoteString))
        mission, leg, seq0 = self._args
        try:
            self.mission = mission or note.get("mission") or self.mission
            self.leg = int(leg if leg is not None else note.get("leg", 0))
            self.seq0 = int(seq0 if seq0 is not None else note.get("seq", 0))
        except ValueError:
            pass
        self._seq = {"port": self.seq0, "stbd": self.seq0}

    def __iter__(self) -> Iterator[LogRecord]:
        self._last_t = -math.inf
        self._last_ping_t = -math.inf
        self._header: list = []
        self._seq = {"port": self.seq0, "stbd": self.seq0}
        self._last_gga: tuple | None = None
        self._last_gga_t = -math.inf
        self._zda_second = -math.inf
        self._last_dx: float | None = None
        self._alt_prior: BottomTrack | None = None
        block: list[XtfPing] = []
        key = None
        for item in self._items():
            if self._header:  # filled by the generator before its first item
                self._use_header(self._header.pop())
            if isinstance(item, XtfSerial):
                for line in item.lines:
                    if line.startswith(b"$"):  # an NMEA sentence as the port delivered it
                        self.stats.nmea["raw_serial"] += 1
                        yield self._record(item.t, "nmea", line + b"\r\n", item.offset)
                    else:
                        self.stats.skipped["raw_serial_text"] += 1
                continue
            if isinstance(item, XtfNav):
                self.stats.nav_fixes += 1
                yield from self._nav_records(item, item.t, item.fix_t, item.offset)
                continue
            ping = item
            if ping.nav.t < self._last_ping_t:
                self.stats.pings_dropped["time_backwards"] += 1
                continue
            self._last_ping_t = ping.nav.t
            k = _block_key(ping)
            gap = bool(block) and ping.nav.t - block[-1].nav.t > self.max_gap_s
            if block and (k != key or len(block) >= self.tile_pings or gap or not _same_axis(ping, block[0])):
                yield from self._tiles(block)
                block = []
            key = k
            block.append(ping)
            self.stats.pings += 1
            if not _nav_valid(ping.nav):
                self.stats.pings_without_nav += 1
            yield from self._nav_records(ping.nav, ping.nav.t, ping.nav.fix_t, ping.offset)
        if block:
            yield from self._tiles(block)
        if self.stats.pings:
            log.info("%s: %s", self.path, self.stats.altitude_line())
        if self.stats.channels_unused:
            log.info("%s: %s", self.path, self.stats.frequency_line())

    def _items(self) -> Iterator[XtfPing | XtfNav | XtfSerial]:
        """The pings, fixes and serial text of the file; the hook other formats (JSF) override."""
        return iter_xtf_items(self.path, self.stats, self._header, positions=self.positions, frequency=self.frequency)

    # -- records -----------------------------------------------------------------------------
    def _record(self, t: float, link: str, msg, offset: int) -> LogRecord:
        self._last_t = max(t, self._last_t)
        return LogRecord(t=self._last_t, link=link, msg=msg, offset=offset)

    def _sentence(self, t: float, kind: str, make, offset: int) -> Iterator[LogRecord]:
        try:
            line = make()
        except NmeaError as exc:
            self.stats.quirk(f"{kind} not written", f"{self.path}: at byte {offset}: {kind} not written: {exc}")
            return
        self.stats.nmea[kind] += 1
        yield self._record(t, "nmea", line, offset)

    def _nav_records(self, nav: XtfNav, t: float, fix_t: float, offset: int) -> Iterator[LogRecord]:
        """NMEA sentences for one ping header or navigation packet."""
        if nav.has_position:
            fix = (nav.lat_deg, nav.lon_deg, fix_t)
            t_fix = fix_t if math.isfinite(fix_t) else t
            if fix != self._last_gga or t - self._last_gga_t >= 1.0:
                if math.floor(t_fix) > self._zda_second:
                    self._zda_second = math.floor(t_fix)
                    yield from self._sentence(t, "ZDA", lambda: encode_zda(t_fix), offset)
                height = -nav.depth_m if math.isfinite(nav.depth_m) else (
                    nav.height_m if math.isfinite(nav.height_m) else 0.0)
                yield from self._sentence(t, "GGA", lambda: encode_gga(t_fix, nav.lat_deg, nav.lon_deg,
                                                                        height_m=height), offset)
                self._last_gga, self._last_gga_t = fix, t
                if math.isfinite(nav.speed_m_s) and nav.speed_m_s >= 0:
                    kn = nav.speed_m_s / KNOT_M_S
                    yield from self._sentence(t, "VTG", lambda: format_sentence(
                        "GPVTG", ["", "T", "", "M", f"{kn:.2f}", "N", f"{nav.speed_m_s * 3.6:.2f}", "K", "A"]),
                        offset)
        if math.isfinite(nav.heading_deg):
            yield from self._sentence(t, "HDT", lambda: encode_hdt(nav.heading_deg), offset)
        if math.isfinite(nav.altitude_m) and nav.altitude_m >= 0:
            yield from self._sentence(t, "DPT", lambda: encode_dpt(nav.altitude_m), offset)

    # -- tiles -------------------------------------------------------------------------------
    def _dx_m(self, block: list[XtfPing]) -> float:
        """Along-track ping spacing: mean speed x median ping interval, else from positions."""
        t = np.array([p.nav.t for p in block])
        dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
        v = np.array([p.nav.speed_m_s for p in block])
        v = v[np.isfinite(v) & (v > 0)]
        dx = 0.0
        if dt > 0 and v.size:
            dx = float(v.mean()) * dt
        elif t.size > 1 and block[0].nav.has_position and block[-1].nav.has_position:
            dx = float(_haversine_m(block[0].nav.lat_deg, block[0].nav.lon_deg,
                                    block[-1].nav.lat_deg, block[-1].nav.lon_deg)) / (t.size - 1)
        if not (math.isfinite(dx) and dx > 0):
            dx = self._last_dx if self._last_dx is not None else self.sensor.dx_m
        self._last_dx = dx
        return dx

    def _sensor_info(self, ping: XtfPing, side: str) -> SensorInfo:
        ch = ping.channels[side]
        missing = ["tx_length_m", "rx_length_m"]
        if not ch.frequency_hz > 0:
            missing.append("frequency_hz")
        if not ch.bandwidth_hz > 0:
            missing.append("bandwidth_hz")
        self.stats.sensor_defaults = tuple(sorted(set(self.stats.sensor_defaults) | set(missing)))
        s = self.sensor
        # XTF side-scan channels are real-aperture: one receiver, no SAS processing.
        return SensorInfo(frequency_hz=ch.frequency_hz if ch.frequency_hz > 0 else s.frequency_hz,
                          bandwidth_hz=ch.bandwidth_hz * 1e3 if ch.bandwidth_hz > 0 else s.bandwidth_hz,
                          tx_length_m=s.tx_length_m, rx_length_m=s.rx_length_m, n_rx=1, sas=False)

    def _altitude_m(self, tiles: dict[str, Tile], recorded: np.ndarray) -> np.ndarray:
        """The altitude of a block's pings (``altitude`` in the class docstring), counted by
        source in ``stats``."""
        st = self.stats
        rec = np.asarray(recorded, dtype=np.float64)
        zero = rec == 0
        missing = ~np.isfinite(rec) | (rec < 0)
        st.altitude_recorded_bad["zero"] += int(zero.sum())
        st.altitude_recorded_bad["missing"] += int(missing.sum())
        first = next(iter(tiles.values()))
        if not first.slant or (self.altitude == "altimeter" and not missing.any()):
            img = np.full(rec.size, np.nan)  # not tracked: not wanted, or no slant range to track on
        else:
            img = self._image_altitude_m(tiles)
        have = np.isfinite(img)
        if self.altitude == "altimeter":
            use = have & missing
        elif self.altitude == "sonar":
            use = have
        else:
            # recorded where plausible: > 0 and, where the image has a first-return track,
            # within ALTITUDE_RTOL (or 2 samples) of it; the image's elsewhere. Pings the track
            # carried over (no clear return of their own) are judged against it too: a
            # recorded value that jumps away from its neighbours' track for a ping or two
            # would put the water column back into the image there.
            tol = np.maximum(ALTITUDE_RTOL * np.where(have, img, 0.0), 2.0 * first.dr_m)
            inconsistent = have & ~(zero | missing) & ~(np.abs(rec - img) <= tol)
            st.altitude_recorded_bad["inconsistent with the image"] += int(inconsistent.sum())
            use = have & (zero | missing | inconsistent)
        # neither recorded nor seen in the image: the nominal altitude, so that the ping keeps
        # its position (a tile without nav is dropped by the node when no INS fix is near)
        nominal = ~use & missing
        st.altitude_source["image"] += int(use.sum())
        if nominal.any():
            st.altitude_source["nominal"] += int(nominal.sum())
        st.altitude_source["recorded"] += int((~use & ~nominal).sum())
        st.altitude_from_sonar += int(use.sum())
        return np.where(use, img, np.where(nominal, float(self.sensor.altitude_m), rec))

    def _image_altitude_m(self, tiles: dict[str, Tile]) -> np.ndarray:
        """The first-return track of a block (:func:`.xtf_bottom.track_bottom`), NaN where the
        image shows none; sides on different range axes are counted."""
        port, stbd = tiles.get("port"), tiles.get("stbd")
        if port is not None and stbd is not None and not shares_axis(port, stbd):
            self.stats.altitude_sides_resampled += port.rows
        # the previous block's track: the Viterbi starts from its end, the along-track envelope
        # (which fills early returns of objects near the nadir) continues over it
        track = track_bottom(port, stbd, prior=self._alt_prior)
        have = np.isfinite(track.altitude_m)
        if have.any():
            self._alt_prior = track
        self.stats.altitude_image_carried += int((have & ~track.found).sum())
        return track.altitude_m

    def _tiles(self, block: list[XtfPing]) -> Iterator[LogRecord]:
        first, last = block[0], block[-1]
        ping_time = np.array([p.nav.t for p in block], dtype=np.float64)
        nav = None
        if _nav_valid(first.nav):
            nav = TileNav(*(np.array([getattr(p.nav, k) for p in block])
                            for k in ("lat_deg", "lon_deg", "heading_deg", "altitude_m")))
            self.stats.nav_jumps += int(nav_jumps(nav, ping_time).size)
        dx = self._dx_m(block)
        tiles = {}
        for side in ("port", "stbd"):
            if side not in first.channels:
                continue
            ch = first.channels[side]
            raw = np.stack([p.channels[side].samples for p in block])
            wire = WIRE_DTYPE.get(raw.dtype, "float32")
            pixels = raw.astype(np.float32)
            if wire == "float32":
                pixels[~np.isfinite(pixels) | (pixels < 0)] = np.nan  # no data, never negative (ICD 1)
            else:
                pixels[raw == 0] = np.nan
            for i, p in enumerate(block[1:], 1):
                # within AXIS_RTOL of the first ping's axis (_same_axis): put on that axis
                c = p.channels[side]
                moved = _on_axis(pixels[i], c.range0_m, c.dr_m, ch.range0_m, ch.dr_m)
                if moved is not None:
                    pixels[i] = moved
                    self.stats.pings_resampled += 1
            tiles[side] = Tile(mission=self.mission, leg=self.leg, side=side, seq=self._seq[side], pixels=pixels,
                               kind="amplitude", range0_m=ch.range0_m, dr_m=ch.dr_m, dx_m=dx, slant=ch.slant,
                               ping_time=ping_time, nav=None, sensor=self._sensor_info(first, side),
                               wire_dtype=wire)
        if nav is not None:
            nav = TileNav(nav.lat_deg, nav.lon_deg, nav.heading_deg, self._altitude_m(tiles, nav.altitude_m))
        for side, tile in tiles.items():
            self._seq[side] += 1
            self.stats.tiles += 1
            yield self._record(float(ping_time[-1]), "sonar", tile.replace(nav=nav).to_map(), last.offset)


def iter_xtf_records(path: str | os.PathLike[str], *, tile_pings: int = DEFAULT_TILE_PINGS,
                     mission: str | None = None, leg: int | None = None, seq0: int | None = None,
                     sensor: SensorSettings | None = None, altitude: str = "auto",
                     stats: XtfStats | None = None, crs: str = "", frequency: str | float = "high") -> Iterator[LogRecord]:
    """Stream an XTF file as ``.atrlog`` records (see :class:`XtfReader`).

    ``stats``, when given, is filled as the records stream (packets by type, skipped unknown
    types, pings, tiles, NMEA sentences); read it once the iterator is exhausted.
    """
    reader = XtfReader(path, tile_pings=tile_pings, mission=mission, leg=leg, seq0=seq0, sensor=sensor,
                       altitude=altitude, crs=crs, frequency=frequency)
    if stats is not None:
        stats.path = reader.stats.path
        reader.stats = stats
    return iter(reader)
