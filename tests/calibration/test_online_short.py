"""On-line calibration on short recordings (issue 18 item 6).

Real parts: the simulated mission of ``tests/conftest.py`` cut after 6 tiles (fewer than
``calibration.online_tiles`` = 8), replayed by ``atr-node replay`` in its own process or by the
node's pipeline with a real calibration worker. Before the fix the replay switched models at
tile 16, so a 6-tile recording gave byte-identical contacts with on-line calibration on and off,
and nothing said so. Now the replay holds its first tiles until the worker has them, uses the
on-line model from tile 1, stays deterministic, and says which model it used and why.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from atr_node.calibration.model import PerformanceModel
from atr_node.calibration.online import OnlineCalibrator, model_report
from atr_node.config import CalibrationSettings, load_settings
from atr_node.io.atrlog import AtrLogWriter, read_atrlog
from atr_node.node import state as node_state
from atr_node.node.pipeline import Pipeline

from ..waiting import WAIT_S, wait_until

REPO = Path(__file__).resolve().parents[2]

FAST_CALIBRATION = "\n[calibration]\nonline_iterations = 1\ntargets_per_image = 5\n"
"""A cheap on-line calibration (6 images x 1 iteration x 5 targets): the test is about when the
model is used, not about its quality."""

SLOW_CALIBRATION = "\n[calibration]\nonline_iterations = 3000\ntargets_per_image = 40\nconverge_pd = 0\n"
"""Minutes of calibration (no early stop at convergence): a replay is certainly still waiting
for it when signalled."""

SHORT_TILES = 6


def cut(src: Path, dst: Path, tiles: int) -> Path:
    """The records of ``src`` up to (not including) its tile number ``tiles + 1``."""
    n = 0
    with AtrLogWriter(dst) as w:
        for r in read_atrlog(src):
            if r.link == "sonar":
                if n == tiles:
                    break
                n += 1
            w.write(r.t, r.link, r.msg)
    assert n == tiles
    return dst


@pytest.fixture(scope="module")
def short(small_mission, tmp_path_factory):
    """(settings, config path, 6-tile log, folder)."""
    _, cfg, files = small_mission
    d = tmp_path_factory.mktemp("online_short")
    conf = d / "short.toml"
    conf.write_text(cfg.read_text() + FAST_CALIBRATION)
    log = cut(files.atrlog, d / "short6.atrlog", SHORT_TILES)
    return load_settings(conf), conf, log, d


def replay_cmd(log: Path, conf: Path, out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "atr_node", "-v", "replay", str(log), "--config", str(conf), "--publish", "none",
            "--quiet", "--contacts-out", str(out / "contacts.jsonl"), "--summary", str(out / "summary.json"), *extra]


def run_replay(log: Path, conf: Path, out: Path, *extra: str) -> tuple[bytes, dict, str]:
    """(contacts file bytes, summary, stderr) of one ``atr-node replay``."""
    out.mkdir(parents=True, exist_ok=True)
    p = subprocess.run(replay_cmd(log, conf, out, *extra), capture_output=True, text=True, cwd=REPO,
                       timeout=5 * WAIT_S)  # a whole replay: a hang guard
    assert p.returncode == 0, p.stderr[-3000:]
    return (out / "contacts.jsonl").read_bytes(), json.loads((out / "summary.json").read_text()), p.stderr


@pytest.fixture(scope="module")
def replays(short):
    """Two replays with on-line calibration and one without, of the 6-tile recording."""
    _, conf, log, d = short
    return {name: run_replay(log, conf, d / name, "--online-calibration", oc)
            for name, oc in (("on", "on"), ("on_again", "on"), ("off", "off"))}


def test_a_6_tile_replay_uses_the_online_model_from_tile_1_and_says_so(replays):
    on, _, err = replays["on"]
    off, off_summary, off_err = replays["off"]
    model = replays["on"][1]["model"]
    assert model["state"] == "on-line" and model["from_tile"] == 1
    assert (model["images"], model["offered"], model["of"]) == (6, 6, 8)
    want = "on-line calibration: 6 of 8 images (the recording has 6 tiles), model used from tile 1"
    assert model["text"] == want
    assert re.search(r"INFO atr_node\.calibration\.online: " + re.escape(want), err)
    end = [line for line in err.splitlines() if line.startswith("atr-node replay:")]
    assert len(end) == 1 and end[0].endswith("; on-line model (6 images)"), end
    assert off_summary["model"]["text"] == "on-line calibration off; the shipped model for all 6 tiles"
    assert off_err.rstrip().endswith("shipped model (on-line calibration off)")
    # the symptom of the issue: byte-identical contacts whether calibration was on or off
    assert on and off and on != off


def test_two_replays_of_the_same_log_give_identical_contacts(replays):
    assert replays["on"][0] == replays["on_again"][0]
    assert replays["on"][1]["model"] == replays["on_again"][1]["model"]


def _pipeline_run(settings, records, *, online: bool, mode: str = "replay", workers: int = 1,
                  between=None) -> tuple[Pipeline, list]:
    """Feed ``records`` through a pipeline; return it (finished, not closed) and the
    (leg, side, seq, model) of every fused unit, in order."""
    shipped = PerformanceModel.shipped()
    oc = OnlineCalibrator(settings, shipped, deterministic=mode == "replay") if online else None
    pipe = Pipeline(settings, model=shipped, workers=workers, mode=mode, online=oc)
    fused = []
    pipe.on_fused = lambda unit, model, res: fused.append((unit.leg, unit.side, unit.seq, model))
    for rec in records:
        pipe.feed(rec)
        if between is not None:
            between(pipe)
    pipe.finish()
    return pipe, fused


def test_every_unit_of_a_short_replay_is_fused_with_the_online_model_in_order(short):
    settings, _, log, _ = short
    records = list(read_atrlog(log))
    on, fused_on = _pipeline_run(settings, records, online=True)
    off, fused_off = _pipeline_run(settings, records, online=False)
    try:
        assert on.calibration_held == 0 and on.stats.tiles_done == SHORT_TILES == off.stats.tiles_done
        online = on.online.model
        assert online.provenance["source"] == "on-line" and online.tau != off.model.tau
        assert fused_on and all(m is online for *_, m in fused_on)
        # held tiles keep their order (and nav: the same units, at the same places)
        assert [u[:3] for u in fused_on] == [u[:3] for u in fused_off]
        assert on.model_report()["from_tile"] == 1
    finally:
        on.close()
        off.close()


def test_a_failed_calibration_reports_the_shipped_model_for_all_tiles(small_mission, tmp_path):
    """16-ping tiles have no room for a target and its context window: the worker fails on
    every one; the replay uses the shipped model throughout, exactly as with calibration off."""
    from atr_node.simulation.mission import generate_mission

    _, cfg, _ = small_mission
    conf = tmp_path / "tiny.toml"
    conf.write_text(cfg.read_text().replace("mission_tile_pings = 128", "mission_tile_pings = 16") + FAST_CALIBRATION)
    files = generate_mission(load_settings(conf), tmp_path / "m", seed=7)
    log = cut(files.atrlog, tmp_path / "tiny6.atrlog", SHORT_TILES)
    on, summary, err = run_replay(log, conf, tmp_path / "on", "--online-calibration", "on")
    off, _, _ = run_replay(log, conf, tmp_path / "off", "--online-calibration", "off")
    model = summary["model"]
    assert model["state"] == "failed" and model["from_tile"] is None
    assert "no image has room for a target" in model["error"]
    assert model["text"].startswith("on-line calibration failed (AtrError: calibration: no image has room")
    assert model["text"].endswith("; the shipped model for all 6 tiles")
    assert re.search(r"WARNING atr_node\.calibration\.online: on-line calibration failed \(", err)
    assert err.rstrip().endswith("shipped model (on-line calibration failed)")
    assert on == off


def test_a_snapshot_while_tiles_are_held_or_after_resumes_to_the_same_contacts(short, tmp_path):
    """online_tiles = 4: a cut after 2 tiles snapshots tiles held for the calibration (offered
    again to the resumed node's calibrator), a cut after 5 the on-line model and how it came."""
    settings, _, log, _ = short
    settings = dataclasses.replace(settings, calibration=dataclasses.replace(settings.calibration, online_tiles=4))
    records = list(read_atrlog(log))
    ref, _ = _pipeline_run(settings, records, online=True, workers=0)
    want, want_model = ref.contacts, ref.model_report()
    ref.close()
    assert want and want_model["state"] == "on-line" and want_model["images"] == 4
    sonar = [i for i, r in enumerate(records) if r.link == "sonar"]
    for tiles, held in ((2, 2), (5, 0)):
        k = sonar[tiles - 1] + 1
        shipped = PerformanceModel.shipped()
        a = Pipeline(settings, model=shipped, workers=0,
                     online=OnlineCalibrator(settings, shipped, deterministic=True))
        for r in records[:k]:
            a.feed(r)
        assert a.stats.tiles_in == tiles
        # the nav merger may still hold the newest tile: everything else is held for calibration
        assert a.calibration_held + a.merger.held == tiles if held else a.calibration_held == 0
        node_state.save(tmp_path / f"s{tiles}", a, position=k)
        a.close()
        b = Pipeline(settings, model=shipped, workers=0,
                     online=OnlineCalibrator(settings, shipped, deterministic=True))
        try:
            assert node_state.load(tmp_path / f"s{tiles}", b)["position"] == k
            assert b.calibration_held == (tiles - a.merger.held if held else 0)
            for r in records[k:]:
                b.feed(r)
            b.finish()
            assert b.contacts == want, f"cut after tile {tiles}"
            assert b.model_report() == want_model
        finally:
            b.close()


def test_ctrl_c_while_waiting_for_the_model_exits_at_once_and_the_resume_loses_nothing(short, replays):
    """Ctrl-C (SIGINT to the whole process group, as a terminal sends it) while the replay waits
    for a long calibration: exit 130, the held tiles in the snapshot. The resume runs with the
    fast calibration: nothing computed before the signal depends on it, so its contacts must
    equal those of the uninterrupted fast replay."""
    _, conf, log, d = short
    slow = d / "slow.toml"
    slow.write_text(conf.read_text().replace(FAST_CALIBRATION, SLOW_CALIBRATION))
    state, out = d / "ctrl_c_state", d / "ctrl_c"
    out.mkdir()
    proc = subprocess.Popen(replay_cmd(log, slow, out, "--state-dir", str(state), "--workers", "0"),
                            stderr=subprocess.PIPE, text=True, cwd=REPO, start_new_session=True)
    try:
        lines = []
        for line in proc.stderr:
            lines.append(line)
            if "waiting for the model from" in line:
                os.killpg(proc.pid, signal.SIGINT)
                break
        rest = proc.stderr.read()
        # a guard against a hang (the calibration alone would take minutes), not a timing test
        assert proc.wait(timeout=WAIT_S) == 130, "".join(lines) + rest
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "Traceback" not in rest, rest
    assert "on-line calibration not finished" in rest
    with np.load(node_state.read_current(state) / "node.npz") as z:
        meta = json.loads(z["meta"].tobytes())
    assert meta["cal_held"] + meta["held"] == SHORT_TILES and meta["model_use"] is None
    contacts, summary, _ = run_replay(log, conf, out, "--state-dir", str(state), "--workers", "0")
    assert summary["resumed_from"] == meta["position"]
    assert summary["model"]["text"] == replays["on"][1]["model"]["text"]
    assert contacts == replays["on"][0]


def test_live_keeps_the_given_model_until_the_worker_delivers_and_logs_the_switch(short, caplog):
    settings, _, log, _ = short
    # short units (6.4 m; the recording's tiles are 12.8 m): units are fused before the worker
    # is waited for, after the second tile
    settings = dataclasses.replace(settings, calibration=dataclasses.replace(settings.calibration, online_tiles=2),
                                   node=dataclasses.replace(settings.node, unit_length_m=6.4, first_unit_length_m=6.4))

    def wait_for_worker(pipe: Pipeline) -> None:
        # a live node never waits: the test waits, between records, for the worker to answer,
        # so that the switch happens within the recording
        if pipe.online.offered == 2 and not pipe.online.done:
            assert wait_until(pipe.online.ready)  # WAIT_S: a hang guard, never a timing assertion

    with caplog.at_level(logging.INFO, logger="atr_node.calibration.online"):
        pipe, fused = _pipeline_run(settings, list(read_atrlog(log)), online=True, mode="live", workers=0,
                                    between=wait_for_worker)
    try:
        rep = pipe.model_report()
        assert rep["state"] == "on-line" and rep["images"] == 2, rep
        t = rep["from_tile"]
        assert 2 <= t <= SHORT_TILES
        online, shipped = pipe.model, fused[0][3]
        assert online.provenance["source"] == "on-line" and shipped is not online
        used = [m is online for *_, m in fused]
        k = used.index(True)
        assert not any(used[:k]) and all(used[k:]), "the fallback, then the on-line model"
        assert rep["text"] == f"tiles 1-{t - 1}: shipped model; on-line model (2 of 2 images) from tile {t}"
        assert rep["text"] in caplog.messages
    finally:
        pipe.close()


def test_model_report_lines():
    base = {"deterministic": True, "fallback": "shipped model", "offered": 8, "of": 8, "images": 8, "skipped": 0,
            "from_tile": 1, "error": None}
    assert model_report({**base, "state": "on-line"}, tiles=40, fallback="x")["text"] == \
        "on-line calibration: 8 of 8 images, model used from tile 1"
    r = model_report({**base, "state": "on-line", "offered": 4, "images": 3, "skipped": 1}, tiles=4, fallback="x")
    assert r["text"] == ("on-line calibration: 3 of 8 images (the recording has 4 tiles; 1 too small for a target "
                         "and its context window), model used from tile 1")
    r = model_report({**base, "state": "on-line", "deterministic": False, "from_tile": 24}, tiles=99, fallback="x")
    assert r["text"] == "tiles 1-23: shipped model; on-line model (8 of 8 images) from tile 24"
    r = model_report({**base, "state": "failed", "images": None, "from_tile": None, "error": "E"}, tiles=6,
                     fallback="x")
    assert r["text"] == "on-line calibration failed (E); the shipped model for all 6 tiles"
    r = model_report({**base, "state": "pending", "offered": 3, "images": None, "from_tile": None}, tiles=3,
                     fallback="x")
    assert r["text"] == "on-line calibration not finished (3 of 8 images when the run ended); the shipped model " \
                        "for all 3 tiles"
    assert model_report(None, tiles=6, fallback="model given")["text"] == \
        "on-line calibration off; the model given for all 6 tiles"


def test_the_retired_switch_tile_setting_loads_with_a_warning_naming_its_replacement(tmp_path, caplog):
    conf = tmp_path / "old.toml"
    conf.write_text("[calibration]\nonline_switch_tile = 16\n")
    with caplog.at_level(logging.WARNING, logger="atr_node.config"):
        s = load_settings(conf)
    assert s.calibration.online_tiles == CalibrationSettings().online_tiles
    assert any("online_switch_tile = 16 ignored" in m and "retired" in m and "from tile 1" in m
               for m in caplog.messages), caplog.messages
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="atr_node.config"):
        CalibrationSettings(online_switch_tile=0)
    assert not caplog.messages
