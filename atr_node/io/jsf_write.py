"""Write sonar tiles as an EdgeTech JSF file (for tests and for handing tiles to JSF tools).

Per ping, one message 80 per side (channel 0 port, 1 starboard) of one side-scan subsystem
(default 21, high frequency), with the 240-byte header of :data:`.jsf.PING_FIELDS` (JSF rev
1.20 offsets, see :mod:`.jsf`) filled as follows:

- time: seconds since 1970 at 0 and ``ms today`` at 200 (1 ms resolution), CPU time year,
  day, hour, minute, second at 156-165, time basis 3, position fix time = the ping's second;
- geometry: sound speed 1500 m/s (float32 at 148, validity bit 14), sample interval
  round(2 dr / c) ns, start depth round(range0 / dr - 1/2) samples (so ``range0_m`` comes back
  to within dr/2 and ``dr_m`` to within 1 ns of travel time);
- samples: data format 0 (envelope, uint16) or 1 (analytic, int16 I/Q at a range-dependent
  phase), scaled by 2^N with the weighting factor N (int16 at 168) the largest that keeps the
  ping's brightest sample in range: integer pixels up to 65535 come back exactly; no data
  (NaN) is written as 0;
- navigation (when the tile has ``nav``): coordinate units 2 (minutes of arc x 10000, so
  1.7e-6 deg), heading in 1/100 deg, altitude in mm, speed = dx / median ping interval in
  1/100 knot (tenths at 194, hundredths in LSB2); validity flags for what is written;
- frequency: the sensor's frequency -/+ half its bandwidth, in 10 Hz (MSB bits for > 655 kHz).

NMEA records become message 2002; :meth:`JsfWriter.write_message` writes any message (tests
use it for pitch/roll, situation and unknown types). A tile without its other side is
written alone (one channel per ping).
"""

from __future__ import annotations

import math
import os
import struct
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ..records.tile import Tile
from .atrlog import LogRecord
from .ping_writer import PairedPingWriter
from .jsf import (ANALYTIC, ENVELOPE, HEADER, NMEA, PING_FIELDS, SONAR, START_MARKER, VALID_ALTITUDE,
                  VALID_HEADING, VALID_POSITION, VALID_SPEED)

SOUND_SPEED_M_S = 1500.0
VALID_SOUND_SPEED = 1 << 14
CHANNEL = {"port": 0, "stbd": 1}
FORMATS = {"envelope": ENVELOPE, "analytic": ANALYTIC}


@dataclass
class JsfWriteStats:
    """What a conversion to JSF wrote and left out."""

    pings: int = 0
    tiles: int = 0
    messages: Counter = field(default_factory=Counter)
    unpaired_tiles: int = 0
    rejected: list[str] = field(default_factory=list)
    skipped: Counter = field(default_factory=Counter)
    """Records JSF cannot hold here, by link."""


def message(kind: int, payload: bytes, *, subsystem: int = 0, channel: int = 0, version: int = 8) -> bytes:
    """One JSF message: the 16-byte header and ``payload``."""
    return HEADER.pack(START_MARKER, version, 0, kind, 0, subsystem, channel, 0, 0, len(payload)) + payload


def _weighting(peak: float, limit: int) -> int:
    """Largest N in [-16, 15] with peak x 2^N <= limit."""
    if not (math.isfinite(peak) and peak > 0):
        return 0
    return int(min(15, max(-16, math.floor(math.log2(limit / peak)))))


class JsfWriter(PairedPingWriter):
    """Write tiles (and NMEA sentences) to a JSF file; a context manager, or call :meth:`close`.

    Parameters
    ----------
    path
        The file; overwritten.
    subsystem
        Side-scan subsystem number of the pings (20, 21, 22).
    data_format
        ``envelope`` (uint16 magnitudes) or ``analytic`` (int16 I/Q pairs).
    """

    def __init__(self, path: str | os.PathLike[str], *, subsystem: int = 21, data_format: str = "envelope") -> None:
        if data_format not in FORMATS:
            raise ValueError(f"data_format must be one of {tuple(FORMATS)}, got {data_format!r}")
        self.path = Path(path)
        self.subsystem = int(subsystem)
        self.data_format = FORMATS[data_format]
        self._fh = open(self.path, "wb")
        self._pending: Tile | None = None
        self._ping_number = 0
        self.stats = JsfWriteStats()

    # -- public ------------------------------------------------------------------------------
    def write_message(self, kind: int, payload: bytes, *, subsystem: int = 0, channel: int = 0) -> None:
        self._fh.write(message(kind, payload, subsystem=subsystem, channel=channel))
        self.stats.messages[kind] += 1

    def write_nmea(self, t: float, sentence: bytes) -> None:
        """Message 2002: time, milliseconds, source 1 (sonar), the sentence."""
        ms = round(t * 1000.0)
        self.write_message(NMEA, struct.pack("<iiB3x", ms // 1000, ms % 1000, 1) + sentence.rstrip(b"\r\n"))

    # -- hooks of PairedPingWriter -------------------------------------------------------------
    def _write_link(self, rec: LogRecord) -> bool:
        if rec.link == "nmea":
            self.write_nmea(rec.t, bytes(rec.msg))
            return True
        return False

    # -- messages ----------------------------------------------------------------------------
    def _samples(self, row: np.ndarray) -> tuple[bytes, int]:
        """(sample bytes, weighting factor N) of one ping of one side; NaN -> 0."""
        v = np.nan_to_num(row.astype(np.float64), nan=0.0).clip(0.0, None)
        peak = float(v.max()) if v.size else 0.0
        if self.data_format == ENVELOPE:
            n = _weighting(peak, 65535)
            return np.rint(v * 2.0 ** n).clip(0, 65535).astype("<u2").tobytes(), n
        n = _weighting(peak, 32767)
        phase = 0.7 * np.arange(v.size)  # any phase: only the magnitude is imagery
        iq = np.stack([v * np.cos(phase), v * np.sin(phase)], axis=1) * 2.0 ** n
        return np.rint(iq).clip(-32768, 32767).astype("<i2").tobytes(), n

    def _header(self, tile: Tile, i: int, speed_kn: float) -> np.ndarray:
        h = np.zeros(1, PING_FIELDS)[0]
        ms_total = round(float(tile.ping_time[i]) * 1000.0)
        when = datetime.fromtimestamp(ms_total // 1000, tz=timezone.utc)
        h["ping_time_s"] = ms_total // 1000
        h["ms_today"] = ms_total % 86_400_000
        h["year"], h["day"] = when.year, when.timetuple().tm_yday
        h["fix_hour"], h["fix_minute"], h["fix_second"] = when.hour, when.minute, when.second
        h["ping_number"] = self._ping_number
        h["packet"] = 1
        h["data_format"] = self.data_format
        h["sound_speed"] = SOUND_SPEED_M_S
        interval_ns = round(2.0 * tile.dr_m / SOUND_SPEED_M_S * 1e9)
        h["interval_ns"] = interval_ns
        dr = SOUND_SPEED_M_S * interval_ns * 1e-9 / 2.0
        h["start_depth"] = max(0, round(tile.range0_m / dr - 0.5))
        n = tile.cols
        h["samples"] = n & 0xFFFF
        msb = (n >> 16 & 0xF) << 8
        flags = VALID_SOUND_SPEED
        if tile.sensor is not None and tile.sensor.frequency_hz > 0:
            f0 = round((tile.sensor.frequency_hz - tile.sensor.bandwidth_hz / 2.0) / 10.0)
            f1 = round((tile.sensor.frequency_hz + tile.sensor.bandwidth_hz / 2.0) / 10.0)
            h["start_freq_dahz"], h["end_freq_dahz"] = f0 & 0xFFFF, f1 & 0xFFFF
            msb |= (f0 >> 16 & 0xF) | (f1 >> 16 & 0xF) << 4
        h["msb"] = msb
        if speed_kn > 0:
            hundredths = round(speed_kn * 100.0)
            h["speed_dkn"], h["lsb2"] = min(hundredths // 10, 32767), hundredths % 10
            flags |= VALID_SPEED
        nav = tile.nav
        if nav is not None:
            h["coord_units"] = 2
            h["x"], h["y"] = round(float(nav.lon_deg[i]) * 600000.0), round(float(nav.lat_deg[i]) * 600000.0)
            h["heading_cdeg"] = round(float(nav.heading_deg[i]) % 360.0 * 100.0) % 36000
            flags |= VALID_POSITION | VALID_HEADING
            alt = float(nav.altitude_m[i])
            if math.isfinite(alt) and alt >= 0:
                h["altitude_mm"] = round(alt * 1000.0)
                flags |= VALID_ALTITUDE
        h["validity"] = flags
        return h

    def _write_pings(self, tiles: dict[str, Tile]) -> None:
        sides = [s for s in ("port", "stbd") if s in tiles]
        first = tiles[sides[0]]
        _, speed_kn = self._interval_and_speed(first)
        for i in range(first.rows):
            for s in sides:
                t = tiles[s]
                h = self._header(t, i, speed_kn)
                data, n = self._samples(t.pixels[i])
                h["weighting"] = n
                head = bytearray(h.tobytes())
                struct.pack_into("<h", head, 28, 1)  # ID code: always 1 (seismic data)
                struct.pack_into("<h", head, 166, 3)  # time basis: always 3
                self.write_message(SONAR, bytes(head) + data, subsystem=self.subsystem, channel=CHANNEL[s])
            self._ping_number += 1
        self.stats.pings += first.rows


def write_jsf(path: str | os.PathLike[str], records: Iterable[LogRecord], **kwargs: Any) -> JsfWriteStats:
    """Write the sonar and NMEA records of a record stream (e.g. an .atrlog) as a JSF file."""
    with JsfWriter(path, **kwargs) as w:
        for rec in records:
            w.write_record(rec)
    return w.stats
