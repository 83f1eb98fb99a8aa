"""Batch runs on a real local Dask cluster (2 workers): recordings to one grid, the same as a
serial run bit for bit; failed tasks retried and reported; calibration Monte Carlo."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from atr_node.batch import Engine, recording_deltas, run_calibration, run_recordings
from atr_node.batch.grids import node_ids, reduce_recordings
from atr_node.calibration import collect_responses
from atr_node.calibration.model import PerformanceModel
from atr_node.calibration.sources import synthetic_images
from atr_node.fusion.exchange import committed_state


def flaky(marker: str, value: int) -> int:
    """Fails the first time it runs for ``marker`` (a file), succeeds after: a transient fault."""
    p = Path(marker)
    if not p.exists():
        p.write_text("failed once")
        raise RuntimeError(f"transient fault ({p.name})")
    return value * 2


def always_fails(value: int) -> int:
    raise ValueError(f"broken input {value}")


@pytest.fixture(scope="module")
def cluster():
    eng = Engine(None, workers=2, retries=2).start()
    try:
        yield eng
    finally:
        eng.close()


def test_local_cluster_gives_the_serial_result_bit_for_bit(cluster, tiny_missions):
    settings, _, logs = tiny_missions
    model = PerformanceModel.shipped()
    assert len(cluster.client.scheduler_info()["workers"]) == 2
    seen = []
    par = run_recordings(logs, settings, model, cluster, progress=lambda d, t, f: seen.append((d, t, f)))
    ser = run_recordings(logs, settings, model, Engine("serial"))
    assert all(o.ok and o.attempts == 1 for o in par.outcomes)
    assert seen[-1] == (3, 3, 0) and [s[0] for s in seen] == [1, 2, 3]
    assert par.contacts and par.contacts == ser.contacts
    a, b = committed_state(par.grid), committed_state(ser.grid)
    assert a.keys() == b.keys() and all(np.array_equal(a[k].view(np.uint64), b[k].view(np.uint64)) for k in a)
    assert par.info["missions"] == ["sim-1", "sim-2", "sim-3"]
    # three missions reuse legs 0 and 1: each (mission, leg) stays one look
    assert sorted(par.grid.closed_legs) == [0, 1, 10000, 10001, 20000, 20001]
    # the reduction is the union of the per-recording grids: one mission alone = its own node grid
    one = recording_deltas(str(logs[0]), settings, model, node_ids(logs)[0])
    grid, _, _, _ = reduce_recordings([one], settings)
    assert grid.covered_cells() <= par.grid.covered_cells()
    assert sum(r.tiles_in for r in [one]) > 0


def test_a_failed_task_is_retried_and_reported(cluster, tmp_path):
    items = [(f"item{i}", (str(tmp_path / f"marker{i}"), i)) for i in range(3)]
    out = cluster.map(flaky, items)
    assert [o.result for o in out] == [0, 2, 4]
    assert all(o.ok and o.attempts == 2 for o in out)
    assert all(o.errors == (f"RuntimeError: transient fault (marker{i})",) for i, o in enumerate(out))
    bad = cluster.map(always_fails, [("x", (7,))])
    assert not bad[0].ok and bad[0].attempts == 3 and bad[0].errors == ("ValueError: broken input 7",) * 3
    assert "always_fails" in bad[0].traceback
    ser = Engine("serial", retries=1).map(always_fails, [("x", (7,))])
    assert not ser[0].ok and ser[0].attempts == 2


def test_a_broken_recording_is_reported_and_the_others_still_merge(cluster, tiny_missions, tmp_path):
    settings, _, logs = tiny_missions
    broken = tmp_path / "broken.atrlog"
    broken.write_bytes(b"\x93not an atrlog at all" * 10)
    res = run_recordings([logs[0], broken, tmp_path / "missing.atrlog"], settings, PerformanceModel.shipped(),
                         cluster)
    ok = [o.name for o in res.outcomes if o.ok]
    assert ok == [Path(logs[0]).name]
    assert [o.attempts for o in res.failures] == [3, 3]
    assert "no such file" in res.failures[1].errors[0]
    solo = run_recordings([logs[0]], settings, PerformanceModel.shipped(), Engine("serial"))
    assert res.contacts == solo.contacts


def test_calibration_monte_carlo_equals_the_serial_collection(cluster):
    from atr_node.config import Settings

    settings = Settings()
    images = synthetic_images(2, settings=settings, rows=400, cols=420, seed=4, seabed="silt")
    got, outcomes = run_calibration(images, settings, cluster, iterations=2, targets_per_image=2, seed=9)
    ref = collect_responses(images, settings=settings, iterations=2, targets_per_image=2, seed=9)
    assert len(outcomes) == 2 and got.n_targets == ref.n_targets == 8
    for d in ref.detectors:
        np.testing.assert_array_equal(got.target[d], ref.target[d])
        np.testing.assert_array_equal(got.nontarget[d], ref.nontarget[d])
    np.testing.assert_array_equal(got.target_range_m, ref.target_range_m)


def test_command_serial_writes_contacts_and_summary(tiny_missions, tmp_path):
    _, cfg, logs = tiny_missions
    out, summary = tmp_path / "c.jsonl", tmp_path / "s.json"
    r = subprocess.run([sys.executable, "-m", "atr_node", "batch", str(logs[0]), str(logs[1]), "--config", str(cfg),
                        "--scheduler", "serial", "--contacts-out", str(out), "--summary", str(summary), "--quiet"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    s = json.loads(summary.read_text())
    assert s["recordings"] == 2 and s["failed"] == 0 and s["deltas"] > 0
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert len(lines) == s["contacts"] > 0 and all(c["type"] == "contact" for c in lines)
    r = subprocess.run([sys.executable, "-m", "atr_node", "batch", str(tmp_path / "nope.atrlog"), "--scheduler",
                        "serial", "--retries", "0", "--quiet"], capture_output=True, text=True, timeout=300)
    # a missing file on a local engine is bad input, told in one line before any task (issue 20)
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and "nope.atrlog: cannot open" in r.stderr


def test_a_real_xtf_recording_goes_through_and_frames_are_checked(real_data, tiny_missions):
    from atr_node.errors import FusionError

    settings, _, logs = tiny_missions
    xtf = real_data / "xtf" / "scotsman-iver2.xtf"
    res = run_recordings([xtf], settings, PerformanceModel.shipped(), Engine("serial"))
    assert res.outcomes[0].ok and res.info["tiles_in"] > 0 and res.deltas > 0
    assert res.frame is not None and "+proj=utm" in res.frame.proj4
    # a campaign is one frame: a recording of another UTM zone is refused, naming both frames
    with pytest.raises(FusionError, match=r"frame .*zone=\d+.* differs from the grid's .*zone=\d+"):
        run_recordings([xtf, logs[0]], settings, PerformanceModel.shipped(), Engine("serial"))


def test_a_scheduler_address_is_used_as_given(cluster, tiny_missions):
    """``--scheduler ADDRESS``: a client of an already running cluster (here the fixture's)."""
    settings, _, logs = tiny_missions
    address = cluster.cluster.scheduler_address
    with Engine(address) as remote:
        assert remote.cluster is None and remote.describe() == f"Dask scheduler {address}"
        got = run_recordings(logs[:1], settings, PerformanceModel.shipped(), remote)
    assert got.outcomes[0].ok
    assert got.contacts == run_recordings(logs[:1], settings, PerformanceModel.shipped(), Engine("serial")).contacts
    assert cluster.client.status == "running"  # closing the remote client left the cluster up
