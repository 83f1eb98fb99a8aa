"""NMEA 0183 over a serial line: any URL pyserial opens (ICD section 2).

``/dev/ttyS1`` aboard, ``socket://host:port`` for a serial-to-Ethernet server, ``loop://`` and
a pty slave path on the bench. Bytes go through :class:`hw.framing.LineFramer`; every
complete line becomes one record ``LogRecord(t=arrival, link="nmea", msg=line)``: garbage
lines are delivered too (the recorder keeps them, the decoder counts and drops them).

With ``reconnect=True`` a port that fails to open or drops (USB adapter unplugged, pty master
closed, TCP server gone) is reopened with exponential backoff (``backoff_s`` doubling up to
``max_backoff_s``); the link reports ``connected`` and counts ``disconnects``. Without it,
the failure raises :class:`hw.errors.LinkError`.
"""

from __future__ import annotations

import logging
import time
from collections import deque

import serial

from atr_node.errors import describe
from atr_node.io.atrlog import LogRecord

from .base import Link
from .errors import LinkError, LinkSpecError
from .framing import LineFramer

log = logging.getLogger(__name__)
READ_CHUNK = 1 << 16


class SerialNmeaLink(Link):
    """NMEA sentences from a pyserial URL.

    Parameters
    ----------
    url
        Anything ``serial.serial_for_url`` accepts: a device or pty path, ``socket://host:port``,
        ``loop://``, ``rfc2217://host:port``.
    baudrate
        Line speed (ignored by ``socket://`` and ``loop://``).
    reconnect
        Reopen the port with backoff when it fails, instead of raising.
    backoff_s, max_backoff_s
        First and longest wait between reconnection attempts.
    max_line_bytes
        Longest line kept by the framer (longer ones are dropped and counted).
    """

    kind = "nmea"

    def __init__(self, url: str, *, baudrate: int = 115200, reconnect: bool = False, backoff_s: float = 0.5,
                 max_backoff_s: float = 10.0, max_line_bytes: int = 1024) -> None:
        super().__init__(url)
        if not isinstance(url, str) or not url:
            raise LinkSpecError(f"serial link: url {url!r}: expected a device path or a pyserial URL "
                                f"like 'socket://host:port' or 'loop://'")
        if int(baudrate) <= 0 or backoff_s <= 0 or max_backoff_s < backoff_s:
            raise LinkSpecError(f"serial link {url}: expected baudrate > 0 and 0 < backoff_s <= max_backoff_s, "
                                f"got {baudrate}, {backoff_s}, {max_backoff_s}")
        self.url = url
        self.baudrate = int(baudrate)
        self.reconnect = bool(reconnect)
        self.backoff_s = float(backoff_s)
        self.max_backoff_s = float(max_backoff_s)
        self.framer = LineFramer(max_line_bytes)
        self.port: serial.SerialBase | None = None
        self._pending: deque[LogRecord] = deque()
        self._wait_s = self.backoff_s
        self._next_try = 0.0
        self._open()

    @property
    def connected(self) -> bool:
        return self.port is not None

    def _open(self) -> None:
        try:
            self.port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            self._failed(f"cannot open: {describe(exc)}")
            return
        if self.counts["disconnects"]:
            log.info("serial link %s: reconnected", self.url)
        self._wait_s = self.backoff_s

    def _failed(self, why: str) -> None:
        """Drop the port; raise unless reconnecting, then schedule the next attempt."""
        if self.port is not None:
            self.counts["disconnects"] += 1
            try:
                self.port.close()
            except (serial.SerialException, OSError):
                pass
            self.port = None
        self.framer.flush()  # a partial line cannot be completed by a new connection
        if not self.reconnect:
            raise LinkError(f"serial link {self.url}: {why}")
        log.warning("serial link %s: %s; retrying in %.1f s", self.url, why, self._wait_s)
        self._next_try = time.monotonic() + self._wait_s
        self._wait_s = min(self._wait_s * 2.0, self.max_backoff_s)

    def _recv_internal(self, timeout: float) -> LogRecord | None:
        if self._pending:
            return self._pending.popleft()
        if self.port is None:
            wait = self._next_try - time.monotonic()
            if wait > timeout:
                time.sleep(timeout)
                return None
            time.sleep(max(wait, 0.0))
            self._open()
            if self.port is None:
                return None
        port = self.port
        try:
            if port.timeout is None or abs(port.timeout - timeout) > 1e-3:
                port.timeout = timeout  # a termios call on real ports: only when it changes
            data = port.read(1)  # blocks up to timeout for the first byte
            # then what is already there: read(in_waiting) returns at once. Never more than
            # in_waiting: pyserial's socket:// handler would look past the data, meet the peer's
            # close and discard what it had read
            while data and len(data) < READ_CHUNK and (waiting := port.in_waiting):
                data += port.read(waiting)
        except (serial.SerialException, OSError) as exc:
            self._failed(f"read failed: {describe(exc)}")
            return None
        if not data:
            return None
        t = time.time()
        self.counts["bytes"] += len(data)
        overflows = self.framer.overflows
        for line in self.framer.feed(data):
            self._pending.append(LogRecord(t=t, link="nmea", msg=line))
        self.counts["overlong_dropped"] += self.framer.overflows - overflows
        return self._pending.popleft() if self._pending else None

    def write(self, data: bytes) -> int:
        """Write raw bytes to the port (``loop://`` tests, or a device that takes commands)."""
        if self.port is None:
            raise LinkError(f"serial link {self.url}: not connected")
        return int(self.port.write(data) or 0)

    def _shutdown_internal(self) -> None:
        if self.port is not None:
            try:
                self.port.close()
            except (serial.SerialException, OSError):
                pass
            self.port = None
