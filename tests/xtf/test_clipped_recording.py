"""An 8-bit recording that clips (river-000_1236: its port seabed at 10-40 % of full scale, speckle
and echoes at 255), replayed as users do, with the on-line calibration: injected echoes cut at
the file's full scale, clipped seabed scored with its own likelihood ratios (docs/fusion.md,
"Clipped recordings"), and a resume that loses none of it."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from atr_node.calibration.model import PerformanceModel
from atr_node.calibration.online import OnlineCalibrator
from atr_node.config import Settings
from atr_node.evaluation.waterfall import SidePings, locate_contacts
from atr_node.geo import MissionFrame
from atr_node.node import state as node_state
from atr_node.node.pipeline import Pipeline
from atr_node.io.recording import open_recording
from atr_node.records.tile import Tile

from .conftest import run_cli


@pytest.fixture(scope="module")
def river(real_data):
    return real_data / "xtf" / "river-000_1236.xtf"


@pytest.fixture(scope="module")
def records(river):
    return list(open_recording(river))


def test_the_files_tiles_clip_at_255(records):
    tiles = [Tile.from_map(r.msg) for r in records if r.link == "sonar"]
    assert tiles and all(t.wire_dtype == "uint8" and t.saturation == 255.0 for t in tiles)
    assert all(t.as_intensity().saturation == 255.0 ** 2 for t in tiles)
    # the file does reach full scale: clipping is real here, not a formality
    assert max(float(np.nanmax(t.pixels)) for t in tiles) == 255.0


def test_river_replay_reports_few_contacts_on_seabed_and_both_small_objects(river, records, tmp_path):
    out, summary = tmp_path / "c.jsonl", tmp_path / "s.json"
    r = run_cli("replay", river, "--publish", "none", "--speed", "max", "--contacts-out", out, "--summary", summary)
    assert r.returncode == 0, r.stderr
    contacts = [c for c in map(json.loads, out.read_text().splitlines()) if c["state"] != "withdrawn"]
    model = json.loads(summary.read_text())["model"]
    assert model["state"] == "on-line" and model["clipped_db"] == Settings().calibration.clip_headroom_db
    assert "scored with its own likelihood ratios" in model["text"]
    # look_weights "auto": the file's seabed clips, so the look score's weights are fitted, and
    # the summary says so
    assert model["weights_fitted"] is True and "detector weights fitted" in model["text"]
    # issue 18: fewer than 15 contacts (19 before the clipping rules, 134 before the issue)
    assert 0 < len(contacts) < 15
    tiles = [Tile.from_map(x.msg) for x in records if x.link == "sonar"]
    pings = [SidePings.from_tiles(tiles, side) for side in ("port", "stbd")]
    nav = next(t for t in tiles if t.nav is not None)
    frame = MissionFrame("utm", float(nav.nav.lat_deg[0]), float(nav.nav.lon_deg[0]))
    places = locate_contacts(pings, contacts, frame, band_m=Settings().sensor.first_return_band_m)
    assert len(places) == len(contacts) and all(p.zone == "seabed" for p in places)
    assert all(c["detections"] > 0 for c in contacts)
    # issue 18: its two small objects read by eye, each within 3 m (ICD section 5's match radius;
    # 14 pings is 3 m along-track): starboard ping ~925 at 29 m slant, port ping ~330 at 23.5 m
    # (on the waterfall the port one, "ping about 325 at 18 m" in the shared README, lies at
    # 23-25 m: tools/figures/real_recordings.py). The port one is found since the look score's
    # weights are fitted on the file's own calibration (docs/fusion.md): its look is carried by
    # the shadow, which the plain sum outvoted with three highlight detectors on clipped seabed
    for side, ping, slant in (("stbd", 925, 29.0), ("port", 330, 23.5)):
        assert any(p.side == side and abs(p.ping - ping) <= 14 and abs(p.slant_range_m - slant) <= 3.0 for p in places), \
            (side, ping, slant, [(p.side, p.ping, round(p.slant_range_m, 1)) for p in places])
    # ... and with the plain sum (the default before, and what "auto" gives float data) the port
    # object stays under report_bel: the weights are what finds it, not a change elsewhere
    cfg = tmp_path / "sum.toml"
    cfg.write_text('[calibration]\nlook_weights = "sum"\n')
    out2 = tmp_path / "c2.jsonl"
    r = run_cli("replay", river, "--config", cfg, "--publish", "none", "--speed", "max", "--contacts-out", out2)
    assert r.returncode == 0, r.stderr
    plain = [c for c in map(json.loads, out2.read_text().splitlines()) if c["state"] != "withdrawn"]
    plain_places = locate_contacts(pings, plain, frame, band_m=Settings().sensor.first_return_band_m)
    assert not any(p.side == "port" and abs(p.ping - 330) <= 14 and abs(p.slant_range_m - 23.5) <= 3.0
                   for p in plain_places)


@pytest.mark.parametrize("cut_after", [3, 10])
def test_a_resume_keeps_the_full_scale_of_held_tiles_and_strips(records, tmp_path, cut_after):
    """Cut after 3 tiles (tiles held for the on-line calibration: the snapshot keeps their full
    scale beside the wire map) or 10 (the strips' state holds it): the resumed run ends with the
    contacts of the run without a cut."""
    settings = Settings()
    shipped = PerformanceModel.shipped()

    def pipeline():
        return Pipeline(settings, model=shipped, workers=0,
                        online=OnlineCalibrator(settings, shipped, deterministic=True))

    ref = pipeline()
    try:
        for rec in records:
            ref.feed(rec)
        ref.finish()
        want = ref.contacts
        assert ref.model.looks.lrs_clipped is not None
    finally:
        ref.close()
    sonar = [i for i, r in enumerate(records) if r.link == "sonar"]
    k = sonar[cut_after - 1] + 1
    a = pipeline()
    try:
        for rec in records[:k]:
            a.feed(rec)
        if cut_after == 3:
            assert a.calibration_held > 0
            assert all(t.saturation == 255.0 ** 2 for t in a._cal_held)
        node_state.save(tmp_path / "s", a, position=k)
    finally:
        a.close()
    b = pipeline()
    try:
        assert node_state.load(tmp_path / "s", b)["position"] == k
        if cut_after == 3:
            assert b.calibration_held > 0 and all(t.saturation == 255.0 ** 2 for t in b._cal_held)
        else:
            assert all(st.full_scale == 255.0 ** 2 for st in b.strips._legs.values())
        for rec in records[k:]:
            b.feed(rec)
        b.finish()
        assert b.contacts == want
        assert math.isclose(b.model.looks.clip_headroom_db, settings.calibration.clip_headroom_db)
    finally:
        b.close()
