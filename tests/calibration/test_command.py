"""`atr-node calibrate` end to end on synthetic seabeds and on a real .atrlog file; the shipped
model loads; the figures are written."""

from __future__ import annotations

import numpy as np
import pytest

from atr_node.calibration.model import PerformanceModel
from atr_node.calibration.plots import figure3_thresholds
from atr_node.calibration.stats import dobeck_threshold
from atr_node.cli import main
from atr_node.io.atrlog import AtrLogWriter
from atr_node.records.tile import Tile
from atr_node.calibration.sources import synthetic_seabed


def test_calibrate_synthetic_writes_model_and_figures(tmp_path, capsys):
    out = tmp_path / "m.json"
    rc = main(["calibrate", "--rows", "200", "--cols", "500", "--iterations", "2", "--targets", "4",
               "--seed", "3", "--out", str(out), "--plots", str(tmp_path / "fig")])
    assert rc == 0
    model = PerformanceModel.load(out)
    assert set(model.tau) == {"mf", "lac", "smf", "z"}
    assert model.provenance["seed"] == 3 and model.provenance["n_target_responses"] == 8
    assert model.provenance["seabed"] == "silt" and model.provenance["iterations"] == 2
    for f in ("confidence.png", "pyr.png"):
        assert (tmp_path / "fig" / f).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    err = capsys.readouterr().err
    assert "2/2" in err  # the progress bar reached the end


def test_calibrate_on_a_recording(tmp_path):
    log = tmp_path / "rec.atrlog"
    with AtrLogWriter(log) as w:
        for k in range(3):
            px = synthetic_seabed(200, 400, range0_m=30.0, dr_m=0.1, dx_m=0.1, seabed="sand",
                                  rng=np.random.default_rng(k))
            t = Tile("m", 1, "port", k, px, "intensity", 30.0, 0.1, 0.1, False, 1e9 + k * 20 + np.arange(200) * 0.1)
            w.write(1e9 + k, "sonar", t.to_map())
            w.write(1e9 + k, "nmea", b"$GPZDA,120000.00,01,08,2014,00,00*4C")
    out = tmp_path / "m.json"
    rc = main(["calibrate", "--input", str(log), "--max-images", "2", "--iterations", "1", "--targets", "3",
               "--out", str(out), "--no-plots", "--no-progress"])
    assert rc == 0
    model = PerformanceModel.load(out)
    assert model.provenance["n_images"] == 2 and len(model.provenance["images"]) == 2
    assert model.provenance["seabed"] == "recorded" and str(log) in model.provenance["source"]


def test_calibrate_reports_bad_input(tmp_path, capsys):
    assert main(["calibrate", "--input", str(tmp_path / "absent.atrlog"), "--no-plots"]) == 1
    assert "no such file" in capsys.readouterr().err.lower()
    bad = tmp_path / "x.png"
    bad.write_bytes(b"not a picture")
    assert main(["calibrate", "--input", str(bad), "--no-plots"]) == 1
    assert "not a picture" in capsys.readouterr().err


def test_shipped_model_loads_and_is_sane():
    m = PerformanceModel.shipped()
    assert set(m.tau) == {"mf", "lac", "smf", "z"}
    assert m.provenance["n_target_responses"] >= 2000
    for d in m.tau:
        c = m.confidence(d, np.linspace(m.tau[d], 10 * abs(m.tau[d]) + 1, 50))
        assert np.all((c > 0) & (c < 1)) and np.all(np.diff(c) >= 0)
        assert m.pd(d, 0.0) == 0.0 and m.pd(d, 1e4) == 0.0
        assert 0.5 < m.detectors[d].pd_at_tau < 1.0


def test_figure3_thresholds_are_three_distinct_operating_points(rng):
    x = rng.normal(5.0, 1.0, size=500)
    x_n = rng.normal(0.0, 1.0, size=5000)
    taus = figure3_thresholds(x, 3.4, x_n)
    assert len(taus) == 3 and taus == sorted(taus) and 3.4 in taus
    assert np.mean(x_n > taus[0]) == pytest.approx(0.01, abs=0.001)
    assert taus[-1] == dobeck_threshold(x, 0.8, default=0.0) and np.mean(x > taus[-1]) >= 0.8
    no_cells = figure3_thresholds(x, 3.4)
    assert np.mean(x > no_cells[0]) >= 0.99


def test_calibrate_on_a_real_xtf_recording(real_data, tmp_path):
    """The Iver2 side-scan XTF (600 kHz, 30 m slant range): its first tiles (one ping each)
    are too small and skipped with a warning, the next ones put on ground range at their nav
    altitude and calibrated."""
    out = tmp_path / "m.json"
    rc = main(["calibrate", "--input", str(real_data / "xtf" / "scotsman-iver2.xtf"), "--max-images", "4",
               "--iterations", "2", "--targets", "3", "--out", str(out), "--no-plots", "--no-progress"])
    assert rc == 0
    m = PerformanceModel.load(out)
    assert len(m.provenance["skipped_images"]) == 2 and m.provenance["n_images"] == 2
    for d in m.tau:
        y = m.detectors[d].pyr
        assert y.edges_m[0] >= 0.0 and y.edges_m[-1] <= 40.0  # ground ranges of a 30 m slant-range sonar
