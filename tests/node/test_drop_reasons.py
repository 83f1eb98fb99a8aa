"""Tiles dropped for navigation are counted in ``tiles_dropped``, with their reason, in the
heartbeat, the summary and the end-of-run line (issue 18).

The recording is the real Iver2 side-scan written back by the project's XTF writer without
its positions: no ping has a position and no INS feeds the node, so every tile is dropped at
the nav merge, as the pings of an XTF in projected metres were before ``--crs``.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys

import pytest

from atr_node.calibration.model import PerformanceModel
from atr_node.config import Settings
from atr_node.io.xtf import XtfReader, iter_xtf_records
from atr_node.io.xtf_write import XtfWriter
from atr_node.node import wire
from atr_node.node.publisher import Subscriber
from atr_node.node.service import NodeService
from atr_node.records.tile import Tile

from ..waiting import wait_until


@pytest.fixture(scope="module")
def no_positions(real_data, tmp_path_factory):
    """(path, number of tiles the reader gives) of the Iver2 tiles without their nav."""
    path = tmp_path_factory.mktemp("nonav") / "iver2-no-positions.xtf"
    with XtfWriter(path) as w:
        for r in XtfReader(real_data / "xtf" / "scotsman-iver2.xtf"):
            if r.link == "sonar":
                w.write_tile(Tile.from_map(r.msg).replace(nav=None))
    n = sum(1 for r in XtfReader(path) if r.link == "sonar")
    return path, n


def test_replay_counts_the_tiles_dropped_for_nav_with_their_reason(no_positions, tmp_path):
    path, n = no_positions
    summary = tmp_path / "summary.json"
    r = subprocess.run([sys.executable, "-m", "atr_node", "replay", str(path), "--online-calibration", "off",
                        "--publish", "none", "--workers", "0", "--quiet", "--summary", str(summary)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    s = json.loads(summary.read_text())
    assert n >= 2 and s["tiles_in"] == n and s["tiles_done"] == 0
    assert s["tiles_dropped"] == n and s["drop_reasons"] == {"no usable nav": n}
    assert s["navmerge"]["dropped"] == {"no usable nav": n}
    end = r.stderr.strip().splitlines()[-1]
    assert f"{n} tiles in, 0 done, 0 rejected, {n} dropped (no usable nav x {n}); 0 contacts" in end
    # the first drop is logged, the others only counted
    assert r.stderr.count("no usable nav for any ping") == 1


def test_heartbeat_carries_the_nav_drops(no_positions, caplog):
    path, n = no_positions
    service = NodeService(Settings(), model=PerformanceModel.shipped(), workers=0, publish="tcp://127.0.0.1:*")
    sub = Subscriber(service.publisher.endpoint, topics=(wire.TOPIC_HEARTBEAT,))
    try:
        # the subscription is in place once a heartbeat gets through (ZeroMQ's slow joiner)
        assert wait_until(lambda: sub.recv(timeout_s=0.05) is not None, poll_s=0.0,
                          step=lambda: service.publisher.heartbeat(service.heartbeat())), \
            "no heartbeat reached the subscriber"
        with caplog.at_level(logging.WARNING):
            assert service.run(iter_xtf_records(path)) is True
        final: list[dict] = []

        def final_heartbeat() -> bool:
            got = sub.recv(timeout_s=0.5)
            if got is not None and got[1]["tiles_in"] == n:
                final.append(got[1])
            return bool(final)

        assert wait_until(final_heartbeat, poll_s=0.0), "the final heartbeat did not arrive"
        last = final[0]
        assert wire.validate_heartbeat(last) == []
        assert last["tiles_dropped"] == n and last["tiles_done"] == 0
        assert service.summary()["drop_reasons"] == {"no usable nav": n}
        assert sum("no usable nav" in r.getMessage() for r in caplog.records) == 1
    finally:
        sub.close()
        service.close()


def test_a_recording_with_nav_drops_nothing_for_nav(small_mission):
    settings, _, files = small_mission
    from atr_node.io.atrlog import read_atrlog

    service = NodeService(settings, model=PerformanceModel.shipped(), workers=0)
    try:
        service.run(read_atrlog(files.atrlog))
        s, hb = service.summary(), service.heartbeat()
    finally:
        service.close()
    assert s["tiles_in"] > 0 and s["tiles_dropped"] == 0 and s["drop_reasons"] == {}
    assert hb["tiles_dropped"] == 0


def test_drop_reasons_survive_a_snapshot_and_resume(no_positions, tmp_path):
    """After a resume the reasons still add up to ``tiles_dropped`` (they are in the snapshot)."""
    path, n = no_positions
    state = tmp_path / "state"
    first = NodeService(Settings(), model=PerformanceModel.shipped(), workers=0, state_dir=state)
    try:
        assert first.run(iter_xtf_records(path)) is True
        first.snapshot()
    finally:
        first.close()
    again = NodeService(Settings(), model=PerformanceModel.shipped(), workers=0, state_dir=state)
    try:
        again.resume()
        s = again.summary()
    finally:
        again.close()
    assert s["tiles_dropped"] == n and s["drop_reasons"] == {"no usable nav": n}


def test_the_measured_first_return_band_survives_a_snapshot(tmp_path):
    """A tile too short to measure its first-return band uses the side's last measured one:
    a resumed node must have it too, or its contacts could differ from an uninterrupted run's."""
    from atr_node.node import state as node_state
    from atr_node.node.pipeline import Pipeline

    settings = Settings()
    first = Pipeline(settings, model=PerformanceModel.shipped(), workers=0)
    try:
        first.merger._band_by_side = {"port": 1.7, "stbd": 0.53}
        node_state.save(tmp_path, first, position=0)
    finally:
        first.close()
    again = Pipeline(settings, model=PerformanceModel.shipped(), workers=0)
    try:
        node_state.load(tmp_path, again)
        assert again.merger._band_by_side == {"port": 1.7, "stbd": 0.53}
    finally:
        again.close()
