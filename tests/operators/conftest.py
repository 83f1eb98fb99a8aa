"""A small generated mission and a real node publishing it on loopback (ZeroMQ over TCP)."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any, Callable

import pytest

from atr_node.calibration.model import PerformanceModel
from atr_node.io.atrlog import read_atrlog
from atr_node.node.service import NodeService

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
    thread: threading.Thread | None = None

    def release(self) -> None:
        self.gate.set()

    def join(self, timeout: float = 120.0) -> None:
        self.thread.join(timeout)
        assert not self.thread.is_alive(), "the node did not finish the mission"


def start_node(settings, log_path, *, state_dir=None, before_feed: Callable[[], None] | None = None) -> LiveNode:
    emitted: list[dict[str, Any]] = []
    service = NodeService(settings, model=PerformanceModel.shipped(), mode="replay", workers=0,
                          publish="tcp://127.0.0.1:*", state_dir=state_dir, on_contact=emitted.append)
    node = LiveNode(service, service.publisher.endpoint, emitted)

    def records():
        node.gate.wait(60.0)  # heartbeats already flow (run() started them)
        yield from read_atrlog(log_path)

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
        n.service.stop()
        if n.thread is not None:
            n.thread.join(30)
