"""Early stop of the calibration's iterations once an image's responses converged (issue 19):
the rule against an independent reading of its definition, the cap, the switch, and that the
split of images between processes cannot change it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from atr_node.calibration.responses import collect_image, collect_parts, usable_images
from atr_node.calibration.sources import synthetic_images
from atr_node.config import Settings, load_settings
from atr_node.errors import ConfigError

POOLED = 8
CAP = 10


def _with(s: Settings, **cal) -> Settings:
    return s.replace(calibration=dataclasses.replace(s.calibration, **cal))


@pytest.fixture(scope="module")
def setup():
    """Settings with the early stop on (off by default), and one image."""
    s = _with(Settings(), converge_pd=0.02)
    ims = synthetic_images(1, settings=s, rows=512, cols=500, seed=7, seabed="sand")
    return s, ims[0]


def _dobeck(x: np.ndarray, pd: float) -> float:
    """The largest response value that leaves at least ceil(pd m) responses above it."""
    x = np.sort(x[np.isfinite(x)])
    need = math.ceil(pd * x.size - 1e-9)
    best = np.nextafter(x[0], -np.inf)
    for v in x:
        if np.sum(x > v) >= need:
            best = v
    return float(best)


def _wilson_half(k: float, n: float, z: float = 1.959963984540054) -> float:
    p = k / n
    return z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)


def _criterion(s: Settings, resp_now, resp_before) -> bool:
    """issue 19's rule, read directly from its definition (docs/calibration.md)."""
    cal = s.calibration
    # the thresholds read the targets clear of the swath's end (the nominal ones among them)
    whole_now, whole_before = resp_now.whole, resp_before.whole
    nominal_now = resp_now.nominal & whole_now
    nominal_before = resp_before.nominal & whole_before
    for d in resp_now.detectors:
        x, xb = resp_now.target[d], resp_before.target[d]
        sel = x[nominal_now] if nominal_now.sum() >= 20 else x[whole_now]
        selb = xb[nominal_before] if nominal_before.sum() >= 20 else xb[whole_before]
        tau, tau_b = _dobeck(sel, cal.pd_target), _dobeck(selb, cal.pd_target)
        f = x[np.isfinite(x)]
        iqr = np.percentile(f, 75) - np.percentile(f, 25)
        if abs(tau - tau_b) > cal.converge_tau * iqr:
            return False
        if _wilson_half(float(np.sum(f > tau)), float(x.size)) / math.sqrt(POOLED) > cal.converge_pd:
            return False
    return True


def _collect(s, image, iterations, *, pooled=POOLED, seed=3, progress=None):
    return collect_image(image, settings=s, iterations=iterations, targets_per_image=s.calibration.targets_per_image,
                         rng=np.random.default_rng([seed, 0]), pooled=pooled, progress=progress)


def test_an_image_stops_at_the_first_iteration_its_rule_holds(setup):
    s, image = setup
    ticks = []
    got = _collect(s, image, CAP, progress=lambda: ticks.append(1))
    done = got.provenance["iterations_done"][0]
    assert 2 <= done < CAP  # it converged before the cap on this image
    assert not got.whole.all()  # some targets reach the swath's end: the rule must leave them out
    assert len(ticks) == CAP  # progress still counts every iteration (the spared ones at the end)
    off = _with(s, converge_pd=0.0)
    # the first `done` iterations of a run without the rule: the same draws, the same responses
    full = [_collect(off, image, r) for r in range(1, done + 1)]
    np.testing.assert_array_equal(full[-1].target_range_m, got.target_range_m)
    for d in got.detectors:
        np.testing.assert_array_equal(full[-1].target[d], got.target[d])
    # the rule holds at `done` and at no earlier iteration from the second
    assert _criterion(s, full[done - 1], full[done - 2])
    for r in range(2, done):
        assert not _criterion(s, full[r - 1], full[r - 2]), r


def test_the_cap_and_the_switch(setup):
    s, image = setup
    for settings in (Settings(), _with(s, converge_pd=0.0), _with(s, converge_tau=0.0), _with(s, converge_pd=1e-6)):
        assert _collect(settings, image, 4).provenance["iterations_done"] == [4]
    assert _collect(s, image, 4, pooled=None).provenance["iterations_done"] == [4]  # no pooling known: no rule


def test_more_images_pooled_stop_sooner(setup):
    s, image = setup
    few = _collect(s, image, CAP, pooled=1).provenance["iterations_done"][0]
    many = _collect(s, image, CAP, pooled=64).provenance["iterations_done"][0]
    assert many <= few


def test_any_split_between_processes_gives_the_same_parts():
    s = _with(Settings(), converge_pd=0.02)
    ims = synthetic_images(3, settings=s, rows=300, cols=400, seed=9, seabed="silt")
    usable, _ = usable_images(ims, settings=s)
    kw = dict(settings=s, iterations=6, targets_per_image=20, seed=4)
    whole = collect_parts(usable, **kw)
    parts = {**collect_parts(usable, which=[0, 2], **kw), **collect_parts(usable, which=[1], **kw)}
    for k in range(len(usable)):
        assert whole[k].provenance["iterations_done"] == parts[k].provenance["iterations_done"]
        for d in whole[k].detectors:
            np.testing.assert_array_equal(whole[k].target[d], parts[k].target[d])


@pytest.mark.parametrize("key,value", [("converge_tau", -0.1), ("converge_tau", 1.0), ("converge_pd", 0.5)])
def test_bad_settings_are_refused(tmp_path, key, value):
    f = tmp_path / "bad.toml"
    f.write_text(f"[calibration]\n{key} = {value}\n")
    with pytest.raises(ConfigError, match=f"calibration.{key}"):
        load_settings(f)


def test_the_rule_s_thresholds_leave_out_the_targets_the_swath_s_end_cut():
    """Convergence reads the thresholds estimate_model will set: on the whole targets (the
    nominal ones among them when there are enough), not on those the swath's end cut."""
    from atr_node.calibration.responses import Convergence

    rng = np.random.default_rng(5)
    m = 200
    x = rng.normal(3.0, 1.0, m)
    whole = np.ones(m)
    whole[:30] = 0.0
    x[:30] = -5.0  # cut targets: far weaker
    nominal = (rng.random(m) < 0.5).astype(float)
    cal = _with(Settings(), converge_pd=0.02).calibration
    for w, sel in ((whole, (nominal > 0) & (whole > 0)), (None, nominal > 0)):
        conv = Convergence(cal, POOLED)
        conv.done({"mf": list(x)}, list(nominal), None if w is None else list(w))
        assert conv.last["mf"] == _dobeck(x[sel], cal.pd_target)
