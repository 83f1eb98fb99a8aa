"""CAN navigation codec: the frames of ``config/atr_node.dbc`` and the decoder to :class:`NavFix`.

Frames (standard 11-bit ids, Intel byte order, 8 data bytes; the DBC is the reference)::

    0x100 ATR_NavPosition  Latitude  int32 1e-7 deg | Longitude int32 1e-7 deg
    0x101 ATR_NavAttitude  Heading uint16 0.01 deg | Pitch int16 0.01 deg | Roll int16 0.01 deg
                           | Speed uint16 0.001 m/s (65535 = not available)
    0x102 ATR_NavAltitude  Altitude uint16 0.01 m (65535 = n/a) | Depth uint32 0.001 m (n/a = max)
    0x103 ATR_Time         Seconds uint32 | Microseconds uint20 (UNIX time of the vehicle clock)
    0x104 ATR_MissionLeg   Leg uint16 | Survey 1 bit (1 on a survey line, 0 transit)

Position, attitude and altitude frames carry no time stamp: they are valid at their arrival
time, corrected by the offset between the vehicle clock (last ``ATR_Time`` frame) and the
arrival clock. Encoders return ``(arbitration_id, data, is_extended)`` ready for a
``can.Message`` or an ``.atrlog`` record; they raise :class:`CanCodecError` naming the signal
and its range when a value does not fit. The decoder never raises on bus input: frames that
are not in the DBC (a shared NMEA 2000 bus, say) are counted as ``unknown``.

Decoding per frame: cantools parses the DBC once, and :func:`compile_message` turns each of its
messages into a :class:`FastMessage` that unpacks the bits directly and returns exactly what
cantools' ``Message.decode`` returns (tested on every message and random payloads); frames it
does not cover (another length, data not ``bytes``, an extended flag) go through cantools.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import cantools
from cantools.database.can import Database, Message
from cantools.database.conversion import (IdentityConversion, LinearConversion, LinearIntegerConversion,
                                          NamedSignalConversion)
from cantools.database.namedsignalvalue import NamedSignalValue

from atr_node.errors import describe
from atr_node.records.nav import NavFix, make_fix

from .errors import CanCodecError, LinkSpecError

log = logging.getLogger(__name__)

DEFAULT_DBC = Path(__file__).resolve().parent.parent / "config" / "atr_node.dbc"
NAV_POSITION, NAV_ATTITUDE, NAV_ALTITUDE, TIME, MISSION_LEG = 0x100, 0x101, 0x102, 0x103, 0x104
NOT_AVAILABLE = "NotAvailable"

Frame = tuple[int, bytes, bool]
"""(arbitration_id, data, is_extended)."""

CAN_FD_MAX_BYTES = 64
"""Data bytes of the longest CAN frame (CAN FD; a classic frame holds at most 8). Longer "frames"
(a corrupt record) are no frame at all: ``too_long``, whatever their id."""


@lru_cache(maxsize=8)
def load_dbc(path: str | None = None) -> Database:
    """The CAN database (``config/atr_node.dbc`` by default), parsed once per path."""
    p = Path(path) if path else DEFAULT_DBC
    try:
        db = cantools.database.load_file(str(p), strict=True)
    except (OSError, cantools.database.UnsupportedDatabaseFormatError) as exc:
        raise LinkSpecError(f"CAN database {p}: cannot be loaded ({exc}); expected a DBC file") from None
    if not isinstance(db, Database):
        raise LinkSpecError(f"CAN database {p}: expected a CAN DBC file, got {type(db).__name__}")
    return db


def _encode(frame_id: int, values: dict[str, Any], dbc: str | None) -> Frame:
    msg = load_dbc(dbc).get_message_by_frame_id(frame_id)
    for k, v in values.items():
        if isinstance(v, float) and not math.isfinite(v):
            raise CanCodecError(f"{msg.name}.{k} = {v!r}: expected a finite number")
    try:
        data = msg.encode(values, strict=True)
    except (cantools.database.EncodeError, ValueError, KeyError) as exc:
        raise CanCodecError(f"{msg.name}: {exc}") from None
    return msg.frame_id, bytes(data), bool(msg.is_extended_frame)


def encode_position(lat_deg: float, lon_deg: float, *, dbc: str | None = None) -> Frame:
    """ATR_NavPosition: WGS84 latitude and longitude in degrees (resolution 1e-7 deg)."""
    lon = (float(lon_deg) + 180.0) % 360.0 - 180.0 if math.isfinite(lon_deg) else lon_deg
    return _encode(NAV_POSITION, {"Latitude": float(lat_deg), "Longitude": lon}, dbc)


def encode_attitude(heading_deg: float, *, pitch_deg: float = 0.0, roll_deg: float = 0.0,
                    speed_m_s: float | None = None, dbc: str | None = None) -> Frame:
    """ATR_NavAttitude: true heading (wrapped to [0, 360)), pitch, roll, optional speed."""
    if not math.isfinite(heading_deg):
        raise CanCodecError(f"ATR_NavAttitude.Heading = {heading_deg!r}: expected a finite number")
    heading = round(heading_deg * 100.0) % 36000 / 100.0  # wrap after rounding: 359.996 -> 0.00
    speed: float | str = NOT_AVAILABLE if speed_m_s is None else float(speed_m_s)
    return _encode(NAV_ATTITUDE, {"Heading": heading, "Pitch": float(pitch_deg), "Roll": float(roll_deg),
                                  "Speed": speed}, dbc)


def encode_altitude(altitude_m: float | None, *, depth_m: float | None = None,
                    dbc: str | None = None) -> Frame:
    """ATR_NavAltitude: altitude above the seabed and depth, metres (None = not available)."""
    return _encode(NAV_ALTITUDE, {"Altitude": NOT_AVAILABLE if altitude_m is None else float(altitude_m),
                                  "Depth": NOT_AVAILABLE if depth_m is None else float(depth_m)}, dbc)


def encode_time(t: float, *, dbc: str | None = None) -> Frame:
    """ATR_Time: UNIX seconds ``t`` split into whole seconds and microseconds."""
    if not math.isfinite(t) or t < 0:
        raise CanCodecError(f"ATR_Time: t = {t!r}: expected finite UNIX seconds >= 0")
    us = round(t * 1e6)
    return _encode(TIME, {"Seconds": us // 1_000_000, "Microseconds": us % 1_000_000}, dbc)


def encode_leg(leg: int, *, survey: bool = True, dbc: str | None = None) -> Frame:
    """ATR_MissionLeg: survey leg number and whether the vehicle is on a survey line."""
    if isinstance(leg, bool) or int(leg) != leg:
        raise CanCodecError(f"ATR_MissionLeg.Leg = {leg!r}: expected an integer in [0, 65535]")
    return _encode(MISSION_LEG, {"Leg": int(leg), "Survey": int(bool(survey))}, dbc)


# --- decoder ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class LegChange:
    """The mission leg changed (or was first heard): from ``t`` on, tiles belong to ``leg``."""

    t: float
    """UNIX seconds (vehicle clock)."""
    leg: int
    survey: bool
    """True on a survey line, False in transit or turns."""
    source: str = "can:ATR_MissionLeg"


class FastMessage:
    """A DBC message decoded by direct bit unpacking, built from cantools' description of it.

    ``decode(data)`` returns exactly what ``message.decode(data, decode_choices=True,
    scaling=True)`` returns for ``len(data) == message.length`` (same keys, values and types,
    the same ``NamedSignalValue`` objects for choices), several times cheaper: cantools stays
    the source of truth, this only skips its generic per-frame machinery. Built by
    :func:`compile_message`, which declines the messages it cannot reproduce exactly.

    ``signals`` holds, per signal, ``(name, start, mask, sign, scaled, scale, offset,
    choices)``; ``decode`` is a function generated from them once (straight-line code, no
    loop over signals: a third of the cost of an interpreted loop).
    """

    __slots__ = ("message", "frame_id", "length", "signals", "decode")

    def __init__(self, message: Message, signals: list[tuple[Any, ...]]) -> None:
        self.message = message
        self.frame_id = int(message.frame_id)  # a plain attribute: cantools' is a property
        self.length = int(message.length)
        self.signals = tuple(signals)
        self.decode = _generate(self.signals)


def _generate(signals: tuple[tuple[Any, ...], ...]) -> Any:
    """The decode function of :class:`FastMessage`: ``data (bytes) -> {signal: value}``."""
    consts: dict[str, Any] = {"_from_bytes": int.from_bytes}
    lines = ["def decode(data):", "    raw = _from_bytes(data, 'little')  # Intel order: DBC bit i = bit i"]
    items = []
    for i, (name, start, mask, sign, scaled, scale, offset, choices) in enumerate(signals):
        lines.append(f"    v{i} = (raw >> {start}) & {mask}" if start else f"    v{i} = raw & {mask}")
        if sign:  # two's complement
            lines.append(f"    if v{i} & {sign}:\n        v{i} -= {sign << 1}")
        # cantools' LinearConversion / LinearIntegerConversion: raw * scale + offset
        consts[f"_k{i}"], consts[f"_o{i}"] = scale, offset
        value = f"v{i} * _k{i} + _o{i}" if scaled else f"v{i}"
        if choices is not None:  # NamedSignalConversion: the choice of the raw value, if any
            consts[f"_c{i}"] = choices
            lines.append(f"    x{i} = _c{i}.get(v{i})\n    if x{i} is None:\n        x{i} = {value}")
            value = f"x{i}"
        items.append(f"{name!r}: {value}")
    lines.append("    return {" + ", ".join(items) + "}")
    exec(compile("\n".join(lines), "<can_nav FastMessage>", "exec"), consts)  # noqa: S102 (our own text)
    return consts["decode"]


def _linear(conv: Any) -> tuple[bool, Any, Any] | None:
    """(scaled, scale, offset) of an identity or linear conversion; None for any other kind."""
    if type(conv) is IdentityConversion and not conv.is_float:
        return False, 1, 0
    if type(conv) in (LinearConversion, LinearIntegerConversion):
        return True, conv.scale, conv.offset
    return None


def compile_message(message: Message) -> FastMessage | None:
    """A :class:`FastMessage` for ``message``, or None when it has a feature the fast path
    does not reproduce exactly (big-endian or float signals, multiplexing, containers, an
    unknown conversion): such messages keep cantools' decode."""
    if message.is_container or message.is_multiplexed() or message.length <= 0:
        return None
    signals = []
    for sg in message.signals:
        if sg.byte_order != "little_endian" or sg.is_float or sg.multiplexer_ids or sg.length <= 0:
            return None
        conv, choices = sg.conversion, None
        if type(conv) is NamedSignalConversion:
            choices = dict(conv.choices)  # raw int -> the NamedSignalValue cantools returns
            conv = getattr(conv, "_conversion", None)  # the numeric part, used when no choice matches
        lin = _linear(conv)
        if lin is None or sg.start + sg.length > 8 * message.length:
            return None
        sign = 1 << (sg.length - 1) if sg.is_signed else 0
        signals.append((sg.name, sg.start, (1 << sg.length) - 1, sign, *lin, choices))
    return FastMessage(message, signals)


def _frame_id(arbitration_id: Any) -> str:
    """``0x100`` for an int id, its repr for anything else (a message must never fail)."""
    return f"0x{arbitration_id:X}" if type(arbitration_id) is int else repr(arbitration_id)


def _value(v: Any) -> float | None:
    """A decoded signal value, None for the ``NotAvailable`` choice."""
    if isinstance(v, (NamedSignalValue, str)):
        return None
    return float(v)


class CanNavDecoder:
    """Frames of the DBC in, :class:`NavFix` and :class:`LegChange` out. Never raises on bus input.

    Parameters
    ----------
    dbc
        Path of the DBC file; None = ``config/atr_node.dbc``.

    Attributes
    ----------
    counts
        ``Counter`` with ``accepted``, ``unknown`` (id not in the DBC, e.g. NMEA 2000 traffic),
        ``too_long`` (more than :data:`CAN_FD_MAX_BYTES` data bytes), ``bad_length`` (a DBC id
        whose data length is not the DBC's: a DLC mismatch), ``bad_frame`` (undecodable) and
        ``out_of_range`` (a signal outside its DBC range ``[min|max]``, e.g. a heading of 360
        or a latitude of 100 deg). The first rejection of each reason is logged, the others
        only counted.
    last_reject
        What the last rejected frame was and why, or ``""``.
    """

    def __init__(self, dbc: str | None = None) -> None:
        self.db = load_dbc(str(dbc) if dbc else None)
        self.counts: Counter[str] = Counter()
        self.last_reject = ""
        self._offset_s = 0.0  # vehicle clock - arrival clock, from the last ATR_Time frame
        self._leg: tuple[int, bool] | None = None
        # standard-id messages that cantools' lookup returns for their own id, decoded directly
        self._fast: dict[int, FastMessage] = {}
        for m in self.db.messages:
            fm = compile_message(m)
            if (fm is not None and not m.is_extended_frame and 0 <= m.frame_id <= 0x7FF
                    and self.db.get_message_by_frame_id(m.frame_id) is m):
                self._fast[m.frame_id] = fm
        # frame id -> (signal, low, high) of the signals whose raw field can exceed their DBC
        # range (a 16-bit heading of 0.01 deg reaches 655.35); half a step of slack, so that a
        # limit the DBC rounds (359.99) still holds
        self._limits: dict[int, tuple[tuple[str, float, float], ...]] = {}
        for m in self.db.messages:
            lims = []
            for sg in m.signals:
                if sg.minimum is None or sg.maximum is None or sg.is_float:
                    continue
                half = abs(float(sg.scale)) / 2.0
                lo, hi = float(sg.minimum) - half, float(sg.maximum) + half
                raw = (-(1 << (sg.length - 1)), (1 << (sg.length - 1)) - 1) if sg.is_signed else (0, (1 << sg.length) - 1)
                ends = [r * float(sg.scale) + float(sg.offset) for r in raw]
                if min(ends) < lo or max(ends) > hi:
                    lims.append((sg.name, lo, hi))
            self._limits[m.frame_id] = tuple(lims)

    def _decode(self, arbitration_id: int, data: bytes, is_extended: bool) -> tuple[Message | None, Any]:
        """(message, signals) of a frame through cantools; (None, None) when it is rejected
        (counted). ``feed`` takes a :class:`FastMessage` instead for the usual frames: an int
        id of a compiled message, bytes of its length, standard flag; same message, same values."""
        n = len(data)
        if n > CAN_FD_MAX_BYTES:
            self._reject("too_long", f"frame id {_frame_id(arbitration_id)} of {n} data bytes: a CAN frame holds at most "
                                     f"{CAN_FD_MAX_BYTES} (CAN FD; classic 8)")
            return None, None
        try:
            msg = self.db.get_message_by_frame_id(arbitration_id)
        except KeyError:
            msg = None
        if msg is None or bool(msg.is_extended_frame) != bool(is_extended):
            self._unknown(arbitration_id)
            return None, None
        if n != msg.length:  # cantools would drop excess bytes and decode the rest as a valid frame
            self._reject("bad_length", f"{msg.name} 0x{msg.frame_id:X} with {n} data bytes, the DBC says "
                                       f"{msg.length}")
            return None, None
        try:
            return msg, msg.decode(bytes(data), decode_choices=True, scaling=True)
        except Exception as exc:  # cantools raises several types for short or malformed data
            self._reject("bad_frame", f"{msg.name} 0x{msg.frame_id:X} data {bytes(data)[:16].hex()}: {describe(exc)}")
            return None, None

    def feed(self, arbitration_id: int, data: bytes, is_extended: bool, t_arrival: float) -> list[NavFix | LegChange]:
        """Decode one frame received at ``t_arrival`` (UNIX s)."""
        fm = self._fast.get(arbitration_id) if type(arbitration_id) is int else None
        if fm is not None and type(data) is bytes and len(data) == fm.length and not is_extended:
            msg, sig, fid = fm.message, fm.decode(data), fm.frame_id  # the usual frame
        else:
            msg, sig = self._decode(arbitration_id, data, is_extended)
            if msg is None:
                return []
            fid = msg.frame_id
        for name, lo, hi in self._limits.get(fid, ()):
            v = sig[name]
            if not isinstance(v, (NamedSignalValue, str)) and not lo <= v <= hi:  # a choice is "n/a"
                return self._reject("out_of_range", f"{msg.name}: {name} {v!r} outside its DBC range "
                                                    f"[{lo:.6g}, {hi:.6g}]")
        t = float(t_arrival) + self._offset_s
        out: list[NavFix | LegChange] = []
        if fid == NAV_POSITION:
            lat, lon = float(sig["Latitude"]), float(sig["Longitude"])
            if abs(lat) > 90.0 or abs(lon) > 180.0:
                return self._reject("out_of_range", f"{msg.name}: position {lat}, {lon} out of range")
            out.append(make_fix(t, lat, lon, None, None, None, None, "can:ATR_NavPosition"))
        elif fid == NAV_ATTITUDE:
            hdg = float(sig["Heading"])
            if not 0.0 <= hdg < 360.0:
                return self._reject("out_of_range", f"{msg.name}: heading {hdg} outside [0, 360)")
            out.append(make_fix(t, None, None, hdg, None, None, _value(sig["Speed"]), "can:ATR_NavAttitude"))
        elif fid == NAV_ALTITUDE:
            alt, depth = _value(sig["Altitude"]), _value(sig["Depth"])
            out.append(make_fix(t, None, None, None, alt, depth, None, "can:ATR_NavAltitude"))
        elif fid == TIME:
            us = int(sig["Microseconds"])
            if us > 999_999:
                return self._reject("out_of_range", f"{msg.name}: microseconds {us} > 999999")
            self._offset_s = int(sig["Seconds"]) + us * 1e-6 - float(t_arrival)
        elif fid == MISSION_LEG:
            leg = (int(sig["Leg"]), str(sig["Survey"]) == "Survey")
            if leg != self._leg:
                self._leg = leg
                out.append(LegChange(t=t, leg=leg[0], survey=leg[1]))
        else:
            self._unknown(fid)
            return []
        self.counts["accepted"] += 1
        return out

    def _unknown(self, arbitration_id: Any) -> None:
        """A frame not in the DBC: counted (a shared bus carries many), the first one logged."""
        self.counts["unknown"] += 1
        if self.counts["unknown"] == 1:  # ordinary traffic on a shared bus: information, not a fault
            log.info("CAN frame id %r is not in the DBC: such frames are counted as 'unknown', not logged",
                     arbitration_id)

    def _reject(self, reason: str, detail: str) -> list[NavFix | LegChange]:
        self.counts[reason] += 1
        self.last_reject = detail
        if self.counts[reason] == 1:  # one line per reason; the rest are counted
            log.warning("CAN frame rejected (%s): %s; further %s rejections are counted, not logged",
                        reason, detail, reason)
        return []
