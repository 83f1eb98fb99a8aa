"""Sonar altitude from the first seabed return: planted seabeds, edge cases, and the real file."""

from __future__ import annotations

import numpy as np
import pytest

from atr_node.io.xtf import XtfReader
from atr_node.io.xtf_bottom import bottom_altitude_m, first_return_length_m, first_return_m
from atr_node.records.tile import Tile

from .conftest import make_tile


def _planted(altitudes_m, *, dr_m=0.03, cols=800, side="stbd", rng=None):
    """Slant pings: saturated ring-down, dark water column, seabed from R = H on."""
    rng = rng or np.random.default_rng(7)
    rows = len(altitudes_m)
    tile = make_tile(side, rows=rows, cols=cols, dr_m=dr_m, range0_m=0.5 * dr_m, rng=rng)
    r = tile.ranges_m
    px = np.where(r[None, :] >= np.asarray(altitudes_m)[:, None], 5000.0, 40.0)
    px = px * rng.exponential(1.0, size=px.shape) ** 0.5  # speckle (amplitude of exponential intensity)
    px[:, :4] = 65535.0
    return tile.replace(pixels=px.astype(np.float32))


def test_first_return_finds_a_planted_seabed():
    h = np.array([3.0, 4.25, 7.5, 11.0, 2.0])
    tile = _planted(h)
    # pings 1.25 to 9 m apart: tracked each on its own (no ping-to-ping continuity, no envelope)
    got = first_return_m(tile, jump_penalty=0.0, envelope_s=0.0)
    np.testing.assert_allclose(got, h, atol=tile.dr_m)


def test_altitude_takes_the_later_side_and_filters_outliers():
    h = np.full(21, 5.0)
    port = _planted(h, side="port")
    early = h.copy()
    early[5:9] = 2.0  # a proud object near the nadir on the starboard side only
    stbd = _planted(early, rng=np.random.default_rng(8))
    alt = bottom_altitude_m(port, stbd)
    np.testing.assert_allclose(alt, 5.0, atol=0.11)
    # each ping on its own (no continuity, no along-track envelope), the early side is fooled
    lone = bottom_altitude_m(None, stbd, jump_penalty=0.0, envelope_s=0.0)
    assert np.all(lone[5:9] < 2.2)


def test_no_return_is_nan_and_ground_tiles_are_refused():
    tile = make_tile("stbd", rows=3, cols=50)
    dark = tile.replace(pixels=np.full((3, 50), np.nan, dtype=np.float32))
    assert np.all(np.isnan(first_return_m(dark)))
    assert np.all(np.isnan(bottom_altitude_m(dark, dark)))
    with pytest.raises(ValueError, match="slant"):
        first_return_m(tile.replace(slant=False))
    with pytest.raises(ValueError, match="at least one side"):
        bottom_altitude_m(None, None)


def test_sonar_altitude_removes_the_dark_band_of_the_real_file(iver2):
    """The Iver2 altimeter reads 7 to 27 % below the sonar's first return: with it, the water
    column between the two lands next to the nadir as a dark band; with the sonar's altitude
    the seabed continues to the nadir."""
    tiles, ratio = {}, {}
    for mode in ("altimeter", "sonar"):
        reader = XtfReader(iver2, altitude=mode)
        tiles[mode] = [Tile.from_map(r.msg) for r in reader if r.link == "sonar"]
        tiles[mode] = [t for t in tiles[mode] if t.nav is not None and t.side == "port"]
        grounds = [t.ground_range() for t in tiles[mode]]
        ratio[mode] = min(np.nanmedian(g.pixels[:, g.ranges_m < 2.0])
                          / np.nanmedian(g.pixels[:, (g.ranges_m >= 5.0) & (g.ranges_m < 10.0)]) for g in grounds)
    assert reader.stats.altitude_from_sonar == 460
    sonar = np.concatenate([t.nav.altitude_m for t in tiles["sonar"]])
    recorded = np.concatenate([t.nav.altitude_m for t in tiles["altimeter"]])
    assert np.all(sonar > recorded) and np.all(sonar < 1.35 * recorded)
    assert ratio["altimeter"] < 0.05 and ratio["sonar"] > 0.1


def test_first_return_length_measures_a_planted_rise():
    """Seabed rising linearly from 0.1 to 1 of its level over 1.2 m after the first return:
    it reaches 0.7 at 0.8 m (by construction), whatever the altitude of each ping."""
    rng = np.random.default_rng(31)
    rows, dr = 120, 0.03
    alt = 4.0 + 0.5 * np.sin(np.arange(rows) / 15.0)
    tile = make_tile("port", rows=rows, cols=600, dr_m=dr, range0_m=0.5 * dr, rng=rng)
    x = tile.ranges_m[None, :] - alt[:, None]
    level = np.where(x < 0, 0.01, np.clip(0.1 + 0.9 * x / 1.2, 0.1, 1.0))
    px = (3000.0 * level * rng.rayleigh(1.0, size=level.shape)).astype(np.float32)
    tile = tile.replace(pixels=px)
    got = first_return_length_m(tile, alt, level=0.7, max_m=2.5)
    assert got == pytest.approx(0.8, abs=3 * dr)
    # a sharp step (the river's starboard side) has no length; too few pings are not measured
    step = tile.replace(pixels=np.where(x < 0, 30.0, 3000.0).astype(np.float32))
    assert first_return_length_m(step, alt) == pytest.approx(0.0, abs=dr)
    assert np.isnan(first_return_length_m(tile, alt, min_rows=rows + 1))
    with pytest.raises(ValueError, match="slant"):
        first_return_length_m(tile.replace(slant=False), alt)
