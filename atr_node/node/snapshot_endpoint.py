"""Late joiners (ICD v1.1 section 3): the node's snapshot endpoint and its client.

A subscriber that starts while the node runs gets the contacts published before it joined
with the zguide's clone pattern: it subscribes to the PUB socket first, then asks the snapshot
endpoint for ``{seq, contacts}`` (the last ``seq`` published and the last message of every
live contact) and applies only stream messages with a larger ``seq``. Frames are in
:mod:`atr_node.node.wire`.

Node side::

    pipeline (main thread) --emit--> NodeService._emit --> ContactView.published  (under a lock)
                                                      \\-> Publisher (PUB)
    SnapshotServer thread: ROUTER socket <- b"contacts" -> ContactView.snapshot() -> reply

The view is written by the thread that runs the pipeline and read by the server thread; the
lock makes every reply a state the stream actually passed through: its contacts are exactly
the live ones after message ``seq``, no message more, none less. The ROUTER socket is bound in
the constructor (a port in use fails at start, in one line) and then used by the server thread
alone.

Client side: :func:`request_snapshot` (a REQ socket per request, with a timeout, so a v1 node
without the endpoint costs one wait and a warning, never a hang).
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any, Mapping

import zmq

from ..errors import AtrError
from . import wire

log = logging.getLogger(__name__)

POLL_S = 0.1
"""How often the server thread looks at its stop flag while no request comes."""


def derived_snapshot_endpoint(publish_endpoint: str) -> str | None:
    """The snapshot endpoint a client assumes for a node publishing on ``publish_endpoint``:
    the same host, port + 1 (``tcp://127.0.0.1:5560`` -> ``tcp://127.0.0.1:5561``, the
    defaults of ``links.publish_endpoint`` and ``links.snapshot_endpoint``); None when it
    cannot be derived (not ``tcp://host:port``)."""
    if not publish_endpoint.startswith("tcp://"):
        return None
    host, sep, port = publish_endpoint[len("tcp://"):].rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65535:
        return None
    return f"tcp://{host}:{int(port) + 1}"


def bind_error(what: str, endpoint: str, exc: Exception, setting: str) -> AtrError:
    """One line for a socket the node could not bind (a port in use, a bad endpoint)."""
    errno_ = getattr(exc, "errno", None)
    why = zmq.strerror(errno_) if errno_ else str(exc)
    hint = ("another node on that port? Choose another with" if errno_ == zmq.EADDRINUSE
            else "expected an endpoint like tcp://127.0.0.1:5560, set with")
    return AtrError(f"cannot bind the {what} to {endpoint!r}: {why}; {hint} {setting}")


class ContactView:
    """The live contacts and the last ``seq`` published, shared by the pipeline's thread
    (:meth:`published`, :meth:`reset`) and the snapshot server's (:meth:`snapshot`)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._live: dict[int, dict[str, Any]] = {}
        self._seq = 0

    def published(self, message: Mapping[str, Any]) -> None:
        """Account for one contact message as it is published (a v1.1 one: with ``seq``)."""
        m = dict(message)
        with self._lock:
            self._seq = int(m["seq"])
            if m["state"] == "withdrawn":
                self._live.pop(int(m["id"]), None)
            else:
                self._live[int(m["id"])] = m

    def reset(self, seq: int, live: list[Mapping[str, Any]]) -> None:
        """Start again from a restored state (a resume): its last ``seq`` and live contacts."""
        with self._lock:
            self._seq = int(seq)
            self._live = {int(m["id"]): dict(m) for m in live}

    def snapshot(self) -> tuple[int, list[dict[str, Any]]]:
        """(last seq, live contacts by id): a consistent copy."""
        with self._lock:
            return self._seq, [self._live[k] for k in sorted(self._live)]


class SnapshotServer:
    """The node's ROUTER socket answering ``contacts`` requests from a :class:`ContactView`.

    Parameters
    ----------
    endpoint : str
        Where to bind (``links.snapshot_endpoint``; ``tcp://127.0.0.1:*`` for a free port).
    view : ContactView
        What to answer with.
    curve : atr_node.security.CurveConfig, optional
        The node's CURVE settings: the socket is then a CURVE server like the PUB socket.
    setting : str
        The option or key that sets ``endpoint``, named when the bind fails.

    Attributes
    ----------
    served, refused : int
        Snapshots sent; requests answered with an error (anything but ``contacts``).
    """

    def __init__(self, endpoint: str, view: ContactView, *, curve: Any = None, context: zmq.Context | None = None,
                 setting: str = "links.snapshot_endpoint") -> None:
        self.view = view
        self.served = 0
        self.refused = 0
        self.last_refused = ""
        ctx = context or zmq.Context.instance()
        self._sock = ctx.socket(zmq.ROUTER)
        self._sock.setsockopt(zmq.LINGER, 0)  # a reply to a client gone away is not worth waiting for
        try:
            if curve is not None:  # the same CURVE server settings (and authorized keys) as the PUB socket
                curve.secure_server(self._sock)
            self._sock.bind(endpoint)
        except zmq.ZMQError as exc:
            self._sock.close()
            raise bind_error("snapshot endpoint (ROUTER)", endpoint, exc, setting) from None
        self.endpoint = self._sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="atr-snapshot", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        try:
            while not self._stop.is_set():
                if not self._sock.poll(int(POLL_S * 1000)):
                    continue
                try:
                    frames = self._sock.recv_multipart(zmq.NOBLOCK)
                    self._sock.send_multipart(self.answer(frames))
                except zmq.Again:
                    continue
                except Exception as exc:  # a client's bad request never takes the node down
                    self.refused += 1
                    self.last_refused = f"{type(exc).__name__}: {exc}"
                    log.warning("snapshot endpoint: request failed: %s", self.last_refused)
        finally:
            self._sock.close()

    def answer(self, frames: list[bytes]) -> list[bytes]:
        """The reply frames to one request as a ROUTER receives it: [peer id, (b"" from a REQ), body...]."""
        peer, rest = frames[0], frames[1:]
        envelope = [b""] if len(rest) >= 2 and rest[0] == b"" else []  # a REQ's delimiter (then a body)
        body = rest[len(envelope):]
        if body == [wire.SNAPSHOT_REQUEST]:
            seq, contacts = self.view.snapshot()
            self.served += 1
            return [peer, *envelope, wire.snapshot_reply(seq, contacts)]
        self.refused += 1
        shown = b"|".join(body)[:40]
        self.last_refused = f"unknown request {shown!r}"
        return [peer, *envelope, wire.snapshot_error(f"{self.last_refused}; the only request is "
                                                     f"{wire.SNAPSHOT_REQUEST.decode()!r} (one frame)")]

    def close(self) -> None:
        """Stop the thread (it closes the socket); idempotent."""
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout=2.0)


def request_snapshot(endpoint: str, *, timeout_s: float = 2.0, curve: Any = None,
                     context: zmq.Context | None = None) -> tuple[int, list[dict[str, Any]]]:
    """Ask a node's snapshot endpoint for ``(last seq, live contacts)``.

    Parameters
    ----------
    endpoint : str
        The node's snapshot endpoint (:func:`derived_snapshot_endpoint` of its PUB endpoint
        by default).
    timeout_s : float
        How long to wait for the reply.
    curve : atr_node.security.CurveConfig, optional
        This client's keys and the node's public key (``server_public_key``), for a CURVE node.

    Raises
    ------
    AtrError
        No reply within ``timeout_s`` (a v1 node has no snapshot endpoint; a wrong CURVE key
        is refused silently), an error reply, or a reply that is not ``{seq, contacts}``. The
        contact maps are returned as received: the caller checks them.
    """
    ctx = context or zmq.Context.instance()
    sock = ctx.socket(zmq.REQ)
    sock.setsockopt(zmq.LINGER, 0)
    try:
        if curve is not None:
            curve.secure_client(sock)
        try:
            sock.connect(endpoint)
        except zmq.ZMQError as exc:
            raise AtrError(f"snapshot endpoint {endpoint!r}: {exc}; expected e.g. tcp://127.0.0.1:5561") from None
        # the send waits too, within the same time: a REQ socket whose peer refused it (a wrong
        # CURVE key) has no pipe to send on, and a plain send would block for ever (found in CI
        # under load)
        deadline = time.monotonic() + timeout_s
        try:
            if not sock.poll(int(timeout_s * 1000), zmq.POLLOUT):
                raise zmq.Again()
            sock.send(wire.SNAPSHOT_REQUEST, zmq.NOBLOCK)
        except zmq.Again:
            raise AtrError(f"no snapshot from {endpoint} within {timeout_s:g} s") from None
        if not sock.poll(max(int((deadline - time.monotonic()) * 1000), 0)):
            raise AtrError(f"no snapshot from {endpoint} within {timeout_s:g} s")
        frames = sock.recv_multipart()
    finally:
        sock.close()
    if len(frames) != 1:
        raise AtrError(f"snapshot from {endpoint}: expected one frame, got {len(frames)}")
    try:
        return wire.read_snapshot_reply(frames[0])
    except ValueError as exc:
        raise AtrError(f"snapshot from {endpoint}: {exc}") from None


def node_snapshot_endpoint(settings: Any, *, publish_arg: str | None, snapshot_arg: str | None
                           ) -> tuple[str | None, str]:
    """Where a replaying node binds its snapshot endpoint, and the option that said so.

    ``--snapshot EP`` wins (``none`` or empty: off); else a ``--publish EP`` given on the
    command line moves it along (port + 1: where clients look for it); else
    ``links.snapshot_endpoint`` (empty: off). ``--publish none`` (no PUB socket) binds nothing,
    which the caller sees as no publisher.
    """
    if snapshot_arg is not None:
        return (None if snapshot_arg in ("", "none") else snapshot_arg), "--snapshot"
    if publish_arg is not None and publish_arg not in ("", "none"):
        derived = derived_snapshot_endpoint(publish_arg)
        if derived is None:
            log.warning("no snapshot endpoint for late joiners: cannot derive one from --publish %s "
                        "(give --snapshot ENDPOINT)", publish_arg)
        return derived, "--snapshot (default: the port after --publish)"
    return (settings.links.snapshot_endpoint or None), "links.snapshot_endpoint"
