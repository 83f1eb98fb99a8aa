"""Issue 20, item 2: the demo reports what the node published.

The demo's node row must be what ``atr-node evaluate --contacts`` says of the contacts the node
published (its ``--contacts-out`` stream, reproduced here by ``atr-node replay``), the
comparison rows must say they are the comparison pass, and the ROC and mosaic figures must
stay readable (no empty panel, no matplotlib warning, labels that do not overlap).
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings

import numpy as np
import pytest

COMPARISON = "comparison pass, recomputed from the node's detections"


def _atr(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "atr_node", *args], capture_output=True, text=True, timeout=timeout)


def _key(c: dict) -> tuple:
    return (c["id"], c["state"], round(c["lat_deg"], 9), round(c["lon_deg"], 9), round(c["bel"], 9))


def test_demo_node_row_is_evaluate_contacts_on_what_the_node_published(tmp_path):
    out = tmp_path / "demo"
    r = _atr("demo", "--small", "--missions", "1", "--online-calibration", "off", "--out", str(out), timeout=600)
    assert r.returncode == 0, r.stderr
    mission = out / "mission-1-silt"
    rows = json.loads((out / "summary.json").read_text())[0]["rows"]
    node = rows[0]
    assert node["source"] == "node's contacts" and "the node, as published" in node["method"]
    assert all(row["source"] == COMPARISON for row in rows[1:])
    report = (out / "report.md").read_text()
    assert COMPARISON in report and "node's contacts" in report

    # the contacts the demo scored are the node's --contacts-out stream: a plain replay of the
    # same recording with the same settings publishes the same contacts
    replayed = tmp_path / "replayed.jsonl"
    r = _atr("replay", str(mission / "mission.atrlog"), "--online-calibration", "off", "--publish", "none",
             "--contacts-out", str(replayed), "--no-progress")
    assert r.returncode == 0, r.stderr
    demo_contacts = [json.loads(x) for x in (mission / "contacts.jsonl").read_text().splitlines()]
    node_contacts = [json.loads(x) for x in replayed.read_text().splitlines()]
    assert demo_contacts and sorted(map(_key, demo_contacts)) == sorted(map(_key, node_contacts))

    # ... and the demo's node row is what `atr-node evaluate --contacts` says of them
    r = _atr("evaluate", "--truth", str(mission / "truth.csv"), "--contacts", str(replayed), "--out",
             str(tmp_path / "ev"))
    assert r.returncode == 0, r.stderr
    assert "Warning" not in r.stderr  # e.g. matplotlib's "No artists with labels found"
    ev = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    assert ev["pd"] == pytest.approx(node["pd"]) and ev["false_alarms"] == node["false_alarms"]
    # an independent count at the operating point: live contacts at Bel >= 0.5 within 3 m of a
    # target can match at most that many targets, the rest are false alarms
    reported = [c for c in node_contacts if c["state"] != "withdrawn" and c["bel"] >= 0.5]
    assert ev["matched"] + ev["false_alarms"] == len(reported)

    # the comparison pass fuses as the node does: its DS of every detector, at the operating
    # point, is the node's result (the same detections and model here: calibration off)
    ds_all = rows[-1]
    assert "(weakest)" in ds_all["method"]
    assert (ds_all["pd"], ds_all["false_alarms"]) == (node["pd"], node["false_alarms"])
    stats = json.loads((out / "summary.json").read_text())[0]["stats"]
    assert stats["node_vs_comparison"] == "agree"


def test_roc_of_contacts_alone_is_one_fusion_panel_without_warnings(tmp_path):
    from atr_node.evaluation.report import plot_roc
    from atr_node.evaluation.scoring import roc

    curve = roc("node contacts", np.array([[0.0, 0.0], [10.0, 0.0]]), [0.9, 0.6], np.array([[0.0, 0.0]]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plot_roc([], [], tmp_path / "roc.png", covered_km2=0.0, title="t", fused=[curve])
    assert (tmp_path / "roc.png").stat().st_size > 1000


def test_mosaic_labels_do_not_overlap(tmp_path):
    """Crowded contacts (a hard mission's hundreds): the labels placed overlap neither each other
    nor leave the axes, measured on the drawn text, not on the placement's own estimate."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from atr_node.evaluation.report import _place_labels

    rng = np.random.default_rng(3)
    pts = rng.uniform(0, 200, (300, 2))
    pts[:100] = rng.uniform(90, 110, (100, 2))  # a dense cluster
    fig = plt.figure(figsize=(8, 8))
    ax = fig.add_axes((0.1, 0.1, 0.85, 0.85))
    ax.set_xlim(0, 200)
    ax.set_ylim(0, 200)
    items = [(p, f"{i + 100}: 0.{i % 100:02d}", i < 5) for i, p in enumerate(pts)]
    placed = _place_labels(fig, ax, items, max_labels=60)
    assert 20 <= placed <= 60
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    from matplotlib.text import Text

    boxes = [Text.get_window_extent(t, r) for t in ax.texts]  # the text, not its leader line
    assert len(boxes) == placed
    axb = ax.get_window_extent(r)
    for i, a in enumerate(boxes):
        assert axb.x0 - 1 <= a.x0 and a.x1 <= axb.x1 + 1 and axb.y0 - 1 <= a.y0 and a.y1 <= axb.y1 + 1
        for b in boxes[i + 1:]:
            overlap_px = min(a.x1, b.x1) - max(a.x0, b.x0), min(a.y1, b.y1) - max(a.y0, b.y0)
            assert not (overlap_px[0] > 1 and overlap_px[1] > 1), (a, b)
    plt.close(fig)
