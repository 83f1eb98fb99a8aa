"""Geometry (SPEC section 0): mission frames, pixel georeferencing, nav interpolation."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import Geod

from atr_node.errors import GeometryError
from atr_node.geo import MissionFrame, across_track_unit, tile_geometry, utm_zone
from atr_node.records import NavFix, NavTrack, Tile, TileNav, nav_jumps, wrap180

GEOD = Geod(ellps="WGS84")
LAT0, LON0 = 44.08, 9.85  # La Spezia


def ground_tile(side, heading_deg, rows=5, cols=101, lat=LAT0, lon=LON0, r0=10.0, dr=0.5) -> Tile:
    """A tile whose pings all sit at one point (so positions are easy to compute by hand)."""
    h = np.broadcast_to(np.asarray(heading_deg, dtype=float), (rows,)).copy()
    nav = TileNav(np.full(rows, lat), np.full(rows, lon), h, np.full(rows, 14.0))
    return Tile("m", 1, side, 0, np.ones((rows, cols), np.float32), "intensity", r0, dr, 0.1, False,
                np.arange(rows, dtype=float), nav=nav)


# -- hand-computed positions in a local tangent plane ------------------------------------

HAND = [
    # heading, side, (east, north) direction of increasing range
    (0.0, "stbd", (1.0, 0.0)),     # north-bound: starboard is east
    (0.0, "port", (-1.0, 0.0)),
    (90.0, "stbd", (0.0, -1.0)),   # east-bound: starboard is south
    (90.0, "port", (0.0, 1.0)),
    (180.0, "stbd", (-1.0, 0.0)),  # south-bound: starboard is west
    (180.0, "port", (1.0, 0.0)),
    (270.0, "stbd", (0.0, 1.0)),   # west-bound: starboard is north
    (270.0, "port", (0.0, -1.0)),
]


@pytest.mark.parametrize("heading,side,direction", HAND)
def test_hand_computed_positions_ltp(heading, side, direction):
    frame = MissionFrame("ltp", LAT0, LON0)
    g = tile_geometry(ground_tile(side, heading), frame)
    e, n = g.world(np.array([0, 2]), np.array([0, 100]))
    # at the origin of an azimuthal equidistant frame, scale is 1 and convergence 0
    np.testing.assert_allclose(e[0], direction[0] * 10.0, atol=1e-6)
    np.testing.assert_allclose(n[0], direction[1] * 10.0, atol=1e-6)
    np.testing.assert_allclose(e[1], direction[0] * 60.0, atol=1e-6)
    np.testing.assert_allclose(n[1], direction[1] * 60.0, atol=1e-6)


def test_heading_crossing_north_both_sides():
    frame = MissionFrame("ltp", LAT0, LON0)
    for h in (359.0, 1.0, -1.0, 361.0):
        for side, sign in (("stbd", 1.0), ("port", -1.0)):
            g = tile_geometry(ground_tile(side, h), frame)
            e, n = g.world(0, 100)
            a = np.radians(h)
            np.testing.assert_allclose(e, sign * 60.0 * np.cos(a), atol=1e-6)
            np.testing.assert_allclose(n, -sign * 60.0 * np.sin(a), atol=1e-6)


@pytest.mark.parametrize("kind", ["utm", "ltp"])
@pytest.mark.parametrize("heading", [0.0, 37.0, 90.0, 180.0, 271.5, 359.9])
@pytest.mark.parametrize("side", ["port", "stbd"])
def test_georef_matches_geodesic(kind, heading, side):
    """Away from the origin (convergence and scale not trivial) against pyproj's geodesic."""
    lat, lon = LAT0 + 0.05, LON0 + 1.3  # ~100 km east of the origin
    frame = MissionFrame(kind, LAT0, LON0)
    tile = ground_tile(side, heading, lat=lat, lon=lon, r0=0.0, dr=1.5, cols=101)
    g = tile_geometry(tile, frame)
    e, n = g.world(np.zeros(101, int), np.arange(101))
    az = heading + (90.0 if side == "stbd" else -90.0)
    lon2, lat2, _ = GEOD.fwd(np.full(101, lon), np.full(101, lat), np.full(101, az), tile.ranges_m)
    e_ref, n_ref = frame.to_frame(lat2, lon2)
    err = np.hypot(e - e_ref, n - n_ref)
    assert err.max() < 0.005, err.max()  # 5 mm at 150 m range


@pytest.mark.parametrize("kind", ["utm", "ltp"])
@pytest.mark.parametrize("side", ["port", "stbd"])
def test_locate_inverts_world(kind, side):
    """locate(world(i, j)) gives back the ping and the column's range (scale factor k != 1 in UTM
    100 km off the central meridian's frame origin); a point off the lines says how far."""
    lat, lon = LAT0 + 0.05, LON0 + 1.3
    tile = ground_tile(side, 37.0, rows=5, lat=lat, lon=lon)
    # pings 2 m apart along the heading, so each ping's line is its own
    lon2, lat2, _ = GEOD.fwd(np.full(5, lon), np.full(5, lat), np.full(5, 37.0), 2.0 * np.arange(5))
    tile = tile.replace(nav=TileNav(lat2, lon2, tile.nav.heading_deg, tile.nav.altitude_m))
    g = tile_geometry(tile, MissionFrame(kind, LAT0, LON0))
    for i, j in ((0, 0), (2, 50), (4, 100)):
        e, n = g.world(i, j)
        row, r, off = g.locate(float(e), float(n))
        assert row == i and abs(r - g.ranges_m[j]) < 1e-6 and off < 1e-6
    # 0.7 m along-track of ping 2's line at column 40: ping 2, the same range, 0.7 m off
    e, n = g.world(2, 40)
    a = g.heading_grid_rad[2]  # along-track in the frame: the grid heading
    row, r, off = g.locate(float(e) + 0.7 * np.sin(a), float(n) + 0.7 * np.cos(a))
    assert row == 2 and abs(r - g.ranges_m[40]) < 0.01 and abs(off - 0.7) < 0.01


def test_frame_round_trip_and_utm_zone():
    for kind in ("utm", "ltp"):
        f = MissionFrame(kind, LAT0, LON0)
        lat = LAT0 + np.linspace(-0.1, 0.1, 7)
        lon = LON0 + np.linspace(-0.1, 0.1, 7)
        e, n = f.to_frame(lat, lon)
        lat2, lon2 = f.to_latlon(e, n)
        np.testing.assert_allclose(lat2, lat, atol=1e-10)
        np.testing.assert_allclose(lon2, lon, atol=1e-10)
        assert MissionFrame.from_dict(f.to_dict()) == f
    # published: La Spezia 44.08N 9.85E is UTM 32N; Bergen 60.39N 5.32E is 32V (exception)
    assert utm_zone(44.08, 9.85) == (32, True)
    assert utm_zone(60.39, 5.32) == (32, True)
    assert utm_zone(-33.9, 18.4) == (34, False)
    # UTM easting of the central meridian is 500 000 m
    e, _ = MissionFrame("utm", 44.0, 9.0).to_frame(44.0, 9.0)
    assert abs(float(e) - 500000.0) < 1e-6


def test_frame_errors():
    with pytest.raises(GeometryError):
        MissionFrame("mercator", 0.0, 0.0)
    with pytest.raises(GeometryError):
        MissionFrame("utm", 89.0, 0.0)
    with pytest.raises(GeometryError, match="ground range"):
        tile_geometry(ground_tile("port", 0.0).replace(slant=True), MissionFrame("ltp", 0, 0))
    with pytest.raises(GeometryError):
        across_track_unit(np.zeros(1), "left")


# -- nav interpolation --------------------------------------------------------------------

def test_heading_wraps_across_north():
    track = NavTrack(max_gap_s=5)
    track.add(NavFix(t=0.0, lat_deg=LAT0, lon_deg=LON0, heading_deg=350.0, altitude_m=10.0))
    track.add(NavFix(t=1.0, lat_deg=LAT0, lon_deg=LON0, heading_deg=10.0, altitude_m=12.0))
    s = track.interpolate(np.array([0.0, 0.25, 0.5, 0.75, 1.0]))
    np.testing.assert_allclose(s.nav.heading_deg, [350.0, 355.0, 0.0, 5.0, 10.0], atol=1e-9)
    np.testing.assert_allclose(s.nav.altitude_m, [10.0, 10.5, 11.0, 11.5, 12.0])
    assert s.valid.all() and not s.reason


def test_position_interpolation_linear_and_antimeridian():
    track = NavTrack(max_gap_s=5, max_speed_m_s=1e6)
    track.add(NavFix(t=0.0, lat_deg=10.0, lon_deg=179.9, heading_deg=90.0, altitude_m=5.0))
    track.add(NavFix(t=2.0, lat_deg=10.2, lon_deg=-179.9, heading_deg=90.0, altitude_m=5.0))
    s = track.interpolate(np.array([1.0]))
    np.testing.assert_allclose(s.nav.lat_deg, [10.1])
    assert abs(wrap180(s.nav.lon_deg[0] - 180.0)) < 1e-9


def test_stale_nav_is_invalid_not_extrapolated():
    track = NavTrack(max_gap_s=2.0)
    for t in (0.0, 1.0, 10.0, 11.0):
        track.add(NavFix(t=t, lat_deg=LAT0 + t * 1e-6, lon_deg=LON0, heading_deg=0.0, altitude_m=14.0))
    s = track.interpolate(np.array([0.5, 5.0, 10.5, 12.5, 14.0, -3.0]))
    assert s.valid.tolist() == [True, False, True, True, False, False]
    assert any("position" in r for r in s.reason)


def test_duplicate_timestamps_keep_last_and_out_of_order_is_sorted():
    track = NavTrack(max_gap_s=5)
    track.add(NavFix(t=2.0, heading_deg=20.0))
    track.add(NavFix(t=0.0, heading_deg=0.0))
    track.add(NavFix(t=1.0, heading_deg=99.0))
    track.add(NavFix(t=1.0, heading_deg=10.0))  # duplicate time: the last received wins
    for t in (0.0, 1.0, 2.0):
        track.add(NavFix(t=t, lat_deg=LAT0, lon_deg=LON0, altitude_m=1.0))
    s = track.interpolate(np.array([0.5, 1.0, 1.5]))
    np.testing.assert_allclose(s.nav.heading_deg, [5.0, 10.0, 15.0])


def test_nav_jump_invalidates_pings_between():
    track = NavTrack(max_gap_s=5, max_speed_m_s=10.0)
    track.add(NavFix(t=0.0, lat_deg=LAT0, lon_deg=LON0, heading_deg=0.0, altitude_m=14.0))
    track.add(NavFix(t=1.0, lat_deg=LAT0 + 1e-5, lon_deg=LON0, heading_deg=0.0, altitude_m=14.0))  # 1.1 m
    track.add(NavFix(t=2.0, lat_deg=LAT0 + 1e-3, lon_deg=LON0, heading_deg=0.0, altitude_m=14.0))  # 110 m jump
    s = track.interpolate(np.array([0.5, 1.5]))
    assert s.valid.tolist() == [True, False]
    assert "nav jump" in s.reason
    nav = TileNav(np.array([LAT0, LAT0 + 1e-5, LAT0 + 1e-3]), np.full(3, LON0), np.zeros(3), np.ones(3))
    assert nav_jumps(nav, np.array([0.0, 1.0, 2.0]), max_speed_m_s=10.0).tolist() == [1]


def test_missing_altitude_uses_default_or_invalid():
    fix = NavFix(t=0.0, lat_deg=LAT0, lon_deg=LON0, heading_deg=0.0)
    a = NavTrack(default_altitude_m=14.0)
    a.add(fix)
    assert a.interpolate(np.array([0.0])).valid.all()
    b = NavTrack()
    b.add(fix)
    s = b.interpolate(np.array([0.0]))
    assert not s.valid.any() and "no fresh altitude" in s.reason


def test_forget_before_keeps_bracketing_fix():
    track = NavTrack(max_gap_s=100)
    for t in range(100):
        track.add(NavFix(t=float(t), lat_deg=LAT0, lon_deg=LON0, heading_deg=float(t), altitude_m=1.0))
    track.forget_before(50.5)
    s = track.interpolate(np.array([50.75]))
    assert s.valid.all() and abs(s.nav.heading_deg[0] - 50.75) < 1e-9
    assert track.span == (50.0, 99.0)
