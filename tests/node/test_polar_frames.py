"""Polar and outlier-robust mission frames (issue 21, item 5).

Before: a fix north of 84 deg or south of -84 deg ended the node (``origin latitude 85.0
outside [-84, 84]``, exit 1), with ``frame = "ltp"`` too, and the first fix alone set the
frame origin, however wild. Now the node takes the local tangent plane where UTM is not
defined, and the origin is the robust median of the first fixes.
"""

from __future__ import annotations

import json
import logging
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pyproj import Geod

from atr_node.calibration.model import PerformanceModel
from atr_node.config import load_settings, settings_from_dict
from atr_node.geo import MissionFrame, OriginEstimator, robust_origin
from atr_node.io.atrlog import AtrLogWriter, read_atrlog
from atr_node.node.pipeline import Pipeline
from atr_node.simulation.mission import generate_mission

GEOD = Geod(ellps="WGS84")  # the independent reference for distances on the ellipsoid

POLAR = """
[simulation]
mission_legs = 2
mission_leg_length_m = 70.0
mission_swath_m = 30.0
mission_targets = 4
mission_tile_pings = 128
mission_clutter_per_km2 = 500.0
mission_origin_lat_deg = {lat}
mission_origin_lon_deg = {lon}

[mission]
frame = "{frame}"
"""


def _dist_m(lat1, lon1, lat2, lon2) -> np.ndarray:
    _, _, d = GEOD.inv(np.broadcast_to(lon1, np.shape(lon2)), np.broadcast_to(lat1, np.shape(lat2)), lon2, lat2)
    return np.asarray(d)


def _replay(cfg: Path, log: Path, out: Path) -> tuple[subprocess.CompletedProcess, list[dict], dict]:
    contacts, summary = out / "contacts.jsonl", out / "summary.json"
    r = subprocess.run([sys.executable, "-m", "atr_node", "replay", str(log), "--config", str(cfg), "--publish", "none",
                        "--online-calibration", "off", "--speed", "max", "--contacts-out", str(contacts),
                        "--summary", str(summary)], capture_output=True, text=True, timeout=300)
    if r.returncode != 0:
        return r, [], {}
    return r, [json.loads(line) for line in contacts.read_text().splitlines()], json.loads(summary.read_text())


# -- the robust origin, on its own ---------------------------------------------------------------

def test_robust_origin_of_one_fix_is_the_fix():
    assert robust_origin([85.123456789], [-170.5]) == (85.123456789, -170.5)


def test_robust_origin_ignores_one_10_km_outlier_among_five():
    lat0, lon0 = 58.1, 11.2
    # four fixes 0.3 m apart along a track heading north-east, then one 10 km off
    lons, lats, _ = GEOD.fwd([lon0] * 4, [lat0] * 4, [45.0] * 4, [0.0, 0.3, 0.6, 0.9])
    olon, olat, _ = GEOD.fwd(lon0, lat0, 200.0, 10_000.0)
    lat, lon = robust_origin([olat, *lats], [olon, *lons])
    assert _dist_m(lat0, lon0, lat, lon) < 1.0  # within the good fixes' spread
    naive = (np.mean([olat, *lats]), np.mean([olon, *lons]))
    assert _dist_m(lat0, lon0, *naive) > 1000.0  # a mean would not have been robust


@pytest.mark.parametrize("lat0, lon0", [(89.99999, 0.0), (-89.99999, 123.0), (10.0, 179.99999), (-30.0, -180.0)])
def test_robust_origin_near_a_pole_and_across_the_antimeridian(lat0, lon0):
    """Five fixes within 2 m of a point where a median of longitudes would be meaningless."""
    lons, lats, _ = GEOD.fwd([lon0] * 5, [lat0] * 5, [0.0, 72.0, 144.0, 216.0, 288.0], [2.0] * 5)
    lat, lon = robust_origin(lats, lons)
    assert -180.0 <= lon < 180.0
    assert _dist_m(lat0, lon0, lat, lon) < 2.0


def test_origin_estimator_skips_implausible_fixes_and_takes_a_tiles_pings_spread_out():
    est = OriginEstimator(5)
    for lat, lon in ((math.nan, 1.0), (0.0, 0.0), (91.0, 3.0), (45.0, 7.0)):
        est.add(lat, lon)
    assert est.fixes == [(45.0, 7.0)] and est.implausible == 3 and not est.ready
    est.add_track(np.linspace(45.0, 45.001, 128), np.full(128, 7.0))
    assert est.ready and len(est.fixes) == 5
    assert est.fixes[1][0] == 45.0 and est.fixes[-1][0] > 45.0005  # spread over the tile, not its first pings


# -- frames at any latitude ------------------------------------------------------------------------

@pytest.mark.parametrize("lat", [85.0, -87.0, 89.9999, 90.0, -90.0])
def test_ltp_frame_round_trips_at_polar_latitudes(lat):
    f = MissionFrame("ltp", lat, 10.0)
    lons, lats, _ = GEOD.fwd([10.0] * 4, [lat] * 4, [0.0, 90.0, 180.0, 270.0], [100.0] * 4)
    e, n = f.to_frame(lats, lons)
    assert np.allclose(np.hypot(e, n), 100.0, atol=1e-6)  # aeqd: distances from the origin are exact
    back_lat, back_lon = f.to_latlon(e, n)
    assert np.all(_dist_m(lats, lons, back_lat, back_lon) < 1e-6)
    conv, scale = f.grid_factors(lats, lons)
    assert np.all(np.isfinite(conv)) and np.all(np.abs(scale - 1.0) < 1e-6)


def test_utm_asked_beyond_84_deg_gives_the_local_tangent_plane_with_one_info_line(caplog):
    settings = settings_from_dict({"mission": {"frame": "utm"}})
    with caplog.at_level(logging.INFO, logger="atr_node.geo.frame"):
        f = MissionFrame.from_settings(settings.mission, first_fix=(85.0, 10.0))
        g = MissionFrame.from_settings(settings.mission, first_fix=(60.0, 10.0))
    assert f.kind == "ltp" and (f.origin_lat_deg, f.origin_lon_deg) == (85.0, 10.0)
    assert g.kind == "utm"
    lines = [r for r in caplog.records if r.name == "atr_node.geo.frame"]
    assert len(lines) == 1 and lines[0].levelno == logging.INFO and "tangent plane" in lines[0].getMessage()


# -- polar missions through the node ---------------------------------------------------------------

@pytest.mark.parametrize("lat, frame", [(85.0, "utm"), (-87.0, "utm"), (-87.0, "ltp")])
def test_polar_mission_replays_with_contacts_at_the_targets(tmp_path, lat, frame):
    cfg = tmp_path / "polar.toml"
    cfg.write_text(POLAR.format(lat=lat, lon=10.0, frame=frame))
    files = generate_mission(load_settings(cfg), tmp_path / "m", seed=3)
    r, contacts, summary = _replay(cfg, files.atrlog, tmp_path)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    assert summary["frame"]["kind"] == "ltp"  # UTM is not defined there
    assert contacts, "no contact at all"
    clat = np.array([c["lat_deg"] for c in contacts])
    clon = np.array([c["lon_deg"] for c in contacts])
    assert np.all(np.isfinite(clat)) and np.all(np.isfinite(clon))
    assert np.all(_dist_m(lat, 10.0, clat, clon) < 300.0)  # on the mission's area, not elsewhere on the globe
    truth = np.genfromtxt(files.truth, delimiter=",", names=True, dtype=None, encoding="utf-8")
    # each target's nearest contact: most targets found, where they are
    near = np.array([_dist_m(t["lat_deg"], t["lon_deg"], clat, clon).min() for t in truth])
    assert np.sum(near < 3.0) >= len(truth) // 2, near


# -- one outlier first fix ---------------------------------------------------------------------------

def test_a_10_km_outlier_first_fix_does_not_set_the_frame_origin(tmp_path):
    """The mission's first GGA is moved 10 km away: the frame origin stays within metres of
    the clean run's (before: the outlier itself was the origin)."""
    from hw.nmea import encode_gga

    cfg = tmp_path / "ltp.toml"
    cfg.write_text(POLAR.format(lat=58.0, lon=11.0, frame="ltp"))
    files = generate_mission(load_settings(cfg), tmp_path / "m", seed=5)
    records = list(read_atrlog(files.atrlog))
    i = next(k for k, rec in enumerate(records) if rec.link == "nmea" and b"GGA," in rec.msg)
    first = records[i]
    fields = first.msg.decode().split(",")
    lat = (int(fields[2][:2]) + float(fields[2][2:]) / 60.0) * (1 if fields[3] == "N" else -1)
    lon = (int(fields[4][:3]) + float(fields[4][3:]) / 60.0) * (1 if fields[5] == "E" else -1)
    olon, olat, _ = GEOD.fwd(lon, lat, 90.0, 10_000.0)
    outlier = tmp_path / "outlier.atrlog"
    w = AtrLogWriter(outlier)
    try:
        for k, rec in enumerate(records):
            w.write(rec.t, rec.link, encode_gga(rec.t, olat, olon) if k == i else rec.msg)
    finally:
        w.close()
    origins = []
    for log in (files.atrlog, outlier):  # the node's pipeline in this process: its frame
        pipe = Pipeline(load_settings(cfg), model=PerformanceModel.shipped(), workers=0)
        try:
            pipe.replay(read_atrlog(log))
            origins.append((pipe.frame.origin_lat_deg, pipe.frame.origin_lon_deg))
        finally:
            pipe.close()
    assert _dist_m(*origins[0], *origins[1]) < 5.0
    assert _dist_m(lat, lon, *origins[1]) < 5.0
    # through the command: the same frame in the summary, contacts where the clean run put them
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    ra, ca, sa = _replay(cfg, files.atrlog, tmp_path / "a")
    rb, cb, sb = _replay(cfg, outlier, tmp_path / "b")
    assert ra.returncode == 0 and rb.returncode == 0, ra.stderr + rb.stderr
    fb = sb["frame"]
    assert (fb["origin_lat_deg"], fb["origin_lon_deg"]) == origins[1] and fb["kind"] == "ltp"
    assert len(ca) == len(cb) > 0
    for a, b in zip(ca, cb):
        assert _dist_m(a["lat_deg"], a["lon_deg"], b["lat_deg"], b["lon_deg"]) < 0.5
