"""Synthetic seabed backgrounds for demos and tests.

Intensity of pixel (i, j) = ``gain(r_j) * texture * speckle``:

- ``speckle`` ~ exponential(1) (fully developed speckle, Rayleigh in amplitude);
- ``texture`` ~ Gamma(nu, 1/nu), so the product is K-distributed with order nu (heavier
  tails than Rayleigh as nu falls: rougher, patchier seabeds);
- ``gain(r)``: a range-dependent mean that is deliberately not flat (a residual of the
  sonar's time-varying gain and beam pattern: dim near nadir, a bright shoulder, a slow
  fall-off at far range), so that detectors must normalise by range.

Sand ripples are a multiplicative modulation defined in world coordinates
(:func:`ripple_modulation`), so that they are at the same place on every leg; their contrast
depends on the look direction (strongest when looking across the crests). Rocks and other
clutter are ray-traced objects placed by the mission generator (:mod:`.mission`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def gain_curve(ranges_m: np.ndarray, *, altitude_m: float, max_range_m: float | None = None) -> np.ndarray:
    """Mean intensity versus ground range (cols,), about 1 on average, not flat.

    ``g(r) = (1 - 0.8 exp(-(r / 1.2H)^2)) * (1 + 0.6 exp(-((r - 2.5H) / 1.5H)^2)) * (1 - 0.4 r / R_max)``
    """
    r = np.asarray(ranges_m, dtype=np.float64)
    H = float(altitude_m)
    rmax = float(max_range_m) if max_range_m else max(float(r.max(initial=1.0)), 1.0)
    near = 1.0 - 0.8 * np.exp(-(r / (1.2 * H)) ** 2)          # beam-pattern dip under the vehicle
    shoulder = 1.0 + 0.6 * np.exp(-((r - 2.5 * H) / (1.5 * H)) ** 2)  # TVG overshoot
    far = 1.0 - 0.4 * np.clip(r / rmax, 0.0, 1.0)             # TVG falls short at far range
    return near * shoulder * far


def seabed_pixels(*, rows: int, cols: int, range0_m: float, dr_m: float, altitude_m: float,
                  rng: np.random.Generator, k_order: float = 6.0, max_range_m: float | None = None,
                  nadir_gap_m: float = 0.0) -> np.ndarray:
    """A K-distributed seabed intensity tile with a non-flat range gain.

    Parameters
    ----------
    rows, cols
        Tile size (pings, range bins).
    range0_m, dr_m
        Ground range of column 0 and range-bin spacing.
    altitude_m
        Sensor altitude (shapes the gain curve).
    rng
        Random generator.
    k_order
        K-distribution order nu (>= 50 is practically Rayleigh speckle).
    nadir_gap_m
        Ground ranges below this are NaN (no data under the vehicle).

    Returns
    -------
    ndarray, shape (rows, cols), float32
        Linear intensity, NaN in the nadir gap.
    """
    ranges = range0_m + dr_m * np.arange(cols)
    g = gain_curve(ranges, altitude_m=altitude_m, max_range_m=max_range_m).astype(np.float32)
    px = rng.standard_exponential((rows, cols), dtype=np.float32)
    px *= rng.standard_gamma(np.float32(k_order), (rows, cols), dtype=np.float32) / np.float32(k_order)
    px *= g[None, :]
    if nadir_gap_m > 0:
        px[:, ranges < nadir_gap_m] = np.nan
    return px


@dataclass(frozen=True)
class RippleField:
    """A patch of sand ripples in the world frame (metres east/north)."""

    east_m: float
    north_m: float
    radius_m: float
    """Gaussian patch radius."""
    wavelength_m: float
    crest_azimuth_deg: float
    """Direction of the wave vector (across the crests), clockwise from north."""
    depth: float
    """Modulation depth in (0, 1)."""


def ripple_modulation(east_m: np.ndarray, north_m: np.ndarray, look_azimuth_deg: np.ndarray,
                      fields: list[RippleField]) -> np.ndarray:
    """Multiplicative intensity modulation of ripple fields at world points.

    Parameters
    ----------
    east_m, north_m : ndarray, shape (rows, cols)
        World position of each pixel.
    look_azimuth_deg : ndarray, shape (rows, 1) or (rows, cols)
        Azimuth the sonar looks along at each pixel (heading +- 90 deg).
    fields
        Ripple patches.

    Returns
    -------
    ndarray, shape (rows, cols), float32
        ``1 + sum_f depth_f w_f |cos(look - crest)| sin(2 pi k_f . p / wavelength_f)``, clipped
        to >= 0.05; w_f the Gaussian patch weight.
    """
    out = np.ones(np.broadcast(east_m, north_m).shape, dtype=np.float32)
    look = np.radians(look_azimuth_deg)
    for f in fields:
        de, dn = east_m - f.east_m, north_m - f.north_m
        w = np.exp(-(de * de + dn * dn) / (2.0 * f.radius_m ** 2))
        if float(w.max(initial=0.0)) < 1e-3:
            continue
        a = np.radians(f.crest_azimuth_deg)
        phase = 2.0 * np.pi * (de * np.sin(a) + dn * np.cos(a)) / f.wavelength_m
        facing = np.abs(np.cos(look - a))
        out += (f.depth * w * facing * np.sin(phase)).astype(np.float32)
    return np.maximum(out, 0.05)


def dropout_rows(rows: int, rng: np.random.Generator, *, rate: float = 0.002, max_run: int = 4) -> np.ndarray:
    """Boolean (rows,) of pings lost (drop-outs): runs of 1..max_run pings starting at ``rate``."""
    lost = np.zeros(rows, dtype=bool)
    starts = np.flatnonzero(rng.random(rows) < rate)
    for s in starts:
        lost[s:s + int(rng.integers(1, max_run + 1))] = True
    return lost
