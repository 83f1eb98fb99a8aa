"""Recording and merging of links: the recorder and the multiplexer.

* :class:`RecordingLink` wraps any link and appends every record it delivers to an
  ``.atrlog`` (ICD section 4) before handing it on, garbage lines and unknown frames included:
  the recording is what the links received, so a replay reproduces the run.
* :class:`LinkMux` reads several links in one background thread each and delivers their
  records, in arrival order, through one bounded queue: the node's ingest sees one link.
  A link that fails is logged and counted in ``counts["failed:<name>"]``; the others go on.
"""

from __future__ import annotations

import logging
import os
import queue
import threading
from typing import Sequence

from atr_node.errors import describe
from atr_node.io.atrlog import AtrLogWriter, LogRecord

from .base import Link
from .errors import LinkError, LinkSpecError

log = logging.getLogger(__name__)


class RecordingLink(Link):
    """Deliver the records of ``link`` and write each to an ``.atrlog``.

    Parameters
    ----------
    link
        The link to record.
    out
        An open :class:`AtrLogWriter` (shared between links, e.g.) or a path to create.
    flush_every
        With a path: records between flushes to the OS (a power cut loses at most these).
    """

    def __init__(self, link: Link, out: AtrLogWriter | str | os.PathLike[str], *, flush_every: int = 1) -> None:
        super().__init__(link.name)
        self.inner = link
        self.kind = link.kind
        self._own_writer = not isinstance(out, AtrLogWriter)
        self.writer = AtrLogWriter(out, flush_every=flush_every) if self._own_writer else out

    def _recv_internal(self, timeout: float) -> LogRecord | None:
        rec = self.inner.recv(timeout)
        if rec is None:
            self.at_end = self.inner.at_end
            return None
        try:
            self.writer.write_record(rec)
        except OSError as exc:
            # disk full: the record still goes to the node (its evidence is not lost live); the
            # recording misses it, and the writer keeps the file whole for the records after
            self.counts["record_failed"] += 1
            if self.counts["record_failed"] == 1 or self.counts["record_failed"] % 1000 == 0:
                log.error("recording %s: %s (%d records not recorded)", self.writer.path, exc,
                          self.counts["record_failed"])
        return rec

    def _shutdown_internal(self) -> None:
        self.inner.shutdown()
        if self._own_writer:
            self.writer.close()
        else:
            self.writer.flush()


_END = object()


class LinkMux(Link):
    """Several links read in parallel threads and delivered as one.

    Parameters
    ----------
    links
        The links; the mux owns them and shuts them down with itself.
    maxsize
        Queue bound: a full queue blocks the reader threads (back-pressure to the links' own
        buffers), it never drops.
    """

    kind = "*"

    def __init__(self, links: Sequence[Link], *, maxsize: int = 1024) -> None:
        if not links:
            raise LinkSpecError("link mux: expected at least one link")
        super().__init__("+".join(l.name for l in links))
        self.links = list(links)
        self._q: queue.Queue[object] = queue.Queue(maxsize=maxsize)
        self._running = len(self.links)
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._pump, args=(l,), name=f"link:{l.name}", daemon=True)
                         for l in self.links]
        for th in self._threads:
            th.start()

    def _pump(self, link: Link) -> None:
        try:
            while not self._stop.is_set() and not link.at_end:
                rec = link.recv(timeout=0.1)
                if rec is None:
                    continue
                while not self._stop.is_set():
                    try:
                        self._q.put(rec, timeout=0.1)
                        break
                    except queue.Full:
                        continue
        except Exception as exc:  # one failing link must not stop the others (LinkError, or a driver bug)
            log.error("link %s failed: %s", link.name, describe(exc), exc_info=not isinstance(exc, LinkError))
            self.counts[f"failed:{link.name}"] += 1
            self.last_reject = describe(exc)
        finally:
            while not self._stop.is_set():
                try:
                    self._q.put(_END, timeout=0.1)
                    break
                except queue.Full:
                    continue

    def _recv_internal(self, timeout: float) -> LogRecord | None:
        while True:
            try:
                item = self._q.get(timeout=timeout)
            except queue.Empty:
                return None
            if item is _END:
                self._running -= 1
                if self._running == 0:
                    self.at_end = True
                    return None
                continue
            return item  # type: ignore[return-value]

    def _shutdown_internal(self) -> None:
        self._stop.set()
        for th in self._threads:
            th.join(timeout=2.0)
        for l in self.links:
            l.shutdown()
