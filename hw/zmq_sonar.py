"""Sonar tiles over ZeroMQ (ICD section 1).

Wire format, per message::

    PULL socket: frame 0 = msgpack tile map
    SUB socket:  frame 0 = topic (ASCII, matched by prefix), frame 1 = msgpack tile map
                 (a single-frame message on SUB is taken as the map itself)

The map is decoded with ``msgpack.unpackb(raw=False)`` and delivered as
``LogRecord(t=arrival, link="sonar", msg=map)`` WITHOUT validation: the pipeline validates it
with ``Tile.from_map`` and counts rejections. Payloads that are not msgpack, or not a map,
are counted (``undecodable``) and dropped, never fatal.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING, Literal

import msgpack
import zmq

from atr_node.errors import AtrError
from atr_node.errors import describe
from atr_node.io.atrlog import LogRecord

from .base import Link
from .errors import LinkError, LinkSpecError

if TYPE_CHECKING:
    from atr_node.security import CurveConfig

log = logging.getLogger(__name__)
MAX_TILE_BYTES = 512 << 20
"""Largest message accepted (ZMQ_MAXMSGSIZE): a bigger peer message is dropped by ZeroMQ."""


class ZmqTileLink(Link):
    """Tile maps from a ZeroMQ PULL or SUB socket.

    Parameters
    ----------
    endpoint
        ZeroMQ endpoint, e.g. ``tcp://127.0.0.1:5550``, ``ipc:///run/sas.sock``, ``inproc://x``.
    socket
        ``"pull"`` or ``"sub"``.
    bind
        Bind the endpoint (the sonar processor connects) instead of connecting to it.
    topic
        SUB prefix filter (bytes or ASCII str); ignored by PULL.
    rcvhwm
        Receive high-water mark, in messages: beyond it ZeroMQ holds tiles back at the sender
        (PULL) or drops them (SUB).
    context
        ZeroMQ context to use (``inproc://`` needs the sender's); None = the process's instance.
    curve
        ZeroMQ CURVE (:mod:`atr_node.security`): a bound socket is a CURVE server admitting
        the authorized peers, a connecting one a client of ``curve.server_public_key``.
        None = plain (loopback on the bench).
    """

    kind = "sonar"

    def __init__(self, endpoint: str, *, socket: Literal["pull", "sub"] = "pull", bind: bool = False,
                 topic: bytes | str = b"", rcvhwm: int = 100, context: zmq.Context | None = None,
                 curve: "CurveConfig | None" = None) -> None:
        super().__init__(endpoint)
        if socket not in ("pull", "sub"):
            raise LinkSpecError(f"sonar link {endpoint}: socket {socket!r}: expected 'pull' or 'sub'")
        self.endpoint = endpoint
        self.socket_type = socket
        self.ctx = context or zmq.Context.instance()
        self.sock = self.ctx.socket(zmq.PULL if socket == "pull" else zmq.SUB)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.RCVHWM, int(rcvhwm))
        self.sock.setsockopt(zmq.MAXMSGSIZE, MAX_TILE_BYTES)
        if socket == "sub":
            self.sock.setsockopt(zmq.SUBSCRIBE, topic.encode("ascii") if isinstance(topic, str) else bytes(topic))
        try:
            if curve is not None:
                curve.secure_server(self.sock) if bind else curve.secure_client(self.sock)
            if bind:
                self.sock.bind(endpoint)
            else:
                self.sock.connect(endpoint)
        except (zmq.ZMQError, AtrError) as exc:
            self.sock.close(linger=0)
            if isinstance(exc, AtrError):
                raise LinkSpecError(f"sonar link {endpoint}: {describe(exc)}") from None
            raise LinkSpecError(f"sonar link: cannot {'bind' if bind else 'connect'} {endpoint!r}: {exc}; "
                                f"expected an endpoint like 'tcp://127.0.0.1:5550'") from None
        self.bound_endpoint = self.sock.getsockopt_string(zmq.LAST_ENDPOINT) if bind else endpoint
        self._poller = zmq.Poller()
        self._poller.register(self.sock, zmq.POLLIN)

    def _recv_internal(self, timeout: float) -> LogRecord | None:
        try:
            if not self._poller.poll(int(timeout * 1000)):
                return None
            frames = self.sock.recv_multipart(zmq.NOBLOCK, copy=True)
        except zmq.Again:
            return None
        except zmq.ZMQError as exc:
            raise LinkError(f"sonar link {self.endpoint}: receive failed: {describe(exc)}") from None
        t = time.time()
        payload = frames[-1]
        self.counts["bytes"] += len(payload)
        try:
            obj = msgpack.unpackb(payload, raw=False, strict_map_key=False)
        except (ValueError, TypeError, msgpack.ExtraData, msgpack.FormatError, msgpack.StackError) as exc:
            return self._drop(f"not msgpack ({exc})", payload)
        if not isinstance(obj, dict):
            return self._drop(f"a msgpack {type(obj).__name__}, expected a map", payload)
        return LogRecord(t=t, link="sonar", msg=obj)

    def _drop(self, why: str, payload: bytes) -> None:
        self.counts["undecodable"] += 1
        self.last_reject = f"{len(payload)}-byte message: {why}"
        log.warning("sonar link %s: dropped %s", self.endpoint, self.last_reject)
        return None

    def _shutdown_internal(self) -> None:
        self.sock.close(linger=0)
