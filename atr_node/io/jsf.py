"""EdgeTech JSF side-scan recordings as the records of an ``.atrlog`` (ICD sections 1 and 4).

No maintained Python JSF reader fits (``pyjsf`` 0.0.1, one release: whole file in memory,
envelope only, stops at the first bad header with ``RuntimeError``, NMEA text not decoded), so
this module reads the format from its public description, the EdgeTech "JSF Data File
Description" (0004824 rev 1.20; 0023492 rev M, 2024, which keeps the rev 1.20 offsets). Each
offset below was checked against two independent public readers of those revisions: ge0mlib
``gJsf0080Read.m`` (rev 1.20, byte ranges in its comments) and a Python reader citing rev M
(``struct`` formats). MB-System's older ``mbsys_jstar.h`` (2005) agrees on the message
header, the pitch/roll and DVL messages, and in message 80 on start depth, ping number, data
format, samples, sample interval, CPU time, weighting factor and ``ms today`` (its navigation
block predates rev 1.20). Message 2091 has one source only (the rev M reader).

A JSF file is a sequence of messages, little-endian, each a 16-byte header::

    0 uint16 start marker 0x1601   2 uint8 protocol version   3 uint8 session
    4 uint16 message type          6 uint8 command            7 uint8 subsystem
    8 uint8 channel                9 uint8 sequence          10 uint16 reserved
   12 int32 size of the message that follows

What is turned into values (everything else is skipped by its size and counted by name):

===================== ====================================================================
message               values
===================== ====================================================================
80 sonar data         one channel of one ping (subsystem 20/21/22 = low/high/very high
                      frequency side-scan; channel 0 port, 1 starboard): a 240-byte header
                      (offsets in :data:`PING_FIELDS`) and the samples; port and starboard of
                      the same ping number are joined into one :class:`~.xtf_packets.XtfPing`
2002 NMEA string      the sentence as recorded (time, ms, source, 3 reserved, text at 12)
2020 pitch/roll       heading (uint16 at 34, 1/100 deg) when validity (int32 at 36) bit 9
2080 DVL              heading (uint16 at 50, 1/100 deg) when validity (uint32 at 12) bit 6
2091 situation        latitude, longitude (float64 at 28, 36, degrees), depth, altitude,
                      heading (float32 at 44, 48, 76) by validity (uint32 at 12) bits 2/1,
                      3, 4, 10
===================== ====================================================================

Ping values: time = seconds since 1970 (int32 at 0) + the milliseconds of ``ms today``
(uint32 at 200) modulo 1000 (protocol versions before 8 have 0 at byte 0: year and day at
156, 158 and ``ms today`` then); samples uint16 at 114 with bits 8-11 of the MSB word (16)
as bits 16-19; sample interval ns (uint32 at 116; the fractional LSB bits are ignored: their
scale is not stated consistently, and they are below 1 ns); range spacing = sound speed
(float32 at 148 when 1300-1800 m/s, else 1500) x interval / 2; ``range0_m`` = (start depth
(uint32 at 4, samples) + 1/2) x spacing; samples x 2^-N with N the signed weighting factor
(int16 at 168); data format (int16 at 34) 0 = envelope (uint16, as MB-System reads it), 1 and
9 = analytic I/Q (int16 pairs: the magnitude is used); other formats are dropped and
counted. Position (int32 X at 80, Y at 84) only in coordinate units (int16 at 88) 2 =
minutes of arc x 10000; units 1, 3, 4 (X, Y in mm, dm, cm) are projected coordinates in a
projection the file does not name: converted with the CRS the user gives (``crs``, as for
XTF: :mod:`.crs`); without one the first such ping raises
:class:`~atr_node.errors.LogFormatError` naming ``--crs`` (undefined units: not used, said once
in ``stats.errors``). Validity flags (uint16 at
30): bit 0 position, 2 speed (int16 at 194, 1/10 knot, + LSB2 (20) bits 0-3 in 1/100 knot),
3 heading (uint16 at 172, 1/100 deg), 6 altitude (int32 at 144, mm; 0 = not filled), 9 depth
(int32 at 136, mm); a file whose flags are all 0 (older software) has its non-zero fields
taken as valid. Position fix time: hour, minute, second at 186-190.
Frequency: (start + end) / 2 of the pulse (uint16 at 126, 128, in 10 Hz, MSB bits 0-3 / 4-7),
bandwidth their difference; the mixer frequency (float32 at 152) when they are 0.

Framing: a message whose start marker is not 0x1601 or whose size runs past the end of the
file ends the read with one warning naming the byte offset; everything before it is kept.
A file whose first message is not JSF raises :class:`~atr_node.errors.LogFormatError`.
"""

from __future__ import annotations

import logging
import math
import os
import struct
from datetime import datetime, timezone
from typing import Iterator

import numpy as np

from ..config import SensorSettings
from ..errors import LogFormatError
from .atrlog import LogRecord
from .xtf import DEFAULT_TILE_PINGS, XtfReader
from .crs import EXAMPLE_CRS, Projection, projection
from .xtf_packets import KNOT_M_S, XtfChannel, XtfNav, XtfPing, XtfSerial, fix_time
from .xtf_stats import XtfStats

__all__ = ["JsfReader", "JsfStats", "check_jsf", "iter_jsf_items", "iter_jsf_records"]

log = logging.getLogger(__name__)

JsfStats = XtfStats
"""What reading a JSF file met (the XTF counters: ``packets`` are JSF messages by name)."""

START_MARKER = 0x1601
HEADER = struct.Struct("<HBBHBBBBHi")
HEADER_BYTES = HEADER.size  # 16
PING_HEADER_BYTES = 240
SONAR, NMEA, PITCH_ROLL, DVL, SITUATION = 80, 2002, 2020, 2080, 2091
MESSAGE_NAMES = {SONAR: "sonar", 82: "sidescan_82", 86: "sas_86", 181: "nav_offsets", 182: "system_info",
                 426: "file_timestamp", 428: "file_padding", NMEA: "nmea", PITCH_ROLL: "pitch_roll",
                 2040: "misc_analog", 2060: "pressure", 2071: "reflection", DVL: "dvl", 2090: "message",
                 SITUATION: "situation", 2100: "cable_counter", 2101: "km_pipe", 2111: "container_time",
                 3000: "bathy"}
"""Names in ``stats.packets``; types whose use the two sources do not agree on (3001-3005)
are left ``unknown_<n>``."""
SIDE_SCAN_SUBSYSTEMS = (20, 21, 22)
SIDES = {0: "port", 1: "stbd"}
COORD_MINUTES_X10000 = 2
COORD_METRES = {1: 1e-3, 3: 0.1, 4: 0.01}
"""Coordinate units of projected X, Y -> metres per unit."""
DEFAULT_SOUND_SPEED_M_S = 1500.0
SOUND_SPEED_STEP_M_S = 2.0
"""A measured sound speed changes the range spacing only past this step, so that a few
cm/s of sensor noise does not end a tile every ping (2 m/s = 0.13 % of range)."""

PING_FIELDS = np.dtype({
    "names": ["ping_time_s", "start_depth", "ping_number", "msb", "lsb2", "validity", "data_format",
              "x", "y", "coord_units", "samples", "interval_ns", "start_freq_dahz", "end_freq_dahz",
              "depth_mm", "altitude_mm", "sound_speed", "mixer_hz", "year", "day", "weighting",
              "heading_cdeg", "fix_hour", "fix_minute", "fix_second", "speed_dkn", "ms_today", "packet"],
    "formats": ["<i4", "<u4", "<u4", "<u2", "<u2", "<u2", "<i2", "<i4", "<i4", "<i2", "<u2", "<u4", "<u2",
                "<u2", "<i4", "<i4", "<f4", "<f4", "<i2", "<i2", "<i2", "<u2", "<i2", "<i2", "<i2", "<i2",
                "<u4", "<u2"],
    "offsets": [0, 4, 8, 16, 20, 30, 34, 80, 84, 88, 114, 116, 126, 128, 136, 144, 148, 152, 156, 158, 168,
                172, 186, 188, 190, 194, 200, 220],
    "itemsize": PING_HEADER_BYTES})
"""The message 80 header fields read, at their rev 1.20 byte offsets (module docstring)."""

VALID_POSITION, VALID_SPEED, VALID_HEADING, VALID_ALTITUDE, VALID_DEPTH = 1, 1 << 2, 1 << 3, 1 << 6, 1 << 9
ENVELOPE, ANALYTIC, ANALYTIC_UNMATCHED = 0, 1, 9


def message_name(kind: int) -> str:
    return MESSAGE_NAMES.get(kind, f"unknown_{kind}")


def _msg_time(raw: bytes) -> float:
    """Seconds since 1970 (int32) + milliseconds (int32, in the second or since 1970: mod 1000)."""
    s, ms = struct.unpack_from("<ii", raw, 0)
    return float(s) + (ms % 1000) / 1000.0


def _ping_time(h: np.void) -> float:
    if h["ping_time_s"] > 0:
        return float(h["ping_time_s"]) + (int(h["ms_today"]) % 1000) / 1000.0
    # protocol < 8: no seconds since 1970; year, day of year and ms since midnight
    day0 = datetime(int(h["year"]), 1, 1, tzinfo=timezone.utc).timestamp() + (int(h["day"]) - 1) * 86400.0
    return day0 + int(h["ms_today"]) / 1000.0


class _PingParser:
    """Message 80 channels -> values; holds the sticky sound speed (see SOUND_SPEED_STEP_M_S)."""

    def __init__(self, stats: XtfStats, projection: Projection | None = None) -> None:
        self.stats = stats
        self.projection = projection
        self.sound_speed = math.nan
        self._said_units: set[int] = set()

    def samples(self, h: np.void, body: bytes, n: int) -> np.ndarray | None:
        fmt = int(h["data_format"])
        scale = np.float32(2.0 ** -int(h["weighting"]))  # block floating point: all samples x 2^-N
        if fmt == ENVELOPE:
            if len(body) < 2 * n:
                return None
            return np.frombuffer(body, "<u2", n).astype(np.float32) * scale
        if fmt in (ANALYTIC, ANALYTIC_UNMATCHED):
            if len(body) < 4 * n:
                return None
            iq = np.frombuffer(body, "<i2", 2 * n).astype(np.float32).reshape(n, 2)
            return np.hypot(iq[:, 0], iq[:, 1]) * scale
        self.stats.pings_dropped[f"data_format_{fmt}"] += 1
        return None

    def channel(self, h: np.void, body: bytes, side: str) -> XtfChannel | None:
        n = int(h["samples"]) | ((int(h["msb"]) >> 8 & 0xF) << 16)
        x = self.samples(h, body, n)
        if x is None:
            if int(h["data_format"]) in (ENVELOPE, ANALYTIC, ANALYTIC_UNMATCHED):
                self.stats.pings_dropped["short_message"] += 1
            return None
        c = float(h["sound_speed"])
        if 1300.0 <= c <= 1800.0:
            if not abs(c - self.sound_speed) <= SOUND_SPEED_STEP_M_S:
                self.sound_speed = c
        elif math.isnan(self.sound_speed):
            self.sound_speed = DEFAULT_SOUND_SPEED_M_S
        dr = self.sound_speed * int(h["interval_ns"]) * 1e-9 / 2.0
        if n == 0 or not dr > 0:
            self.stats.pings_dropped["no_range"] += 1
            return None
        f0 = int(h["start_freq_dahz"]) | ((int(h["msb"]) & 0xF) << 16)
        f1 = int(h["end_freq_dahz"]) | ((int(h["msb"]) >> 4 & 0xF) << 16)
        freq_hz = 5.0 * (f0 + f1) if f0 + f1 > 0 else max(float(h["mixer_hz"]), 0.0)
        # XtfChannel.bandwidth_hz holds kHz (XTF's unit): XtfReader._sensor_info multiplies by 1e3
        return XtfChannel(side=side, samples=x, range0_m=(int(h["start_depth"]) + 0.5) * dr, dr_m=dr, slant=True,
                          frequency_hz=freq_hz, bandwidth_hz=abs(f1 - f0) * 10.0 / 1e3)

    def latlon(self, h: np.void, path: str, offset: int | None = None) -> tuple[float, float]:
        """Degrees of a ping's position; NaN when it has none or its units are not defined.

        Raises
        ------
        LogFormatError
            Projected units (1, 3, 4) and no CRS given: one line naming ``--crs``, as for an
            XTF file in projected metres (ICD section 6).
        """
        units, x, y = int(h["coord_units"]), int(h["x"]), int(h["y"])
        if not (x or y):
            return math.nan, math.nan
        if units == COORD_MINUTES_X10000:
            lat, lon = y / 600000.0, x / 600000.0
            return (lat, lon) if abs(lat) <= 90.0 and abs(lon) <= 180.0 else (math.nan, math.nan)
        if units in COORD_METRES:
            if self.projection is None:
                raise LogFormatError(f"positions are projected X, Y (JSF coordinate units {units}) in a "
                                     "projection the file does not name: give their CRS with --crs (or the "
                                     f"recording.crs key), e.g. --crs {EXAMPLE_CRS}", path=path, offset=offset)
            return self.projection.to_latlon(x * COORD_METRES[units], y * COORD_METRES[units])
        if units not in self._said_units:
            self._said_units.add(units)
            self.stats.errors.append(f"{path}: coordinate units {units} (not defined): positions not used")
        return math.nan, math.nan

    def nav(self, h: np.void, t: float, offset: int, path: str) -> XtfNav:
        legacy = int(h["validity"]) == 0  # software without flags: every non-zero field counts
        flags = 0xFFFF if legacy else int(h["validity"])

        def field(bit: int, value: float, *, zero_is_unset: bool = False) -> float:
            if not flags & bit or (value == 0 and (legacy or zero_is_unset)):
                return math.nan
            return value

        lat, lon = self.latlon(h, path, offset) if flags & VALID_POSITION else (math.nan, math.nan)
        speed_kn = int(h["speed_dkn"]) / 10.0 + (int(h["lsb2"]) & 0xF) / 100.0
        fix_t = math.nan
        hh, mm, ss = int(h["fix_hour"]), int(h["fix_minute"]), int(h["fix_second"])
        if (hh or mm or ss) and 0 <= hh < 24 and 0 <= mm < 60 and 0 <= ss < 61:
            fix_t = fix_time(t, hh * 3600 + mm * 60 + ss)
        return XtfNav(t=t, lat_deg=lat, lon_deg=lon,
                      heading_deg=field(VALID_HEADING, int(h["heading_cdeg"]) / 100.0) % 360.0,
                      altitude_m=field(VALID_ALTITUDE, int(h["altitude_mm"]) / 1000.0, zero_is_unset=True),
                      depth_m=field(VALID_DEPTH, int(h["depth_mm"]) / 1000.0),
                      speed_m_s=field(VALID_SPEED, speed_kn) * KNOT_M_S, fix_t=fix_t, source="jsf:sonar",
                      offset=offset)


def parse_nav_message(kind: int, raw: bytes, offset: int = 0) -> XtfNav | XtfSerial | None:
    """Messages 2002, 2020, 2080, 2091 (payload after the 16-byte header); None when nothing valid."""
    t = _msg_time(raw)
    if kind == NMEA:
        text = raw[12:].split(b"\x00", 1)[0]
        lines = (line.strip() for line in text.replace(b"\r", b"\n").split(b"\n"))
        return XtfSerial(t=t, lines=tuple(line for line in lines if line), offset=offset)
    if kind == PITCH_ROLL:
        heading, flags = struct.unpack_from("<Hi", raw, 34)
        ok = flags & (1 << 9)
    elif kind == DVL:
        (flags,) = struct.unpack_from("<I", raw, 12)
        (heading,) = struct.unpack_from("<H", raw, 50)
        ok = flags & (1 << 6) and not flags & (1 << 31)  # bit 31: the DVL reports an error
    else:
        (flags,) = struct.unpack_from("<I", raw, 12)
        lat, lon = struct.unpack_from("<dd", raw, 28)
        depth, alt = struct.unpack_from("<ff", raw, 44)
        (hdg,) = struct.unpack_from("<f", raw, 76)
        has_pos = (flags & 0b110) == 0b110 and abs(lat) <= 90.0 and abs(lon) <= 180.0 and (lat or lon)
        nav = XtfNav(t=t, lat_deg=lat if has_pos else math.nan, lon_deg=lon if has_pos else math.nan,
                     depth_m=depth if flags & (1 << 3) else math.nan,
                     altitude_m=alt if flags & (1 << 4) else math.nan,
                     heading_deg=hdg % 360.0 if flags & (1 << 10) and math.isfinite(hdg) else math.nan,
                     source="jsf:situation", offset=offset)
        return nav if has_pos or math.isfinite(nav.heading_deg) or math.isfinite(nav.altitude_m) else None
    return XtfNav(t=t, heading_deg=(heading / 100.0) % 360.0, source=f"jsf:{message_name(kind)}",
                  offset=offset) if ok else None


MIN_BYTES = {SONAR: PING_HEADER_BYTES, NMEA: 12, PITCH_ROLL: 44, DVL: 72, SITUATION: 100}


def check_jsf(path: str | os.PathLike[str]) -> None:
    """Raise :class:`~atr_node.errors.LogFormatError` (one line) unless ``path`` starts with a
    JSF message header whose message fits in the file."""
    path = str(path)
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as fh:
            head = fh.read(HEADER_BYTES)
    except OSError as exc:
        raise LogFormatError(f"cannot read: {exc.strerror or exc}", path=path) from None
    if len(head) < HEADER_BYTES:
        raise LogFormatError(f"not a JSF file: {size} bytes, a message header is {HEADER_BYTES}", path=path, offset=0)
    marker, n = HEADER.unpack(head)[0], HEADER.unpack(head)[-1]
    if marker != START_MARKER:
        raise LogFormatError(f"not a JSF file: start marker {marker:#06x}, expected 0x1601", path=path, offset=0)
    if n < 0 or HEADER_BYTES + n > size:
        raise LogFormatError(f"not a JSF file: first message of {n} bytes runs past the end of the file "
                             f"({size} bytes)", path=path, offset=0)


def iter_jsf_items(path: str | os.PathLike[str], stats: XtfStats, *, subsystem: int | None = None,
                   positions: Projection | None = None) -> Iterator[XtfPing | XtfNav | XtfSerial]:
    """Stream the pings, navigation fixes and NMEA text of a JSF file, in file order.

    Parameters
    ----------
    path
        The JSF file.
    stats
        Filled as the file streams (messages by name, skipped, dropped pings, errors).
    subsystem
        Side-scan subsystem whose pings are read (20 low, 21 high, 22 very high frequency);
        None: the first met. Pings of the others are skipped and counted.
    positions
        The projection of X, Y in projected coordinate units (1, 3, 4); None: not used.

    Raises
    ------
    LogFormatError
        The file does not start with a JSF message. Damage further in ends the stream with
        a warning.
    """
    path = str(path)
    stats.path = stats.path or path
    size = os.path.getsize(path)
    parser = _PingParser(stats, positions)
    pending: dict[str, XtfChannel] = {}
    pending_key: tuple | None = None  # (ping number, nav, byte offset) of the ping being joined
    with open(path, "rb") as fh:
        offset = 0
        while offset < size:
            head = fh.read(HEADER_BYTES)
            why = None
            if len(head) < HEADER_BYTES:
                why = f"{size - offset} bytes left, a message header is {HEADER_BYTES}"
            else:
                marker, _, _, kind, _, subsys, chan, _, _, n = HEADER.unpack(head)
                if marker != START_MARKER:
                    why = f"message start marker {marker:#06x}, expected 0x1601"
                elif n < 0 or offset + HEADER_BYTES + n > size:
                    why = f"message of {n} bytes runs past the end of the file ({size} bytes)"
            if why is not None:
                if offset == 0:
                    raise LogFormatError(f"not a JSF file: {why}", path=path, offset=0)
                stats.truncated = True
                msg = f"{path}: at byte {offset}: {why}; the rest of the file is ignored"
                log.warning(msg)
                stats.errors.append(msg)
                break
            raw = fh.read(n)
            here, offset = offset, offset + HEADER_BYTES + n
            name = message_name(kind)
            stats.packets[name] += 1
            if kind not in MIN_BYTES:
                stats.skipped[name] += 1
                continue
            if len(raw) < MIN_BYTES[kind]:
                stats.bad += 1
                stats.quirk(f"short message ({name})", f"{path}: {name} message at byte {here}: {n} bytes, "
                            f"at least {MIN_BYTES[kind]} expected")
                continue
            if kind != SONAR:
                item = parse_nav_message(kind, raw, here)
                if item is not None:
                    yield item
                continue
            if subsys not in SIDE_SCAN_SUBSYSTEMS or chan not in SIDES:
                stats.skipped[f"sonar_subsystem_{subsys}" if subsys not in SIDE_SCAN_SUBSYSTEMS
                              else f"sonar_channel_{chan}"] += 1
                continue
            if subsystem is None:
                subsystem = subsys
            if subsys != subsystem:
                stats.skipped[f"sonar_subsystem_{subsys}"] += 1
                continue
            h = np.frombuffer(raw, PING_FIELDS, 1)[0]
            side = SIDES[chan]
            if pending and pending_key is not None and int(h["ping_number"]) != pending_key[0]:
                yield XtfPing(nav=pending_key[1], channels=pending, ping_number=pending_key[0], offset=pending_key[2])
                pending, pending_key = {}, None
            try:
                t = _ping_time(h)
            except (ValueError, OverflowError):
                stats.pings_dropped["bad_time"] += 1
                continue
            ch = parser.channel(h, raw[PING_HEADER_BYTES:], side)
            if ch is None:
                continue
            if side in pending:
                if int(h["packet"]) > 1:  # a long ping split over packets: samples continue
                    prev = pending[side]
                    ch = XtfChannel(side=side, samples=np.concatenate([prev.samples, ch.samples]),
                                    range0_m=prev.range0_m, dr_m=prev.dr_m, slant=True,
                                    frequency_hz=prev.frequency_hz, bandwidth_hz=prev.bandwidth_hz)
                else:
                    stats.pings_dropped["duplicate_channel"] += 1
                    continue
            if pending_key is None:
                pending_key = (int(h["ping_number"]), parser.nav(h, t, here, path), here)
            pending[side] = ch
        if pending and pending_key is not None:
            yield XtfPing(nav=pending_key[1], channels=pending, ping_number=pending_key[0], offset=pending_key[2])


_FREQUENCY_SAID: set[str] = set()
"""Files whose ignored ``frequency`` was warned about (once per process)."""


class JsfReader(XtfReader):
    """Stream the records of a JSF file: the :class:`~.xtf.XtfReader` tiling and NMEA synthesis
    on the pings and fixes of :func:`iter_jsf_items` (parameters as there, plus ``subsystem``)."""

    def __init__(self, path: str | os.PathLike[str], *, subsystem: int | None = None, **kwargs) -> None:
        if subsystem is not None and subsystem not in SIDE_SCAN_SUBSYSTEMS:
            raise ValueError(f"subsystem must be one of {SIDE_SCAN_SUBSYSTEMS} (side-scan), got {subsystem}")
        self.subsystem = subsystem
        check_jsf(path)  # at construction, as XtfReader: a command fails before writing anything
        super().__init__(path, **kwargs)

    def _read_positions(self, crs: str) -> Projection | None:
        # JSF says per ping whether positions are degrees or projected: the CRS is checked now
        # (one line for a bad one) and used only by pings in projected units. The side-scan
        # subsystem is chosen by number (``subsystem``), not by frequency: a frequency asked
        # is said once per file and process (a command opens a file twice: checked, then read)
        if self.frequency != "high" and str(self.path) not in _FREQUENCY_SAID:
            _FREQUENCY_SAID.add(str(self.path))
            log.warning("%s: --frequency (recording.frequency) chooses the channels of an XTF file; a JSF file's "
                        "side-scan subsystem is chosen by number: atr-node convert %s OUT.atrlog --subsystem "
                        "20|21|22", self.path, self.path)
        return projection(crs) if crs else None

    def _items(self) -> Iterator[XtfPing | XtfNav | XtfSerial]:
        return iter_jsf_items(self.path, self.stats, subsystem=self.subsystem, positions=self.positions)


def iter_jsf_records(path: str | os.PathLike[str], *, tile_pings: int = DEFAULT_TILE_PINGS,
                     mission: str | None = None, leg: int | None = None, seq0: int | None = None,
                     sensor: SensorSettings | None = None, altitude: str = "auto", subsystem: int | None = None,
                     crs: str = "", stats: XtfStats | None = None, frequency: str | float = "high") -> Iterator[LogRecord]:
    """Stream a JSF file as ``.atrlog`` records (see :class:`JsfReader`); ``stats`` as in
    :func:`~.xtf.iter_xtf_records`."""
    reader = JsfReader(path, tile_pings=tile_pings, mission=mission, leg=leg, seq0=seq0, sensor=sensor,
                       altitude=altitude, subsystem=subsystem, crs=crs, frequency=frequency)
    if stats is not None:
        stats.path = reader.stats.path
        reader.stats = stats
    return iter(reader)

