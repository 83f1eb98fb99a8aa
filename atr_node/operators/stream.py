"""Following a live node: its PUB stream (ICD section 3) into a :class:`ContactBook`.

:class:`NodeFollower` owns one SUB socket (:class:`atr_node.node.publisher.Subscriber`) and
turns frames into state: contact messages go into the book, the last heartbeat is kept with
its arrival time. It never raises on what the node sends: frames that are not two frames, not
msgpack, of an unknown topic or failing the ICD validators are counted under ``bad`` with the
last reason, and change nothing.

When to stop is the caller's choice, through :meth:`NodeFollower.follow`: after ``duration_s``,
when the node has been silent for ``until_silent_s`` (a node heartbeats at least once a second
while running, so a few seconds of silence means it stopped), or when ``stop`` is set. ZeroMQ
drops what a publisher sends before the subscription is up (the slow-joiner effect): a
follower sees the contacts published after it joined, which is why an export of a whole run
is best taken from ``--contacts-out`` or from a follower started before the node.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import zmq

from ..errors import AtrError
from ..node import wire
from ..node.publisher import Subscriber
from .book import ContactBook

log = logging.getLogger(__name__)


@dataclass
class FollowStats:
    """Counters of one follower."""

    heartbeats: int = 0
    contacts: int = 0
    bad: int = 0
    last_bad: str = ""
    started_at: float = field(default_factory=time.monotonic)
    last_message_at: float | None = None
    """``time.monotonic()`` of the last message of any kind (None: nothing yet)."""
    last_heartbeat_at: float | None = None


class NodeFollower:
    """Subscribe to a node's PUB ``endpoint`` and keep its contacts and last heartbeat.

    Parameters
    ----------
    endpoint : str
        The node's publish endpoint (``tcp://127.0.0.1:5560`` by default in the node's config).
    book : ContactBook, optional
        Where contacts go (a new one by default).
    on_contact : callable, optional
        Called with every accepted contact message, after the book is updated.
    curve : atr_node.security.CurveConfig, optional
        For a node whose PUB socket is a CURVE server: this client's key pair and the node's
        public key (``server_public_key``); see ``atr_node.commands._follow``.
    """

    def __init__(self, endpoint: str, *, book: ContactBook | None = None,
                 on_contact: Callable[[dict[str, Any]], None] | None = None,
                 context: zmq.Context | None = None, curve: Any = None) -> None:
        self.endpoint = endpoint
        self.book = book if book is not None else ContactBook()
        self.on_contact = on_contact
        self.heartbeat: dict[str, Any] | None = None
        self.stats = FollowStats()
        try:
            self._sub = Subscriber(endpoint, context=context, curve=curve)
        except zmq.ZMQError as exc:
            raise AtrError(f"cannot subscribe to {endpoint!r}: {exc}; expected a ZeroMQ endpoint "
                           f"like tcp://127.0.0.1:5560") from None

    def _bad(self, why: str) -> None:
        self.stats.bad += 1
        self.stats.last_bad = why
        log.warning("from %s: %s", self.endpoint, why)

    def poll(self, timeout_s: float) -> str | None:
        """Receive at most one message (waiting up to ``timeout_s``); its topic, or None."""
        try:
            got = self._sub.recv(timeout_s=timeout_s)
        except (ValueError, TypeError) as exc:  # decode: frame count, msgpack, ASCII topic
            self._bad(f"undecodable message ({exc})")
            return None
        if got is None:
            return None
        topic, msg = got
        now = time.monotonic()
        self.stats.last_message_at = now
        if topic == wire.TOPIC_HEARTBEAT.decode():
            problems = wire.validate_heartbeat(msg)
            if problems:
                self._bad(f"heartbeat refused: {'; '.join(problems)}")
                return None
            self.heartbeat = msg
            self.stats.heartbeats += 1
            self.stats.last_heartbeat_at = now
        elif topic == wire.TOPIC_CONTACT.decode():
            if not self.book.apply(msg, where=f"{self.endpoint}"):
                self._bad(f"contact refused: {self.book.last_problem}")
                return None
            self.stats.contacts += 1
            if self.on_contact is not None:
                self.on_contact(msg)
        else:
            self._bad(f"unknown topic {topic!r}")
            return None
        return topic

    def follow(self, *, duration_s: float | None = None, until_silent_s: float | None = None,
               stop: threading.Event | None = None, tick: Callable[[], None] | None = None,
               tick_s: float = 0.25) -> str:
        """Receive until a stop condition; return which one (``"duration"``, ``"silent"``, ``"stop"``).

        ``tick`` is called at least every ``tick_s`` (redraws, periodic files). Silence counts
        from the last message, or from the start when nothing came yet.
        """
        t0 = time.monotonic()
        next_tick = t0
        while True:
            now = time.monotonic()
            if stop is not None and stop.is_set():
                return "stop"
            if duration_s is not None and now - t0 >= duration_s:
                return "duration"
            last = self.stats.last_message_at if self.stats.last_message_at is not None else t0
            if until_silent_s is not None and now - last >= until_silent_s:
                return "silent"
            if tick is not None and now >= next_tick:
                tick()
                next_tick = now + tick_s
            self.poll(timeout_s=min(tick_s, 0.1))

    def wait_heartbeat(self, timeout_s: float) -> bool:
        """Receive until the first heartbeat (the connection is up) or ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while self.heartbeat is None and time.monotonic() < deadline:
            self.poll(timeout_s=0.1)
        return self.heartbeat is not None

    def announcer(self, prog: str, out: Any = None) -> Callable[[], None]:
        """A ``tick`` that prints once, to stderr, when the first heartbeat has arrived: from
        then on the subscription is known to be up (nothing published later is missed)."""
        said = [False]

        def tick() -> None:
            if not said[0] and self.heartbeat is not None:
                said[0] = True
                print(f"{prog}: following {self.endpoint}: node up (first heartbeat)", file=out or sys.stderr,
                      flush=True)

        return tick

    def close(self) -> None:
        self._sub.close()

    def __enter__(self) -> "NodeFollower":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

