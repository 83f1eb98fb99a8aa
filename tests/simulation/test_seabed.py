"""Synthetic seabeds: K-distributed statistics, gain, nadir gap, world-fixed ripples, drop-outs."""

from __future__ import annotations

import numpy as np
import pytest

from atr_node.simulation.seabed import RippleField, dropout_rows, gain_curve, ripple_modulation, seabed_pixels


@pytest.mark.parametrize("nu", [2.0, 8.0])
def test_k_distribution_moments(rng, nu):
    """I / g(r) = Gamma(nu, 1/nu) * Exp(1): mean 1 and E[I^2] / E[I]^2 = 2 (1 + 1/nu)."""
    px = seabed_pixels(rows=800, cols=500, range0_m=0.0, dr_m=0.1, altitude_m=14.0, rng=rng, k_order=nu)
    g = gain_curve(np.arange(500) * 0.1, altitude_m=14.0)
    x = (px / g[None, :]).astype(np.float64).ravel()
    assert x.mean() == pytest.approx(1.0, rel=0.01)
    assert (x ** 2).mean() / x.mean() ** 2 == pytest.approx(2.0 * (1.0 + 1.0 / nu), rel=0.04)


def test_gain_is_not_flat_and_nadir_gap(rng):
    r = np.linspace(0.0, 60.0, 601)
    g = gain_curve(r, altitude_m=14.0)
    assert g.max() / g.min() > 3.0 and g[0] < 0.3 and np.all(g > 0)
    px = seabed_pixels(rows=10, cols=100, range0_m=0.0, dr_m=0.1, altitude_m=14.0, rng=rng, nadir_gap_m=2.0)
    assert np.isnan(px[:, :20]).all() and not np.isnan(px[:, 20:]).any()
    assert px.dtype == np.float32


def test_ripples_are_fixed_in_the_world():
    f = [RippleField(east_m=0.0, north_m=0.0, radius_m=20.0, wavelength_m=0.8, crest_azimuth_deg=30.0, depth=0.5)]
    e, n = np.meshgrid(np.linspace(-5, 5, 101), np.linspace(-5, 5, 101))
    # the same points seen looking east (one leg) and looking west (the next): same pattern
    a = ripple_modulation(e, n, np.full((101, 1), 90.0), f)
    b = ripple_modulation(e, n, np.full((101, 1), 270.0), f)
    np.testing.assert_allclose(a, b, atol=1e-6)
    assert a.std() > 0.1 and a.mean() == pytest.approx(1.0, abs=0.05)
    # looking along the crests the ripples vanish; far from the patch nothing changes
    along = ripple_modulation(e, n, np.full((101, 1), 30.0 + 90.0), f)
    assert along.std() < 1e-3
    far = ripple_modulation(e + 500.0, n, np.full((101, 1), 90.0), f)
    np.testing.assert_array_equal(far, 1.0)


def test_dropouts(rng):
    lost = dropout_rows(100000, rng, rate=0.002, max_run=4)
    assert 0.002 < lost.mean() < 0.008
    assert not dropout_rows(1000, rng, rate=0.0).any()
