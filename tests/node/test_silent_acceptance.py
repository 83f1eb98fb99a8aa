"""Silent acceptance (issue 21 item 7), on real replays of the small generated mission: tiles
that repeat a seq are all counted done (and the log says once that seqs repeat), clamped masses
and rejections by reason reach the summary and the end-of-run line, and no warning has an
empty reason."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from atr_node.calibration.model import PerformanceModel
from atr_node.errors import describe
from atr_node.io.atrlog import AtrLogWriter, read_atrlog


def _rewrite(src, dst, change):
    """``src`` with every sonar tile map passed through ``change`` (other records as they are)."""
    with AtrLogWriter(dst) as w:
        for r in read_atrlog(src):
            w.write(r.t, r.link, change(dict(r.msg)) if r.link == "sonar" else r.msg)
    return dst


def _replay(log, tmp_path, *extra):
    summary = tmp_path / "summary.json"
    r = subprocess.run([sys.executable, "-m", "atr_node", "replay", str(log), "--online-calibration", "off",
                        "--publish", "none", "--workers", "0", "--no-progress", "--summary", str(summary), *extra],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return json.loads(summary.read_text()), r.stderr


def test_tiles_that_all_say_seq_0_are_all_counted_done(small_mission, tmp_path):
    settings, cfg, files = small_mission
    zeros = _rewrite(files.atrlog, tmp_path / "seq0.atrlog", lambda m: {**m, "seq": 0})
    s, err = _replay(zeros, tmp_path, "--config", str(cfg))
    n = files.tiles
    assert s["tiles_in"] == n and s["tiles_done"] == n and s["tiles_dropped"] == 0
    # every tile but the first of each leg and side repeats the seq of the one before it
    strips = len({(r.msg["leg"], r.msg["side"]) for r in read_atrlog(files.atrlog) if r.link == "sonar"})
    assert s["seq_repeats"] == n - strips
    assert err.count("does not increase") == 1  # said once, then counted
    end = err.strip().splitlines()[-1]
    assert f"{n} tiles in, {n} done" in end and f"{n - strips} tiles repeat a seq" in end


def test_the_original_mission_has_no_seq_note(small_mission, tmp_path):
    _, cfg, files = small_mission
    s, err = _replay(files.atrlog, tmp_path, "--config", str(cfg))
    assert s["seq_repeats"] == 0 and s["clamped"] == 0 and "does not increase" not in err
    end = err.strip().splitlines()[-1]
    assert "repeat a seq" not in end and "clamped" not in end and "rejected:" not in end


def test_clamped_masses_are_reported(small_mission, tmp_path):
    """A model sure of everything (confidence and Pd 0.99999) with eps 0.009: masses above
    1 - eps are clamped, and the run says how many."""
    _, cfg, files = small_mission
    body = PerformanceModel.shipped().to_dict()
    tables = list(body["detectors"].values()) + list((body.get("looks") or {}).get("tables", {}).values())
    for tab in tables:
        tab["confidence"]["c"] = [0.99999] * len(tab["confidence"]["c"])
        tab["pyr"]["pd"] = [0.99999] * len(tab["pyr"]["pd"])
    body.pop("sha256", None)
    model = tmp_path / "sure.json"
    PerformanceModel.from_dict({**body, "sha256": _digest(body)}).save(model)
    conf = tmp_path / "eps.toml"
    conf.write_text(cfg.read_text() + "\n[fusion]\neps = 0.009\n")
    s, err = _replay(files.atrlog, tmp_path, "--config", str(conf), "--model", str(model))
    assert s["clamped"] > 0
    assert f"{s['clamped']} masses clamped to 1 - eps" in err.strip().splitlines()[-1]


def _digest(body):
    from atr_node.calibration.model import _digest as digest

    return digest(body)


def test_rejected_tiles_are_logged_once_per_reason_and_named_at_the_end(small_mission, tmp_path):
    _, cfg, files = small_mission

    def no_heading(m):
        nav = dict(m["nav"])
        nav["heading_deg"] = np.full(len(nav["heading_deg"]) // 8, np.nan).tobytes()
        return {**m, "nav": nav}

    bad = _rewrite(files.atrlog, tmp_path / "nanhead.atrlog", no_heading)
    s, err = _replay(bad, tmp_path, "--config", str(cfg))
    n = files.tiles
    assert s["tiles_rejected"] == n and s["rejections"] == {"tile field nav.heading_deg": n}
    assert err.count("rejected tile") == 1
    assert f"rejected: tile field nav.heading_deg x {n}" in err.strip().splitlines()[-1]


def test_nav_rejections_are_named_in_the_end_of_run_line(small_mission, tmp_path):
    """Every HDT of the mission turned into 400 deg: rejected (not wrapped to 40), one warning,
    and the count in the end-of-run line."""
    _, cfg, files = small_mission
    from hw.nmea import format_sentence

    out = tmp_path / "hdt400.atrlog"
    n_hdt = 0
    with AtrLogWriter(out) as w:
        for r in read_atrlog(files.atrlog):
            msg = r.msg
            if r.link == "nmea" and msg[3:6] == b"HDT":
                msg, n_hdt = format_sentence(msg[1:6].decode(), ["400.00", "T"]), n_hdt + 1
            w.write(r.t, r.link, msg)
    assert n_hdt > 0, "the generated mission has HDT sentences"
    s, err = _replay(out, tmp_path, "--config", str(cfg))
    assert s["nav"]["nmea"]["out_of_range"] == n_hdt
    assert err.count("NMEA sentence rejected (out_of_range)") == 1
    assert f"nmea out_of_range x {n_hdt}" in err.strip().splitlines()[-1]


def test_describe_never_gives_an_empty_reason():
    assert describe(OSError()) == "OSError (with no message)"
    assert describe(KeyError()) == "KeyError (with no message)"
    assert describe(ValueError("  ")) == "ValueError (with no message)"
    assert describe(ValueError("bad dr_m")) == "bad dr_m"


def test_seq_0_tiles_are_counted_across_a_snapshot_and_resume(small_mission, tmp_path):
    """The strips' arrival numbers survive a snapshot: a resumed node still counts every tile."""
    from atr_node.node.service import NodeService

    settings, _, files = small_mission
    recs = list(read_atrlog(_rewrite(files.atrlog, tmp_path / "seq0.atrlog", lambda m: {**m, "seq": 0})))
    half = next(i for i, r in enumerate(recs) if r.link == "sonar" and r.msg["leg"] == 1) + 3
    state = tmp_path / "state"
    first = NodeService(settings, model=PerformanceModel.shipped(), workers=0, state_dir=state)
    try:
        first.run(recs[:half], finish=False)
        first.snapshot()
    finally:
        first.close()
    again = NodeService(settings, model=PerformanceModel.shipped(), workers=0, state_dir=state)
    try:
        start = again.resume()
        assert start == half
        again.run(recs[start:], start=start)
        s = again.summary()
    finally:
        again.close()
    assert s["tiles_in"] == files.tiles and s["tiles_done"] == files.tiles
