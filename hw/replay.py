"""Replay: recordings as ordinary links, and pacing as a wrapper with a speed factor.

* :class:`ReplayLink` plays an ``.atrlog`` (ICD section 4) and yields its records unchanged,
  ``t`` included, so the same log through the same pipeline gives the same result.
* :class:`StampedNmeaLink` plays a time-stamped NMEA text log (openrvdas style, one
  ``2014-08-01T00:00:00.183000Z $HEHDT,218.53,T*12`` per line) as ``nmea`` records.
* :class:`CandumpLink` plays a ``candump -l`` log (``(1502984866.429162) can0 09F10DCC#FCF8...``,
  ``#`` comment lines skipped) as ``can`` records, parsing each line with python-can.
* :class:`TimeMerge` merges several recordings into one stream ordered by ``t``.
* :class:`Paced` wraps any link and releases each record when its ``t`` is due on the wall
  clock: at 1x, at any factor, or (``speed=None``) as fast as the consumer takes them.

Pacing (``speed`` s, anchor = first record's ``t`` and the wall clock at that moment)::

    due(record) = wall0 + (record.t - t0) / speed

Gaps in the log longer than ``max_gap_s`` are shortened to it (the anchor moves), so a
recording with an hour of silence need not be waited out. Records whose ``t`` goes back are
released at once.
"""

from __future__ import annotations

import io
import os
import time
from datetime import datetime
from typing import Iterable, Iterator

import can

from atr_node.io.atrlog import LINKS, AtrLogReader, LogRecord

from .base import Link
from .errors import LinkSpecError


class ReplayLink(Link):
    """Records of an ``.atrlog``, in file order, unchanged.

    Parameters
    ----------
    path
        The log file.
    links
        Keep only these link kinds (``"sonar"``, ``"nmea"``, ``"can"``, or a comma-separated
        string of them); None = all.
    strict
        Raise on a malformed record instead of skipping it with a warning.

    Attributes
    ----------
    reader
        The underlying :class:`AtrLogReader`, with its counters (``rejected``, ``truncated``).
    """

    kind = "*"

    def __init__(self, path: str | os.PathLike[str], *, links: Iterable[str] | None = None,
                 strict: bool = False) -> None:
        super().__init__(str(path))
        if not os.path.isfile(path):
            raise LinkSpecError(f"replay link: {path}: no such file; expected an .atrlog recording")
        if isinstance(links, str):  # from a URL query string: links=nmea,can
            links = [x for x in links.split(",") if x]
        self.links = None if links is None else frozenset(links)
        if self.links is not None and not self.links <= set(LINKS):
            raise LinkSpecError(f"replay link {path}: links {sorted(self.links)}: expected a subset of {list(LINKS)}")
        self.reader = AtrLogReader(path, strict=strict)
        self._it: Iterator[LogRecord] = iter(self.reader)

    def _recv_internal(self, timeout: float) -> LogRecord | None:
        for rec in self._it:
            if self.links is None or rec.link in self.links:
                return rec
            self.counts["filtered"] += 1
        self.at_end = True
        return None

    def _shutdown_internal(self) -> None:
        close = getattr(self._it, "close", None)
        if close is not None:
            close()  # closes the file held by the generator


class IterLink(Link):
    """Any iterable of :class:`LogRecord` as a link (an XTF file read as records, a filtered
    log): the end of the iterable is the end of the link."""

    kind = "*"

    def __init__(self, records: Iterable[LogRecord], *, name: str = "records") -> None:
        super().__init__(name)
        self._it: Iterator[LogRecord] = iter(records)

    def _recv_internal(self, timeout: float) -> LogRecord | None:
        for rec in self._it:
            return rec
        self.at_end = True
        return None

    def _shutdown_internal(self) -> None:
        close = getattr(self._it, "close", None)
        if close is not None:
            close()


class StampedNmeaLink(Link):
    """A text log of ISO 8601 time stamps followed by one NMEA sentence, as ``nmea`` records.

    Lines without a parseable time stamp are counted (``bad_lines``) and skipped.
    """

    kind = "nmea"

    def __init__(self, path: str | os.PathLike[str]) -> None:
        super().__init__(str(path))
        try:
            self._fh = open(path, "rb")
        except OSError as exc:
            raise LinkSpecError(f"stamped NMEA link: {path}: {exc.strerror}; expected a text log") from None

    def _recv_internal(self, timeout: float) -> LogRecord | None:
        for line in self._fh:
            stamp, _, sentence = line.strip().partition(b" ")
            try:
                t = datetime.fromisoformat(stamp.decode("ascii").replace("Z", "+00:00")).timestamp()
            except (UnicodeDecodeError, ValueError):
                self.counts["bad_lines"] += 1
                self.last_reject = f"{self.name}: no time stamp in {line[:40]!r}"
                continue
            if sentence:
                return LogRecord(t=t, link="nmea", msg=sentence.strip())
            self.counts["bad_lines"] += 1
        self.at_end = True
        return None

    def _shutdown_internal(self) -> None:
        self._fh.close()


class CandumpLink(Link):
    """A ``candump -l`` text log as ``can`` records, time stamps kept.

    Comment (``#``) and blank lines are skipped; a line python-can cannot parse is counted
    (``bad_lines``) and skipped; error frames are counted (``error_frames``) and skipped.
    """

    kind = "can"

    def __init__(self, path: str | os.PathLike[str]) -> None:
        super().__init__(str(path))
        try:
            self._fh = open(path, encoding="ascii", errors="replace")
        except OSError as exc:
            raise LinkSpecError(f"candump link: {path}: {exc.strerror}; expected a candump -l log") from None
        self._lineno = 0

    def _recv_internal(self, timeout: float) -> LogRecord | None:
        for line in self._fh:
            self._lineno += 1
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            try:  # python-can's parser, one line at a time, so one bad line costs one frame
                msg = next(iter(can.CanutilsLogReader(io.StringIO(text + "\n"))))
            except (ValueError, StopIteration, IndexError) as exc:
                self.counts["bad_lines"] += 1
                self.last_reject = f"{self.name} line {self._lineno}: {exc or 'unparseable'}: {text[:60]!r}"
                continue
            if msg.is_error_frame:
                self.counts["error_frames"] += 1
                continue
            return LogRecord(t=float(msg.timestamp), link="can",
                             msg={"id": int(msg.arbitration_id), "data": bytes(msg.data), "ext": bool(msg.is_extended_id)})
        self.at_end = True
        return None

    def _shutdown_internal(self) -> None:
        self._fh.close()


class Paced(Link):
    """Release the records of ``link`` at ``speed`` times their recorded pace.

    Parameters
    ----------
    link
        Any link (a replay, usually).
    speed
        1.0 = real time, 10.0 = ten times faster, None = as fast as possible.
    max_gap_s
        Longest recorded gap waited out, in log seconds (None = wait every gap in full).
    """

    def __init__(self, link: Link, speed: float | None = 1.0, *, max_gap_s: float | None = None) -> None:
        super().__init__(link.name)
        if speed is not None and not speed > 0:
            raise LinkSpecError(f"paced link {link.name}: speed {speed!r}: expected a factor > 0 or None (max)")
        if max_gap_s is not None and not max_gap_s >= 0:
            raise LinkSpecError(f"paced link {link.name}: max_gap_s {max_gap_s!r}: expected >= 0 or None")
        self.inner = link
        self.kind = link.kind
        self.speed = None if speed is None else float(speed)
        self.max_gap_s = max_gap_s
        self._held: LogRecord | None = None
        self._held_due = 0.0
        self._wall0 = 0.0
        self._t0: float | None = None
        self._last_t = 0.0

    def _due(self, rec: LogRecord) -> float:
        """Wall-clock (monotonic) time at which ``rec`` is released."""
        assert self.speed is not None
        if self._t0 is None:
            self._t0, self._wall0, self._last_t = rec.t, time.monotonic(), rec.t
        gap = rec.t - self._last_t
        if self.max_gap_s is not None and gap > self.max_gap_s:
            self._t0 += gap - self.max_gap_s  # shorten the gap: move the anchor forward
        self._last_t = max(self._last_t, rec.t)
        return self._wall0 + (rec.t - self._t0) / self.speed

    def _recv_internal(self, timeout: float) -> LogRecord | None:
        if self._held is None:
            rec = self.inner.recv(timeout)
            if rec is None:
                self.at_end = self.inner.at_end
                return None
            if self.speed is None:
                return rec
            self._held, self._held_due = rec, self._due(rec)
        wait = self._held_due - time.monotonic()
        if wait > timeout:
            time.sleep(timeout)
            return None
        if wait > 0:
            time.sleep(wait)
        rec, self._held = self._held, None
        return rec

    @property
    def lag_s(self) -> float:
        """How far behind schedule the consumer is, in wall seconds (0 when on time or unpaced)."""
        if self.speed is None or self._t0 is None:
            return 0.0
        return max(0.0, time.monotonic() - (self._wall0 + (self._last_t - self._t0) / self.speed))

    def _shutdown_internal(self) -> None:
        self.inner.shutdown()


class TimeMerge(Link):
    """Several recordings merged into one stream in ``t`` order (a k-way merge).

    Each input must itself be in ``t`` order (a recording is); ties keep the order of
    ``links``. Meant for finite recordings: a live link that stays silent holds the merge.
    """

    kind = "*"

    def __init__(self, links: Iterable[Link]) -> None:
        self.links = list(links)
        if not self.links:
            raise LinkSpecError("time merge: expected at least one recording")
        super().__init__("+".join(l.name for l in self.links))
        self._heads: list[LogRecord | None] = [None] * len(self.links)

    def _recv_internal(self, timeout: float) -> LogRecord | None:
        for i, link in enumerate(self.links):
            if self._heads[i] is None and not link.at_end:
                self._heads[i] = link.recv(timeout)
                if self._heads[i] is None and not link.at_end:
                    return None  # this input has not delivered yet: its next record may be the earliest
        live = [(rec.t, i) for i, rec in enumerate(self._heads) if rec is not None]
        if not live:
            self.at_end = True
            return None
        _, i = min(live)
        rec, self._heads[i] = self._heads[i], None
        return rec

    def _shutdown_internal(self) -> None:
        for link in self.links:
            link.shutdown()
