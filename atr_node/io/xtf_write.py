"""Write sonar tiles as an XTF file: the file header and one sonar ping packet per ping.

The structures are pyxtf's ctypes classes serialised with ``bytes(struct)``; the layout is::

    XTFFileHeader (1024 bytes): NavUnits 3 (lat/lon), or 0 (projected metres) when the
        writer is given a projected ``crs``, 2 sonar channels,
        ChanInfo[0] port (TypeOfChannel 1), ChanInfo[1] starboard (2): BytesPerSample and
        SampleFormat from the first tile's wire dtype (uint16: 2/3, uint8: 1/8, float32: 4/5),
        CorrectionFlags 1 (slant range) or 2 (ground range), Frequency in kHz;
        NoteString "atr-node mission=<name> leg=<n> seq=<first seq>" (read back by the reader)
    per ping: XTFPingHeader (256 bytes): UTC time to the hundredth of a second, PingNumber,
        SoundVelocity 750 (one way), Sensor/Ship X,Y = lon, lat (or easting, northing in
        the ``crs``: XTF does not record which projection), SensorHeading = ShipGyro,
        SensorPrimaryAltitude, SensorSpeed (knots, = dx / median ping interval)
      then per channel XTFPingChanHeader (64 bytes): ChannelNumber, SlantRange (= GroundRange
        for ground-range tiles) = dr x samples, TimeDelay = (range0 - dr/2) / 750,
        TimeDuration, SecondsPerPing, Frequency and BandWidth (kHz), NumSamples; samples
        (port far range first, as XTF stores it).

Port and starboard tiles with the same ping times go into the same ping packets; a tile
without its other side is written alone (one channel per ping). What an XTF file cannot hold
is lost and said in the docs: ping times are rounded to 0.01 s, depth and NMEA or CAN records
are not written (counted in ``skipped``), float values of the ping header are float32.
"""

from __future__ import annotations

import ctypes
import os
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Iterable

import numpy as np
from pyxtf.xtf_ctypes import XTFFileHeader, XTFPingChanHeader, XTFPingHeader

from ..errors import ConfigError
from .crs import projection
from ..records.tile import Tile
from .atrlog import LogRecord
from .ping_writer import PairedPingWriter
from .xtf_packets import NOTE_PREFIX

SOUND_VELOCITY_ONE_WAY = 750.0
FORMATS = {"uint16": (2, 3, np.dtype("<u2")), "uint8": (1, 8, np.dtype("u1")), "float32": (4, 5, np.dtype("<f4"))}
"""wire dtype -> (BytesPerSample, SampleFormat, sample dtype)."""
CHANNEL = {"port": 0, "stbd": 1}


@dataclass
class XtfWriteStats:
    """What a conversion to XTF wrote and left out."""

    pings: int = 0
    tiles: int = 0
    unpaired_tiles: int = 0
    rejected: list[str] = field(default_factory=list)
    """Tile maps that broke ICD section 1 (with the reason); not written."""
    skipped: Counter = field(default_factory=Counter)
    """Records XTF cannot hold, by link."""


def _samples(tile: Tile, dtype: np.dtype) -> np.ndarray:
    """(rows, cols) samples in the file's type; NaN -> 0 for integer types (ICD no data)."""
    if dtype.kind == "f":
        return np.ascontiguousarray(tile.pixels, dtype=dtype)
    info = np.iinfo(dtype)
    return np.clip(np.rint(np.nan_to_num(tile.pixels, nan=0.0)), info.min, info.max).astype(dtype)


class XtfWriter(PairedPingWriter):
    """Write tiles to an XTF file; use as a context manager or call :meth:`close`.

    Parameters
    ----------
    path
        The file to write (overwritten).
    crs
        "" (default): positions in degrees (``NavUnits`` 3). A projected CRS (e.g.
        ``EPSG:32619``): positions as easting and northing in it (``NavUnits`` 0), as some
        recorders write them; reading such a file back needs the same ``--crs``.
    """

    def __init__(self, path: str | os.PathLike[str], *, crs: str = "") -> None:
        self.projection = projection(crs) if crs else None
        if self.projection is not None and not self.projection.projected:
            raise ConfigError(f"--crs {crs!r} is geographic: an XTF file in degrees says so (NavUnits 3); "
                              "write it without --crs, or give a projected CRS")
        self.path = Path(path)
        self._fh = open(self.path, "wb")
        self._pending: Tile | None = None
        self._format: tuple[int, int, np.dtype] | None = None
        self._ping_number = 0
        self.stats = XtfWriteStats()

    # -- hooks of PairedPingWriter -------------------------------------------------------------
    def _before_tile(self, tile: Tile) -> None:
        if self._format is None:
            self._write_header(tile)

    def _before_close(self) -> None:
        if self._format is None:
            self._fh.write(bytes(self._file_header(None)))

    # -- packets -----------------------------------------------------------------------------
    def _file_header(self, tile: Tile | None) -> XTFFileHeader:
        h = XTFFileHeader()
        h.RecordingProgramName = b"atr-node"
        h.RecordingProgramVersion = b"1"
        h.ThisFileName = self.path.name.encode("ascii", "replace")[:63]
        h.NavUnits = 3 if self.projection is None else 0
        if tile is None:
            return h
        note = f"{NOTE_PREFIX}mission={tile.mission} leg={tile.leg} seq={tile.seq}"
        h.NoteString = note.encode("ascii", "replace")[:63]
        h.NumberOfSonarChannels = 2
        nbytes, fmt, _ = self._format
        for side, name in (("port", b"PORT"), ("stbd", b"STARBOARD")):
            ci = h.ChanInfo[CHANNEL[side]]
            ci.TypeOfChannel = 1 if side == "port" else 2
            ci.SubChannelNumber = CHANNEL[side]
            ci.CorrectionFlags = 1 if tile.slant else 2
            ci.UniPolar = 1
            ci.BytesPerSample = nbytes
            ci.SampleFormat = fmt
            ci.ChannelName = name
            ci.BeamsPerArray = 1
            ci.Reserved = 0
            if tile.sensor is not None:
                ci.Frequency = tile.sensor.frequency_hz / 1e3
        return h

    def _write_header(self, tile: Tile) -> None:
        self._format = FORMATS[tile.wire_dtype]
        self._fh.write(bytes(self._file_header(tile)))

    def _write_pings(self, tiles: dict[str, Tile]) -> None:
        sides = [s for s in ("port", "stbd") if s in tiles]
        first = tiles[sides[0]]
        _, _, dtype = self._format
        data = {s: _samples(tiles[s], dtype) for s in sides}
        dt, speed_kn = self._interval_and_speed(first)
        x = y = None
        if first.nav is not None:
            # XTF X is longitude or easting, Y latitude or northing
            x, y = first.nav.lon_deg, first.nav.lat_deg
            if self.projection is not None:
                x, y = self.projection.from_latlon(first.nav.lat_deg, first.nav.lon_deg)
        chans = {}
        for s in sides:
            t = tiles[s]
            c = XTFPingChanHeader()
            c.ChannelNumber = CHANNEL[s]
            c.DownsampleMethod = 2
            c.SlantRange = t.dr_m * t.cols
            if not t.slant:
                c.GroundRange = t.dr_m * t.cols
            c.TimeDelay = (t.range0_m - 0.5 * t.dr_m) / SOUND_VELOCITY_ONE_WAY
            c.TimeDuration = c.SlantRange / SOUND_VELOCITY_ONE_WAY
            c.SecondsPerPing = dt
            if t.sensor is not None:
                c.Frequency = min(int(round(t.sensor.frequency_hz / 1e3)), 65535)
                c.BandWidth = min(int(round(t.sensor.bandwidth_hz / 1e3)), 65535)
            c.NumSamples = t.cols
            chans[s] = c
        for i in range(first.rows):
            p = XTFPingHeader()
            cs = round(float(first.ping_time[i]) * 100.0)
            when = datetime.fromtimestamp(cs // 100, tz=timezone.utc)
            p.Year, p.Month, p.Day = when.year, when.month, when.day
            p.Hour, p.Minute, p.Second, p.HSeconds = when.hour, when.minute, when.second, cs % 100
            p.JulianDay = when.timetuple().tm_yday
            p.PingNumber = self._ping_number
            p.SoundVelocity = SOUND_VELOCITY_ONE_WAY
            p.SensorSpeed = speed_kn
            if first.nav is not None:
                nav = first.nav
                p.SensorYcoordinate = p.ShipYcoordinate = y[i]
                p.SensorXcoordinate = p.ShipXcoordinate = x[i]
                p.SensorHeading = p.ShipGyro = nav.heading_deg[i]
                p.SensorPrimaryAltitude = nav.altitude_m[i]
            p.NumChansToFollow = len(sides)
            parts = [b""]
            for s in sides:
                row = data[s][i][::-1] if s == "port" else data[s][i]  # XTF port: far range first
                parts.append(bytes(chans[s]) + np.ascontiguousarray(row).tobytes())
            body = b"".join(parts)
            p.NumBytesThisRecord = ctypes.sizeof(XTFPingHeader) + len(body)
            self._fh.write(bytes(p) + body)
            self._ping_number += 1
        self.stats.pings += first.rows


def write_xtf(path: str | os.PathLike[str], records: Iterable[LogRecord], *, crs: str = "") -> XtfWriteStats:
    """Write the sonar records of a record stream (e.g. an .atrlog) as an XTF file (positions
    in ``crs`` when given, see :class:`XtfWriter`)."""
    with XtfWriter(path, crs=crs) as w:
        for rec in records:
            w.write_record(rec)
    return w.stats
