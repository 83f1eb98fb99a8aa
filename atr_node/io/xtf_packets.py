"""XTF packets to pings and navigation fixes (eXtended Triton Format, rev. 35 and later).

The byte layouts are pyxtf's ctypes structures (the maintained parser); this module owns the
framing, so that a packet type nobody knows is skipped by its length and counted instead of
being built, warned about or allowed to stop the file. An XTF file is::

    file header (1024 bytes: XTFFileHeader, 6 XTFChanInfo of 128 bytes)
    packets: each starts with XTFPacketStart (14 bytes)
        MagicNumber 0xFACE (uint16), HeaderType (uint8), SubChannelNumber (uint8),
        NumChansToFollow (uint16), Reserved (2 x uint16), NumBytesThisRecord (uint32)
    and is NumBytesThisRecord bytes long, padding included.

What is turned into values:

========================== ===============================================================
HeaderType                 values
========================== ===============================================================
0 sonar                    one :class:`XtfPing`: per side (port/stbd channel) the samples
                           from the nadir outwards (port is stored far-to-near and is
                           reversed), slant range and sample spacing; time, position,
                           heading, altitude, depth, speed and fix time from the ping header
42 navigation, 107 raw nav position (and time); 42 also altitude above the datum
3 attitude                 heading (``Heading`` field)
6 raw serial               the text lines a serial port logged (NMEA sentences, as recorded)
23 gyro, 84 source gyro    heading (``Gyro`` field)
========================== ===============================================================

Everything else is skipped and counted under its pyxtf type name (``unknown_<n>`` for types
pyxtf does not name). A packet that cannot be parsed is skipped and counted as ``bad`` and,
by kind, in ``quirks`` (``zero date (attitude)``: older recorders leave the date of attitude
packets 0; ``bad date``, ``short packet``, ``unparsable``), with the first of each kind kept
as an example: a file with thousands of them gives one line, not thousands. A packet whose
framing is broken (wrong magic number, length past the end of the file) ends the read with a
warning that names the byte offset, keeping everything before it.

Positions (:class:`XtfPositions`): ``NavUnits`` 3 in the file header says degrees (Y
latitude, X longitude); 0 says projected metres (Y northing, X easting) in a projection the
file does not name, so the reader needs it (``--crs``, :mod:`.crs`) and refuses the file at
its header without it. No other value is defined by the XTF specification (rev. 35-40); such a
file needs ``--crs`` too (``EPSG:4326`` if its positions are degrees). (0, 0) is "no fix".
"""

from __future__ import annotations

import ctypes
import io
import logging
import math
import os
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any, BinaryIO, Iterator

import numpy as np
from pyxtf.enumerations import XTFHeaderType
from pyxtf.xtf_ctypes import (XTFAttitudeData, XTFFileHeader, XTFHeaderGyro, XTFHeaderNavigation,
                              XTFPacketStart, XTFPingHeader, XTFPosRawNavigation, XTFRawSerialHeader)

from ..errors import LogFormatError
from .crs import EXAMPLE_CRS, Projection, projection
from .xtf_stats import XtfStats

log = logging.getLogger(__name__)

MAGIC = 0xFACE
FILE_HEADER_BYTES = ctypes.sizeof(XTFFileHeader)
PACKET_START_BYTES = ctypes.sizeof(XTFPacketStart)
KNOT_M_S = 1852.0 / 3600.0
NAV_UNITS_METRES, NAV_UNITS_LATLON = 0, 3  # XTFFileHeader.NavUnits: the only two the specification defines
CHANNEL_SIDES = {1: "port", 2: "stbd"}  # XTFChanInfo.TypeOfChannel
SONAR, RAW_SERIAL, NAVIGATION, POS_RAW_NAVIGATION = 0, 6, 42, 107
ATTITUDE, GYRO, SOURCETIME_GYRO = 3, 23, 84


def type_name(header_type: int) -> str:
    """pyxtf's name of an XTF packet type, or ``unknown_<n>``."""
    try:
        return XTFHeaderType(header_type).name
    except ValueError:
        return f"unknown_{header_type}"


@dataclass(frozen=True)
class XtfChannel:
    """One side of one ping, samples from the nadir outwards (column 0 nearest the sonar)."""

    side: str
    samples: np.ndarray
    """(n,) in the file's dtype."""
    range0_m: float
    """Slant range of sample 0's centre."""
    dr_m: float
    """Range spacing: slant (or ground) range / number of samples."""
    slant: bool
    """False when the channel says ground range (XTFChanInfo.CorrectionFlags 2)."""
    frequency_hz: float
    bandwidth_hz: float


@dataclass(frozen=True)
class XtfNav:
    """Navigation of a ping or of a navigation packet; NaN = not in the packet."""

    t: float
    """UNIX seconds of the packet (ping time for pings)."""
    lat_deg: float = math.nan
    lon_deg: float = math.nan
    heading_deg: float = math.nan
    altitude_m: float = math.nan
    """Above the seabed (sonar pings: SensorPrimaryAltitude)."""
    depth_m: float = math.nan
    speed_m_s: float = math.nan
    fix_t: float = math.nan
    """UNIX seconds of the position fix, when the packet says (ping FixTime fields)."""
    height_m: float = math.nan
    """Antenna height above the datum (navigation packets)."""
    source: str = ""
    offset: int = 0
    """Byte offset of the packet in the file."""

    @property
    def has_position(self) -> bool:
        return math.isfinite(self.lat_deg) and math.isfinite(self.lon_deg)


@dataclass(frozen=True)
class XtfSerial:
    """Text a serial port logged into the file (raw serial packet), split into lines."""

    t: float
    lines: tuple[bytes, ...]
    offset: int = 0


@dataclass(frozen=True)
class XtfPing:
    """One sonar ping: navigation and the port and starboard channels present."""

    nav: XtfNav
    channels: dict
    """side -> :class:`XtfChannel`."""
    ping_number: int
    offset: int
    """Byte offset of the packet in the file."""


NOTE_PREFIX = "atr-node "


def note_fields(note: bytes) -> dict[str, str]:
    """``mission``, ``leg``, ``seq`` from a file header NoteString written by :mod:`.xtf_write`."""
    text = note.decode("ascii", "replace")
    if not text.startswith(NOTE_PREFIX):
        return {}
    return dict(kv.split("=", 1) for kv in text[len(NOTE_PREFIX):].split() if "=" in kv)


def read_file_header(fh: BinaryIO, path: str) -> XTFFileHeader:
    """The XTF file header, checked (format byte, channel count)."""
    raw = fh.read(FILE_HEADER_BYTES)
    if len(raw) < FILE_HEADER_BYTES:
        raise LogFormatError(f"not an XTF file: {len(raw)} bytes, a file header is {FILE_HEADER_BYTES}",
                             path=path, offset=0)
    header = XTFFileHeader.create_from_buffer(raw)
    if header.FileFormat != 0x7B:
        raise LogFormatError(f"not an XTF file: format byte {header.FileFormat:#x}, expected 0x7b", path=path, offset=0)
    if header.channel_count() > 6:
        raise LogFormatError(f"{header.channel_count()} channels: this reader handles at most 6 "
                             "(one 1024-byte file header)", path=path, offset=0)
    return header


class PacketQuirk(ValueError):
    """A packet that cannot be used for a reason older or odd writers share (a zero date):
    counted by ``kind`` in :attr:`XtfStats.quirks` rather than reported packet by packet."""

    def __init__(self, kind: str, message: str) -> None:
        self.kind = kind
        super().__init__(message)


def _utc(year: int, month: int, day: int, hour: int, minute: int, second: int) -> float:
    """UNIX seconds of a UTC calendar time; :class:`PacketQuirk` when the fields are not a time."""
    if year == 0 and month == 0 and day == 0:
        # older recorders leave the date of attitude packets unset (time of day only)
        raise PacketQuirk("zero date", "date fields all 0 (time of day only)")
    try:
        return datetime(year, month, day, hour, minute, second, tzinfo=timezone.utc).timestamp()
    except ValueError as exc:
        raise PacketQuirk("bad date", f"date {year:04d}-{month:02d}-{day:02d} {hour:02d}:{minute:02d}:"
                                      f"{second:02d} is not a time ({exc})") from None


def fix_time(t: float, seconds_of_day: float) -> float:
    """UNIX time of a position fix stamped with its time of day only, in the day of the ping
    time ``t``; a fix stamped before midnight of a ping after it is in the day before (a fix is
    never 12 h after its ping)."""
    fix_t = t - (t % 86400.0) + seconds_of_day
    return fix_t - 86400.0 if fix_t - t > 43200.0 else fix_t


def _finite_or_nan(x: float) -> float:
    x = float(x)
    return x if math.isfinite(x) else math.nan


class XtfPositions:
    """How the coordinate pairs of one XTF file become lat/lon: its ``NavUnits`` and, for
    positions that are not marked as degrees, the CRS the user gave (:mod:`.crs`).

    Build it with :func:`file_positions`, which refuses a file whose positions cannot be
    read without a CRS.
    """

    def __init__(self, nav_units: int, projection: Projection | None = None) -> None:
        self.nav_units = int(nav_units)
        self.projection = projection
        self.usable = projection is not None or self.nav_units == NAV_UNITS_LATLON

    def describe(self) -> str:
        """One phrase for the summary: what the positions are and how they were read."""
        if self.projection is None:
            return "lat/lon (NavUnits 3)" if self.usable else f"not used (NavUnits {self.nav_units})"
        what = "projected metres" if self.nav_units == NAV_UNITS_METRES else f"NavUnits {self.nav_units}"
        return f"{what} in {self.projection.crs} ({self.projection.name}), converted to WGS 84 lat/lon"

    def latlon(self, y: float, x: float) -> tuple[float, float]:
        """(lat, lon) of an XTF coordinate pair (Y northing or latitude, X easting or
        longitude); NaN when not set ((0, 0): a recorder's "no fix") or not a position."""
        if not self.usable or (y == 0.0 and x == 0.0) or not (math.isfinite(y) and math.isfinite(x)):
            return math.nan, math.nan
        if self.projection is not None:
            return self.projection.to_latlon(float(x), float(y))
        if not (abs(y) <= 90.0 and abs(x) <= 180.0):
            return math.nan, math.nan
        return float(y), float(x)


def file_positions(header: XTFFileHeader, path: str, crs: str = "", *, option: str = "--crs") -> XtfPositions:
    """The :class:`XtfPositions` of a file from its header and the user's CRS (``""``: none).

    ``NavUnits`` 3 (degrees) needs no CRS; one given is ignored with a warning. ``NavUnits``
    0 (projected metres) and values the XTF specification does not define need one.

    Raises
    ------
    LogFormatError
        Positions that are not degrees and no CRS: one line naming ``--crs``.
    ConfigError
        A CRS pyproj does not know, or not a horizontal one (:func:`.crs.projection`).
    """
    units = int(header.NavUnits)
    if units == NAV_UNITS_LATLON:
        if crs:
            log.warning("%s: positions are degrees (XTF NavUnits 3): %s %s ignored", path, option, crs)
        return XtfPositions(units)
    if not crs:
        what = ("positions are projected metres (XTF NavUnits 0)" if units == NAV_UNITS_METRES else
                f"NavUnits {units} is not an XTF value (0 projected metres, 3 degrees), so what the "
                "positions are is unknown")
        raise LogFormatError(f"{what}: give their CRS with --crs (or the recording.crs key), e.g. "
                             f"--crs {EXAMPLE_CRS}" + ("" if units == NAV_UNITS_METRES else
                                                       " for UTM 10N metres, --crs EPSG:4326 for degrees"),
                             path=path)
    return XtfPositions(units, projection(crs, option=option))


def read_positions(path: str | os.PathLike[str], crs: str = "", *, option: str = "--crs",
                   frequency: str | float = "high") -> XtfPositions:
    """:func:`file_positions` of a file, reading its header only (so a command fails at once),
    and :func:`check_frequency` of ``frequency`` on the same header."""
    path = str(path)
    try:
        with open(path, "rb") as fh:
            header = read_file_header(fh, path)
    except OSError as exc:
        raise LogFormatError(f"cannot read: {exc.strerror or exc}", path=path) from None
    check_frequency(header, frequency, path)
    return file_positions(header, path, crs, option=option)


def parse_ping(p: XTFPingHeader, header: XTFFileHeader, offset: int, stats: XtfStats,
               positions: XtfPositions | None = None, frequency: str | float = "high") -> XtfPing | None:
    """A sonar ping packet as :class:`XtfPing`, or None (counted in ``stats``); positions read
    as ``positions`` says (default: degrees when the header says so, else none); of a side with
    more than one side-scan channel (a dual-frequency sonar) the one :func:`pick_channel` picks
    by ``frequency`` (the others counted in ``stats.channels_unused``)."""
    positions = positions or XtfPositions(header.NavUnits)
    try:
        t = _utc(p.Year, p.Month, p.Day, p.Hour, p.Minute, p.Second) + p.HSeconds / 100.0
    except ValueError:
        stats.pings_dropped["bad_time"] += 1
        return None
    fix_t = math.nan
    if p.FixTimeHour or p.FixTimeMinute or p.FixTimeSecond or p.FixTimeHsecond:
        fix_t = fix_time(t, p.FixTimeHour * 3600 + p.FixTimeMinute * 60 + p.FixTimeSecond + p.FixTimeHsecond / 100.0)
    lat, lon = positions.latlon(p.SensorYcoordinate, p.SensorXcoordinate)
    if math.isnan(lat):
        lat, lon = positions.latlon(p.ShipYcoordinate, p.ShipXcoordinate)
    has_pos = not math.isnan(lat)
    nav = XtfNav(t=t, lat_deg=lat, lon_deg=lon,
                 heading_deg=_finite_or_nan(p.SensorHeading) % 360.0 if has_pos else math.nan,
                 altitude_m=_finite_or_nan(p.SensorPrimaryAltitude) if has_pos else math.nan,
                 depth_m=_finite_or_nan(p.SensorDepth) if has_pos else math.nan,
                 speed_m_s=_finite_or_nan(p.SensorSpeed) * KNOT_M_S if has_pos else math.nan,
                 fix_t=fix_t, source="xtf:sonar")
    sv = float(p.SoundVelocity)
    sv = 750.0 if not (math.isfinite(sv) and sv > 0) else (sv / 2.0 if sv > 1000.0 else sv)  # one-way speed
    found: dict[str, list[tuple[float, Any, np.ndarray, Any]]] = {}
    for ch, data in zip(p.ping_chan_headers, p.data):
        info = header.ChanInfo[ch.ChannelNumber] if ch.ChannelNumber < 6 else None
        side = CHANNEL_SIDES.get(info.TypeOfChannel) if info is not None else None
        if side is None:
            stats.skipped[f"channel_type_{info.TypeOfChannel if info is not None else '?'}"] += 1
            continue
        freq = float(ch.Frequency) * 1e3 if ch.Frequency else float(info.Frequency) * 1e3
        found.setdefault(side, []).append((freq if math.isfinite(freq) and freq > 0 else 0.0, ch, data, info))
    channels: dict[str, XtfChannel] = {}
    for side, cands in found.items():
        k = pick_channel([c[0] for c in cands], frequency)
        for j, c in enumerate(cands):
            if j != k:
                stats.channels_unused[c[0]] += 1
        if k is None:
            continue
        freq, ch, data, info = cands[k]  # only the channel read is looked into
        n = int(data.size)
        is_slant = info.CorrectionFlags != 2
        slant = float(ch.SlantRange if is_slant or not ch.GroundRange > 0 else ch.GroundRange)
        if not (math.isfinite(slant) and slant > 0):
            slant = float(ch.TimeDuration) * sv
        if n == 0 or not (math.isfinite(slant) and slant > 0):
            stats.pings_dropped["no_range"] += 1
            return None
        samples = data  # dtype from SampleFormat / BytesPerSample (pyxtf)
        if side == "port":  # stored far range first: column 0 must be nearest the sonar
            samples = samples[::-1]
        dr = slant / n
        stats.channels_used[freq] += 1
        channels[side] = XtfChannel(side=side, samples=np.ascontiguousarray(samples),
                                    range0_m=float(ch.TimeDelay) * sv + 0.5 * dr, dr_m=dr, slant=is_slant,
                                    frequency_hz=freq, bandwidth_hz=float(ch.BandWidth))
    if not channels:
        stats.pings_dropped["no_side_scan_channel" if not found else f"no_channel_at_{frequency:g}_kHz"] += 1
        return None
    return XtfPing(nav=nav, channels=channels, ping_number=int(p.PingNumber), offset=offset)


# -- which side-scan channel of a side (dual-frequency sonars) ---------------------------------
FREQUENCY_TOLERANCE = 0.1
"""A channel is at a frequency asked in kHz when that is within this share of the channel's."""


def pick_channel(freqs_hz: list[float], frequency: str | float = "high") -> int | None:
    """Which channel of one side to read: an index into the frequencies (Hz, 0 = unknown) of
    the side's channels of one ping, in channel order.

    ``high`` / ``low``: the highest / lowest known frequency (the first channel on a tie);
    a number: the nearest channel if that many kHz is within :data:`FREQUENCY_TOLERANCE` of its
    frequency, else None. Channels whose frequency is unknown (0) are read only
    where none of the side's is known: then the first, whatever was asked (nothing to choose by).
    """
    known = [i for i, f in enumerate(freqs_hz) if f > 0]
    if not known:
        return 0 if freqs_hz else None
    if frequency == "high":
        return max(known, key=lambda i: freqs_hz[i])  # max/min keep the first of equals
    if frequency == "low":
        return min(known, key=lambda i: freqs_hz[i])
    want = float(frequency) * 1e3
    best = min(known, key=lambda i: abs(freqs_hz[i] - want))
    return best if _near(freqs_hz[best], want) else None


def _near(channel: float, asked: float) -> bool:
    """A frequency asked for is a channel's when within :data:`FREQUENCY_TOLERANCE` of it (any unit)."""
    return abs(channel - asked) <= FREQUENCY_TOLERANCE * channel


def side_scan_frequencies_khz(header: XTFFileHeader) -> list[float]:
    """The side-scan channel frequencies the file header lists (kHz, known ones, sorted)."""
    n = min(int(header.NumberOfSonarChannels), 6)
    return sorted({float(header.ChanInfo[i].Frequency) for i in range(n)
                   if header.ChanInfo[i].TypeOfChannel in CHANNEL_SIDES and header.ChanInfo[i].Frequency > 0})


def check_frequency(header: XTFFileHeader, frequency: str | float, path: str, option: str = "--frequency") -> None:
    """Fail at once (:class:`LogFormatError`, one line naming ``option``) when a frequency in
    kHz is asked for and the file header lists side-scan frequencies, none of them near it."""
    if isinstance(frequency, str):
        return
    have = side_scan_frequencies_khz(header)
    if have and not any(_near(f, frequency) for f in have):
        raise LogFormatError(f"no side-scan channel at {frequency:g} kHz ({option}): the file's are at "
                             f"{', '.join(f'{f:g}' for f in have)} kHz; give one of them, high or low", path=path)


def parse_nav_packet(kind: int, raw: bytes, header: XTFFileHeader, offset: int = 0,
                     positions: XtfPositions | None = None) -> XtfNav:
    """A navigation, attitude or gyro packet as :class:`XtfNav`; :class:`PacketQuirk` when its
    time is not a time."""
    if kind in (NAVIGATION, POS_RAW_NAVIGATION):
        p = (XTFHeaderNavigation if kind == NAVIGATION else XTFPosRawNavigation).from_buffer_copy(raw[:ctypes.sizeof(
            XTFHeaderNavigation if kind == NAVIGATION else XTFPosRawNavigation)])
        # Microsecond: 0-999999 in packet 42, but 0-9999 (tenths of a millisecond) in packet 107
        tick = 1e-6 if kind == NAVIGATION else 1e-4
        t = _utc(p.Year, p.Month, p.Day, p.Hour, p.Minute, p.Second) + p.Microsecond * tick
        lat, lon = (positions or XtfPositions(header.NavUnits)).latlon(p.RawYcoordinate, p.RawXcoordinate)
        return XtfNav(t=t, lat_deg=lat, lon_deg=lon, height_m=_finite_or_nan(p.RawAltitude),
                      source=f"xtf:{type_name(kind)}", offset=offset)
    if kind == ATTITUDE:
        p = XTFAttitudeData.from_buffer_copy(raw[:ctypes.sizeof(XTFAttitudeData)])
        if p.SourceEpoch:
            t = float(p.SourceEpoch) + p.EpochMicroseconds * 1e-6
        else:
            t = _utc(p.Year, p.Month, p.Day, p.Hour, p.Minute, p.Second) + p.Millisecond * 1e-3
        return XtfNav(t=t, heading_deg=_finite_or_nan(p.Heading) % 360.0, source="xtf:attitude", offset=offset)
    p = XTFHeaderGyro.from_buffer_copy(raw[:ctypes.sizeof(XTFHeaderGyro)])
    t = float(p.SourceEpoch) + p.Microsecond * 1e-6 if p.SourceEpoch else \
        _utc(p.Year, p.Month, p.Day, p.Hour, p.Minute, p.Second) + p.Microsecond * 1e-6
    return XtfNav(t=t, heading_deg=_finite_or_nan(p.Gyro) % 360.0, source=f"xtf:{type_name(kind)}", offset=offset)


def parse_raw_serial(raw: bytes, offset: int = 0) -> XtfSerial:
    """A raw serial packet: its time (hundredths) and the non-empty lines of its text."""
    p = XTFRawSerialHeader.from_buffer_copy(raw[:ctypes.sizeof(XTFRawSerialHeader)])
    t = _utc(p.Year, p.Month, p.Day, p.Hour, p.Minute, p.Second) + p.HSeconds / 100.0
    text = raw[ctypes.sizeof(XTFRawSerialHeader):ctypes.sizeof(XTFRawSerialHeader) + p.StringSize]
    lines = tuple(line.strip(b"\x00 ") for line in text.replace(b"\r", b"\n").split(b"\n"))
    return XtfSerial(t=t, lines=tuple(line for line in lines if line), offset=offset)


NAV_KINDS = (NAVIGATION, POS_RAW_NAVIGATION, ATTITUDE, GYRO, SOURCETIME_GYRO)
MIN_BYTES = {SONAR: ctypes.sizeof(XTFPingHeader), NAVIGATION: ctypes.sizeof(XTFHeaderNavigation),
             POS_RAW_NAVIGATION: ctypes.sizeof(XTFPosRawNavigation), ATTITUDE: ctypes.sizeof(XTFAttitudeData),
             GYRO: ctypes.sizeof(XTFHeaderGyro), SOURCETIME_GYRO: ctypes.sizeof(XTFHeaderGyro),
             RAW_SERIAL: ctypes.sizeof(XTFRawSerialHeader)}


def iter_xtf_items(path: str | os.PathLike[str], stats: XtfStats, header_out: list | None = None, *,
                   crs: str = "", positions: XtfPositions | None = None,
                   frequency: str | float = "high") -> Iterator[XtfPing | XtfNav | XtfSerial]:
    """Stream the pings, navigation fixes and serial text of an XTF file, in file order.

    Parameters
    ----------
    path
        The XTF file.
    stats
        Filled as the file streams (packets by type, skipped, bad, truncated, errors).
    header_out
        If given, the file header (``XTFFileHeader``) is appended to it before the first item.
    crs
        CRS of positions that are not degrees (:func:`file_positions`); "" = none.
    positions
        How to read positions, already decided (:func:`read_positions`); overrides ``crs``.
    frequency
        Of a side with more than one side-scan channel, which to read (:func:`pick_channel`):
        ``high`` (default), ``low`` or a frequency in kHz.

    Raises
    ------
    LogFormatError
        The file is not XTF (file header), or its positions need a CRS and none was given.
        Damage further in ends the stream with a warning.
    ConfigError
        ``crs`` is not a CRS pyproj knows.

    Packets that cannot be used (a zero date, too short, unparsable) are counted by kind in
    ``stats.quirks``, the first of each kind kept as an example in ``stats.errors``.
    """
    path = str(path)
    stats.path = stats.path or path
    size = os.path.getsize(path)
    with open(path, "rb") as fh:
        header = read_file_header(fh, path)
        positions = positions or file_positions(header, path, crs)
        stats.positions = positions.describe()
        if header_out is not None:
            header_out.append(header)
        offset = FILE_HEADER_BYTES
        while offset < size:
            start = fh.read(PACKET_START_BYTES)
            why = None
            if len(start) < PACKET_START_BYTES:
                why = f"{size - offset} bytes left, a packet header is {PACKET_START_BYTES}"
            else:
                ps = XTFPacketStart.from_buffer_copy(start)
                if ps.MagicNumber != MAGIC:
                    why = f"packet magic number {ps.MagicNumber:#06x}, expected 0xface"
                elif ps.NumBytesThisRecord < PACKET_START_BYTES:
                    why = f"packet length {ps.NumBytesThisRecord} shorter than its header"
                elif offset + ps.NumBytesThisRecord > size:
                    why = f"packet of {ps.NumBytesThisRecord} bytes runs past the end of the file ({size} bytes)"
            if why is not None:
                stats.truncated = True
                msg = f"{path}: at byte {offset}: {why}; the rest of the file is ignored"
                log.warning(msg)
                stats.errors.append(msg)
                return
            kind = int(ps.HeaderType)
            name = type_name(kind)
            stats.packets[name] += 1
            raw = start + fh.read(ps.NumBytesThisRecord - PACKET_START_BYTES)
            here, offset = offset, offset + ps.NumBytesThisRecord
            if kind not in MIN_BYTES:
                stats.skipped[name] += 1
                continue
            if len(raw) < MIN_BYTES[kind]:
                stats.bad += 1
                stats.quirk(f"short packet ({name})", f"{path}: {name} packet at byte {here}: {len(raw)} bytes, "
                                                      f"its header alone is {MIN_BYTES[kind]}")
                continue
            try:
                if kind == SONAR:
                    item = parse_ping(XTFPingHeader.create_from_buffer(io.BytesIO(raw), file_header=header),
                                      header, here, stats, positions, frequency)
                elif kind == RAW_SERIAL:
                    item = parse_raw_serial(raw, here)
                else:
                    item = parse_nav_packet(kind, raw, header, here, positions)
            except (RuntimeError, ValueError, IndexError, OverflowError) as exc:
                stats.bad += 1
                why = exc.kind if isinstance(exc, PacketQuirk) else "unparsable"
                stats.quirk(f"{why} ({name})", f"{path}: {name} packet at byte {here}: {exc}")
                continue
            if item is not None:
                yield item
