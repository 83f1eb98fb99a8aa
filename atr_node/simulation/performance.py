"""Sonar performance model: background, shadow and echo levels per range (SPEC section 4).

A stand-in for ESPRESSO: the sonar equation evaluated per ground range r at altitude H,
slant range R = sqrt(r^2 + H^2), grazing angle theta = atan(H / r). Levels in dB re 1 uPa^2:

- transmission loss (one way): ``TL = 20 log10 R + alpha R``, alpha from Francois-Garrison
  (:func:`francois_garrison_db_per_km`);
- seabed backscatter by Lambert's rule: ``BS = 10 log10 mu + 10 log10 sin^2 theta`` with mu
  by seabed type (:data:`LAMBERT_MU_DB`);
- resolution cell ``A = (c / 2B) / cos theta * dx_res``, dx_res = L_T / 2 for SAS, the
  physical beam ``lambda R / L_R`` for a real aperture;
- background ``BL = SL - 2 TL + BS + 10 log10 A``;
- noise: thermal plus wind (sea-state) ambient noise spectral level, over the bandwidth, less
  the receive directivity index and the synthetic-aperture gain;
- multipath: a floor ``multipath_db`` below the background;
- shadow ``SHL`` = noise + multipath (power sum);
- target echo per pixel ``EL = SL - 2 TL + TS + 10 log10(dx_res * c / 2B)``: a facet at
  normal incidence filling a slant-range cell, TS = ``target_strength_db`` its scattering
  strength per square metre.

Only ratios leave the model: ``rho_shadow = 10^((SHL - BL)/10)``,
``rho_echo = 10^((EL - BL)/10)`` (intensity ratios).

References
----------
R. E. Francois, G. R. Garrison, "Sound absorption based on ocean measurements. Part II: Boric
acid contribution and equation for total absorption", JASA 72(6), 1879-1890, 1982.
APL-UW High-Frequency Ocean Environmental Acoustic Models Handbook, APL-UW TR 9407, 1994
(Lambert's mu by seabed type, order of magnitude). R. J. Urick, Principles of Underwater Sound,
3rd ed., 1983 (noise, sonar equation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import SensorSettings, SimulationSettings
from ..errors import GeometryError

LAMBERT_MU_DB: dict[str, float] = {"mud": -37.0, "silt": -33.0, "sand": -27.0, "gravel": -22.0, "rock": -17.0}
"""10 log10(mu) of Lambert's rule per seabed type (dB), typical high-frequency values."""


def francois_garrison_db_per_km(frequency_hz: np.ndarray | float, *, temperature_c: float, salinity_psu: float,
                                depth_m: float, ph: float) -> np.ndarray:
    """Sound absorption in sea water, Francois and Garrison (1982), dB/km.

    alpha = A1 P1 f1 f^2 / (f1^2 + f^2)   (boric acid)
          + A2 P2 f2 f^2 / (f2^2 + f^2)   (magnesium sulphate)
          + A3 P3 f^2                      (pure water), f in kHz.
    Valid 0.2-1000 kHz, -2..22 deg C, 30-35 psu (used a little beyond), depth 0-3.5 km.
    """
    f = np.asarray(frequency_hz, dtype=np.float64) / 1e3
    T, S, D = float(temperature_c), float(salinity_psu), float(depth_m)
    c = 1412.0 + 3.21 * T + 1.19 * S + 0.0167 * D
    tk = T + 273.0
    a1 = 8.86 / c * 10.0 ** (0.78 * ph - 5.0)
    f1 = 2.8 * math.sqrt(S / 35.0) * 10.0 ** (4.0 - 1245.0 / tk)
    a2 = 21.44 * S / c * (1.0 + 0.025 * T)
    p2 = 1.0 - 1.37e-4 * D + 6.2e-9 * D * D
    f2 = 8.17 * 10.0 ** (8.0 - 1990.0 / tk) / (1.0 + 0.0018 * (S - 35.0))
    p3 = 1.0 - 3.83e-5 * D + 4.9e-10 * D * D
    if T <= 20.0:
        a3 = 4.937e-4 - 2.59e-5 * T + 9.11e-7 * T ** 2 - 1.50e-8 * T ** 3
    else:
        a3 = 3.964e-4 - 1.146e-5 * T + 1.45e-7 * T ** 2 - 6.5e-10 * T ** 3
    f_sq = f * f
    return a1 * f1 * f_sq / (f1 * f1 + f_sq) + a2 * p2 * f2 * f_sq / (f2 * f2 + f_sq) + a3 * p3 * f_sq


def q_sas(range_m: np.ndarray | float, *, wavelength_m: float, tx_length_m: float, rx_length_m: float) -> np.ndarray:
    """SAS gain ``Q_SAS = 2 lambda r / (L_T L_R)`` (SPEC section 4), at least 1."""
    r = np.asarray(range_m, dtype=np.float64)
    return np.maximum(2.0 * wavelength_m * r / (tx_length_m * rx_length_m), 1.0)


@dataclass(frozen=True)
class Levels:
    """Sonar-equation levels per range, dB re 1 uPa^2 (arrays of the ranges' shape)."""

    background_db: np.ndarray
    shadow_db: np.ndarray
    echo_db: np.ndarray
    noise_db: np.ndarray
    multipath_db: np.ndarray

    @property
    def rho_shadow(self) -> np.ndarray:
        """Shadow-to-background intensity ratio."""
        return 10.0 ** ((self.shadow_db - self.background_db) / 10.0)

    @property
    def rho_echo(self) -> np.ndarray:
        """Echo (facet at normal incidence filling a pixel) to background intensity ratio."""
        return 10.0 ** ((self.echo_db - self.background_db) / 10.0)


@dataclass(frozen=True)
class SonarModel:
    """The sonar equation of one sensor in one environment.

    Build it with :meth:`from_settings`; call :meth:`levels` or :meth:`ratios`.
    """

    sensor: SensorSettings
    simulation: SimulationSettings

    @classmethod
    def from_settings(cls, sensor: SensorSettings | None = None,
                      simulation: SimulationSettings | None = None) -> "SonarModel":
        return cls(sensor or SensorSettings(), simulation or SimulationSettings())

    @property
    def wavelength_m(self) -> float:
        return self.sensor.sound_speed_m_s / self.sensor.frequency_hz

    @property
    def alpha_db_per_m(self) -> float:
        s = self.simulation
        return float(francois_garrison_db_per_km(self.sensor.frequency_hz, temperature_c=s.temperature_c,
                                                 salinity_psu=s.salinity_psu, depth_m=s.depth_m, ph=s.ph)) / 1e3

    def along_track_resolution_m(self, range_m: np.ndarray | float) -> np.ndarray:
        """L_T / 2 for SAS (at every range), ``lambda R / L_R`` for a real aperture."""
        r = np.asarray(range_m, dtype=np.float64)
        if self.sensor.sas:
            real = self.wavelength_m * r / self.sensor.rx_length_m
            return np.minimum(np.full_like(r, self.sensor.tx_length_m / 2.0), real)
        return self.wavelength_m * r / self.sensor.rx_length_m

    def noise_db(self, range_m: np.ndarray | float) -> np.ndarray:
        """Noise level in an image pixel: thermal + sea-state ambient noise (spectral, Urick
        ch. 7: thermal ``-15 + 20 log10 f_kHz``, wind ``44 + 23 log10(SS + 1) - 17 log10 f_kHz``),
        plus ``10 log10 B``, minus the receive DI ``10 log10(2 L_R / lambda)`` and the
        synthetic-aperture gain ``10 log10 Q_SAS``."""
        f_khz = self.sensor.frequency_hz / 1e3
        thermal = -15.0 + 20.0 * math.log10(f_khz)
        wind = 44.0 + 23.0 * math.log10(self.simulation.sea_state + 1.0) - 17.0 * math.log10(f_khz)
        spectral = 10.0 * math.log10(10 ** (thermal / 10) + 10 ** (wind / 10))
        di = 10.0 * math.log10(2.0 * self.sensor.rx_length_m / self.wavelength_m)
        band = spectral + 10.0 * math.log10(self.sensor.bandwidth_hz) - di
        r = np.asarray(range_m, dtype=np.float64)
        if self.sensor.sas:
            q = q_sas(r, wavelength_m=self.wavelength_m, tx_length_m=self.sensor.tx_length_m,
                      rx_length_m=self.sensor.rx_length_m)
            return band - 10.0 * np.log10(q)
        return np.full_like(r, band)

    def levels(self, range_m: np.ndarray | float, altitude_m: float) -> Levels:
        """Background, shadow, echo, noise and multipath levels at ground ranges ``range_m``.

        Ranges at or below 0 are treated as 1 cm (directly under the sonar).
        """
        if not (math.isfinite(altitude_m) and altitude_m > 0):
            raise GeometryError(f"altitude must be finite and > 0, got {altitude_m!r}")
        r = np.maximum(np.asarray(range_m, dtype=np.float64), 0.01)
        H = float(altitude_m)
        slant = np.hypot(r, H)
        sin_g = H / slant
        cos_g = r / slant
        tl = 20.0 * np.log10(slant) + self.alpha_db_per_m * slant
        sl = self.simulation.source_level_db
        mu_db = LAMBERT_MU_DB[self.simulation.seabed]
        bs = mu_db + 10.0 * np.log10(sin_g ** 2)
        dr_res = self.sensor.sound_speed_m_s / (2.0 * self.sensor.bandwidth_hz)
        dx_res = self.along_track_resolution_m(slant)
        # The ground footprint of a slant-range cell is dr_res / cos(theta); near nadir it is
        # bounded by the beam, so cap the stretch at the cell that sees the whole altitude.
        cell = np.minimum(dr_res / np.maximum(cos_g, 1e-3), np.sqrt(2.0 * dr_res * H)) * dx_res
        bl = sl - 2.0 * tl + bs + 10.0 * np.log10(cell)
        nl = self.noise_db(slant)
        mp = bl - self.simulation.multipath_db
        shl = 10.0 * np.log10(10.0 ** (nl / 10.0) + 10.0 ** (mp / 10.0))
        el = sl - 2.0 * tl + self.simulation.target_strength_db + 10.0 * np.log10(dr_res * dx_res)
        # The echo sits above noise too: what the image shows is echo + noise.
        el = 10.0 * np.log10(10.0 ** (el / 10.0) + 10.0 ** (nl / 10.0))
        bl_seen = 10.0 * np.log10(10.0 ** (bl / 10.0) + 10.0 ** (nl / 10.0))
        return Levels(background_db=bl_seen, shadow_db=shl, echo_db=el, noise_db=nl, multipath_db=mp)

    def ratios(self, range_m: np.ndarray | float, altitude_m: float) -> tuple[np.ndarray, np.ndarray]:
        """(rho_shadow, rho_echo) intensity ratios to the background at ``range_m``."""
        lv = self.levels(range_m, altitude_m)
        return lv.rho_shadow, lv.rho_echo
