"""A small generated mission and a real node publishing it on loopback (ZeroMQ over TCP)."""

from __future__ import annotations

import socket
import threading
from dataclasses import dataclass, field
from typing import Any, Callable

import pytest

from atr_node.calibration.model import PerformanceModel
from atr_node.errors import AtrError
from atr_node.io.atrlog import read_atrlog
from atr_node.node.service import NodeService

from ..waiting import WAIT_S, wait_until  # noqa: F401  (the operator tests import them from here)


@pytest.fixture(scope="session")
def mission(small_mission):
    return small_mission


@dataclass
class LiveNode:
    """A NodeService publishing on tcp://127.0.0.1:<random port>, replaying the mission once
    ``release()`` is called (so subscribers can join first: ZeroMQ's slow joiner)."""

    service: NodeService
    endpoint: str
    emitted: list[dict[str, Any]] = field(default_factory=list)
    gate: threading.Event = field(default_factory=threading.Event)
    paused: threading.Event = field(default_factory=threading.Event)
    """Set when the node stopped feeding at ``pause_after`` (its contacts so far are published)."""
    resume_feed: threading.Event = field(default_factory=threading.Event)
    thread: threading.Thread | None = None

    def release(self) -> None:
        self.gate.set()

    def join(self, timeout: float = 120.0) -> None:
        self.thread.join(timeout)
        assert not self.thread.is_alive(), "the node did not finish the mission"


def free_port_pair() -> int:
    """A port p with p and p + 1 both free now: a PUB endpoint and the snapshot endpoint that
    clients derive from it (ICD v1.1 defaults: 5560 and 5561)."""
    for _ in range(50):
        with socket.socket() as a:
            a.bind(("127.0.0.1", 0))
            p = a.getsockname()[1]
            if p >= 65534:
                continue
            with socket.socket() as b:
                try:
                    b.bind(("127.0.0.1", p + 1))
                except OSError:
                    continue
                return p
    raise RuntimeError("no free pair of ports")


def start_node(settings, log_path, *, state_dir=None, before_feed: Callable[[], None] | None = None,
               snapshot: bool = True, pause_after: int | None = None) -> LiveNode:
    """A node replaying ``log_path`` once released; ``snapshot``: with the ICD v1.1 snapshot
    endpoint on the port after its PUB port (False: a v1 node); ``pause_after``: it stops
    feeding after that many records until ``resume_feed`` is set (a client can join mid-run)."""
    emitted: list[dict[str, Any]] = []
    for attempt in range(5):
        port = free_port_pair()
        try:
            service = NodeService(settings, model=PerformanceModel.shipped(), mode="replay", workers=0,
                                  publish=f"tcp://127.0.0.1:{port}", state_dir=state_dir, on_contact=emitted.append,
                                  snapshot=f"tcp://127.0.0.1:{port + 1}" if snapshot else None)
            break
        except AtrError:  # taken between the check and the bind: another pair
            if attempt == 4:
                raise
    node = LiveNode(service, service.publisher.endpoint, emitted)

    def records():
        node.gate.wait(60.0)  # heartbeats already flow (run() started them)
        for i, rec in enumerate(read_atrlog(log_path)):
            if i == pause_after:
                node.paused.set()
                node.resume_feed.wait(60.0)
            yield rec

    def main():
        try:
            service.run(records())
        finally:
            service.close()

    node.thread = threading.Thread(target=main, name="test-node", daemon=True)
    node.thread.start()
    return node


@pytest.fixture
def live_node(mission, tmp_path):
    settings, _, files = mission
    nodes: list[LiveNode] = []

    def make(**kw) -> LiveNode:
        n = start_node(settings, files.atrlog, **kw)
        nodes.append(n)
        return n

    yield make
    for n in nodes:
        n.release()
        n.resume_feed.set()
        n.service.stop()
        if n.thread is not None:
            n.thread.join(30)


# -- waiting for events, not for silence ----------------------------------------------------
# A client that stops after S seconds without a message (``--until-silent``, ``follow(until_
# silent_s=...)``) stops early when a loaded machine delays the node by S seconds, and the test
# then misses messages. The tests below stop their clients when what they wait for has come
# (tests/waiting.py: the deadlines there are hang guards only).


def follow_until(follower, done: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
    """Receive on ``follower`` until ``done()`` holds; False if it never did."""
    return wait_until(done, timeout_s, step=lambda: follower.poll(0.1))


class StreamLines:
    """Every line of a subprocess's text stream, read by a thread (nothing lost, no hang)."""

    def __init__(self, stream) -> None:
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream) -> None:
        for line in stream:
            self.lines.append(line)

    @property
    def text(self) -> str:
        return "".join(self.lines)

    def wait_for(self, done: Callable[[str], bool], timeout_s: float = WAIT_S) -> None:
        """Until ``done(text so far)`` holds; fails with the stream's tail if it never does."""
        assert wait_until(lambda: done(self.text), timeout_s), f"never came; the stream ended with: {self.text[-2000:]}"

    def close(self, timeout_s: float = WAIT_S) -> str:
        """The whole text, once the stream has ended."""
        self._thread.join(timeout_s)
        return self.text


def stop_client(proc, timeout_s: float = WAIT_S) -> int:
    """SIGTERM (the clients' clean stop: last frame, files written, end-of-run line), then its exit."""
    import signal

    proc.send_signal(signal.SIGTERM)
    return proc.wait(timeout=timeout_s)
