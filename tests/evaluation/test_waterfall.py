"""Contacts mapped back to ping and slant range: the inverse of the forward georeferencing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from atr_node.evaluation.waterfall import SidePings, locate_contacts, zone_of
from atr_node.geo import MissionFrame
from atr_node.geo.georef import pixel_latlon
from atr_node.records.tile import Tile, TileNav


def _slant_tile(side: str, rows: int = 200, cols: int = 400, heading_deg: float = 33.0) -> Tile:
    """A slant-range tile on a straight, slightly turning track at 60 N (scale factor != 1)."""
    t = 1.0e9 + np.arange(rows) * 0.1
    s = np.arange(rows) * 0.2  # 0.2 m per ping
    hdg = heading_deg + np.linspace(0.0, 4.0, rows)
    lat = 60.0 + s * np.cos(np.radians(hdg)) / 111_320.0
    lon = 5.0 + s * np.sin(np.radians(hdg)) / (111_320.0 * math.cos(math.radians(60.0)))
    alt = 5.0 + 0.5 * np.sin(np.arange(rows) / 30.0)
    nav = TileNav(lat, lon, hdg, alt)
    px = np.ones((rows, cols), np.float32)
    return Tile(mission="m", leg=0, side=side, seq=0, pixels=px, kind="amplitude", range0_m=0.05, dr_m=0.1,
                dx_m=0.2, slant=True, ping_time=t, nav=nav)


@pytest.mark.parametrize("side", ["port", "stbd"])
def test_contacts_land_back_on_their_ping_and_range(side: str) -> None:
    tiles = [_slant_tile("port"), _slant_tile("stbd")]
    tile = tiles[0 if side == "port" else 1]
    ground = tile.ground_range()
    frame = MissionFrame("utm", 60.0, 5.0)
    rng = np.random.default_rng(3)
    rows = rng.integers(5, ground.rows - 5, 20)
    cols = rng.integers(10, ground.cols - 1, 20)
    lat, lon = pixel_latlon(ground, frame, rows, cols)  # forward georeferencing, SPEC section 0
    contacts = [{"id": k, "lat_deg": float(a), "lon_deg": float(b)} for k, (a, b) in enumerate(zip(lat, lon))]
    places = locate_contacts([SidePings.from_tiles(tiles, s) for s in ("port", "stbd")], contacts, frame,
                             band_m=1.0)
    assert [p.id for p in places] == list(range(20))
    for p, i, j in zip(places, rows, cols):
        assert p.side == side
        assert p.ping == i
        g = ground.range0_m + j * ground.dr_m
        assert p.ground_range_m == pytest.approx(g, abs=2e-3)
        h = tile.nav.altitude_m[i]
        assert p.slant_range_m == pytest.approx(math.hypot(g, h), abs=2e-3)
        assert p.along_offset_m < 0.11  # half the ping spacing, and a little


def test_contact_off_the_track_is_not_placed() -> None:
    tiles = [_slant_tile("stbd")]
    frame = MissionFrame("utm", 60.0, 5.0)
    lat, lon = frame.to_latlon(*(v - 500.0 for v in frame.to_frame(60.0, 5.0)))
    assert locate_contacts([SidePings.from_tiles(tiles, "stbd")], [{"id": 1, "lat_deg": float(lat),
                                                                    "lon_deg": float(lon)}], frame) == []


def test_zones() -> None:
    assert zone_of(3.9, 4.0, 1.5) == "water column"
    assert zone_of(4.0, 4.0, 1.5) == "first return"
    assert zone_of(5.49, 4.0, 1.5) == "first return"
    assert zone_of(5.5, 4.0, 1.5) == "seabed"
    assert zone_of(10.0, float("nan"), 1.5) == "water column"  # no altitude: nothing can be said to be seabed


def test_waterfall_rows_are_the_pings_of_every_tile_of_the_side() -> None:
    """Rows of the drawn waterfall stay those of :class:`SidePings` (a tile on another spacing,
    or recorded in ground range, is placed, never skipped)."""
    from atr_node.evaluation.waterfall import slant_waterfall

    a = _slant_tile("stbd", rows=10, cols=50)
    b = a.replace(pixels=np.full((10, 25), 2.0, np.float32), dr_m=0.2, slant=False)
    img, r0, dr = slant_waterfall([a, b], "stbd")
    assert img.shape[0] == len(SidePings.from_tiles([a, b], "stbd")) == 20
    assert r0 == pytest.approx(0.05) and dr == pytest.approx(0.1)
    assert np.all(img[:10, :50] == 1.0)
    # b's samples at 0.05 + 0.2 k land on every second column of the 0.1 m axis
    assert np.all(img[10:, 0:50:2] == 2.0) and np.all(np.isnan(img[10:, 1:49:2]))
