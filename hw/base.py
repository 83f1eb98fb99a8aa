"""The one interface of every link driver: :class:`Link` (python-can's ``BusABC`` model).

A link yields :class:`atr_node.io.atrlog.LogRecord` exactly as an ``.atrlog`` stores them::

    LogRecord(t=arrival UNIX seconds, link="nmea", msg=sentence bytes, no CR LF)
    LogRecord(t=...,                  link="can",  msg={"id": int, "data": bytes, "ext": bool})
    LogRecord(t=...,                  link="sonar", msg=tile map dict, msgpack-decoded, NOT validated)

so a replayed log and a live link are interchangeable. The base owns the timeout loop,
iteration, the context manager and an idempotent :meth:`Link.shutdown`; a backend implements
:meth:`Link._recv_internal` (and :meth:`Link._shutdown_internal` when it holds resources).
A backend that will never deliver more (end of a replayed log) sets ``at_end``; iteration then
stops. ``counts`` holds per-link counters (records, bytes, dropped ... ) for the heartbeat.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections import Counter
from typing import Any, Iterator

from atr_node.io.atrlog import LogRecord

from .errors import LinkClosedError

POLL_S = 0.1
"""Longest single wait inside ``recv`` and iteration, so shutdown and ``at_end`` are noticed."""


class Link(ABC):
    """Abstract link: a source of :class:`LogRecord`.

    Attributes
    ----------
    name
        Human-readable identity (URL, channel or endpoint) used in messages.
    at_end
        True once the link will deliver nothing more (end of a recording).
    counts
        Counters of what the link received, delivered and dropped.
    last_reject
        What the last dropped input was and why, or ``""``.
    """

    kind: str = "?"
    """Which ``LogRecord.link`` this driver yields: ``nmea``, ``can``, ``sonar`` or ``*`` (any)."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.at_end = False
        self.counts: Counter[str] = Counter()
        self.last_reject = ""
        self._closed = False

    @abstractmethod
    def _recv_internal(self, timeout: float) -> LogRecord | None:
        """Wait at most ``timeout`` s (at most :data:`POLL_S`) for one record; None on timeout or end."""

    def _shutdown_internal(self) -> None:
        """Release ports, sockets and buses (called once)."""

    @property
    def closed(self) -> bool:
        return self._closed

    def recv(self, timeout: float | None = None) -> LogRecord | None:
        """Next record, or None after ``timeout`` seconds (None: wait until one comes or the end).

        Raises
        ------
        LinkClosedError
            The link was shut down.
        """
        if self._closed:
            raise LinkClosedError(f"link {self.name}: recv() after shutdown()")
        deadline = None if timeout is None else time.monotonic() + max(float(timeout), 0.0)
        while not self.at_end:
            # wait in slices so a shutdown() from another thread is noticed within POLL_S
            left = POLL_S if deadline is None else min(max(deadline - time.monotonic(), 0.0), POLL_S)
            rec = self._recv_internal(left)
            if rec is not None:
                self.counts["records"] += 1
                return rec
            if self._closed or (deadline is not None and time.monotonic() >= deadline):
                return None
        return None

    def __iter__(self) -> Iterator[LogRecord]:
        """Records until ``at_end`` or shutdown; waits in slices of :data:`POLL_S`."""
        while not self._closed and not self.at_end:
            rec = self.recv(timeout=POLL_S)
            if rec is not None:
                yield rec

    def shutdown(self) -> None:
        """Close the link; safe to call more than once."""
        if self._closed:
            return
        self._closed = True
        self._shutdown_internal()

    def __enter__(self) -> "Link":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.shutdown()

    def __del__(self) -> None:
        # a link dropped without shutdown() must not leak its port or socket
        try:
            if not getattr(self, "_closed", True):
                self.shutdown()
        except Exception:  # interpreter teardown: nothing useful left to do
            pass

    def __repr__(self) -> str:
        state = "closed" if self._closed else ("at end" if self.at_end else "open")
        return f"{type(self).__name__}({self.name!r}, {state})"
