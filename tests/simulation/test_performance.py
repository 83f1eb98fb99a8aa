"""Sonar performance model: Francois-Garrison absorption, sonar equation, ratios."""

from __future__ import annotations

import math

import numpy as np
import pytest

from atr_node.config import SensorSettings, SimulationSettings
from atr_node.errors import GeometryError
from atr_node.simulation.performance import LAMBERT_MU_DB, SonarModel, francois_garrison_db_per_km, q_sas


def ainslie_mccolm_db_per_km(f_khz, T, S, z_m, pH):
    """Ainslie & McColm, JASA 103(3), 1671-1672, 1998, eq. (2)-(4): a separately published
    simplified formula fitted to Francois-Garrison (its abstract: agreement within 10 %
    from 100 Hz to 1 MHz for the ocean conditions it covers)."""
    z = z_m / 1000.0
    f1 = 0.78 * math.sqrt(S / 35.0) * math.exp(T / 26.0)
    f2 = 42.0 * math.exp(T / 17.0)
    f = f_khz
    return (0.106 * f1 * f ** 2 / (f1 ** 2 + f ** 2) * math.exp((pH - 8.0) / 0.56)
            + 0.52 * (1 + T / 43.0) * (S / 35.0) * f2 * f ** 2 / (f2 ** 2 + f ** 2) * math.exp(-z / 6.0)
            + 0.00049 * f ** 2 * math.exp(-(T / 27.0 + z / 17.0)))


@pytest.mark.parametrize("T,S,z,pH", [(4.0, 35.0, 1000.0, 8.0), (10.0, 35.0, 0.0, 8.0), (14.0, 38.0, 30.0, 8.1)])
@pytest.mark.parametrize("f_khz", [10.0, 100.0, 120.0])
def test_francois_garrison_against_published_ainslie_mccolm(T, S, z, pH, f_khz):
    """Three frequencies (10, 100, 120 kHz) within 5 % of the published Ainslie-McColm
    values for the same water (F&G's own Table IV was not available to us; A&M is an
    independent publication reproducing F&G). 4 degC, 35 psu, 1 km, pH 8 is the condition
    of A&M's comparison figure."""
    a = float(francois_garrison_db_per_km(f_khz * 1e3, temperature_c=T, salinity_psu=S, depth_m=z, ph=pH))
    b = ainslie_mccolm_db_per_km(f_khz, T, S, z, pH)
    assert a == pytest.approx(b, rel=0.05)


def test_francois_garrison_structure():
    kw = dict(temperature_c=10.0, salinity_psu=35.0, depth_m=0.0, ph=8.0)
    f = np.array([1e3, 1e4, 1e5, 1e6])
    a = francois_garrison_db_per_km(f, **kw)
    assert np.all(np.diff(a) > 0)  # absorption grows with frequency
    # Far above both relaxations, pure water dominates: alpha ~ A3 f^2 (dB/km, f in kHz).
    A3 = 4.937e-4 - 2.59e-5 * 10 + 9.11e-7 * 100 - 1.50e-8 * 1000
    hi = francois_garrison_db_per_km(1e7, **kw)
    assert hi == pytest.approx(A3 * 1e4 ** 2, rel=0.01)
    # Depth reduces the MgSO4 and pure-water terms.
    assert francois_garrison_db_per_km(1e5, **{**kw, "depth_m": 3000.0}) < francois_garrison_db_per_km(1e5, **kw)
    # Both temperature branches agree closely at 20 degC (the published split point).
    lo = francois_garrison_db_per_km(1e5, **{**kw, "temperature_c": 20.0})
    up = francois_garrison_db_per_km(1e5, **{**kw, "temperature_c": 20.0001})
    assert lo == pytest.approx(up, rel=0.02)


def test_q_sas_closed_form():
    lam = 1500.0 / 120e3
    r = np.array([1.0, 50.0, 150.0])
    np.testing.assert_allclose(q_sas(r, wavelength_m=lam, tx_length_m=0.2, rx_length_m=1.2),
                               np.maximum(2 * lam * r / (0.2 * 1.2), 1.0))


def test_levels_by_hand_at_50_m():
    """The sonar equation of the module docstring recomputed term by term at one range."""
    sensor, sim = SensorSettings(), SimulationSettings()
    m = SonarModel.from_settings(sensor, sim)
    r, H = 50.0, 14.0
    R = math.hypot(r, H)
    alpha = float(francois_garrison_db_per_km(sensor.frequency_hz, temperature_c=sim.temperature_c,
                                              salinity_psu=sim.salinity_psu, depth_m=sim.depth_m, ph=sim.ph)) / 1e3
    tl = 20 * math.log10(R) + alpha * R
    bs = LAMBERT_MU_DB[sim.seabed] + 10 * math.log10((H / R) ** 2)
    cell = (1500.0 / (2 * sensor.bandwidth_hz)) / (r / R) * sensor.tx_length_m / 2
    bl = sim.source_level_db - 2 * tl + bs + 10 * math.log10(cell)
    lv = m.levels(np.array([r]), H)
    nl = float(lv.noise_db[0])
    assert float(lv.background_db[0]) == pytest.approx(10 * math.log10(10 ** (bl / 10) + 10 ** (nl / 10)), abs=1e-9)
    el = sim.source_level_db - 2 * tl + sim.target_strength_db + 10 * math.log10(1500.0 / 30e3 * 0.1)
    assert float(lv.echo_db[0]) == pytest.approx(10 * math.log10(10 ** (el / 10) + 10 ** (nl / 10)), abs=1e-9)
    mp = bl - sim.multipath_db
    assert float(lv.shadow_db[0]) == pytest.approx(10 * math.log10(10 ** (nl / 10) + 10 ** (mp / 10)), abs=1e-9)


def test_ratios_behave():
    m = SonarModel.from_settings()
    r = np.linspace(0.0, 150.0, 301)
    rs, re = m.ratios(r, 14.0)
    assert np.all(np.isfinite(rs)) and np.all(np.isfinite(re))  # r -> 0 is fine
    assert np.all((rs > 0) & (rs < 1))
    # Shadows fill in at far range (noise overtakes the background); echoes stand out more
    # as the background's grazing angle falls.
    assert rs[-1] > rs[100] and re[200] > re[20]
    # Harder seabeds give brighter backgrounds: lower echo contrast.
    rock = SonarModel.from_settings(simulation=SimulationSettings(seabed="rock"))
    assert np.all(rock.ratios(r, 14.0)[1] < re)
    with pytest.raises(GeometryError):
        m.levels(r, 0.0)


def test_real_aperture_resolution_grows_with_range():
    sas = SonarModel.from_settings(SensorSettings(sas=True))
    ssl = SonarModel.from_settings(SensorSettings(sas=False))
    r = np.array([20.0, 80.0])
    np.testing.assert_allclose(sas.along_track_resolution_m(r), [0.1, 0.1])
    np.testing.assert_allclose(ssl.along_track_resolution_m(r), 1500 / 120e3 * r / 1.2)
