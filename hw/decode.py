"""One entry point from link records to navigation: :class:`NavDecoder`.

The pipeline feeds every record it receives (live or replayed) and gets back what it means
for navigation::

    nmea record  -> NmeaDecoder  -> [NavFix]              (0 or 1)
    can record   -> CanNavDecoder -> [NavFix | LegChange]  (0 or 1)
    sonar record -> []                                     (tiles are the pipeline's business)

Nothing here raises on link input; the counters say what was accepted and why the rest was
dropped (``stats()``), for the heartbeat and the run report.
"""

from __future__ import annotations

import logging
from typing import Any

from atr_node.io.atrlog import LogRecord
from atr_node.records.nav import NavFix

from .can_nav import CanNavDecoder, LegChange
from .nmea_decoder import NmeaDecoder

NavEvent = NavFix | LegChange

log = logging.getLogger(__name__)


class NavDecoder:
    """Records in, :class:`NavFix` and :class:`LegChange` out.

    Parameters
    ----------
    dbc
        CAN database path (None = ``config/atr_node.dbc``).
    date_from_arrival
        See :class:`hw.nmea.NmeaDecoder`.
    """

    def __init__(self, *, dbc: str | None = None, date_from_arrival: bool = True) -> None:
        self.nmea = NmeaDecoder(date_from_arrival=date_from_arrival)
        self.can = CanNavDecoder(dbc)

    def feed(self, record: LogRecord) -> list[NavEvent]:
        """Decode one record; [] when it carries no navigation or was dropped."""
        link = record.link
        if link == "nmea":
            msg = record.msg
            if type(msg) is bytes:  # the usual case: no copy, no further check
                return self.nmea.feed(msg, record.t)
            if not isinstance(msg, (bytes, bytearray)):
                self.nmea.counts["garbage"] += 1
                if self.nmea.counts["garbage"] == 1:
                    log.warning("NMEA record of t %r holds a %s, not bytes: rejected as garbage; further "
                                "garbage is counted, not logged", record.t, type(msg).__name__)
                return []
            return self.nmea.feed(bytes(msg), record.t)
        if link == "can":
            m = record.msg
            if type(m) is dict:
                # the usual case, checked once here by exact type: what int(), bytes() and
                # bool() below would return unchanged
                cid, data, ext = m.get("id"), m.get("data"), m.get("ext")
                if type(cid) is int and type(data) is bytes and type(ext) is bool:
                    return self.can.feed(cid, data, ext, record.t)
            try:
                # data must already be bytes: bytes(<int>) would allocate that many zeros
                if not isinstance(m["data"], (bytes, bytearray)):
                    raise TypeError("CAN data is not bytes")
                cid, data, ext = int(m["id"]), bytes(m["data"]), bool(m["ext"])
            except (TypeError, KeyError, ValueError, OverflowError) as exc:
                self.can._reject("bad_frame", f"CAN record of t {record.t!r}: {type(exc).__name__} "
                                              f"{exc or 'with no message'} (expected a map of int id, bytes data, "
                                              f"bool ext)")
                return []
            return self.can.feed(cid, data, ext, record.t)
        return []

    def stats(self) -> dict[str, Any]:
        """Counters: ``{"nmea": {...}, "nmea_types": {...}, "can": {...}}``."""
        return {"nmea": dict(self.nmea.counts), "nmea_types": dict(self.nmea.by_type), "can": dict(self.can.counts)}
