"""Hardware-in-the-loop outputs: a recording played OUT onto the node's real link drivers.

The node under test opens its ordinary links on the other ends:

=================  ==========================================  ===============================
output             what it creates                             the node opens
=================  ==========================================  ===============================
``PtyNmeaOut``     a pseudo-terminal; writes each sentence      ``nmea_url = out.slave_path``
                   + CR LF to the master side
``CanBusOut``      a python-can bus (``virtual`` channel on      ``can_interface = "virtual"``,
                   the bench, or a real interface)              ``can_channel`` = same channel
``ZmqTileOut``     a bound PUSH or PUB socket; frames as in     ``sonar_endpoint`` (PULL / SUB)
                   :mod:`hw.zmq_sonar`
=================  ==========================================  ===============================

:class:`HilPlayer` takes any link (usually ``Paced(ReplayLink(log), speed)``) and routes each
record to the output of its kind. Outputs apply back-pressure up to ``write_timeout_s`` and
then drop and count, like a real line with nobody listening.
"""

from __future__ import annotations

import errno
import os
import select
import tty
from collections import Counter
from typing import Any

import can
import msgpack
import zmq

from atr_node.errors import describe
from atr_node.io.atrlog import LogRecord

from .base import Link
from .errors import LinkError, LinkSpecError


class PtyNmeaOut:
    """NMEA sentences written to a new pseudo-terminal; the reader opens ``slave_path``."""

    def __init__(self, *, write_timeout_s: float = 1.0) -> None:
        self.master_fd, self._slave_fd = os.openpty()
        tty.setraw(self._slave_fd)  # no echo, no CR/LF translation: bytes pass as sent
        os.set_blocking(self.master_fd, False)
        self.slave_path = os.ttyname(self._slave_fd)
        self.write_timeout_s = float(write_timeout_s)
        self.counts: Counter[str] = Counter()

    def send(self, rec: LogRecord) -> bool:
        """Write one sentence (CR LF added when missing); False when dropped after the timeout."""
        data = bytes(rec.msg)
        if not data.endswith(b"\n"):
            data = data.rstrip(b"\r") + b"\r\n"
        view = memoryview(data)
        while view:
            _, ready, _ = select.select([], [self.master_fd], [], self.write_timeout_s)
            if not ready:
                self.counts["dropped"] += 1
                return False
            try:
                n = os.write(self.master_fd, view)
            except OSError as exc:
                if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
                    continue
                raise LinkError(f"pty output {self.slave_path}: write failed: {describe(exc)}") from None
            view = view[n:]
        self.counts["sent"] += 1
        return True

    def close(self) -> None:
        for fd in (self.master_fd, self._slave_fd):
            try:
                os.close(fd)
            except OSError:
                pass
        self.master_fd = self._slave_fd = -1


class CanBusOut:
    """CAN records sent on a python-can bus (``virtual`` on the bench)."""

    def __init__(self, interface: str = "virtual", channel: str = "atr-hil", *, write_timeout_s: float = 1.0,
                 **bus_options: Any) -> None:
        try:
            self.bus = can.Bus(interface=interface, channel=channel, **bus_options)
        except (can.CanError, OSError, ValueError, TypeError) as exc:
            raise LinkSpecError(f"CAN output {interface}:{channel}: cannot open the bus: {describe(exc)}") from None
        self.channel = channel
        self.last_error = ""
        self.write_timeout_s = float(write_timeout_s)
        self.counts: Counter[str] = Counter()

    def send(self, rec: LogRecord) -> bool:
        m = rec.msg
        msg = can.Message(arbitration_id=int(m["id"]), data=bytes(m["data"]), is_extended_id=bool(m["ext"]),
                          timestamp=rec.t)
        try:
            self.bus.send(msg, timeout=self.write_timeout_s)
        except (can.CanError, ValueError) as exc:
            self.counts["dropped"] += 1
            self.last_error = f"frame 0x{m['id']:X}: {describe(exc)}"
            return False
        self.counts["sent"] += 1
        return True

    def close(self) -> None:
        self.bus.shutdown()


class ZmqTileOut:
    """Tile maps sent on a bound ZeroMQ PUSH or PUB socket (``PUB``: frames [topic, map])."""

    def __init__(self, endpoint: str = "tcp://127.0.0.1:*", *, socket: str = "push", topic: bytes = b"tile",
                 write_timeout_s: float = 1.0, context: zmq.Context | None = None) -> None:
        if socket not in ("push", "pub"):
            raise LinkSpecError(f"sonar output {endpoint}: socket {socket!r}: expected 'push' or 'pub'")
        self.ctx = context or zmq.Context.instance()
        self.sock = self.ctx.socket(zmq.PUSH if socket == "push" else zmq.PUB)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.SNDTIMEO, int(write_timeout_s * 1000))
        try:
            self.sock.bind(endpoint)
        except zmq.ZMQError as exc:
            self.sock.close(linger=0)
            raise LinkSpecError(f"sonar output: cannot bind {endpoint!r}: {describe(exc)}") from None
        self.endpoint = self.sock.getsockopt_string(zmq.LAST_ENDPOINT)
        """The bound endpoint, with the real port when ``*`` was asked."""
        self.topic = topic
        self.pub = socket == "pub"
        self.counts: Counter[str] = Counter()

    def send(self, rec: LogRecord) -> bool:
        payload = msgpack.packb(rec.msg, use_bin_type=True)
        try:
            if self.pub:
                self.sock.send_multipart([self.topic, payload])
            else:
                self.sock.send(payload)
        except zmq.Again:
            self.counts["dropped"] += 1
            return False
        self.counts["sent"] += 1
        return True

    def close(self) -> None:
        self.sock.close(linger=0)


class HilPlayer:
    """Route every record of ``source`` to the output of its kind.

    Parameters
    ----------
    source
        Any link; usually ``Paced(ReplayLink(path), speed)``.
    nmea, can, sonar
        Outputs (objects with ``send(record) -> bool``); records without an output are counted
        as ``skipped``.
    """

    def __init__(self, source: Link, *, nmea: PtyNmeaOut | None = None, can: CanBusOut | None = None,
                 sonar: ZmqTileOut | None = None) -> None:
        self.source = source
        self.outputs = {"nmea": nmea, "can": can, "sonar": sonar}
        self.counts: Counter[str] = Counter()

    def run(self, *, max_records: int | None = None) -> Counter[str]:
        """Play until the source ends (or ``max_records``); return counts per link and outcome."""
        for rec in self.source:
            out = self.outputs.get(rec.link)
            if out is None:
                self.counts[f"{rec.link}_skipped"] += 1
            else:
                self.counts[f"{rec.link}_{'sent' if out.send(rec) else 'dropped'}"] += 1
            if max_records is not None and sum(self.counts.values()) >= max_records:
                break
        return self.counts

    def close(self) -> None:
        """Shut the source and close every output."""
        self.source.shutdown()
        for out in self.outputs.values():
            if out is not None:
                out.close()
