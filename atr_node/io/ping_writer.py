"""What the XTF and JSF writers share: port and starboard tiles of the same pings become one
ping record of the file, records of an ``.atrlog`` are dispatched, the last lone tile is
written at close.

A subclass sets ``self._fh`` (the open file), ``self.stats`` (with ``tiles``,
``unpaired_tiles``, ``rejected`` and ``skipped``) and ``self._pending = None``, and
implements :meth:`_write_pings`; :meth:`_before_tile`, :meth:`_write_link` and
:meth:`_before_close` are optional hooks.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import TileError
from ..records.tile import Tile
from .atrlog import LogRecord
from .xtf_packets import KNOT_M_S


class PairedPingWriter:
    """Base of :class:`~.xtf_write.XtfWriter` and :class:`~.jsf_write.JsfWriter` (module docstring)."""

    _fh: Any
    stats: Any
    _pending: Tile | None

    def write_tile(self, tile: Tile) -> None:
        """Queue one tile; it is written with its other side when that arrives with the same pings."""
        self._before_tile(tile)
        self.stats.tiles += 1
        p = self._pending
        if (p is not None and p.side != tile.side and p.rows == tile.rows
                and np.array_equal(p.ping_time, tile.ping_time)):
            self._write_pings({p.side: p, tile.side: tile})
            self._pending = None
            return
        if p is not None:
            self.stats.unpaired_tiles += 1
            self._write_pings({p.side: p})
        self._pending = tile

    def write_record(self, rec: LogRecord) -> None:
        """A record of an .atrlog: sonar tiles are written, other links as :meth:`_write_link`
        says (counted in ``skipped`` when the format cannot hold them)."""
        if rec.link != "sonar":
            if not self._write_link(rec):
                self.stats.skipped[rec.link] += 1
            return
        try:
            tile = Tile.from_map(rec.msg)
        except TileError as exc:
            self.stats.rejected.append(f"record at byte {rec.offset}: {exc}")
            return
        self.write_tile(tile)

    def close(self) -> None:
        """Write the lone tile left, finish the file and close it (idempotent)."""
        if self._fh.closed:
            return
        if self._pending is not None:
            self.stats.unpaired_tiles += 1
            self._write_pings({self._pending.side: self._pending})
            self._pending = None
        self._before_close()
        self._fh.close()

    def __enter__(self) -> "PairedPingWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    @staticmethod
    def _interval_and_speed(tile: Tile) -> tuple[float, float]:
        """(median ping interval in s, speed in knots = ``dx_m`` / interval) of a tile's pings;
        both 0 for a single ping (the formats store the speed in knots)."""
        dt = float(np.median(np.diff(tile.ping_time))) if tile.rows > 1 else 0.0
        return dt, (tile.dx_m / dt / KNOT_M_S if dt > 0 else 0.0)

    # -- hooks -------------------------------------------------------------------------------
    def _write_pings(self, tiles: dict[str, Tile]) -> None:
        raise NotImplementedError

    def _before_tile(self, tile: Tile) -> None:
        """Called with every tile before it is queued (e.g. a file header from the first)."""

    def _write_link(self, rec: LogRecord) -> bool:
        """Write a non-sonar record; False: the format does not hold it."""
        return False

    def _before_close(self) -> None:
        """Called once before the file is closed, after the last pings."""
