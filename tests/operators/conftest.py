"""A small generated mission and a real node publishing it on loopback (ZeroMQ over TCP)."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any, Callable

import pytest

from atr_node.calibration.model import PerformanceModel
from atr_node.config import load_settings
from atr_node.io.atrlog import read_atrlog
from atr_node.node.service import NodeService
from atr_node.simulation.mission import generate_mission

SMALL_MISSION = """
[simulation]
mission_legs = 3
mission_leg_length_m = 70.0
mission_swath_m = 30.0
mission_targets = 5
mission_tile_pings = 128
mission_clutter_per_km2 = 1000.0

[node]
snapshot_every_tiles = 4
queue_tiles = 4
heartbeat_s = 0.2
"""


@pytest.fixture(scope="session")
def mission(tmp_path_factory):
    d = tmp_path_factory.mktemp("ops_mission")
    cfg = d / "small.toml"
    cfg.write_text(SMALL_MISSION)
    settings = load_settings(cfg)
    files = generate_mission(settings, d, seed=7)
    return settings, cfg, files


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
