"""The detect stage (node worker): coverage bits and detections of a unit, checked against a
direct score_strip + isnan + find_detections of the same core, and across a pickle (the
process boundary the result crosses)."""

from __future__ import annotations

import dataclasses
import math
import pickle
import sys
from pathlib import Path

import numpy as np
import pytest

from atr_node.config import DETECTOR_NAMES, DetectorSettings, TemplateSettings
from atr_node.detectors import column_mean, column_median, find_detections, score_strip
from atr_node.node.detect import DetectJob, detect

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools" / "bench"))
from detectors import GEO, TAU, make_tile  # noqa: E402  (tools/bench/detectors.py)

# SPEC 2's half-valid rule for every window, so the hole gives SMF (context window) a coverage
# of its own, which the sharing test needs (with min_valid_fraction_zones the zones bind first)
# detections at each detector's own peak here (relocate = []): the relocation to the matched
# filter's peak has its own test below, against the same direct maps
T, S = TemplateSettings(), DetectorSettings(min_valid_fraction_zones=0.5, relocate=())
CORE = (20, 220)


@pytest.fixture(scope="module")
def job() -> DetectJob:
    img, _ = make_tile(240, 600, 9, T)
    img[100:130, 400:460] = np.nan  # a hole of no data inside the core: coverage differs by window
    core = img[CORE[0]:CORE[1]]
    return DetectJob(7, img, CORE, GEO["range0_m"], GEO["dr_m"], GEO["dx_m"], GEO["altitude_m"],
                     column_mean(core), column_median(core), dict(TAU), DETECTOR_NAMES, T, S,
                     sweep={"mf": (0.5, 2.0), "z": (1.0,)})


@pytest.fixture(scope="module")
def direct(job) -> dict[str, np.ndarray]:
    return score_strip(job.pixels, core_rows=job.core, range0_m=job.range0_m, dr_m=job.dr_m, dx_m=job.dx_m,
                       altitude_m=job.altitude_m, template=T, detectors=S, background=job.background,
                       median=job.median)


def extract(score: np.ndarray, d: str, tau: float):
    return find_detections(score, tau, detector=d, range0_m=GEO["range0_m"], dr_m=GEO["dr_m"], dx_m=GEO["dx_m"],
                           min_extent_m=S.min_extent_m, max_extent_m=S.max_extent_m)


def test_coverage_and_detections_equal_the_direct_computation(job, direct):
    from atr_node.detectors.windows import window_geometry

    ranges = job.range0_m + job.dr_m * np.arange(job.pixels.shape[1])
    geom = window_geometry(ranges, template=T, dr_m=job.dr_m, dx_m=job.dx_m, altitude_m=job.altitude_m)
    res = detect(job)
    assert res.key == 7 and res.shape == (CORE[1] - CORE[0], 600)
    for d in DETECTOR_NAMES:
        cov = res.covered(d)
        assert cov.dtype == np.bool_ and cov.shape == res.shape
        assert np.array_equal(cov, ~np.isnan(direct[d])), d
        assert [dataclasses.replace(x, joint=None) for x in res.detections[d]] == extract(direct[d], d, TAU[d]), d
        # joint responses (SPEC 6.1): every detector's maximum over the template window of the
        # anchor, brute force over the direct maps
        for x in res.detections[d]:
            j = x.col
            r0, r1 = max(0, x.row + geom.row0), min(direct[d].shape[0], x.row + geom.row0 + geom.length_px)
            c0, c1 = max(0, j - geom.echo_px), min(direct[d].shape[1], j + int(geom.shadow_px[j]))
            for other, v in x.joint:
                w = direct[other][r0:r1, c0:c1]
                want = float(np.nanmax(w)) if np.isfinite(w).any() else float("nan")
                assert v == want or (math.isnan(v) and math.isnan(want)), (d, other)
        assert res.detections[d], d  # the planted targets
    assert res.sweep is not None
    assert res.sweep["mf"] == {0.5: extract(direct["mf"], "mf", 0.5), 2.0: extract(direct["mf"], "mf", 2.0)}
    assert res.sweep["z"] == {1.0: extract(direct["z"], "z", 1.0)}
    assert res.sweep["lac"] == {} and res.sweep["smf"] == {}


def test_equal_coverages_share_one_array_and_cross_a_pickle_intact(job, direct):
    res = detect(job)
    nan = {d: np.isnan(direct[d]) for d in DETECTOR_NAMES}
    # the hole and the nadir gap make some coverages differ; MF and Z share their windows
    assert not np.array_equal(nan["mf"], nan["smf"])
    for a in DETECTOR_NAMES:
        for b in DETECTOR_NAMES:
            assert (res.covered_bits[a] is res.covered_bits[b]) == np.array_equal(nan[a], nan[b]), (a, b)
    back = pickle.loads(pickle.dumps(res))
    separate = {d: res.covered_bits[d].copy() for d in DETECTOR_NAMES}
    assert len(pickle.dumps(res.covered_bits)) < len(pickle.dumps(separate))
    for d in DETECTOR_NAMES:
        assert np.array_equal(back.covered(d), res.covered(d))
        assert back.detections[d] == res.detections[d]


def test_covered_is_a_new_writable_array_each_call(job):
    res = detect(job)
    a = res.covered("mf")
    a[:] = False
    assert res.covered("mf").any() and res.covered("z").any()


def test_same_job_same_result(job):
    a, b = detect(job), detect(job)
    for d in DETECTOR_NAMES:
        assert np.array_equal(a.covered_bits[d], b.covered_bits[d])
        assert a.detections[d] == b.detections[d]


def test_each_detection_carries_the_headroom_of_its_range(job):
    """With the recording's full scale, a detection's headroom is 10 log10(full scale / b(j)) at its
    anchor column (a direct float64 computation); without one (float data), inf."""
    fs = float(np.nanmax(job.pixels)) * 2.0
    res = detect(dataclasses.replace(job, full_scale=fs))
    plain = detect(job)
    b = np.asarray(job.background, dtype=np.float64)
    n = 0
    for d in DETECTOR_NAMES:
        assert [dataclasses.replace(x, headroom_db=math.inf) for x in res.detections[d]] == plain.detections[d]
        for x in res.detections[d]:
            assert x.headroom_db == pytest.approx(10.0 * math.log10(fs / b[x.col]), abs=1e-9)
            n += 1
        assert all(math.isinf(x.headroom_db) for x in plain.detections[d])
    assert n > 0


def test_relocated_detections_sit_at_the_matched_filters_window_peak(job, direct):
    """``detectors.relocate = ["lac"]`` (the default): each LAC detection is the one at its own
    peak, with the same score, extent and joint responses, moved to the first maximum of the
    direct MF map over its template window (brute force), where that maximum is positive."""
    from atr_node.detectors.windows import window_geometry

    ranges = job.range0_m + job.dr_m * np.arange(job.pixels.shape[1])
    geom = window_geometry(ranges, template=T, dr_m=job.dr_m, dx_m=job.dx_m, altitude_m=job.altitude_m)
    plain = detect(job)
    moved = detect(dataclasses.replace(job, detectors=dataclasses.replace(S, relocate=("lac",))))
    for d in ("mf", "smf", "z"):
        assert moved.detections[d] == plain.detections[d], d
    assert len(moved.detections["lac"]) == len(plain.detections["lac"]) > 0
    n_moved = 0
    mf = direct["mf"]
    for a, b in zip(plain.detections["lac"], moved.detections["lac"]):
        assert dataclasses.replace(b, row=a.row, col=a.col, range_m=a.range_m) == a
        j = a.col
        best, at = -math.inf, None
        for r in range(max(0, a.row + geom.row0), min(mf.shape[0], a.row + geom.row0 + geom.length_px)):
            for c in range(max(0, j - geom.echo_px), min(mf.shape[1], j + int(geom.shadow_px[j]))):
                if math.isfinite(mf[r, c]) and mf[r, c] > best:
                    best, at = float(mf[r, c]), (r, c)
        want = at if at is not None and best > 0 else (a.row, a.col)
        assert (b.row, b.col) == want
        assert b.range_m == pytest.approx(job.range0_m + b.col * job.dr_m, abs=1e-12)
        n_moved += (b.row, b.col) != (a.row, a.col)
    assert n_moved > 0  # the planted targets' LAC peaks lie off the echo/shadow boundary
    # without the matched filter there is nothing to place by: every detector at its own peak
    no_mf = tuple(d for d in DETECTOR_NAMES if d != "mf")
    alone = detect(dataclasses.replace(job, enabled=no_mf, taus={d: TAU[d] for d in no_mf}, sweep=None,
                                       detectors=dataclasses.replace(S, relocate=("lac",))))
    assert [dataclasses.replace(x, joint=None) for x in alone.detections["lac"]] == extract(direct["lac"], "lac", TAU["lac"])


def test_where_the_recording_clips_detections_stay_at_their_own_peak(job):
    """``detectors.relocate_headroom_db``: with the job's full scale within that many dB of the
    seabed everywhere (an 8-bit recording that clips), LAC's detections are those at its own
    peak; with a full scale far above it (a 16-bit recording's headroom) they move as on float
    data."""
    relocating = dataclasses.replace(S, relocate=("lac",))
    plain = detect(job).detections["lac"]
    floated = detect(dataclasses.replace(job, detectors=relocating)).detections["lac"]
    assert floated != plain
    b = np.asarray(job.background, dtype=np.float64)
    low, top = float(np.nanmin(b[b > 0])), float(np.nanmax(b))
    # headroom 10 log10(full_scale / b) is at most 9 dB in every column
    clipping = detect(dataclasses.replace(job, detectors=relocating, full_scale=low * 10 ** 0.9)).detections["lac"]
    assert [(x.row, x.col) for x in clipping] == [(x.row, x.col) for x in plain]
    deep = detect(dataclasses.replace(job, detectors=relocating, full_scale=top * 1e6)).detections["lac"]
    assert [(x.row, x.col) for x in deep] == [(x.row, x.col) for x in floated]
