"""Following a live node: its PUB stream (ICD section 3) into a :class:`ContactBook`.

:class:`NodeFollower` owns one SUB socket (:class:`atr_node.node.publisher.Subscriber`) and
turns frames into state: contact messages go into the book, the last heartbeat is kept with
its arrival time. It never raises on what the node sends: frames that are not two frames, not
msgpack, of an unknown topic or failing the ICD validators are counted under ``bad`` with the
last reason, and change nothing.

When to stop is the caller's choice, through :meth:`NodeFollower.follow`: after ``duration_s``,
when the node has been silent for ``until_silent_s`` (a node heartbeats at least once a second
while running, so a few seconds of silence means it stopped), or when ``stop`` is set.

Late joiners (ICD v1.1, the zguide's clone pattern): a PUB socket delivers only what is
published after the subscription is up, so with a ``snapshot`` endpoint the follower, once
its first message from the node has arrived (the subscription is then known to be up), asks
the node for its live contacts and the last ``seq`` published, puts them in the book, and from
then on applies only stream messages with a larger ``seq``; the contact messages received
before the snapshot wait for it. Every message is applied once: by the snapshot or by the
stream. A node without the endpoint (ICD v1) is followed as before, after one warning: only
the contacts published after the follower joined are seen. A ``seq`` that skips counts as a
gap (messages lost); one that goes back means the node restarted (a resume republishes the
work since its last snapshot): counted, and applied.
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
from ..node.snapshot_endpoint import request_snapshot
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
    snapshot: str = "off"
    """Late joining: ``off`` (not asked), ``waiting`` (for the first message), ``ok`` or
    ``unavailable: <why>``."""
    snapshot_seq: int | None = None
    """The ``seq`` of the snapshot applied (None: none)."""
    snapshot_contacts: int = 0
    """Live contacts the snapshot put in the book."""
    duplicates: int = 0
    """Stream messages dropped because the snapshot already held them (``seq`` <= its seq)."""
    gaps: int = 0
    """Contact messages missed: the ``seq`` skipped by that many."""
    seq_resets: int = 0
    """Times the ``seq`` went back (the node restarted)."""


def snapshot_text(st: FollowStats) -> str:
    """How the follower joined, for end-of-run lines: ``snapshot: 28 live contacts at seq 140``."""
    if st.snapshot == "off":
        text = "no snapshot asked"
    elif st.snapshot == "waiting":
        text = "no snapshot (nothing received)"
    elif st.snapshot == "ok":
        text = f"snapshot: {st.snapshot_contacts} live contacts at seq {st.snapshot_seq}"
    else:
        text = f"snapshot {st.snapshot}"
    extra = [f"{n} {what}" for n, what in ((st.duplicates, "duplicates dropped"), (st.gaps, "messages missed"),
                                          (st.seq_resets, "node restarts")) if n]
    return text + (f" ({', '.join(extra)})" if extra else "")


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
        public key (``server_public_key``); see ``atr_node.commands._follow``. Also used for
        the snapshot endpoint.
    snapshot : str, optional
        The node's snapshot endpoint (ICD v1.1): get the contacts published before joining
        (module docstring). None: only what is published from now on.
    snapshot_timeout_s : float
        How long to wait for the snapshot before going on without it.
    """

    def __init__(self, endpoint: str, *, book: ContactBook | None = None,
                 on_contact: Callable[[dict[str, Any]], None] | None = None,
                 context: zmq.Context | None = None, curve: Any = None, snapshot: str | None = None,
                 snapshot_timeout_s: float = 2.0) -> None:
        self.endpoint = endpoint
        self.book = book if book is not None else ContactBook()
        self.on_contact = on_contact
        self.heartbeat: dict[str, Any] | None = None
        self.stats = FollowStats()
        self.snapshot_endpoint = snapshot
        self.snapshot_timeout_s = snapshot_timeout_s
        self._context, self._curve = context, curve
        self._held: list[Any] = []
        """Contact messages received before the snapshot came (applied after it, by seq)."""
        self._last_seq: int | None = None
        if snapshot:
            self.stats.snapshot = "waiting"
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
        topic = self._handle(*got)
        if self.stats.snapshot == "waiting":  # a message came: the subscription is up
            self._catch_up()
        return topic

    def _handle(self, topic: str, msg: Any) -> str | None:
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
            if self.stats.snapshot == "waiting":
                self._held.append(msg)
            elif not self._apply(msg):
                return None
        else:
            self._bad(f"unknown topic {topic!r}")
            return None
        return topic

    def _apply(self, msg: Any) -> bool:
        """Apply one stream contact message unless the snapshot already held it; False: refused."""
        seq = msg.get("seq") if isinstance(msg, dict) else None
        if isinstance(seq, int) and not isinstance(seq, bool):
            last = self._last_seq
            if last is not None and seq <= last:
                self.stats.seq_resets += 1
                log.warning("from %s: contact seq went back from %d to %d: the node restarted", self.endpoint,
                            last, seq)
                self.stats.snapshot_seq = None  # what the restarted node sends is all new
            elif self.stats.snapshot_seq is not None and seq <= self.stats.snapshot_seq:
                self._last_seq = seq
                self.stats.duplicates += 1
                return True
            else:
                expected = (last if last is not None else self.stats.snapshot_seq)
                if expected is not None and seq > expected + 1:
                    self.stats.gaps += seq - expected - 1
            self._last_seq = seq
        if not self.book.apply(msg, where=f"{self.endpoint}"):
            self._bad(f"contact refused: {self.book.last_problem}")
            return False
        self.stats.contacts += 1
        if self.on_contact is not None:
            self.on_contact(msg)
        return True

    def _catch_up(self) -> None:
        """Ask for the snapshot, apply it, then the contact messages held while waiting."""
        where = f"snapshot {self.snapshot_endpoint}"
        try:
            seq, contacts = request_snapshot(self.snapshot_endpoint, timeout_s=self.snapshot_timeout_s,
                                             curve=self._curve, context=self._context)
        except AtrError as exc:
            self.stats.snapshot = f"unavailable: {exc}"
            log.warning("%s (a node without the ICD v1.1 snapshot endpoint?): following %s from now on, "
                        "contacts published before are not shown", exc, self.endpoint)
        else:
            self.stats.snapshot, self.stats.snapshot_seq = "ok", seq
            for m in contacts:
                if not self.book.apply(m, where=where):
                    self._bad(f"contact refused: {self.book.last_problem}")
                    continue
                self.stats.snapshot_contacts += 1
                if self.on_contact is not None:
                    self.on_contact(m)
        # silence counts from here: waiting for the snapshot is not the node falling silent
        self.stats.last_message_at = time.monotonic()
        held, self._held = self._held, []
        for m in held:
            self._apply(m)

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

