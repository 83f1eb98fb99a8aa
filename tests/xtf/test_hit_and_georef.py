"""Slant-to-ground conversion of the real recording, the marked hit on the wreck, and where
the georeferenced wreck lies against the surveyed reference points."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage as ndi

from atr_node.errors import GeometryError
from atr_node.geo import MissionFrame
from atr_node.io.xtf_hits import XtfHit, channel_sides, locate_hit, read_hits, read_survey_csv

SURVEYS = ("ScotsmanLongitudeLatitudeCaris.csv", "ScotsmanLongitudeLatitudeOpenSidescan2020-03-18.csv")


@pytest.fixture(scope="module")
def hit(iver2):
    (h,) = read_hits(str(iver2) + ".hits")
    return h


def test_hit_file_and_channel_sides(iver2, hit):
    assert hit == XtfHit(channel=1, sample=138, ping=281)
    assert channel_sides(iver2) == ["port", "stbd"]


def test_ground_range_drops_the_water_column(iver2_read, iver2, hit):
    """Against a float64 reference per ping: ground g takes the slant sample at sqrt(g^2 + H^2),
    so nothing nearer than the altitude is used, and what the slant swath does not reach is NaN."""
    _, _, tiles = iver2_read
    loc = locate_hit(tiles, hit, channel_sides(iver2))
    slant, ground = tiles[loc.tile_index], loc.ground_tile
    assert ground.range0_m == 0.0 and ground.dr_m == slant.dr_m and not ground.slant
    g = ground.ranges_m
    for i in range(0, slant.rows, 17):
        h = slant.nav.altitude_m[i]
        want = np.interp(np.sqrt(g ** 2 + h ** 2), slant.ranges_m, slant.pixels[i].astype(np.float64),
                         left=np.nan, right=np.nan)
        np.testing.assert_allclose(ground.pixels[i], want, rtol=2e-6, atol=0, equal_nan=True)
        reach = np.sqrt(max(slant.ranges_m[-1] ** 2 - h ** 2, 0.0))
        assert np.all(np.isnan(ground.pixels[i][g > reach + 1e-9]))
        assert not np.any(np.isnan(ground.pixels[i][g <= reach - 1e-9]))
    # the water column (slant range < altitude: 90 to 390 samples a ping here) has no ground range
    assert ground.cols == int(np.floor(np.sqrt(slant.ranges_m[-1] ** 2 - slant.nav.altitude_m.min() ** 2)
                                       / ground.dr_m + 1e-9)) + 1
    assert loc.slant_range_m == pytest.approx(slant.range0_m + 138 * slant.dr_m)
    assert loc.ground_range_m == pytest.approx(np.sqrt(loc.slant_range_m ** 2 - 3.75 ** 2))


def _echo_and_shadow(tiles, loc):
    """(distance in m from the point to bright pixels, metres of shadow beyond it within 12 m).

    Pixels are smoothed over 1 m x 1 m and normalised by the other side's per-range median over
    the same pings (the same seabed without the wreck): bright > 2.5, shadow < 0.3.
    """
    g, i, j = loc.ground_tile, loc.row, loc.ground_col
    other = [t for t in tiles if t.side != g.side and np.array_equal(t.ping_time, g.ping_time)][0].ground_range()
    kr, kx = int(round(1.0 / g.dr_m)), int(round(1.0 / g.dx_m))
    smooth = lambda a: ndi.uniform_filter(np.nan_to_num(a, nan=0.0), size=(kx, kr))  # noqa: E731
    n = smooth(g.pixels) / np.maximum(np.median(smooth(other.pixels), axis=0), 1.0)
    rr, cc = np.nonzero(n > 2.5)
    dist = float(np.min(np.hypot((rr - i) * g.dx_m, (cc - j) * g.dr_m)))
    profile = n[max(i - kx // 2, 0): i + kx // 2 + 1].mean(axis=0)
    beyond = (g.ranges_m > loc.ground_range_m) & (g.ranges_m < loc.ground_range_m + 12.0)
    return dist, float(np.sum(profile[beyond] < 0.3) * g.dr_m)


def test_marked_hit_lands_on_the_wreck(iver2_read, iver2, hit):
    _, _, tiles = iver2_read
    sides = channel_sides(iver2)
    dist, shadow = _echo_and_shadow(tiles, locate_hit(tiles, hit, sides))
    # 1.5 m: the hit is marked 6 samples before the first strong return, and near the nadir a
    # slant step becomes R/g = 2.6 times longer on the ground; plus the 1 m smoothing
    assert dist < 1.5 and shadow >= 1.0
    # the same test fails on plain seabed: before the wreck, on the other side, after the shadow
    for ctrl in (XtfHit(1, 300, 100), XtfHit(0, 1023 - 138, 281), XtfHit(1, 138, 440)):
        d, s = _echo_and_shadow(tiles, locate_hit(tiles, ctrl, sides))
        assert not (d < 1.5 and s >= 1.0), ctrl


def test_georeferenced_hit_against_the_surveyed_points(iver2_read, iver2, hit, real_data):
    """The two surveys of the same wreck (CARIS and OpenSidescan, from another line) disagree
    with each other by about 37 m: that is what the navigation of these dives allows. The hit,
    a point on the wreck, must lie within that disagreement (plus 5 m for this line's own
    heading error over the swath) of each survey's centroid, and nearer the CARIS points."""
    _, _, tiles = iver2_read
    loc = locate_hit(tiles, hit, channel_sides(iver2))
    frame = MissionFrame("utm", loc.lat_deg, loc.lon_deg)
    he, hn = frame.to_frame(loc.lat_deg, loc.lon_deg)
    centroids, nearest = [], []
    for name in SURVEYS:
        pts = read_survey_csv(real_data / "xtf" / name)
        assert len(pts) == 5
        e, n = frame.to_frame([p[1] for p in pts], [p[2] for p in pts])
        centroids.append((float(e.mean()), float(n.mean())))
        nearest.append(float(np.min(np.hypot(e - he, n - hn))))
    between = float(np.hypot(centroids[0][0] - centroids[1][0], centroids[0][1] - centroids[1][1]))
    assert 30.0 < between < 45.0
    for ce, cn in centroids:
        assert np.hypot(ce - he, cn - hn) < between + 5.0
    assert nearest[0] < 15.0 and nearest[0] < nearest[1]
    assert 48.4456 < loc.lat_deg < 48.4458 and -68.8283 < loc.lon_deg < -68.8280


def test_bad_hits_and_survey_files_say_where(tmp_path, iver2_read, iver2):
    bad = tmp_path / "x.hits"
    bad.write_text("1 138 281\n1 abc 3\n")
    with pytest.raises(ValueError, match=r"x\.hits:2: expected '<channel> <sample> <ping>'"):
        read_hits(bad)
    csv = tmp_path / "s.csv"
    csv.write_text("name,x,y\nA,1,2\n")
    with pytest.raises(ValueError, match=r"s\.csv:2: expected latitude/longitude"):
        read_survey_csv(csv)
    _, _, tiles = iver2_read
    sides = channel_sides(iver2)
    with pytest.raises(GeometryError, match="ping 461"):
        locate_hit(tiles, XtfHit(1, 10, 461), sides)
    with pytest.raises(GeometryError, match="channel 2"):
        locate_hit(tiles, XtfHit(2, 10, 5), sides)
    with pytest.raises(GeometryError, match="no navigation"):
        locate_hit(tiles, XtfHit(1, 10, 0), sides)
