"""The ZeroMQ PUB socket to the autonomy layer (ICD section 3) and the heartbeat clock.

Messages are built and checked by :mod:`atr_node.node.wire`; this module only owns the
socket. ``linger`` is short so a stopping node never hangs on a subscriber that went away,
and the high-water mark bounds memory when nobody reads.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Any, Mapping

import zmq

from ..errors import AtrError
from . import wire

if TYPE_CHECKING:
    from ..security import CurveConfig


class Publisher:
    """A PUB socket bound (or connected) to ``endpoint``; thread-safe ``send``."""

    def __init__(self, endpoint: str, *, bind: bool = True, context: zmq.Context | None = None,
                 hwm: int = 10000, curve_secret_key: bytes | None = None, curve_public_key: bytes | None = None,
                 curve: "CurveConfig | None" = None) -> None:
        self._ctx = context or zmq.Context.instance()
        self._sock = self._ctx.socket(zmq.PUB)
        self._sock.setsockopt(zmq.LINGER, 200)
        self._sock.setsockopt(zmq.SNDHWM, hwm)
        if curve is not None:  # CURVE server: encrypted, only authorized subscribers (atr_node.security)
            curve.secure_server(self._sock)
        elif curve_secret_key is not None:
            self._sock.curve_secretkey = curve_secret_key
            self._sock.curve_publickey = curve_public_key
            self._sock.curve_server = True
        try:
            if bind:
                self._sock.bind(endpoint)
            else:
                self._sock.connect(endpoint)
        except zmq.ZMQError as exc:  # a port in use, a bad endpoint: one line, not a traceback
            self._sock.close()
            if not bind:
                raise AtrError(f"cannot connect the contact PUB socket to {endpoint!r}: {exc}") from None
            from .snapshot_endpoint import bind_error

            raise bind_error("contact PUB socket", endpoint, exc, "links.publish_endpoint (replay: --publish)") from None
        self.endpoint = self._sock.getsockopt_string(zmq.LAST_ENDPOINT) if bind else endpoint
        self._lock = threading.Lock()
        self.sent = {"contact": 0, "heartbeat": 0}

    def send(self, topic: bytes, message: Mapping[str, Any]) -> None:
        frames = wire.encode(topic, message)
        with self._lock:
            self._sock.send_multipart(frames)
        self.sent[topic.decode()] = self.sent.get(topic.decode(), 0) + 1

    def contact(self, message: Mapping[str, Any]) -> None:
        self.send(wire.TOPIC_CONTACT, message)

    def heartbeat(self, message: Mapping[str, Any]) -> None:
        self.send(wire.TOPIC_HEARTBEAT, message)

    def close(self) -> None:
        with self._lock:
            if not self._sock.closed:
                self._sock.close()


class Subscriber:
    """A SUB socket for tests, tools and the monitor: ``recv(timeout_s)`` -> (topic, map) or None."""

    def __init__(self, endpoint: str, topics: tuple[bytes, ...] = (b"",), *, context: zmq.Context | None = None,
                 curve: "CurveConfig | None" = None) -> None:
        self._ctx = context or zmq.Context.instance()
        self._sock = self._ctx.socket(zmq.SUB)
        self._sock.setsockopt(zmq.LINGER, 0)
        if curve is not None:  # CURVE client: curve.server_public_key = the node's public key
            curve.secure_client(self._sock)
        for t in topics:
            self._sock.setsockopt(zmq.SUBSCRIBE, t)
        self._sock.connect(endpoint)

    def recv(self, timeout_s: float = 1.0) -> tuple[str, dict[str, Any]] | None:
        if not self._sock.poll(int(timeout_s * 1000)):
            return None
        return wire.decode(self._sock.recv_multipart())

    def close(self) -> None:
        self._sock.close()
