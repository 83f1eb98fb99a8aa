"""What the false alarms lie on (``atr-node evaluate --clutter``, the held-out benchmark's
``fa_anatomy``): hand-placed contacts against hand-made truth and clutter, counted by hand."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time

import numpy as np
import pytest

from atr_node.errors import AtrError
from atr_node.evaluation.scoring import (FA_KINDS, EARTH_RADIUS_M, fa_anatomy, read_clutter, read_truth,
                                         score_contacts)
from atr_node.node.wire import contact_message

from ..waiting import WAIT_S

TRUTH = np.array([[0.0, 0.0], [100.0, 0.0]])
CLUTTER = np.array([[0.0, 50.0], [0.0, 80.0]])
LIKE = np.array([True, False])
ONE_LEG = np.array([[50.0, 50.0]])
# (east, north, score, what it is)
CONTACTS = [
    (0.5, 0.0, 0.9, "matched to target 0"),
    (-1.0, 1.0, 0.8, "second_on_target"),
    (100.0, 1.0, 0.9, "matched to target 1"),
    (50.0, 51.0, 0.7, "one_leg_object"),
    (1.0, 50.0, 0.95, "target_like_clutter"),
    (0.0, 82.0, 0.6, "clutter"),
    (0.0, 83.5, 0.6, "seabed"),          # 3.5 m from the clutter: outside the 3 m radius
    (200.0, 200.0, 0.5, "seabed"),
    (200.0, 220.0, 0.2, "below"),        # below the threshold: not counted
    (0.0, 79.0, 0.3, "below"),           # on the clutter, but below the threshold
]


def _hand_count(threshold: float) -> dict:
    kinds = [k for e, n, s, k in CONTACTS if s >= threshold and not k.startswith("matched")]
    return {"threshold": threshold, "false_alarms": len(kinds), **{k: kinds.count(k) for k in FA_KINDS}}


@pytest.mark.parametrize("threshold", [0.0, 0.5, 0.75, 2.0])
def test_each_false_alarm_is_counted_once_by_the_first_thing_it_lies_on(threshold):
    en = np.array([(e, n) for e, n, _, _ in CONTACTS])
    scores = [s for _, _, s, _ in CONTACTS]
    a = fa_anatomy(en, scores, TRUTH, threshold=threshold, clutter_en=CLUTTER, clutter_target_like=LIKE,
                   one_leg_en=ONE_LEG)
    want = _hand_count(threshold)
    if threshold == 0.0:  # the two below 0.5 count too: one on the seabed, one on the clutter
        want = {**want, "seabed": 3, "clutter": 2, "false_alarms": 8}
    assert a == want
    assert a["false_alarms"] == sum(a[k] for k in FA_KINDS)


def test_without_clutter_every_false_alarm_off_a_target_is_on_the_seabed():
    en = np.array([(e, n) for e, n, _, _ in CONTACTS])
    a = fa_anatomy(en, [s for *_, s, _ in CONTACTS], TRUTH, threshold=0.5)
    assert (a["false_alarms"], a["second_on_target"], a["seabed"]) == (6, 1, 5)
    with pytest.raises(ValueError, match="target_like"):
        fa_anatomy(en, [1.0] * len(en), TRUTH, threshold=0.5, clutter_en=CLUTTER, clutter_target_like=[True])
    with pytest.raises(ValueError, match="scores"):
        fa_anatomy(en, [1.0], TRUTH, threshold=0.5)


def _latlon(e: float, n: float, lat0: float = 43.0, lon0: float = 5.0) -> tuple[float, float]:
    k = math.radians(1.0) * EARTH_RADIUS_M
    return lat0 + n / k, lon0 + e / (k * math.cos(math.radians(lat0)))


def _write_scene(tmp_path, *, clutter_rows: list[str] | None = None):
    truth = tmp_path / "truth.csv"
    truth.write_text("lat_deg,lon_deg,shape\n" + "".join(f"{a:.9f},{b:.9f},cylinder\n" for a, b in
                                                           (_latlon(*p) for p in TRUTH)))
    clutter = tmp_path / "clutter.csv"
    rows = clutter_rows if clutter_rows is not None else [
        f"{a:.9f},{b:.9f},rock,{int(like)}" for (a, b), like in zip((_latlon(*p) for p in CLUTTER), LIKE)]
    clutter.write_text("lat_deg,lon_deg,shape,target_like\n" + "\n".join(rows) + "\n")
    contacts = tmp_path / "contacts.jsonl"
    with open(contacts, "w") as fh:
        for i, (e, n, s, _) in enumerate(CONTACTS):
            lat, lon = _latlon(e, n)
            fh.write(json.dumps(contact_message(id=i + 1, state="update", t=1.0, lat_deg=lat, lon_deg=lon, east_m=e,
                                                north_m=n, sigma_m=1.0, bel=s, pl=1.0, m_theta=1.0 - s, looks=1,
                                                detections=1, detectors=["mf"], legs=[0])) + "\n")
    return truth, clutter, contacts


def test_score_contacts_says_what_the_false_alarms_at_the_operating_point_lie_on(tmp_path):
    truth, clutter, contacts = _write_scene(tmp_path)
    msgs = [json.loads(x) for x in contacts.read_text().splitlines()]
    score = score_contacts(msgs, read_truth(truth), bel=0.5, clutter=read_clutter(clutter))
    want = _hand_count(0.5)
    assert score.point.false_alarms == want["false_alarms"] == 6
    # no one-leg objects in a user's files: those contacts lie on no known object
    assert score.anatomy == {**want, "one_leg_object": 0, "seabed": want["seabed"] + want["one_leg_object"]}
    s = score.summary()["false_alarm_anatomy"]
    assert s == {"second_on_target": 1, "target_like_clutter": 1, "clutter": 1, "seabed": 3}
    assert score_contacts(msgs, read_truth(truth), bel=0.5).anatomy is None


def test_evaluate_command_with_clutter(tmp_path):
    truth, clutter, contacts = _write_scene(tmp_path)
    r = subprocess.run([sys.executable, "-m", "atr_node", "evaluate", "--truth", str(truth), "--contacts",
                        str(contacts), "--clutter", str(clutter), "--bel", "0.5", "--out", str(tmp_path / "ev")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    assert summary["false_alarms"] == 6
    assert summary["false_alarm_anatomy"] == {"second_on_target": 1, "target_like_clutter": 1, "clutter": 1,
                                              "seabed": 3}
    assert "2 on known clutter (1 of it marked target-like), 1 second contacts on a target, 3 on no known object" \
        in r.stdout


@pytest.mark.parametrize("rows, says", [
    (["43.0,5.0,rock,maybe"], "clutter file .*line 2: target_like 'maybe'"),
    (["43.0,5.0,rock,1", "north,5.0,rock,0"], "clutter file .*line 3: lat_deg/lon_deg are not numbers"),
])
def test_a_bad_clutter_file_is_one_line_and_leaves_no_output(tmp_path, rows, says):
    truth, clutter, contacts = _write_scene(tmp_path, clutter_rows=rows)
    with pytest.raises(AtrError, match=says):
        read_clutter(clutter)
    out = tmp_path / "ev"
    r = subprocess.run([sys.executable, "-m", "atr_node", "evaluate", "--truth", str(truth), "--contacts",
                        str(contacts), "--clutter", str(clutter), "--out", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 1 and "Traceback" not in r.stderr  # 1: bad input (README, exit status)
    assert len(r.stderr.strip().splitlines()) == 1 and "clutter file" in r.stderr
    assert not out.exists()


def test_a_clutter_file_without_target_like_marks_nothing_target_like(tmp_path):
    p = tmp_path / "k.csv"
    p.write_text("lat_deg,lon_deg,shape\n43.0,5.0,rock\n43.001,5.0,tyre\n")
    k = read_clutter(p)
    assert len(k.objects) == 2 and not k.target_like.any()
    p.write_text("lat_deg,lon_deg\n43.0,5.0\n")
    with pytest.raises(AtrError, match="clutter file .*header lacks"):
        read_clutter(p)


def test_evaluate_subscribe_with_clutter_scores_a_live_node_s_contacts(tmp_path):
    """``--subscribe``: the contacts of a PUB socket on loopback (published again and again until
    the command ends: a subscriber joins late), scored and broken down as ``--contacts`` does."""
    from atr_node.node.publisher import Publisher

    truth, clutter, contacts = _write_scene(tmp_path)
    msgs = [json.loads(x) for x in contacts.read_text().splitlines()]
    pub = Publisher("tcp://127.0.0.1:*")
    try:
        proc = subprocess.Popen([sys.executable, "-m", "atr_node", "evaluate", "--truth", str(truth), "--subscribe",
                                 pub.endpoint, "--duration", "3", "--clutter", str(clutter), "--bel", "0.5",
                                 "--out", str(tmp_path / "ev")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + WAIT_S  # a hang guard, not a timing assertion
        while proc.poll() is None and time.monotonic() < deadline:
            for m in msgs:
                pub.contact(m)
            try:
                proc.wait(timeout=0.1)
            except subprocess.TimeoutExpired:
                pass
        if proc.poll() is None:
            proc.kill()
        out, err = proc.communicate(timeout=WAIT_S)
    finally:
        pub.close()
    assert proc.returncode == 0, err
    summary = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    assert summary["contacts"] == len(msgs) and summary["false_alarms"] == 6
    assert summary["false_alarm_anatomy"] == {"second_on_target": 1, "target_like_clutter": 1, "clutter": 1,
                                              "seabed": 3}
    assert "2 on known clutter" in out
