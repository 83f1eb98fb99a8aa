"""NMEA 0183 wire format: sentence encoder and framing check (ICD section 2).

Wire form of one sentence (IEC 61162-1), at most 82 characters including ``$`` and CR LF::

    $<talker 2><type 3>,<field>,...,<field>*<checksum 2 hex>\\r\\n

The checksum is the XOR of every byte between ``$`` and ``*``. Sentences understood, with any
talker id (``GP``, ``IN``, ``HE``, ``SD``, ...), and what they give:

===== ======================================================= ===============================
type  fields used                                             NavFix quantities
===== ======================================================= ===============================
GGA   time of day, lat, N/S, lon, E/W, quality, height (MSL)  lat_deg, lon_deg, depth_m = -height
RMC   time of day, status, lat, N/S, lon, E/W, SOG kn, date   lat_deg, lon_deg, speed_m_s
HDT   heading true                                            heading_deg
THS   heading true, mode (A/E/M/S valid, V invalid)           heading_deg
VTG   course true, SOG kn                                     speed_m_s
ZDA   time of day, day, month, year                           (date and clock for the others)
DPT   depth below transducer, offset, max range               altitude_m (downward altimeter)
===== ======================================================= ===============================

The encoder side (``format_sentence`` and ``encode_*``) takes SI values (UNIX seconds, degrees,
metres, m/s) and is what the simulation uses to write NMEA records into generated missions.
:func:`parse_sentence` checks one line (length, framing, checksum) and splits it
(:func:`split_sentence` gives the same as a plain tuple, for the decoder's per-line path); the stateful
:class:`hw.nmea_decoder.NmeaDecoder` (re-exported here) turns sentences into ``NavFix`` and
never raises on bad input: every line is accepted or counted under a reason (``too_long``,
``bad_checksum``, ``garbage``, ``unsupported``, ``bad_field``, ``invalid``, ``out_of_range``,
``no_date``); the first rejection of each reason is logged, the others only counted.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Sequence

from .errors import NmeaError

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


# --- framing check ----------------------------------------------------------------------------

REJECT_REASONS = ("too_long", "bad_checksum", "garbage", "unsupported", "bad_field", "invalid", "out_of_range",
                  "no_date")
"""``invalid``: the sender flags the data invalid (RMC status V, GGA quality 0, a null field);
``out_of_range``: a value outside its range (heading not in [0, 360), ...), as on CAN."""


@dataclass(frozen=True)
class Sentence:
    """A framed sentence whose checksum verified: address split into talker and type."""

    talker: str
    type: str
    fields: tuple[str, ...]


class NmeaReject(NmeaError):
    """A line that is not an acceptable sentence; ``reason`` is one of :data:`REJECT_REASONS`."""

    def __init__(self, reason: str, detail: str) -> None:
        self.reason = reason
        super().__init__(f"{reason}: {detail}")


# masks of the XOR fold in _fast_checksum
_M512, _M256, _M128, _M64, _M32, _M16 = ((1 << k) - 1 for k in (512, 256, 128, 64, 32, 16))
_HEX = {f"{a}{b}".encode(): int(f"{a}{b}", 16) for a in "0123456789ABCDEFabcdef" for b in "0123456789ABCDEFabcdef"}
"""Two hex digits -> value: what ``int(text, 16)`` gives for them, without parsing."""
_ADDRESSES: dict[str, tuple[str, str]] = {}
"""Addresses already matched by ``_ADDRESS``, split into (talker, type): a link repeats a few."""


def _fast_checksum(body: bytes) -> int:
    """:func:`checksum` without a Python step per byte.

    The bytes, read as one little-endian integer, are folded in halves (... -> 64 -> 32 -> 16
    -> 8 bits), starting at the smallest power of two that holds them: XOR is associative and
    every byte keeps its lane, so the last 8 bits are the XOR of all the bytes.
    """
    n = len(body)
    if n > 128:
        return checksum(body)
    x = int.from_bytes(body, "little")
    if n > 8:
        if n > 32:
            if n > 64:
                x = (x >> 512) ^ (x & _M512)
            x = (x >> 256) ^ (x & _M256)
        if n > 16:
            x = (x >> 128) ^ (x & _M128)
        x = (x >> 64) ^ (x & _M64)
    x = (x >> 32) ^ (x & _M32)
    x = (x >> 16) ^ (x & _M16)
    return (x >> 8) ^ (x & 0xFF)


def split_sentence(line: bytes) -> tuple[str, str, tuple[str, ...]]:
    """:func:`parse_sentence` as a plain ``(talker, type, fields)`` tuple (the decoder's hot path).

    Raises
    ------
    NmeaReject
        With ``reason`` ``too_long``, ``garbage`` or ``bad_checksum``.
    """
    body = line.rstrip(b"\r\n")
    n = len(body)
    if n + 2 > MAX_SENTENCE_CHARS:
        raise NmeaReject("too_long", f"{n + 2} characters, at most {MAX_SENTENCE_CHARS}")
    if body[:1] != b"$":
        raise NmeaReject("garbage", f"expected '$' at the start, got {body[:12]!r}")
    star = body.rfind(b"*")
    if star < 0 or n - star != 3:
        raise NmeaReject("bad_checksum", f"expected '*hh' at the end, got {body[-6:]!r}")
    inner = body[1:star]
    try:
        text = inner.decode("ascii")
    except UnicodeDecodeError:
        raise NmeaReject("garbage", f"non-ASCII bytes in {body[:24]!r}") from None
    hexa = body[star + 1:]
    want = _HEX.get(hexa) if type(hexa) is bytes else None  # a bytearray is not hashable
    if want is None:  # int() also takes a few odd forms (' F', '+F'): the same rule as ever
        try:
            want = int(hexa, 16)
        except ValueError:
            raise NmeaReject("bad_checksum", f"checksum {hexa!r} is not two hex digits") from None
    got = _fast_checksum(inner)
    if got != want:
        raise NmeaReject("bad_checksum", f"computed {got:02X}, sentence says {want:02X}")
    fields = text.split(",")
    address = fields[0]
    split = _ADDRESSES.get(address)
    if split is None:
        if not _ADDRESS.match(address):
            raise NmeaReject("garbage", f"address {address!r}: expected talker + type like 'GPGGA'")
        # proprietary: manufacturer code, no talker id
        split = ("P", address[1:]) if address.startswith("P") else (address[:2], address[2:])
        if len(_ADDRESSES) < 1024:  # bounded: a stream of random valid addresses cannot grow it
            _ADDRESSES[address] = split
    return split[0], split[1], tuple(fields[1:])


def parse_sentence(line: bytes) -> Sentence:
    """Check framing, length and checksum of one line and split it into fields.

    Parameters
    ----------
    line
        One sentence, with or without CR LF.

    Raises
    ------
    NmeaReject
        With ``reason`` ``too_long``, ``garbage`` or ``bad_checksum``.
    """
    talker, kind, fields = split_sentence(line)
    return Sentence(talker=talker, type=kind, fields=fields)


from .nmea_decoder import NmeaDecoder  # noqa: E402  (re-export; it builds on the names above)
