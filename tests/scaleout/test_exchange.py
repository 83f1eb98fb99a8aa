"""Evidence exchange (issue 11): two vehicles end with the grid of one vehicle doing both
surveys, bit for bit; duplicated and replayed deltas change nothing; bad deltas are rejected."""

from __future__ import annotations

import dataclasses

import msgpack
import numpy as np
import pytest

from atr_node.calibration.model import PerformanceModel
from atr_node.errors import FusionError
from atr_node.fusion import ContactTracker
from atr_node.fusion.exchange import (DeltaSet, committed_state, decode_delta, encode_delta, leg_numbers,
                                      reduce_deltas)
from atr_node.io.atrlog import read_atrlog
from atr_node.node.exchange import attach_exchange
from atr_node.node.pipeline import Pipeline

from ..waiting import WAIT_S, wait_until
from .conftest import split_by_leg


def run_vehicle(settings, log, node):
    """Replay one vehicle's recording; return its pipeline (closed) and its deltas."""
    pipe = Pipeline(settings, model=PerformanceModel.shipped(), workers=0, mode="replay")
    try:
        grid = attach_exchange(pipe, node=node)
        pipe.replay(read_atrlog(log))
    finally:
        pipe.close()
    return pipe, list(grid.outbox)


def bits(state):
    return {k: v.view(np.uint64).copy() for k, v in state.items()}


def assert_same_bits(a, b):
    assert a.keys() == b.keys()
    for k in a:
        assert np.array_equal(a[k].view(np.uint64), b[k].view(np.uint64)), f"chunk {k} differs"


@pytest.fixture(scope="module")
def surveys(four_leg_mission, tmp_path_factory):
    settings, _, files = four_leg_mission
    # a small commit_after_obs: legs commit in several parts, as long legs do aboard
    settings = settings.replace(fusion=dataclasses.replace(settings.fusion, commit_after_obs=2))
    d = tmp_path_factory.mktemp("split")
    one, one_deltas = run_vehicle(settings, files.atrlog, "solo")
    a, a_deltas = run_vehicle(settings, split_by_leg(files.atrlog, d / "a.atrlog", {0, 2}), "auv-a")
    b, b_deltas = run_vehicle(settings, split_by_leg(files.atrlog, d / "b.atrlog", {1, 3}), "auv-b")
    return settings, (one, one_deltas), (a, a_deltas), (b, b_deltas)


def reduce(settings, deltas, enabled):
    from atr_node.fusion import association_gate_m

    return reduce_deltas(deltas, fusion=settings.fusion, gate_m=association_gate_m(settings.fusion, settings.template),
                         detectors=enabled)


def test_deltas_of_one_node_rebuild_its_grid_bit_for_bit(surveys):
    settings, (one, deltas), _, _ = surveys
    assert {d.id.leg for d in deltas} == {0, 1, 2, 3}
    assert sum(d.final for d in deltas) == 4 and len(deltas) > 4, "legs should commit in several parts"
    grid, _ = reduce(settings, deltas, one.enabled)
    assert_same_bits(committed_state(grid), committed_state(one.grid))
    assert len(grid.detections) == len(one.grid.detections) > 0
    assert grid.covered_cells() == one.grid.covered_cells()


def test_two_vehicles_end_with_the_grid_of_one_vehicle_doing_both(surveys):
    settings, (one, _), (a, a_deltas), (b, b_deltas) = surveys
    ref = committed_state(one.grid)
    # ashore: reduce both vehicles' deltas, in any arrival order
    rng = np.random.default_rng(3)
    for _ in range(3):
        mixed = list(a_deltas + b_deltas)
        rng.shuffle(mixed)
        grid, _ = reduce(settings, mixed, one.enabled)
        assert_same_bits(committed_state(grid), ref)
    # aboard: vehicle A ingests B's deltas (shuffled, each twice) into its own live grid
    rng.shuffle(b_deltas)
    for d in b_deltas + b_deltas[::-1]:
        a.grid.ingest(encode_delta(d))
    assert a.grid.counters["ingested"] == len(b_deltas)
    assert a.grid.counters["duplicates"] == len(b_deltas)
    assert_same_bits(committed_state(a.grid), ref)
    # the same contacts as one vehicle, extracted once from each grid
    got = ContactTracker(settings.fusion, a.frame, gate_m=a.gate_m).update(a.grid, 0.0)
    want = ContactTracker(settings.fusion, one.frame, gate_m=one.gate_m).update(one.grid, 0.0)
    assert want and [c.to_message() for c in got] == [c.to_message() for c in want]
    # the plain sum in arrival order is only exact to rounding: the canonical order matters
    for k, v in ref.items():
        np.testing.assert_allclose(committed_state(a.grid)[k], v, rtol=1e-12, atol=0)


def test_a_duplicated_or_replayed_delta_changes_nothing(surveys):
    settings, (one, deltas), _, _ = surveys
    grid, dset = reduce(settings, deltas + deltas[:3] + [decode_delta(encode_delta(d)) for d in deltas], one.enabled)
    assert dset.duplicates == 3 + len(deltas)
    assert_same_bits(committed_state(grid), committed_state(one.grid))
    assert len(grid.detections) == len(one.grid.detections)
    # replayed into a live exchanging grid: refused as duplicates, no change at all
    live, live_deltas = surveys[2]
    state = bits(committed_state(live.grid))
    dets = len(live.grid.detections)
    for d in live_deltas:
        assert live.grid.ingest(encode_delta(d)) is False
    assert bits(committed_state(live.grid)).keys() == state.keys()
    assert all(np.array_equal(bits(committed_state(live.grid))[k], state[k]) for k in state)
    assert len(live.grid.detections) == dets


def test_codec_round_trip_is_exact(surveys):
    _, (_, deltas), _, _ = surveys
    for d in deltas:
        e = decode_delta(encode_delta(d))
        assert e.id == d.id and e.digest == d.digest and e.final == d.final
        assert np.array_equal(e.d_ln.view(np.uint64), d.d_ln.view(np.uint64))
        assert np.array_equal(e.d_lt.view(np.uint64), d.d_lt.view(np.uint64))
        assert e.detections == d.detections


def _edit(payload: bytes, **changes) -> bytes:
    m = msgpack.unpackb(payload, raw=False)
    m.update(changes)
    return msgpack.packb(m, use_bin_type=True)


def test_bad_deltas_are_rejected_clearly_and_change_nothing(surveys):
    settings, (one, deltas), _, _ = surveys
    d = next(x for x in deltas if len(x.keys))
    good = encode_delta(d)
    with pytest.raises(FusionError, match="version 2 is not supported.*reads v1"):
        decode_delta(_edit(good, v=2))
    with pytest.raises(FusionError, match=r"leg 0 part 0\): missing key 'ln'"):
        m = msgpack.unpackb(good, raw=False)
        del m["ln"]
        decode_delta(msgpack.packb(m, use_bin_type=True))
    with pytest.raises(FusionError, match="'ln' holds .* bytes, expected"):
        decode_delta(_edit(good, ln=msgpack.unpackb(good, raw=False)["ln"][:-8]))
    with pytest.raises(FusionError, match="digest mismatch"):
        ln = bytearray(msgpack.unpackb(good, raw=False)["ln"])
        ln[0:8] = np.float64(-0.5).tobytes()
        decode_delta(_edit(good, ln=bytes(ln)))
    with pytest.raises(FusionError, match="finite and <= 0"):
        ln = bytearray(msgpack.unpackb(good, raw=False)["ln"])
        ln[0:8] = np.float64(0.5).tobytes()
        decode_delta(_edit(good, ln=bytes(ln)))
    with pytest.raises(FusionError, match="not a msgpack map"):
        decode_delta(b"\xc1garbage")
    # the same id with other content
    s = DeltaSet()
    s.add(d)
    other = decode_delta(_edit(good, t=d.t + 1.0))  # t is not in the digest: same content
    assert s.add(other) is False
    changed = dataclasses.replace(d, d_ln=d.d_ln * 0.5, digest="")
    with pytest.raises(FusionError, match="seen before with other content"):
        s.add(changed)
    # a delta of another grid layout is refused by a live grid, which stays as it was
    live, _ = surveys[2]
    state = bits(committed_state(live.grid))
    wrong = dataclasses.replace(d, cell_m=1.0, digest="")
    with pytest.raises(FusionError, match="cell 1.0 m"):
        live.grid.ingest(wrong)
    assert all(np.array_equal(bits(committed_state(live.grid))[k], state[k]) for k in state)


def test_leg_numbers_stay_unless_two_vehicles_share_them():
    from atr_node.fusion.exchange import DeltaId

    ids = [DeltaId("m", 0, "a", 0), DeltaId("m", 1, "b", 0)]
    assert leg_numbers(ids) == {("m", "a", 0): 0, ("m", "b", 1): 1}
    ids = [DeltaId("m1", 0, "a", 0), DeltaId("m2", 0, "a", 0), DeltaId("m2", 1, "a", 3)]
    assert leg_numbers(ids) == {("m1", "a", 0): 0, ("m2", "a", 0): 10000, ("m2", "a", 1): 10001}


def _random_survey(node, legs, rng_seed):
    """An exchanging grid fed random notT masses for ``legs`` on the same 64 x 64 cells."""
    from atr_node.config import FusionSettings
    from atr_node.fusion.exchange_grid import ExchangeGrid
    from atr_node.geo import MissionFrame

    frame = MissionFrame("utm", 44.08, 9.85)
    g = ExchangeGrid(FusionSettings(), gate_m=3.0, detectors=("mf", "z"), node=node, context=lambda: ("m", frame))
    iy, ix = np.mgrid[0:64, 0:64]
    for leg in legs:
        rng = np.random.default_rng([rng_seed, leg])
        g.deposit(leg, "mf", float(leg), iy, ix, m_n=rng.uniform(0.0, 0.99, iy.size))
        g.deposit(leg, "z", float(leg), iy[:8], ix[:8], m_t=rng.uniform(0.0, 0.99, 8 * 64))
        g.close_leg(leg)
    return g


def test_the_canonical_order_is_what_makes_it_bit_exact():
    """Many legs on the same cells: the sum in arrival order differs from one grid in the last
    bit somewhere; the canonical reduction and the live ingest never do."""
    one = _random_survey("solo", range(12), 5)
    a = _random_survey("auv-a", range(0, 12, 2), 5)
    b = _random_survey("auv-b", range(1, 12, 2), 5)
    ref = committed_state(one)
    from atr_node.fusion.exchange import apply_delta

    naive, _ = reduce_deltas(a.outbox, fusion=a.fusion, gate_m=3.0, detectors=a.detectors)
    for d in b.outbox:
        apply_delta(naive, d)
    diff = sum(int((ref[k].view(np.uint64) != v.view(np.uint64)).sum()) for k, v in committed_state(naive).items())
    assert diff > 0, "this case should exercise non-associative sums"
    canon, _ = reduce_deltas(b.outbox + a.outbox, fusion=a.fusion, gate_m=3.0, detectors=a.detectors)
    assert_same_bits(committed_state(canon), ref)
    for d in reversed(b.outbox):
        assert a.ingest(encode_delta(d))
    assert a.counters["resummed_chunks"] > 0
    assert_same_bits(committed_state(a), ref)
    m = canon.masses_at(*canon.cell_centre(3, 5))
    assert np.isfinite(m.m_t) and 0.0 < m.m_t < 1.0


def test_two_nodes_exchange_deltas_over_zeromq(four_leg_mission, tmp_path):
    """Two nodes on loopback, each publishing its committed legs and ingesting the other's:
    both end with the grid of one vehicle doing both surveys, bit for bit; a replayed delta
    is recognised; garbage on the link is counted, never fatal."""
    from atr_node.node.exchange import NodeExchange

    settings, _, files = four_leg_mission
    one, _ = run_vehicle(settings, files.atrlog, "solo")
    ref = committed_state(one.grid)
    logs = {"auv-a": split_by_leg(files.atrlog, tmp_path / "a.atrlog", {0, 2}),
            "auv-b": split_by_leg(files.atrlog, tmp_path / "b.atrlog", {1, 3})}
    pipes, ex = {}, {}
    try:
        for node in logs:
            pipes[node] = Pipeline(settings, model=PerformanceModel.shipped(), workers=0, mode="replay")
            ex[node] = NodeExchange(pipes[node], node=node, publish="tcp://127.0.0.1:*")
        ex["auv-a"].connect(ex["auv-b"].publisher.endpoint)
        ex["auv-b"].connect(ex["auv-a"].publisher.endpoint)
        # each publisher has heard the other's subscription before the first delta (what a PUB
        # sends before that is dropped: ZeroMQ's slow joiner)
        assert wait_until(lambda: all(e.publisher.subscriptions() >= 1 for e in ex.values()))
        for node, log in logs.items():  # the two vehicles survey in turn, pumping as they go
            for rec in read_atrlog(log):
                pipes[node].feed(rec)
                for e in ex.values():
                    e.pump()
            pipes[node].finish()
        n_sent = {node: e.publisher.sent for node, e in ex.items()}
        # a replay of A's deltas and some garbage, sent on A's socket
        replayed = pipes["auv-a"].grid.outbox[:3]
        assert len(replayed) >= 2  # one per leg at least
        for d in replayed:
            ex["auv-a"].publisher.send(d)
        ex["auv-a"].publisher._sock.send_multipart([b"evidence", b"\xc1 not msgpack"])
        wait_until(lambda: (ex["auv-a"].counters["ingested"] == n_sent["auv-b"]
                            and ex["auv-b"].counters["duplicates"] == len(replayed)
                            and ex["auv-b"].counters["rejected"] == 1),
                   step=lambda: [e.pump(timeout_s=0.05) for e in ex.values()])
        assert ex["auv-a"].counters["ingested"] == n_sent["auv-b"] > 0
        assert ex["auv-b"].counters["ingested"] == n_sent["auv-a"] > 0
        assert ex["auv-b"].counters["duplicates"] == len(replayed) and ex["auv-b"].counters["rejected"] == 1
        for node in logs:
            assert_same_bits(committed_state(pipes[node].grid), ref)
    finally:
        for node in pipes:
            ex[node].close()
            pipes[node].close()


def test_node_service_publishes_its_deltas_from_the_settings(four_leg_mission, tmp_path):
    """``node.exchange_publish`` in the settings: the service's commits go out on ZeroMQ."""
    from atr_node.node.exchange import PeerLink
    from atr_node.node.service import NodeService
    from atr_node.io.atrlog import read_atrlog as records

    settings, _, files = four_leg_mission
    node = dataclasses.replace(settings.node, node_id="auv-s", exchange_publish="tcp://127.0.0.1:*")
    service = NodeService(settings.replace(node=node), model=PerformanceModel.shipped(), workers=0)
    try:
        sub = PeerLink([service.exchange.publisher.endpoint])
        assert wait_until(lambda: service.exchange.publisher.subscriptions() >= 1)  # ZeroMQ slow joiner
        assert service.run(records(files.atrlog))
        sent = service.pipeline.grid.outbox
        got = []
        while len(got) < len(sent):
            payload = sub.recv(timeout_s=WAIT_S)  # a hang guard: the deltas were sent before this
            assert payload is not None, f"lost a delta: {len(got)} of {len(sent)}"
            got.append(decode_delta(payload))
        sub.close()
        assert [d.digest for d in got] == [d.digest for d in sent] and all(d.id.node == "auv-s" for d in got)
        assert service.summary()["exchange"]["own_deltas"] == len(sent)
        assert {d.id.mission for d in sent} == {files.name}
    finally:
        service.close()


def test_a_node_resumed_from_a_snapshot_keeps_exchanging_exactly(four_leg_mission, tmp_path):
    """The delta ledger is saved with each node snapshot: after a restart the node still
    publishes its legs (the same deltas as without the restart) and ingests the others'
    exactly; deltas it had ingested before the restart are recognised as duplicates."""
    from atr_node.node.service import NodeService

    settings, _, files = four_leg_mission
    node = dataclasses.replace(settings.node, node_id="auv-a", exchange_publish="tcp://127.0.0.1:*",
                               snapshot_every_tiles=5)
    settings = settings.replace(node=node)
    one, _ = run_vehicle(settings, files.atrlog, "solo")
    a_log = split_by_leg(files.atrlog, tmp_path / "a.atrlog", {0, 2})
    _, a_ref = run_vehicle(settings, a_log, "auv-a")
    _, b_deltas = run_vehicle(settings, split_by_leg(files.atrlog, tmp_path / "b.atrlog", {1, 3}), "auv-b")
    records = list(read_atrlog(a_log))
    half = len(records) * 2 // 3
    first = NodeService(settings, model=PerformanceModel.shipped(), workers=0, state_dir=tmp_path / "state")
    try:
        first.run(iter(records[:half]), finish=False)
        assert first.pipeline.grid.outbox, "the first run should have committed a leg"
        for d in b_deltas[: len(b_deltas) // 2]:
            assert first.exchange.ingest(encode_delta(d))
        first.snapshot()
    finally:
        first.close()
    second = NodeService(settings, model=PerformanceModel.shipped(), workers=0, state_dir=tmp_path / "state")
    try:
        start = second.resume()
        assert start == half and second.exchange is not None
        assert len(second.pipeline.grid.ledger) == len(first.pipeline.grid.ledger)
        second.run(iter(records[start:]), start=start)
        new = [second.exchange.ingest(encode_delta(d)) for d in b_deltas]
        assert new.count(False) == len(b_deltas) // 2
        assert_same_bits(committed_state(second.pipeline.grid), committed_state(one.grid))
        assert [d.digest for d in second.pipeline.grid.outbox] == [d.digest for d in sorted(a_ref, key=lambda d: d.id)]
    finally:
        second.close()
