"""Contacts over serial as ``$EXWPT`` sentences, the external-contact input of SonarWiz.

Layout, as Chesapeake Technology describe their "Waypoint Contact" serial input (Chesapeake
Times vol. 14, July 2023, "Contacts: an update", https://chesapeaketech.com/contacts-an-update/)::

    $EXWPT,<category>,<hh:mm:ss.sss>,<lon>,<lat>,<depth>,<depth unit>,<description>*<checksum>

    category     0 default, 1 unknown, 2 surface mine, 3 submerged mine, 4 wreck
    time         UTC time of day of the contact, with milliseconds (no date field)
    lon, lat     WGS84 decimal degrees, longitude FIRST, signed (west and south negative)
    depth        signed metres, negative below the surface, as in their example ("-23");
                 null when the depth of the seabed there is not known
    depth unit   M
    description  free text; ours: ``ATR <id> <state> bel <Bel(T)>``, shortened to
                 ``ATR <id> <N|U|W> <Bel(T)>`` then ``ATR <id>`` when a long position,
                 depth and id would break the 82-character limit

Their published example (``$EXWPT,4,15:30:30.000,-4.1486191821828067,50.334671400393564,-23,M,
Suspicious 000HH``) shows no ``*`` before the checksum and 16 decimals; we follow IEC 61162-1
framing (``*`` + two hex digits of the XOR checksum, CR LF, at most 82 characters, written by
:func:`hw.nmea.format_sentence`) and 7 decimals (about 1 cm), which any NMEA reader takes.
Category 3 (submerged mine) is the default, as the node reports proud seabed mine-like
contacts. Where the article and a given SonarWiz version differ, the fields above are the
place to change (``docs/operators.md``).

:class:`ExwptOutput` is the adapter: ``offer(contact)`` for every contact message, it sends a
sentence for a new contact and for an update that moved it by ``min_move_m`` or changed its
belief by ``min_bel_change`` (a serial line at 9600 baud carries about 12 sentences a second;
small refinements are not worth a new contact row topside). Withdrawn contacts are not sent
unless ``send_withdrawn``. Sentences wait in a per-contact queue while the port is down or
slow, so a contact accepted is never lost, only its intermediate states coalesced; the port is
reopened on the next ``offer``/``flush``.
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Mapping

import serial

from ..errors import AtrError
from ..io.nmea_encode import NmeaError, format_sentence

log = logging.getLogger(__name__)

ADDRESS = "EXWPT"
CATEGORIES = {0: "default", 1: "unknown", 2: "surface mine", 3: "submerged mine", 4: "wreck"}
SUBMERGED_MINE = 3


def _time_of_day(t: float) -> str:
    """``hh:mm:ss.sss`` UTC of UNIX seconds ``t``, rounded once to the millisecond."""
    if not math.isfinite(t):
        raise AtrError(f"$EXWPT time {t!r}: expected finite UNIX seconds")
    ms = round(t * 1000.0) % 86_400_000
    h, rem = divmod(ms, 3_600_000)
    m, rem = divmod(rem, 60_000)
    return f"{h:02d}:{m:02d}:{rem // 1000:02d}.{rem % 1000:03d}"


def format_exwpt(contact: Mapping[str, Any], *, category: int = SUBMERGED_MINE,
                 depth_m: float | None = None) -> bytes:
    """One ``$EXWPT`` sentence (bytes, CR LF included) for an ICD section 3 contact.

    Parameters
    ----------
    contact : mapping
        The contact message (``id``, ``state``, ``t``, ``lat_deg``, ``lon_deg``, ``bel`` used).
    category : int
        SonarWiz contact category, 0-4 (see :data:`CATEGORIES`).
    depth_m : float or None
        Water depth at the contact, metres, positive down; written negative; None = null field.

    Raises
    ------
    AtrError
        Category outside 0-4, position or depth not finite or out of range.
    """
    if category not in CATEGORIES:
        raise AtrError(f"$EXWPT category {category!r}: expected one of {sorted(CATEGORIES)} "
                       f"({', '.join(f'{k} {v}' for k, v in CATEGORIES.items())})")
    lat, lon = float(contact["lat_deg"]), float(contact["lon_deg"])
    if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90.0 and abs(lon) <= 180.0):
        raise AtrError(f"$EXWPT contact {contact.get('id')}: position ({lat!r}, {lon!r}) is not a WGS84 position")
    depth = ""
    if depth_m is not None:
        if not (math.isfinite(depth_m) and 0.0 <= depth_m < 12_000.0):
            raise AtrError(f"$EXWPT depth {depth_m!r}: expected metres below the surface in [0, 12000)")
        depth = f"{-depth_m:.1f}" if depth_m > 0 else "0.0"
    cid, state, bel = int(contact["id"]), str(contact["state"]), float(contact["bel"])
    fields = [str(category), _time_of_day(float(contact["t"])), f"{lon:.7f}", f"{lat:.7f}", depth, "M"]
    # the 82-character limit leaves 19 to 38 characters for the description: the longest that fits
    for description in (f"ATR {cid} {state} bel {bel:.3f}", f"ATR {cid} {state[0].upper()} {bel:.2f}", f"ATR {cid}"):
        try:
            return format_sentence(ADDRESS, [*fields, description])
        except NmeaError:
            continue
    raise AtrError(f"$EXWPT contact {cid}: id too long for an 82-character sentence")


@dataclass
class ExwptStats:
    offered: int = 0
    sent: int = 0
    skipped_small: int = 0
    skipped_withdrawn: int = 0
    write_errors: int = 0
    unformattable: int = 0
    """Contacts no sentence can carry (an id too long for 82 characters): logged and dropped."""
    bytes_sent: int = 0


class ExwptOutput:
    """Send new and updated contacts as ``$EXWPT`` over a serial port (any pyserial URL).

    Parameters
    ----------
    url : str
        ``/dev/ttyUSB0``, a pty path, ``socket://host:port``, ``loop://``, ``rfc2217://...``.
    baudrate : int
        Line speed (SonarWiz serial inputs default to 9600).
    category, depth_m
        See :func:`format_exwpt`.
    min_move_m, min_bel_change
        An update is sent when the contact moved at least this far (metric frame) or its
        Bel(T) changed at least this much since the last sentence sent for it.
    send_withdrawn : bool
        Also send withdrawn contacts (description says ``withdrawn``).
    port : serial.SerialBase, optional
        An already open port (then ``url`` only names it in messages).
    """

    def __init__(self, url: str, *, baudrate: int = 9600, category: int = SUBMERGED_MINE,
                 depth_m: float | None = None, min_move_m: float = 0.5, min_bel_change: float = 0.02,
                 send_withdrawn: bool = False, write_timeout_s: float = 1.0,
                 port: serial.SerialBase | None = None) -> None:
        format_exwpt({"id": 0, "state": "new", "t": 0.0, "lat_deg": 0.0, "lon_deg": 0.0, "bel": 0.0},
                     category=category, depth_m=depth_m)  # check the options before any contact
        self.url, self.baudrate = url, baudrate
        self.category, self.depth_m = category, depth_m
        self.min_move_m, self.min_bel_change = min_move_m, min_bel_change
        self.send_withdrawn = send_withdrawn
        self.write_timeout_s = write_timeout_s
        self.stats = ExwptStats()
        self._sent: dict[int, Mapping[str, Any]] = {}
        self._pending: OrderedDict[int, Mapping[str, Any]] = OrderedDict()
        self._port = port if port is not None else self._open(strict=True)

    def _open(self, *, strict: bool) -> serial.SerialBase | None:
        try:
            return serial.serial_for_url(self.url, baudrate=self.baudrate, write_timeout=self.write_timeout_s)
        except (serial.SerialException, ValueError, OSError) as exc:
            if strict:
                raise AtrError(f"$EXWPT output {self.url!r}: cannot open it ({exc}); expected a serial device "
                               f"or a pyserial URL (/dev/ttyUSB0, socket://host:port, loop://)") from None
            log.warning("$EXWPT output %s: still cannot open it (%s)", self.url, exc)
            return None

    @property
    def port(self) -> serial.SerialBase | None:
        return self._port

    @property
    def pending(self) -> int:
        return len(self._pending)

    def _worth_sending(self, c: Mapping[str, Any]) -> bool:
        if c["state"] == "withdrawn":
            if not self.send_withdrawn:
                self.stats.skipped_withdrawn += 1
                return False
            return True
        last = self._sent.get(int(c["id"]))
        if last is None or c["state"] == "new" or last["state"] == "withdrawn":
            return True
        moved = math.hypot(c["east_m"] - last["east_m"], c["north_m"] - last["north_m"])
        if moved >= self.min_move_m or abs(c["bel"] - last["bel"]) >= self.min_bel_change:
            return True
        self.stats.skipped_small += 1
        return False

    def offer(self, contact: Mapping[str, Any]) -> int:
        """Queue ``contact`` if it is worth a sentence, then flush; returns sentences written."""
        self.stats.offered += 1
        if self._worth_sending(contact):
            cid = int(contact["id"])
            self._pending.pop(cid, None)  # the newest state of a contact goes to the back
            self._pending[cid] = dict(contact)
        return self.flush()

    def flush(self) -> int:
        """Write queued sentences in arrival order; stop at the first failure (they stay queued)."""
        if not self._pending:
            return 0
        if self._port is None:
            self._port = self._open(strict=False)
            if self._port is None:
                return 0
        n = 0
        while self._pending:
            cid, c = next(iter(self._pending.items()))
            try:
                line = format_exwpt(c, category=self.category, depth_m=self.depth_m)
            except AtrError as exc:
                self.stats.unformattable += 1
                log.warning("$EXWPT output %s: contact %s dropped: %s", self.url, cid, exc)
                del self._pending[cid]
                continue
            try:
                written = self._port.write(line)
                self._port.flush()
            except (serial.SerialException, OSError) as exc:
                self.stats.write_errors += 1
                log.warning("$EXWPT output %s: write failed (%s); %d contact(s) queued, reopening next time",
                            self.url, exc, len(self._pending))
                self._close_port()
                break
            del self._pending[cid]
            self._sent[cid] = c
            self.stats.sent += 1
            self.stats.bytes_sent += written or len(line)
            n += 1
        return n

    def _close_port(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            except (serial.SerialException, OSError):
                pass
            self._port = None

    def close(self) -> None:
        self._close_port()
