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
:class:`hw.nmea_decoder.NmeaDecoder` (built on this module, which does not import it) turns sentences into ``NavFix`` and
never raises on bad input: every line is accepted or counted under a reason (``too_long``,
``bad_checksum``, ``garbage``, ``unsupported``, ``bad_field``, ``invalid``, ``out_of_range``,
``no_date``); the first rejection of each reason is logged, the others only counted.
"""

from __future__ import annotations

from dataclasses import dataclass

from atr_node.io.nmea_encode import (KNOT_M_S, MAX_SENTENCE_CHARS, SENTENCE_TYPES, _ADDRESS,  # noqa: F401  (re-export)
                                      NmeaError, checksum, encode_dpt, encode_gga, encode_hdt, encode_rmc,
                                      encode_ths, encode_vtg, encode_zda, format_sentence)

__all__ = ["KNOT_M_S", "MAX_SENTENCE_CHARS", "REJECT_REASONS", "SENTENCE_TYPES", "NmeaError", "NmeaReject", "Sentence",
           "checksum", "encode_dpt", "encode_gga", "encode_hdt", "encode_rmc", "encode_ths", "encode_vtg",
           "encode_zda", "format_sentence", "parse_sentence", "split_sentence"]

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

