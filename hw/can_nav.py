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
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import cantools
from cantools.database.can import Database
from cantools.database.namedsignalvalue import NamedSignalValue

from atr_node.records.nav import NavFix

from .errors import CanCodecError, LinkSpecError

DEFAULT_DBC = Path(__file__).resolve().parent.parent / "config" / "atr_node.dbc"
NAV_POSITION, NAV_ATTITUDE, NAV_ALTITUDE, TIME, MISSION_LEG = 0x100, 0x101, 0x102, 0x103, 0x104
NOT_AVAILABLE = "NotAvailable"

Frame = tuple[int, bytes, bool]
"""(arbitration_id, data, is_extended)."""


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
        ``bad_frame`` (wrong length or undecodable) and ``invalid`` (values out of range).
    """

    def __init__(self, dbc: str | None = None) -> None:
        self.db = load_dbc(str(dbc) if dbc else None)
        self.counts: Counter[str] = Counter()
        self.last_reject = ""
        self._offset_s = 0.0  # vehicle clock - arrival clock, from the last ATR_Time frame
        self._leg: tuple[int, bool] | None = None

    def feed(self, arbitration_id: int, data: bytes, is_extended: bool, t_arrival: float) -> list[NavFix | LegChange]:
        """Decode one frame received at ``t_arrival`` (UNIX s)."""
        try:
            msg = self.db.get_message_by_frame_id(arbitration_id)
        except KeyError:
            msg = None
        if msg is None or bool(msg.is_extended_frame) != bool(is_extended):
            self.counts["unknown"] += 1
            return []
        try:
            sig = msg.decode(bytes(data), decode_choices=True, scaling=True)
        except Exception as exc:  # cantools raises several types for short or malformed data
            return self._reject("bad_frame", f"{msg.name} 0x{arbitration_id:X} data {bytes(data).hex()}: {exc}")
        t = float(t_arrival) + self._offset_s
        out: list[NavFix | LegChange] = []
        fid = msg.frame_id
        if fid == NAV_POSITION:
            lat, lon = float(sig["Latitude"]), float(sig["Longitude"])
            if abs(lat) > 90.0 or abs(lon) > 180.0:
                return self._reject("invalid", f"{msg.name}: position {lat}, {lon} out of range")
            out.append(NavFix(t=t, lat_deg=lat, lon_deg=lon, source="can:ATR_NavPosition"))
        elif fid == NAV_ATTITUDE:
            hdg = float(sig["Heading"])
            if not 0.0 <= hdg < 360.0:
                return self._reject("invalid", f"{msg.name}: heading {hdg} outside [0, 360)")
            out.append(NavFix(t=t, heading_deg=hdg, speed_m_s=_value(sig["Speed"]), source="can:ATR_NavAttitude"))
        elif fid == NAV_ALTITUDE:
            alt, depth = _value(sig["Altitude"]), _value(sig["Depth"])
            out.append(NavFix(t=t, altitude_m=alt, depth_m=depth, source="can:ATR_NavAltitude"))
        elif fid == TIME:
            us = int(sig["Microseconds"])
            if us > 999_999:
                return self._reject("invalid", f"{msg.name}: microseconds {us} > 999999")
            self._offset_s = int(sig["Seconds"]) + us * 1e-6 - float(t_arrival)
        elif fid == MISSION_LEG:
            leg = (int(sig["Leg"]), str(sig["Survey"]) == "Survey")
            if leg != self._leg:
                self._leg = leg
                out.append(LegChange(t=t, leg=leg[0], survey=leg[1]))
        else:
            self.counts["unknown"] += 1
            return []
        self.counts["accepted"] += 1
        return out

    def _reject(self, reason: str, detail: str) -> list[NavFix | LegChange]:
        self.counts[reason] += 1
        self.last_reject = detail
        return []
