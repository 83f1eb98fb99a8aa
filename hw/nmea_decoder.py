"""Stateful NMEA 0183 decoder: sentences to :class:`NavFix` (ICD section 2).

Field layouts follow IEC 61162-1 (see the table in :mod:`hw.nmea`). Times: GGA and RMC give a
time of day, ZDA and RMC a date; sentences without time (HDT, THS, VTG, DPT) take the
arrival time shifted by the sentence-clock offset (details in :class:`NmeaDecoder`).
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from datetime import datetime, timezone
from typing import Sequence

from atr_node.records.nav import NavFix, make_fix

from .nmea import KNOT_M_S, REJECT_REASONS, SENTENCE_TYPES, NmeaReject, split_sentence

log = logging.getLogger(__name__)

_HALF_DAY_S = 43_200.0
_isfinite = math.isfinite

# Ranges of the decoded quantities, as the CAN path checks the DBC's (both count a value outside
# as ``out_of_range``): the same heading and speed ranges; physical ranges where the DBC's
# only reflect the width of its fields
HEADING_MAX_DEG = 360.0
"""Headings in [0, 360): 400, -90 or 1e308 are a corrupt field, not an angle to wrap."""
SPEED_MAX_M_S = 65.534
"""The DBC's ATR_NavAttitude.Speed maximum (127 kn): faster is no AUV."""
ALTITUDE_MAX_M = 12_000.0
"""DPT depth below the transducer (the node's altitude): no sea is deeper. Not the DBC's
655.34 m, a limit of its 16-bit field: a ship's echo sounder reports 4675 m (the real
``nmea`` recordings)."""
DEPTH_RANGE_M = (-1_000.0, 12_000.0)
"""GGA depth (-height above MSL): the CAN depth is unsigned, but a GNSS antenna above the sea
is a negative depth; below the deepest ocean or 1 km up is a corrupt field."""


def _in_range(value: float, lo: float, hi: float, what: str, *, hi_open: bool = False) -> float:
    """``value`` if in [lo, hi] ([lo, hi) with ``hi_open``), else an ``out_of_range`` reject."""
    if value < lo or value > hi or (hi_open and value == hi):
        raise NmeaReject("out_of_range", f"{what} {value!r} outside [{lo:g}, {hi:g}{')' if hi_open else ']'}")
    return value


def _float(fields: Sequence[str], i: int, what: str) -> float | None:
    """Field ``i`` as a float; None when null or absent."""
    if i >= len(fields):
        return None
    text = fields[i]
    if text == "":
        return None
    try:
        v = float(text)
    except ValueError:
        raise NmeaReject("bad_field", f"{what} = {fields[i]!r}: expected a number") from None
    if not _isfinite(v):
        raise NmeaReject("bad_field", f"{what} = {fields[i]!r}: expected a finite number")
    return v


def _coord(value: str, hemi: str, deg_digits: int, hemis: tuple[str, str], limit: float) -> float:
    """One of latitude (``ddmm.mmm``, N/S) or longitude (``dddmm.mmm``, E/W), signed degrees."""
    dot = value.find(".")
    split = (dot if dot >= 0 else len(value)) - 2
    if split < 1 or split > deg_digits or hemi not in hemis:
        raise NmeaReject("bad_field", f"position {value!r},{hemi!r}: expected d{'d' * (deg_digits - 1)}mm.mmm,"
                                      f"{'N/S' if deg_digits == 2 else 'E/W'}")
    try:
        deg, minutes = int(value[:split]), float(value[split:])
    except ValueError:
        raise NmeaReject("bad_field", f"position {value!r}: expected digits") from None
    v = deg + minutes / 60.0
    if minutes >= 60.0:
        raise NmeaReject("bad_field", f"position {value!r}: minutes {minutes!r} not below 60")
    if v > limit:
        raise NmeaReject("out_of_range", f"position {value!r}: {v!r} deg outside [-{limit:g}, {limit:g}]")
    return -v if hemi in "SW" else v


_NS, _EW = ("N", "S"), ("E", "W")


def _latlon(fields: Sequence[str], i: int) -> tuple[float, float] | None:
    """Latitude and longitude from ``ddmm.mmm,N,dddmm.mmm,E`` starting at field ``i``."""
    if len(fields) < i + 4 or "" in fields[i:i + 4]:
        return None
    return (_coord(fields[i], fields[i + 1], 2, _NS, 90.0),
            _coord(fields[i + 2], fields[i + 3], 3, _EW, 180.0))


_HHMM = {f"{h:02d}{m:02d}": h * 3600.0 + m * 60.0 for h in range(24) for m in range(60)}
"""Every valid ``hhmm`` -> ``h * 3600.0 + m * 60.0``, the first two terms of the sum below."""


def _time_of_day(field: str) -> float:
    """Seconds since midnight from ``hhmmss[.ss]``."""
    hm = _HHMM.get(field[:4])
    if hm is not None and len(field) >= 6:  # the usual case: two int() parses become a lookup
        try:
            s = float(field[4:])
        except ValueError:
            raise NmeaReject("bad_field", f"time {field!r}: expected hhmmss.ss") from None
        if 0.0 <= s < 61.0:
            return hm + s  # == h * 3600.0 + m * 60.0 + s, evaluated left to right
        raise NmeaReject("bad_field", f"time {field!r}: expected hhmmss.ss")
    try:
        h, m, s = int(field[0:2]), int(field[2:4]), float(field[4:])
    except (ValueError, IndexError):
        raise NmeaReject("bad_field", f"time {field!r}: expected hhmmss.ss") from None
    if len(field) < 6 or h > 23 or m > 59 or not 0.0 <= s < 61.0:
        raise NmeaReject("bad_field", f"time {field!r}: expected hhmmss.ss")
    return h * 3600.0 + m * 60.0 + s


def _midnight(year: int, month: int, day: int, where: str) -> float:
    try:
        return datetime(year, month, day, tzinfo=timezone.utc).timestamp()
    except (ValueError, OverflowError):  # OverflowError: a year of 20 digits
        raise NmeaReject("bad_field", f"{where}: no such date {year:04d}-{month:02d}-{day:02d}") from None


class NmeaDecoder:
    """Stateful NMEA 0183 decoder: lines in, :class:`NavFix` out (ICD section 2).

    GGA and RMC carry only a time of day; the date comes from the last ZDA or RMC, and a time of
    day more than 12 h before (after) the last dated time rolls over to the next (previous) day,
    so fixes across midnight keep increasing. Until a date is known, the arrival time's date
    is used (``date_from_arrival=True``) or the fix is dropped as ``no_date``. Sentences with no
    time (HDT, THS, VTG, DPT) are stamped with their arrival time plus the offset between the
    sentence clock and the arrival clock measured on the last timed sentence.

    Attributes
    ----------
    counts
        ``Counter`` with ``accepted`` and one key per reject reason (:data:`REJECT_REASONS`).
    by_type
        ``Counter`` of accepted sentences per type (``GGA``, ...).
    last_reject
        Message of the last rejected line (what and why), or ``""``.
    """

    def __init__(self, *, date_from_arrival: bool = True) -> None:
        self.date_from_arrival = date_from_arrival
        self.counts: Counter[str] = Counter()
        self.by_type: Counter[str] = Counter()
        self.last_reject = ""
        self._last_t: float | None = None  # last dated sentence time (UNIX s)
        self._offset_s = 0.0  # sentence clock - arrival clock
        # sentence type -> bound handler, built once (SENTENCE_TYPES are the ones understood)
        self._handlers = {k: getattr(self, "_" + k.lower()) for k in SENTENCE_TYPES}

    @property
    def rejected(self) -> int:
        return sum(self.counts[r] for r in REJECT_REASONS)

    def feed(self, line: bytes, t_arrival: float) -> list[NavFix]:
        """Decode one line received at ``t_arrival`` (UNIX s); return 0 or 1 fix. Never raises on input."""
        try:
            talker, kind, fields = split_sentence(line)
            handler = self._handlers.get(kind) if talker != "P" else None
            if handler is None:
                raise NmeaReject("unsupported", f"sentence type {'P' + kind if talker == 'P' else kind}")
            fix = handler(fields, float(t_arrival))
        except NmeaReject as exc:
            self.counts[exc.reason] += 1
            self.last_reject = f"{line[:90]!r}: {exc}"
            if self.counts[exc.reason] == 1:  # one line per reason; the rest are counted
                # other sentence types (GSV, GSA, ...) are ordinary traffic, not a fault
                log.log(logging.INFO if exc.reason == "unsupported" else logging.WARNING,
                        "NMEA sentence rejected (%s): %s; further %s rejections are counted, not logged",
                        exc.reason, self.last_reject, exc.reason)
            return []
        self.counts["accepted"] += 1
        self.by_type[kind] += 1
        return [] if fix is None else [fix]

    # -- time ----------------------------------------------------------------------------------
    def _dated(self, tod_s: float, t_arrival: float) -> float:
        """UNIX time of a time of day, on the day nearest the last dated time."""
        ref = self._last_t
        if ref is None:
            if not self.date_from_arrival:
                raise NmeaReject("no_date", "time of day before any ZDA or RMC date")
            ref = t_arrival + self._offset_s
        day0 = math.floor(ref / 86_400.0) * 86_400.0
        t = day0 + tod_s
        if t < ref - _HALF_DAY_S:
            t += 86_400.0
        elif t > ref + _HALF_DAY_S:
            t -= 86_400.0
        return t

    # a sentence without time is stamped ``t_arrival + self._offset_s`` (inlined in the handlers)

    def _clock(self, t: float, t_arrival: float) -> None:
        self._last_t = t
        self._offset_s = t - t_arrival

    # -- sentences -----------------------------------------------------------------------------
    def _gga(self, f: Sequence[str], ta: float) -> NavFix:
        if len(f) < 9:
            raise NmeaReject("bad_field", f"GGA with {len(f)} fields, expected at least 9")
        quality = f[5]
        pos = _latlon(f, 1)
        if quality in ("", "0") or pos is None:
            raise NmeaReject("invalid", f"GGA fix quality {quality!r} or null position")
        t = self._dated(_time_of_day(f[0]), ta)
        self._clock(t, ta)
        height = _float(f, 8, "GGA altitude")
        depth = None if height is None else _in_range(-height, *DEPTH_RANGE_M, "GGA depth (-altitude) m")
        return make_fix(t, pos[0], pos[1], None, None, depth, None, "nmea:GGA")

    def _rmc(self, f: Sequence[str], ta: float) -> NavFix:
        if len(f) < 9:
            raise NmeaReject("bad_field", f"RMC with {len(f)} fields, expected at least 9")
        tod = _time_of_day(f[0])
        d = f[8]
        if len(d) != 6 or not d.isdigit():
            raise NmeaReject("bad_field", f"RMC date {d!r}: expected ddmmyy")
        yy = int(d[4:6])
        t = _midnight(2000 + yy if yy < 80 else 1900 + yy, int(d[2:4]), int(d[0:2]), "RMC date") + tod
        self._clock(t, ta)  # date and clock are good even when the fix is not
        pos = _latlon(f, 2)
        if f[1] != "A" or pos is None or (len(f) > 11 and f[11] == "N"):
            raise NmeaReject("invalid", f"RMC status {f[1]!r} or null position")
        sog = _float(f, 6, "RMC speed")
        if sog is not None:
            _in_range(sog * KNOT_M_S, 0.0, SPEED_MAX_M_S, "RMC speed m/s")
        cog = _float(f, 7, "RMC course")
        if cog is not None:  # not used, but a course of 400 deg is a corrupt sentence
            _in_range(cog, 0.0, HEADING_MAX_DEG, "RMC course deg", hi_open=True)
        return make_fix(t, pos[0], pos[1], None, None, None, None if sog is None else sog * KNOT_M_S, "nmea:RMC")

    def _zda(self, f: Sequence[str], ta: float) -> None:
        if len(f) < 4 or "" in f[:4]:
            raise NmeaReject("bad_field", "ZDA needs time, day, month and year")
        try:
            day, month, year = int(f[1]), int(f[2]), int(f[3])
        except ValueError:
            raise NmeaReject("bad_field", f"ZDA date {f[1:4]!r}: expected integers") from None
        self._clock(_midnight(year, month, day, "ZDA") + _time_of_day(f[0]), ta)
        return None

    def _hdt(self, f: Sequence[str], ta: float) -> NavFix:
        h = _float(f, 0, "HDT heading")
        if h is None:
            raise NmeaReject("invalid", "HDT null heading")
        _in_range(h, 0.0, HEADING_MAX_DEG, "HDT heading deg", hi_open=True)
        return make_fix(ta + self._offset_s, None, None, h or 0.0, None, None, None, "nmea:HDT")  # -0 -> 0

    def _ths(self, f: Sequence[str], ta: float) -> NavFix:
        if len(f) < 2 or f[1] not in ("A", "E", "M", "S"):
            raise NmeaReject("invalid", f"THS mode {f[1] if len(f) > 1 else None!r}, expected A, E, M or S")
        h = _float(f, 0, "THS heading")
        if h is None:
            raise NmeaReject("invalid", "THS null heading")
        _in_range(h, 0.0, HEADING_MAX_DEG, "THS heading deg", hi_open=True)
        return make_fix(ta + self._offset_s, None, None, h or 0.0, None, None, None, "nmea:THS")  # -0 -> 0

    def _vtg(self, f: Sequence[str], ta: float) -> NavFix:
        if len(f) > 8 and f[8] == "N":
            raise NmeaReject("invalid", "VTG mode N (data not valid)")
        kn = _float(f, 4, "VTG speed knots")
        sog = kn * KNOT_M_S if kn is not None else None
        if sog is None:
            kmh = _float(f, 6, "VTG speed km/h")
            sog = None if kmh is None else kmh / 3.6
        if sog is None:
            raise NmeaReject("invalid", "VTG null speed")
        _in_range(sog, 0.0, SPEED_MAX_M_S, "VTG speed m/s")
        cog = _float(f, 0, "VTG course")
        if cog is not None:  # not used, but a course of 400 deg is a corrupt sentence
            _in_range(cog, 0.0, HEADING_MAX_DEG, "VTG course deg", hi_open=True)
        return make_fix(ta + self._offset_s, None, None, None, None, None, sog, "nmea:VTG")

    def _dpt(self, f: Sequence[str], ta: float) -> NavFix:
        d = _float(f, 0, "DPT depth")
        if d is None:
            raise NmeaReject("invalid", "DPT null depth")
        _in_range(d, 0.0, ALTITUDE_MAX_M, "DPT depth below transducer m")
        return make_fix(ta + self._offset_s, None, None, None, d, None, None, "nmea:DPT")
