"""NMEA 0183 sentence encoding (IEC 61162-1): the sentences the simulator, the XTF converter and
the operators' ``$EXWPT`` output write.

It lives in ``atr_node.io`` so that the file formats never import the link drivers: ``hw``
builds on ``atr_node.io`` (and re-exports these names from :mod:`hw.nmea`), never the other way.
"""

from __future__ import annotations

import math
import re
from datetime import datetime, timezone
from typing import Sequence

from ..errors import AtrError


class NmeaError(AtrError, ValueError):
    """A sentence cannot be encoded from the given fields (decoding never raises: it counts)."""


MAX_SENTENCE_CHARS = 82
"""IEC 61162-1 limit, counting ``$`` and CR LF."""
KNOT_M_S = 1852.0 / 3600.0
SENTENCE_TYPES = ("GGA", "RMC", "HDT", "THS", "VTG", "ZDA", "DPT")
_ADDRESS = re.compile(r"^(?:[A-Z][A-Z0-9][A-Z]{3}|P[A-Z0-9]{1,8})$")
_FORBIDDEN = set("$*,!\\^~\r\n")


# --- encoder ----------------------------------------------------------------------------------

def checksum(body: bytes) -> int:
    """XOR of every byte of ``body`` (the text between ``$`` and ``*``)."""
    c = 0
    for b in body:
        c ^= b
    return c


def format_sentence(talker_and_type: str, fields: Sequence[str]) -> bytes:
    """One complete sentence: ``$``, address, fields, ``*`` checksum, CR LF.

    Parameters
    ----------
    talker_and_type
        Address field, e.g. ``"GPGGA"`` (talker ``GP`` + type ``GGA``) or proprietary ``"PSXN"``.
    fields
        Data fields, already formatted; empty string = null field.

    Raises
    ------
    NmeaError
        The address is malformed, a field holds a reserved character, or the sentence would be
        longer than 82 characters.
    """
    if not _ADDRESS.match(talker_and_type):
        raise NmeaError(f"NMEA address {talker_and_type!r}: expected talker (2) + type (3) "
                        f"upper-case characters like 'GPGGA', or a proprietary 'P...' address")
    for i, f in enumerate(fields):
        bad = _FORBIDDEN.intersection(f)
        if bad or not f.isascii():
            raise NmeaError(f"{talker_and_type} field {i + 1} = {f!r}: reserved or non-ASCII "
                            f"character(s) {sorted(bad) or 'non-ASCII'}")
    body = ",".join((talker_and_type, *fields)).encode("ascii")
    line = b"$" + body + b"*%02X\r\n" % checksum(body)
    if len(line) > MAX_SENTENCE_CHARS:
        raise NmeaError(f"{talker_and_type}: sentence of {len(line)} characters, "
                        f"at most {MAX_SENTENCE_CHARS} allowed (IEC 61162-1)")
    return line


def _centis(t: float) -> tuple[datetime, int]:
    """UTC date and time of day in hundredths of a second, rounded once (no 59.999 -> 60.00)."""
    if not math.isfinite(t):
        raise NmeaError(f"time {t!r}: expected finite UNIX seconds")
    cs = round(t * 100.0)
    day = datetime.fromtimestamp((cs // 8_640_000) * 86_400, tz=timezone.utc)
    return day, cs % 8_640_000


def _hhmmss(t: float) -> str:
    _, cs = _centis(t)
    h, rem = divmod(cs, 360_000)
    m, rem = divmod(rem, 6_000)
    return f"{h:02d}{m:02d}{rem // 100:02d}.{rem % 100:02d}"


def _angle(value_deg: float, deg_digits: int, hemis: str, what: str, limit: float) -> tuple[str, str]:
    """``dddmm.mmmmmm`` and hemisphere letter; minutes rounded to 1e-6 (about 2 mm)."""
    if not math.isfinite(value_deg) or abs(value_deg) > limit:
        raise NmeaError(f"{what} {value_deg!r}: expected a finite value in [-{limit}, {limit}] deg")
    micro_min = round(abs(value_deg) * 60.0e6)  # integer micro-minutes: carries minutes into degrees
    deg, mm = divmod(micro_min, 60_000_000)
    text = f"{deg:0{deg_digits}d}{mm // 1_000_000:02d}.{mm % 1_000_000:06d}"
    return text, hemis[0] if value_deg >= 0 else hemis[1]


def _num(value: float, decimals: int, what: str) -> str:
    if not math.isfinite(value):
        raise NmeaError(f"{what} {value!r}: expected a finite number")
    return f"{value:.{decimals}f}"


def encode_gga(t: float, lat_deg: float, lon_deg: float, *, height_m: float = 0.0, quality: int = 1,
               n_sats: int = 10, hdop: float = 1.0, talker: str = "GP") -> bytes:
    """GGA fix: UTC time of day of ``t``, position; ``height_m`` above MSL (an AUV sends -depth)."""
    lat, ns = _angle(lat_deg, 2, "NS", "latitude", 90.0)
    lon, ew = _angle(lon_deg, 3, "EW", "longitude", 180.0)
    return format_sentence(talker + "GGA", [_hhmmss(t), lat, ns, lon, ew, str(int(quality)),
                                            f"{int(n_sats):02d}", _num(hdop, 1, "hdop"),
                                            _num(height_m, 2, "height_m"), "M", "", "M", "", ""])


def encode_rmc(t: float, lat_deg: float, lon_deg: float, *, speed_m_s: float = 0.0,
               course_deg: float = 0.0, talker: str = "GP") -> bytes:
    """RMC: UTC time and date of ``t``, status A, position, speed over ground and course."""
    day, _ = _centis(t)
    lat, ns = _angle(lat_deg, 2, "NS", "latitude", 90.0)
    lon, ew = _angle(lon_deg, 3, "EW", "longitude", 180.0)
    return format_sentence(talker + "RMC", [_hhmmss(t), "A", lat, ns, lon, ew,
                                            _num(speed_m_s / KNOT_M_S, 2, "speed_m_s"),
                                            _num(course_deg % 360.0, 2, "course_deg"),
                                            day.strftime("%d%m%y"), "", "", "A"])


def _heading(heading_deg: float) -> str:
    if not math.isfinite(heading_deg):
        raise NmeaError(f"heading {heading_deg!r}: expected a finite number of degrees")
    return f"{round(heading_deg * 100.0) % 36000 / 100.0:.2f}"  # wrap after rounding: never 360.00


def encode_hdt(heading_deg: float, *, talker: str = "HE") -> bytes:
    """HDT: true heading (degrees clockwise from north, wrapped to [0, 360))."""
    return format_sentence(talker + "HDT", [_heading(heading_deg), "T"])


def encode_ths(heading_deg: float, *, mode: str = "A", talker: str = "IN") -> bytes:
    """THS: true heading and mode indicator (A autonomous, E estimated, M manual, S simulator, V invalid)."""
    return format_sentence(talker + "THS", [_heading(heading_deg), mode])


def encode_vtg(course_deg: float, speed_m_s: float, *, talker: str = "GP") -> bytes:
    """VTG: course over ground (true) and speed over ground (knots and km/h)."""
    return format_sentence(talker + "VTG", [_num(course_deg % 360.0, 2, "course_deg"), "T", "", "M",
                                            _num(speed_m_s / KNOT_M_S, 2, "speed_m_s"), "N",
                                            _num(speed_m_s * 3.6, 2, "speed_m_s"), "K", "A"])


def encode_zda(t: float, *, talker: str = "GP") -> bytes:
    """ZDA: UTC time of day, day, month, year of ``t`` (local zone fields left null)."""
    day, _ = _centis(t)
    return format_sentence(talker + "ZDA", [_hhmmss(t), f"{day.day:02d}", f"{day.month:02d}",
                                            f"{day.year:04d}", "", ""])


def encode_dpt(altitude_m: float, *, offset_m: float = 0.0, max_range_m: float | None = None,
               talker: str = "SD") -> bytes:
    """DPT: depth of water below the transducer; from a downward altimeter, the altitude above the seabed."""
    if not math.isfinite(altitude_m) or altitude_m < 0:
        raise NmeaError(f"altitude_m {altitude_m!r}: expected a finite value >= 0")
    fields = [_num(altitude_m, 2, "altitude_m"), _num(offset_m, 2, "offset_m")]
    if max_range_m is not None:
        fields.append(_num(max_range_m, 1, "max_range_m"))
    return format_sentence(talker + "DPT", fields)
