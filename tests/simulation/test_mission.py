"""Synthetic missions: the .atrlog (ICD 4), its links, the truth (ICD 5) and their geometry."""

from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest

from atr_node.cli import main
from atr_node.config import Settings, SimulationSettings
from atr_node.geo.frame import MissionFrame
from atr_node.geo.georef import tile_geometry
from atr_node.io.atrlog import AtrLogReader
from atr_node.records.tile import NAV_KEYS, Tile, TileNav
from atr_node.simulation.mission import altitude_at, generate_mission
from atr_node.simulation.world import plan_world
from atr_node.simulation.seabed import gain_curve
from hw.can_nav import CanNavDecoder
from hw.nmea_decoder import NmeaDecoder


def small(**kw) -> Settings:
    base = dict(mission_legs=2, mission_leg_length_m=80.0, mission_swath_m=30.0, mission_targets=10,
                mission_tile_pings=128, mission_clutter_per_km2=800.0)
    base.update(kw)
    return Settings().replace(simulation=dataclasses.replace(SimulationSettings(), **base))


@pytest.fixture(scope="module")
def mission(tmp_path_factory):
    out = tmp_path_factory.mktemp("mission")
    return generate_mission(small(mission_nav_error_m=0.0), out, seed=5)


def read_all(path):
    reader = AtrLogReader(path, strict=True)
    return list(reader), reader


def test_log_is_ordered_and_complete(mission):
    recs, reader = read_all(mission.atrlog)
    assert reader.records == mission.records == len(recs) and not reader.truncated
    t = np.array([r.t for r in recs])
    assert np.all(np.diff(t) >= 0)
    links = {r.link for r in recs}
    assert links == {"sonar", "nmea", "can"}
    tiles = [Tile.from_map(r.msg) for r in recs if r.link == "sonar"]
    assert len(tiles) == mission.tiles == 2 * 2 * 7  # legs x sides x ceil(800 / 128)
    for side in ("port", "stbd"):
        seqs = [tl.seq for tl in tiles if tl.side == side]
        assert seqs == list(range(len(seqs)))
    arrival = {id(tl): r.t for tl, r in zip(tiles, [r for r in recs if r.link == "sonar"])}
    for tl in tiles:
        assert tl.nav is not None and len(tl.nav) == tl.rows and not tl.slant
        assert arrival[id(tl)] > tl.ping_time[-1]  # after its last ping
        assert np.isnan(tl.pixels[:, :20]).all()    # nadir gap
        assert np.nanmin(tl.pixels) >= 0 and tl.sensor is not None
        np.testing.assert_allclose(tl.nav.altitude_m, altitude_at(small(), tl.ping_time))
    assert {tl.leg for tl in tiles} == {0, 1}


def test_nmea_and_can_decode_cleanly(mission):
    recs, _ = read_all(mission.atrlog)
    nd, cd = NmeaDecoder(), CanNavDecoder()
    fixes = []
    for r in recs:
        if r.link == "nmea":
            fixes += nd.feed(r.msg, r.t)
        elif r.link == "can":
            cd.feed(r.msg["id"], r.msg["data"], r.msg["ext"], r.t)
    assert nd.rejected == 0 and nd.counts["accepted"] > 1000
    assert set(nd.by_type) == {"GGA", "HDT", "DPT", "ZDA"}
    assert sum(cd.counts[k] for k in cd.counts if k != "accepted") == 0
    alt = np.array([(f.t, f.altitude_m) for f in fixes if f.altitude_m is not None])
    assert alt.size and np.all(np.abs(alt[:, 1] - altitude_at(small(), alt[:, 0])) <= 0.011)  # DPT: 2 decimals
    assert alt[:, 1].max() - alt[:, 1].min() > 0.05  # the altitude swell is there
    frame = MissionFrame("ltp", 44.08, 9.85)
    pos = np.array([(f.lat_deg, f.lon_deg) for f in fixes if f.lat_deg is not None])
    e, n = frame.to_frame(pos[:, 0], pos[:, 1])
    assert e.min() > -0.5 and e.max() < 30.5 and n.min() > -0.5 and n.max() < 80.5


def test_truth_csv_and_geometry(mission):
    """Each truth target, georeferenced into the tiles with the foundation's georef, sits on a
    bright echo followed by a dark shadow in every leg that saw it (nav error 0 here)."""
    with open(mission.truth) as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0])[:3] == ["lat_deg", "lon_deg", "shape"] and len(rows) == mission.targets == 10
    assert {r["shape"] for r in rows} <= {"cylinder", "cone", "wedge"}
    recs, _ = read_all(mission.atrlog)
    tiles = [Tile.from_map(r.msg) for r in recs if r.link == "sonar"]
    # one strip per (leg, side): the tiles of a leg in order, nav included
    strips = {}
    for key in {(t.leg, t.side) for t in tiles}:
        part = [t for t in tiles if (t.leg, t.side) == key]
        nav = TileNav(*(np.concatenate([getattr(t.nav, k) for t in part]) for k in NAV_KEYS))
        strips[key] = part[0].replace(pixels=np.vstack([t.pixels for t in part]),
                                      ping_time=np.concatenate([t.ping_time for t in part]), nav=nav)
    frame = MissionFrame("ltp", 44.08, 9.85)
    g = gain_curve(np.arange(301) * 0.1, altitude_m=14.0, max_range_m=30.0)
    checked = 0
    for tr in rows:
        te, tn = frame.to_frame(float(tr["lat_deg"]), float(tr["lon_deg"]))
        assert float(te) == pytest.approx(float(tr["east_m"]), abs=1e-3)
        for leg in (0, 1):
            side, rng_txt = tr[f"leg{leg}_side"], tr[f"leg{leg}_range_m"]
            if not side or float(tr["burial_m"]) > 0 or not 14.0 <= float(rng_txt) <= 29.0:
                continue
            tl = strips[(leg, side)]
            geo = tile_geometry(tl, frame)
            along = (te - geo.east_m) * -geo.un + (tn - geo.north_m) * geo.ue  # signed along-track offset
            i = int(np.argmin(np.abs(along)))
            assert abs(along[i]) <= 0.06 and 15 <= i < tl.rows - 15
            rng_m = float((te - geo.east_m[i]) * geo.ue[i] + (tn - geo.north_m[i]) * geo.un[i])
            assert rng_m == pytest.approx(float(rng_txt), abs=0.05)
            j = int(round(rng_m / tl.dr_m))
            win = tl.pixels[i - 15:i + 15, j - 15:j + 45] / g[None, j - 15:j + 45]
            k = np.ones(5) / 5
            sm = np.apply_along_axis(lambda v: np.convolve(v, k, "valid"), 1, win)
            sm = np.apply_along_axis(lambda v: np.convolve(v, k, "valid"), 0, sm)
            assert np.nanmax(sm) > 2.0 and np.nanmin(sm) < 0.35
            checked += 1
    assert checked >= 3


def test_world_plan_is_seeded_and_hard_is_harder():
    s = small()
    a = plan_world(s, np.random.default_rng(1))
    b = plan_world(s, np.random.default_rng(1))
    assert [(o.east_m, o.north_m) for o in a[1]] == [(o.east_m, o.north_m) for o in b[1]]
    legs, targets, clutter, ripples = a
    assert len(legs) == 2 and legs[0].heading_deg == 0.0 and legs[1].heading_deg == 180.0
    assert legs[1].start_east_m - legs[0].start_east_m == 30.0  # spacing = swath: the strip is seen twice
    assert legs[0].nav_offset_east_m != legs[1].nav_offset_east_m
    hard = plan_world(s, np.random.default_rng(1), hard=True)
    assert len(hard[2]) > 2 * len(clutter) and len(hard[3]) > 0 and ripples == []
    for o in targets:
        for c in clutter:
            assert (o.east_m - c.east_m) ** 2 + (o.north_m - c.north_m) ** 2 >= 1.5 ** 2


def test_simulate_command(tmp_path, capsys):
    out = tmp_path / "m"
    code = main(["simulate", "--out", str(out), "--seed", "2", "--legs", "2", "--leg-length", "30", "--swath", "20",
                 "--targets", "2", "--shapes", "sphere", "--no-links", "--hard", "--seabed", "sand"])
    assert code == 0
    assert "2 legs" in capsys.readouterr().out
    recs, _ = read_all(out / "mission.atrlog")
    assert {r.link for r in recs} == {"sonar"}
    with open(out / "truth.csv") as fh:
        assert [r["shape"] for r in csv.DictReader(fh)] == ["sphere", "sphere"]
    assert main(["simulate", "--out", str(out), "--config", str(tmp_path / "missing.toml")]) == 1


def test_mesh_file_targets(tmp_path):
    """A target shape from an OBJ file (a 1 m x 0.6 m x 0.6 m block) goes into the mission and
    its truth under the file's stem."""
    obj = tmp_path / "crate.obj"
    v = [(x, y, z) for z in (0.0, 0.6) for y in (-0.3, 0.3) for x in (-0.5, 0.5)]
    f = [(1, 3, 4, 2), (5, 6, 8, 7), (1, 2, 6, 5), (3, 7, 8, 4), (1, 5, 7, 3), (2, 4, 8, 6)]
    obj.write_text("\n".join([f"v {x} {y} {z}" for x, y, z in v] + [f"f {a} {b} {c} {d}" for a, b, c, d in f]))
    files = generate_mission(small(mission_shapes=(str(obj),), mission_targets=2, mission_clutter_per_km2=0.0),
                             tmp_path / "m", seed=1, links=False)
    with open(files.truth) as fh:
        rows = list(csv.DictReader(fh))
    assert [r["shape"] for r in rows] == ["crate", "crate"]
    assert all(float(r["height_m"]) == pytest.approx(0.6 - float(r["burial_m"]), abs=1e-6) for r in rows)
    with pytest.raises(Exception, match="simulation.mission_shapes"):
        small(mission_shapes=("crate.ply",))


def test_same_seed_same_bytes(tmp_path):
    s = small(mission_leg_length_m=30.0, mission_targets=2)
    a = generate_mission(s, tmp_path / "a", seed=9)
    b = generate_mission(s, tmp_path / "b", seed=9)
    c = generate_mission(s, tmp_path / "c", seed=10)
    assert a.atrlog.read_bytes() == b.atrlog.read_bytes() and a.truth.read_bytes() == b.truth.read_bytes()
    assert a.atrlog.read_bytes() != c.atrlog.read_bytes()
