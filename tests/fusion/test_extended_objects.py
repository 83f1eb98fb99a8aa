"""One object, one contact (issue 18 item 5): a wreck is one contact with its extent, a small
object next to it stays separate, a bright band at constant range is background.

The scene is built with numpy (not with ``atr_node.simulation``) and goes through the real
``Pipeline``; the extent then through the wire validation, a snapshot and the JSON export.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from atr_node.calibration.model import PerformanceModel
from atr_node.config import Settings
from atr_node.detectors.objects import find_objects
from atr_node.fusion import snapshot
from atr_node.fusion.contacts import Contact, ContactTracker
from atr_node.fusion.observation import axis_heading_deg
from atr_node.io.atrlog import LogRecord
from atr_node.node import wire
from atr_node.node.pipeline import Pipeline
from atr_node.operators.export import to_csv, to_geojson
from atr_node.records.tile import Tile, TileNav

DX = DR = 0.1
ROWS, COLS, RANGE0 = 520, 520, 10.0
LAT0, LON0 = 43.0, 7.0
WRECK = dict(row=220, range_m=34.0, length_m=20.0, width_m=4.0, axis_deg=30.0)
SMALL = dict(row=220, range_m=18.0)  # 7-8 m nearer than the hull's near edge (about 25.5 m)
BAND_M = (54.0, 55.5)  # bright band: constant range, drifting 1 m over the tile as with the altitude
M_PER_DEG = 111_320.0


def scene(seed: int = 5) -> np.ndarray:
    """Ground-range intensities, starboard, heading north: rows north, columns east."""
    rng = np.random.default_rng(seed)
    img = rng.exponential(1.0, (ROWS, COLS)).astype(np.float32)
    rr, cc = np.mgrid[0:ROWS, 0:COLS]
    y, r = rr * DX, RANGE0 + cc * DR
    # the hull: a 20 m x 4 m rectangle, its long axis 30 deg from the track towards range
    a = math.radians(WRECK["axis_deg"])
    dy, dr = y - WRECK["row"] * DX, r - WRECK["range_m"]
    along, across = dy * math.cos(a) + dr * math.sin(a), -dy * math.sin(a) + dr * math.cos(a)
    hull = (np.abs(along) <= WRECK["length_m"] / 2) & (np.abs(across) <= WRECK["width_m"] / 2)
    # its shadow: 5 m of range behind the hull's far edge, row by row
    far = np.where(hull, cc, -1).max(axis=1)
    shadow = (far[:, None] >= 0) & (cc > far[:, None]) & (cc <= far[:, None] + 50)
    img[shadow] *= 0.05
    img[hull] *= 6.0
    # the small proud object: 1.5 m x 0.8 m echo, 2 m shadow
    sy, sr = SMALL["row"] * DX, SMALL["range_m"]
    echo = (np.abs(y - sy) <= 0.75) & (np.abs(r - sr) <= 0.4)
    img[(np.abs(y - sy) <= 0.75) & (r > sr + 0.4) & (r <= sr + 2.4)] *= 0.05
    img[echo] *= 8.0
    lo = BAND_M[0] + 1.0 * rr / ROWS
    img[(r >= lo) & (r <= lo + BAND_M[1] - BAND_M[0])] *= 3.0
    return img


def tile_map(img: np.ndarray) -> dict:
    """The ICD section 1 map of the scene (one starboard tile, heading north at 1 m/s)."""
    lat = LAT0 + np.arange(ROWS) * DX / M_PER_DEG
    nav = TileNav(lat, np.full(ROWS, LON0), np.zeros(ROWS), np.full(ROWS, 14.0))
    return Tile("wreck", 0, "stbd", 0, img.astype(np.float32), "intensity", RANGE0, DR, DX, False,
                1.7e9 + 0.1 * np.arange(ROWS), nav=nav).to_map()


def offset_m(c: dict, row: float, range_m: float) -> float:
    """Horizontal distance of a contact from a scene point (row, starboard range)."""
    lat = LAT0 + row * DX / M_PER_DEG
    lon = LON0 + range_m / (M_PER_DEG * math.cos(math.radians(lat)))
    dn = (c["lat_deg"] - lat) * M_PER_DEG
    de = (c["lon_deg"] - lon) * M_PER_DEG * math.cos(math.radians(lat))
    return math.hypot(de, dn)


@pytest.fixture(scope="module")
def run():
    settings = Settings()
    msgs: list[dict] = []
    pipe = Pipeline(settings, model=PerformanceModel.shipped(), emit=msgs.append, workers=0)
    try:
        pipe.feed(LogRecord(t=1.7e9 + 60.0, link="sonar", msg=tile_map(scene())))
        pipe.finish()
        yield pipe, msgs
    finally:
        pipe.close()


def live(pipe) -> list[dict]:
    return [c for c in pipe.contacts if c["state"] != "withdrawn"]


def test_the_wreck_is_one_contact_with_its_extent(run):
    pipe, _ = run
    near = [c for c in live(pipe) if offset_m(c, WRECK["row"], WRECK["range_m"]) < 12.0]
    assert len(near) == 1, [(round(offset_m(c, WRECK["row"], WRECK["range_m"]), 1), c.get("length_m")) for c in near]
    c = near[0]
    assert offset_m(c, WRECK["row"], WRECK["range_m"]) < 3.0  # at the hull's centre, not on an edge
    assert abs(c["length_m"] - 20.0) <= 0.2 * 20.0, c
    assert 2.0 <= c["width_m"] <= 8.0, c
    # heading north, starboard = east: the long axis 30 deg from the track towards range is 030
    d = abs(c["heading_deg"] - 30.0)
    assert min(d, 180.0 - d) <= 15.0, c


def test_the_small_object_beside_it_stays_a_contact_of_its_own(run):
    pipe, _ = run
    near = [c for c in live(pipe) if offset_m(c, SMALL["row"], SMALL["range_m"] + 0.4) < 3.0]
    assert len(near) == 1, near
    assert "length_m" not in near[0]  # a mine-sized object has no extent
    assert offset_m(near[0], WRECK["row"], WRECK["range_m"]) > 10.0


def test_no_contact_on_the_bright_band(run):
    pipe, _ = run
    on_band = [c for c in live(pipe) if c["lon_deg"] > LON0 + (BAND_M[0] - 3.0) / (M_PER_DEG * math.cos(math.radians(LAT0)))]
    assert on_band == []


def test_the_band_is_background_in_the_object_map():
    img = scene()
    b = img.mean(axis=0)
    om = find_objects(img, b, dr_m=DR, dx_m=DX, template_length_m=2.0, echo_width_m=0.6, highlight=2.0,
                      shadow=0.3, max_length_m=60.0)
    fy, fx = om.block
    band_cols = np.arange(int((BAND_M[0] - RANGE0) / DR), int((BAND_M[1] + 1.0 - RANGE0) / DR))
    rows = np.arange(20, ROWS - 20, 25)
    assert (om.owner_at(np.repeat(rows, band_cols.size), np.tile(band_cols, rows.size)) <= 0).all()
    extended = [o for o in om.objects if not o.background]
    assert len(extended) == 1 and abs(extended[0].length_m - 20.0) < 4.0


def test_the_extent_goes_over_the_wire_into_a_snapshot_and_the_exports(run, tmp_path):
    pipe, msgs = run
    wreck = [m for m in msgs if "length_m" in m]
    assert wreck and all(wire.validate_contact(m) == [] for m in msgs)
    m = wreck[-1]
    assert wire.decode(wire.encode(wire.TOPIC_CONTACT, m)) == ("contact", m)
    # a snapshot keeps the detections' extents: a tracker rebuilt from it publishes nothing new
    path = snapshot.save(tmp_path / "g.npz", pipe.grid, pipe.tracker)
    grid, state = snapshot.load(path)
    assert [r.length_m for r in grid.detections] == [r.length_m for r in pipe.grid.detections]
    tracker = ContactTracker(pipe.settings.fusion, pipe.frame, gate_m=pipe.gate_m)
    tracker.restore(state)
    assert {c.id: c.to_message() for c in tracker.live.values()} == {
        c.id: c.to_message() for c in pipe.tracker.live.values()}
    assert tracker.update(grid, 1.8e9) == []
    # exports
    feat = [f for f in to_geojson([m])["features"]]
    assert json.loads(json.dumps(feat))[0]["properties"]["length_m"] == m["length_m"]
    rows = to_csv([m]).splitlines()
    header = rows[0].split(",")
    assert rows[1].split(",")[header.index("heading_deg")] == repr(m["heading_deg"])


def test_wire_rejects_a_partial_or_impossible_extent():
    base = dict(id=1, state="new", t=1.7e9, lat_deg=43.0, lon_deg=7.0, east_m=0.0, north_m=0.0, sigma_m=1.0,
                bel=0.9, pl=0.95, m_theta=0.05, looks=1, detections=2, detectors=["mf"], legs=[0])
    ok = wire.contact_message(**base, length_m=20.0, width_m=4.0, heading_deg=30.0)
    assert wire.validate_contact(ok) == []
    assert "length_m" not in wire.contact_message(**base)
    part = dict(ok)
    del part["width_m"]
    assert any("extent needs all" in p for p in wire.validate_contact(part))
    for bad in ({"heading_deg": 180.0}, {"width_m": 25.0}, {"length_m": math.nan}):
        assert wire.validate_contact({**ok, **bad}), bad
    # and a Contact keeps it through its message
    c = Contact.from_message(ok)
    assert (c.length_m, c.width_m, c.heading_deg) == (20.0, 4.0, 30.0) and c.to_message() == ok


@pytest.mark.parametrize("deg, want", [(-30.0, 150.0), (180.0, 0.0), (-1e-17, 0.0), (359.0, 179.0)])
def test_axis_heading_is_in_0_180(deg, want):
    assert axis_heading_deg(deg) == pytest.approx(want)
    assert 0.0 <= axis_heading_deg(deg) < 180.0
