"""Held-out scenes: a second scene generator, independent of ``atr_node.simulation``.

The node's own simulator also makes its calibration signatures, so figures measured on its
missions flatter the node. This module renders lawnmower missions by a different method,
written without reading the simulator, and is used **only for evaluation**: never for
calibration and never to choose a setting (issue 17). It imports nothing from
``atr_node.simulation``, ``.detectors``, ``.calibration`` or ``.fusion`` (a test parses it
to check), only the tile record, the ``.atrlog`` writer and the mission frame.

The method (per ground-range tile, whole arrays at once):

1. A world height field ``H(e, n)`` (seabed: flat sand with roughness, ripples, or flat with a
   real SAS texture as reflectivity) plus local height patches of the objects, and a
   reflectivity field ``R(e, n)``, both sampled on each ping's ground-range line.
2. Shadow by the running minimum of the depression slope: with the sonar at height ``h``, the
   point at range ``r`` and height ``z`` is lit iff
   ``(h - z) / r <= min_{r' < r} (h - H(r')) / r'``.
3. Mean echo ``mu = level * R * (cos t_loc / cos t_flat)^2 * g(r)``: Lambert's law
   (backscatter ~ cos^2 of the local incidence ``t_loc``, from the slope of ``H`` along range),
   normalised by a flat seabed's as a TVG would, times a residual gain ``g(r)`` (darker next to
   the nadir, falling off at far range).
4. K-distributed speckle: ``I = mu * G * E`` with ``G ~ Gamma(nu, 1/nu)`` (texture) and
   ``E ~ Exp(1)`` (speckle), ``nu`` drawn per scene in [2, 30] and varied slowly in space,
   plus an exponential noise floor; ground ranges under 5 m (the nadir gap) and a few dropped
   pings are NaN.

The tiles carry the true track plus a per-leg nav offset of about 0.5 m and a slow drift
(recorded in ``scene.json``); the CSVs give true positions.

Stress variants (:data:`VARIANTS`, ``--variant``) change, for the same seed, what another
team's simulator is likely to do otherwise: the pixel size (0.05 and 0.2 m, and a real
side-scan's 0.05 m in range by 0.2 m along track), the seabed statistics (texture correlated
over 1 m, speckle of an oversampled image; spikier clutter, K shape 0.7-1.5), the survey height
and range (4 m / 40 m, 15 m / 100 m), a poorer INS (nav errors 4 x, per-leg offsets about 2 m).
The base scenes are unchanged by them, byte for byte.

References
----------
.. [1] E. Jakeman and P. N. Pusey, "A model for non-Rayleigh sea echo", IEEE Trans. Antennas
   Propag. 24(6), 1976 (the K distribution, ``E[I^2]/E[I]^2 = 2 (1 + 1/nu)``).
.. [2] D. A. Abraham and A. P. Lyons, "Novel physical interpretations of K-distributed
   reverberation", IEEE J. Oceanic Eng. 27(4), 2002.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import cv2
import numpy as np
from scipy import ndimage

from ..geo import MissionFrame
from ..io.atomic import atomic_path
from ..io.atrlog import AtrLogWriter
from ..records.tile import SensorInfo, Tile, TileNav

GENERATOR_VERSION = "1"
SCENE_FILES = ("mission.atrlog", "truth.csv", "clutter.csv", "one_leg.csv", "scene.json")
"""The files of a scene, as :func:`generate_scene` writes them."""
SEABEDS = ("sand", "ripples", "sassed")
TEXTURES_ENV = "ATR_SAS_TEXTURES"
DEFAULT_TEXTURES_DIR = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "sas_textures"
"""The SASSED crops in ``shared/`` beside the repository (``$ATR_REAL_DATA/sas_textures`` if set)."""

LEG_SPACING_M = 40.0
NADIR_GAP_M = 5.0
MAX_RANGE_M = 60.0
DR_M = 0.1
DX_M = 0.1
ALTITUDE_M = 8.0
SWELL_M = 0.3
SPEED_M_S = 2.0
TILE_PINGS = 256
TURN_S = 60.0
TILE_LATENCY_S = 0.3
EPOCH_S = 1_760_000_000.0
ORIGIN_LAT_DEG, ORIGIN_LON_DEG = 42.97, 5.62
LEVEL = 1000.0
"""Mean intensity of a flat seabed of reflectivity 1 where the residual gain is 1."""
NOISE_FLOOR = 0.03
"""Mean of the additive noise, as a fraction of LEVEL: a shadow is ~15 dB below the seabed."""
N_TARGETS = 16
MIN_SEPARATION_M = 3.0
SENSOR = SensorInfo(frequency_hz=100e3, bandwidth_hz=20e3, tx_length_m=0.25, rx_length_m=1.5, n_rx=32, sas=True)
TARGET_SHAPES = ("cylinder", "truncated_cone", "wedge", "dome")

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class Variant:
    """How a scene's survey and seabed statistics depart from the base scenes: the axes along
    which another team's simulator is likely to differ from this one. ``base`` is every scene
    of the held-out benchmark; the others are stress tests of the same seeds (``VARIANTS``)."""

    name: str = "base"
    dr_m: float = DR_M
    """Ground-range pixel."""
    dx_m: float = DX_M
    """Along-track pixel, the ping spacing (the tiles keep about 25.6 m along track)."""
    altitude_m: float = ALTITUDE_M
    max_range_m: float = MAX_RANGE_M
    texture_m: float = 0.0
    """Correlation length of the K texture ``G`` (Gaussian copula, so ``G`` stays
    Gamma(nu, 1/nu)); 0: independent per pixel, as in the base scenes."""
    speckle_px: float = 0.0
    """Speckle from a complex Gaussian field smoothed over this many pixels (an oversampled
    image, |.|^2 normalised to mean 1); 0: independent Exp(1) per pixel."""
    nu_range: tuple[float, float] = (2.0, 30.0)
    """The K shape ``nu`` of a scene is drawn log-uniformly in this range."""
    nav_scale: float = 1.0
    """Times the base scenes' nav errors (per-leg offset 0.4-0.6 m, drift 0.1-0.3 m per 100 m,
    wander 0.05-0.15 m): 4 is a poorer INS, offsets of 1.6-2.4 m."""
    byte_headroom_db: tuple[float, float] | None = None
    """An 8-bit recorder (:func:`to_byte_amplitude`): the tiles are amplitude in uint8, the gain
    set so that a flat seabed's mean intensity at full gain (``LEVEL``) lies this many dB under
    full scale (255), drawn per scene, uniform in the range; brighter echoes clip at 255, as
    an operator's gain for a mid-grey seabed makes a real side-scan file do. None: float
    intensity (the base scenes)."""

    @property
    def tile_pings(self) -> int:
        return max(1, int(round(TILE_PINGS * DX_M / self.dx_m)))

    def info(self) -> dict[str, Any]:
        """As ``scene.json`` keeps it (tuples as lists)."""
        return {k: ([_r(x) for x in v] if isinstance(v, tuple) else _r(v) if isinstance(v, float) else v)
                for k, v in vars(self).items()}


VARIANTS = {v.name: v for v in (
    Variant(),
    Variant("fine", dr_m=0.05, dx_m=0.05),
    Variant("coarse", dr_m=0.2, dx_m=0.2),
    Variant("aniso", dr_m=0.05, dx_m=0.2),
    Variant("spiky", nu_range=(0.7, 1.5)),
    Variant("nav2", nav_scale=4.0),
    Variant("clumpy", texture_m=1.0, speckle_px=0.8),
    Variant("high", altitude_m=15.0, max_range_m=100.0),
    Variant("low", altitude_m=4.0, max_range_m=40.0),
    Variant("byte", byte_headroom_db=(4.0, 10.0)),
)}
"""Stress variants of the held-out scenes (``--variant``): finer and coarser pixels, a real
side-scan's pixels (fine in range, coarse along track), clumpy seabed statistics (correlated
texture, oversampled speckle), spiky clutter (K shape 0.7-1.5), a higher and a lower survey, a
poorer INS (per-leg nav offsets of about 2 m), an 8-bit recorder that clips (amplitude in
uint8, the seabed 4-10 dB under full scale)."""


@dataclass(frozen=True)
class HeldoutScene:
    """What :func:`generate_scene` wrote."""

    out_dir: Path
    atrlog: Path
    truth: Path
    clutter: Path
    one_leg: Path
    scene_json: Path
    seabed: str
    seed: int
    legs: int
    tiles: int
    targets: int
    rocks: int
    one_leg_objects: int
    nu: float


@dataclass
class _Object:
    kind: str  # "target", "rock" or "one_leg"
    shape: str
    east_m: float
    north_m: float
    heading_deg: float
    height_m: float
    """Visible height above the seabed (after burial)."""
    size_m: float
    """Largest horizontal dimension."""
    reflectivity_db: float
    extent_m: float
    """Radius of a circle around the centre holding the whole footprint."""
    params: dict[str, float] = field(default_factory=dict)
    blobs: np.ndarray | None = None
    """Rocks: (k, 6) rows of (de, dn, sigma_major_m, sigma_minor_m, angle_rad, amplitude_m)."""
    shown_on_leg: int | None = None

    def heights(self, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        """Height of the object's top surface above the seabed at world points (0 outside)."""
        de, dn = e - self.east_m, n - self.north_m
        if self.blobs is not None:  # sum of anisotropic Gaussians
            z = np.zeros(e.shape)
            for be, bn, sa, sb, ang, amp in self.blobs:
                ca, sa_ = math.cos(ang), math.sin(ang)
                x, y = (de - be) * ca + (dn - bn) * sa_, -(de - be) * sa_ + (dn - bn) * ca
                z += amp * np.exp(-0.5 * ((x / sa) ** 2 + (y / sb) ** 2))
            return np.where(z > 0.01, z, 0.0)
        psi = math.radians(self.heading_deg)
        u = de * math.sin(psi) + dn * math.cos(psi)  # along the object's axis
        v = de * math.cos(psi) - dn * math.sin(psi)
        p, burial = self.params, self.params["burial_m"]
        if self.shape == "cylinder":  # lying: top of a circle of radius a centred a above the bed
            a = p["diameter_m"] / 2
            top = a + np.sqrt(np.clip(a * a - v * v, 0.0, None))
            z = np.where((np.abs(u) <= p["length_m"] / 2) & (np.abs(v) < a), top, 0.0)
        elif self.shape == "truncated_cone":
            rho = np.hypot(u, v)
            rb, rt, hh = p["base_diameter_m"] / 2, p["top_diameter_m"] / 2, p["full_height_m"]
            z = hh * np.clip((rb - rho) / (rb - rt), 0.0, 1.0)
        elif self.shape == "wedge":  # trapezoid prism; a top width of 0 makes a wedge
            wb, wt, hh = p["base_width_m"] / 2, p["top_width_m"] / 2, p["full_height_m"]
            z = np.where(np.abs(u) <= p["length_m"] / 2, hh * np.clip((wb - np.abs(v)) / (wb - wt), 0.0, 1.0), 0.0)
        else:  # dome: spherical cap of base radius b, height hh
            b, hh = p["base_diameter_m"] / 2, p["full_height_m"]
            rs = (b * b + hh * hh) / (2 * hh)
            z = np.sqrt(np.clip(rs * rs - u * u - v * v, 0.0, None)) - (rs - hh)
        return np.clip(z - burial, 0.0, None)


# ----------------------------------------------------------------------------------------
# Speckle and fields


def k_intensity(mean: np.ndarray, nu: np.ndarray | float, rng: np.random.Generator) -> np.ndarray:
    """K-distributed intensity of a given mean: ``mean * Gamma(nu, 1/nu) * Exp(1)``.

    Its normalised second moment is ``E[I^2] / E[I]^2 = 2 (1 + 1/nu)`` [1]_.
    """
    return k_intensity_correlated(mean, nu, rng, texture_px=0.0, speckle_px=0.0)


def k_intensity_correlated(mean: np.ndarray, nu: np.ndarray | float, rng: np.random.Generator, *,
                           texture_px: float | tuple[float, float], speckle_px: float) -> np.ndarray:
    """K-distributed intensity with spatial correlation: the texture ``G ~ Gamma(nu, 1/nu)``
    through a Gaussian copula of a field smoothed over ``texture_px`` pixels (its marginal is
    exactly the base scenes'), the speckle ``|c|^2`` of a complex Gaussian field smoothed over
    ``speckle_px`` pixels and normalised to mean 1 (an exponential marginal, correlated as in an
    oversampled image). ``texture_px`` may be (rows, cols) for pixels that are not square. 0 for
    either: independent per pixel."""
    from scipy import special

    mean = np.asarray(mean, dtype=np.float64)
    nu_a = np.broadcast_to(np.asarray(nu, dtype=np.float64), mean.shape)
    if np.any(np.asarray(texture_px) > 0):
        g = ndimage.gaussian_filter(rng.standard_normal(mean.shape), texture_px)
        g /= max(float(g.std()), 1e-12)
        texture = special.gammaincinv(nu_a, np.clip(special.ndtr(g), 1e-12, 1.0 - 1e-12)) / nu_a
    else:
        texture = rng.gamma(nu_a, 1.0 / nu_a)
    if speckle_px > 0:
        c = (ndimage.gaussian_filter(rng.standard_normal(mean.shape), speckle_px)
             + 1j * ndimage.gaussian_filter(rng.standard_normal(mean.shape), speckle_px))
        speckle = np.abs(c) ** 2
        speckle /= max(float(speckle.mean()), 1e-300)
    else:
        speckle = rng.exponential(1.0, mean.shape)
    return mean * texture * speckle


def _slow_field(rng: np.random.Generator, k: int, wavelengths_m: tuple[float, float]):
    """A smooth zero-mean field of unit variance: a sum of ``k`` plane waves."""
    lam = rng.uniform(*wavelengths_m, k)
    th = rng.uniform(0.0, 2 * np.pi, k)
    ph = rng.uniform(0.0, 2 * np.pi, k)
    ke, kn = 2 * np.pi * np.cos(th) / lam, 2 * np.pi * np.sin(th) / lam

    def f(e: np.ndarray, n: np.ndarray) -> np.ndarray:
        out = np.zeros(np.shape(e))
        for i in range(k):
            out += np.sin(ke[i] * e + kn[i] * n + ph[i])
        return out * math.sqrt(2.0 / k)
    return f


def default_textures_dir() -> Path:
    """``$ATR_SAS_TEXTURES``, else ``$ATR_REAL_DATA/sas_textures``, else :data:`DEFAULT_TEXTURES_DIR`."""
    if os.environ.get(TEXTURES_ENV):
        return Path(os.environ[TEXTURES_ENV])
    if os.environ.get("ATR_REAL_DATA"):
        return Path(os.environ["ATR_REAL_DATA"]) / "sas_textures"
    return DEFAULT_TEXTURES_DIR


def _gain(r_m: np.ndarray, max_range_m: float = MAX_RANGE_M) -> np.ndarray:
    """Residual gain after TVG: beam pattern darkening the first metres, far-range loss."""
    return (0.55 + 0.45 * np.clip(r_m / 15.0, 0.0, 1.0)) * (1.0 - 0.4 * (r_m / max_range_m) ** 2)


def _load_texture(textures_dir: Path, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    if not textures_dir.is_dir():
        raise FileNotFoundError(f"SAS texture folder {textures_dir} not found (set {TEXTURES_ENV} or textures_dir=)")
    files = sorted(textures_dir.glob("*.png"))
    if not files:
        raise FileNotFoundError(f"SAS texture folder {textures_dir} holds no .png")
    path = files[int(rng.integers(len(files)))]
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None or img.ndim != 2 or min(img.shape) < 16:
        raise ValueError(f"SAS texture {path}: not a readable 8-bit grey image")
    # Display amplitude -> intensity; a light blur so its own speckle does not double ours.
    inten = ndimage.gaussian_filter(img.astype(np.float64) ** 2, 0.7)
    return inten / inten.mean(), path.name


class _Seabed:
    """World height and reflectivity fields of one scene."""

    def __init__(self, kind: str, rng: np.random.Generator, textures_dir: Path, box: tuple[float, ...]) -> None:
        self.kind = kind
        self.info: dict[str, Any] = {"kind": kind}
        e0, e1, n0, n1 = box
        # Roughness: white noise on a 0.2 m grid, smoothed to ~0.4 m correlation, 1 cm rms.
        self.cell_m = 0.2
        self.origin = (e0, n0)
        ne, nn = int((e1 - e0) / self.cell_m) + 2, int((n1 - n0) / self.cell_m) + 2
        rough = ndimage.gaussian_filter(rng.standard_normal((nn, ne)), 2.0, mode="wrap")
        rms_m = 0.01 if kind != "ripples" else 0.006
        self.rough = (rough * (rms_m / rough.std())).astype(np.float32)
        self.info["roughness_rms_m"] = rms_m
        self.patch = _slow_field(rng, 4, (40.0, 120.0))
        self.patch_db = 0.8
        self.info["reflectivity_patchiness_db"] = self.patch_db
        self.ripples: list[tuple[float, float, float, float]] = []
        if kind == "ripples":
            for i in range(int(rng.integers(1, 3))):
                lam, th = rng.uniform(0.6, 1.5), rng.uniform(0.0, np.pi)
                amp = rng.uniform(0.03, 0.07) / (i + 1)
                self.ripples.append((lam, th, amp, rng.uniform(0.0, 2 * np.pi)))
            self.info["ripples"] = [{"wavelength_m": r[0], "direction_deg": math.degrees(r[1]), "amplitude_m": r[2],
                                     "phase_rad": r[3]} for r in self.ripples]
        self.texture = None
        if kind == "sassed":
            self.texture, name = _load_texture(textures_dir, rng)
            self.tex_px_m = float(rng.uniform(0.05, 0.1))
            self.tex_rot = float(rng.uniform(0.0, 2 * np.pi))
            self.info.update(texture=name, texture_pixel_m=self.tex_px_m,
                             texture_rotation_deg=math.degrees(self.tex_rot))

    def height(self, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        ci = (n - self.origin[1]) / self.cell_m
        cj = (e - self.origin[0]) / self.cell_m
        z = ndimage.map_coordinates(self.rough, [ci.ravel(), cj.ravel()], order=1, mode="nearest").reshape(e.shape)
        z = z.astype(np.float64)
        for lam, th, amp, ph in self.ripples:
            z += amp * np.sin(2 * np.pi * (e * math.cos(th) + n * math.sin(th)) / lam + ph)
        return z

    def reflectivity(self, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        r = 10.0 ** (self.patch_db * self.patch(e, n) / 10.0)
        if self.texture is not None:
            c, s = math.cos(self.tex_rot), math.sin(self.tex_rot)
            rows, cols = self.texture.shape
            ti = _fold((-e * s + n * c) / self.tex_px_m, rows)
            tj = _fold((e * c + n * s) / self.tex_px_m, cols)
            r = r * ndimage.map_coordinates(self.texture, [ti.ravel(), tj.ravel()], order=1,
                                            mode="nearest").reshape(e.shape)
        return r


def _fold(x: np.ndarray, size: int) -> np.ndarray:
    """Pixel coordinate of an endless mirrored tiling of ``size`` pixels."""
    y = np.mod(x, 2 * size)
    return np.clip(np.where(y >= size, 2 * size - 1 - y, y), 0.0, size - 1.0)


# ----------------------------------------------------------------------------------------
# The survey and the objects


@dataclass(frozen=True)
class _Leg:
    index: int
    heading_deg: float
    start_e_m: float
    start_n_m: float
    pings: int
    t0_s: float
    nav_offset_m: tuple[float, float]
    nav_drift_m_per_100m: tuple[float, float]
    nav_wobble: tuple[float, float, float]
    """(amplitude_m, wavelength_m, phase_rad) of a slow across-track wander of the nav."""
    dx_m: float = DX_M
    max_range_m: float = MAX_RANGE_M

    @property
    def along(self) -> np.ndarray:
        h = math.radians(self.heading_deg)
        return np.array([math.sin(h), math.cos(h)])

    def side_unit(self, side: str) -> np.ndarray:
        h = math.radians(self.heading_deg)
        stbd = np.array([math.cos(h), -math.sin(h)])  # heading + 90 deg
        return stbd if side == "stbd" else -stbd

    def leg_coords(self, e: float, n: float, side: str) -> tuple[float, float]:
        """(along_m, ground range to ``side``) of a world point; the range is < 0 on the other side."""
        d = np.array([e - self.start_e_m, n - self.start_n_m])
        return float(d @ self.along), float(d @ self.side_unit(side))

    def covers(self, e: float, n: float) -> bool:
        """Inside this leg's imaged swath: ground range 5 m to the maximum range either side,
        along-track inside."""
        a, c = self.leg_coords(e, n, "stbd")
        return 0.0 <= a <= (self.pings - 1) * self.dx_m and NADIR_GAP_M <= abs(c) <= self.max_range_m

    def nav_error(self, along_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(east, north) error of the recorded nav at along-track positions."""
        amp, lam, ph = self.nav_wobble
        wob = amp * np.sin(2 * np.pi * along_m / lam + ph)
        st = self.side_unit("stbd")
        return (self.nav_offset_m[0] + self.nav_drift_m_per_100m[0] * along_m / 100.0 + wob * st[0],
                self.nav_offset_m[1] + self.nav_drift_m_per_100m[1] * along_m / 100.0 + wob * st[1])


def legs_of_scene(info: Mapping[str, Any]) -> list[_Leg]:
    """The legs a scene was rendered with, as its ``scene.json`` (``info``) records them:
    geometry and nav errors, for the truth of what the recorded nav got wrong
    (:meth:`_Leg.nav_error`)."""
    return [_Leg(index=int(p["leg"]), heading_deg=float(p["heading_deg"]), start_e_m=float(p["start_east_m"]),
                 start_n_m=float(p["start_north_m"]), pings=int(p["pings"]), t0_s=float(p["t0_s"]),
                 nav_offset_m=(float(p["nav_offset_east_m"]), float(p["nav_offset_north_m"])),
                 nav_drift_m_per_100m=(float(p["nav_drift_east_m_per_100m"]), float(p["nav_drift_north_m_per_100m"])),
                 nav_wobble=(float(p["nav_wobble_m"]), float(p["nav_wobble_wavelength_m"]),
                             float(p["nav_wobble_phase_rad"])),
                 dx_m=float(info["dx_m"]), max_range_m=float(info["max_range_m"]))
            for p in info["per_leg"]]


def leg_shift_truth(info: Mapping[str, Any], leg_a: int, leg_b: int, points_en: np.ndarray) -> np.ndarray | None:
    """The generator's truth of a pair of legs' shift (what :mod:`atr_node.fusion.navcheck`
    measures): the mean over ``points_en`` (world east, north: the scene's objects) that both
    legs image of ``nav_error_b - nav_error_a`` there, (east, north); None if no point is
    imaged by both. The recorded nav is the true track plus the error, so an object is placed
    that much off by each leg."""
    legs = {lg.index: lg for lg in legs_of_scene(info)}
    a, b = legs[leg_a], legs[leg_b]
    d = []
    for e, n in np.asarray(points_en, dtype=np.float64).reshape(-1, 2):
        if a.covers(e, n) and b.covers(e, n):
            ea = np.array(a.nav_error(np.array(a.leg_coords(e, n, "stbd")[0])), dtype=np.float64)
            eb = np.array(b.nav_error(np.array(b.leg_coords(e, n, "stbd")[0])), dtype=np.float64)
            d.append(eb - ea)
    return np.mean(d, axis=0) if d else None


def _make_legs(rng: np.random.Generator, legs: int, leg_length_m: float, v: Variant = Variant()) -> list[_Leg]:
    dx = v.dx_m
    pings = int(round(leg_length_m / dx)) + 1
    dt = dx / SPEED_M_S
    out = []
    for k in range(legs):
        north = k % 2 == 0
        f = v.nav_scale  # the same draws, scaled: a poorer INS
        mag, ang = f * rng.uniform(0.4, 0.6), rng.uniform(0.0, 2 * np.pi)
        dmag, dang = f * rng.uniform(0.1, 0.3), rng.uniform(0.0, 2 * np.pi)
        wob = (float(f * rng.uniform(0.05, 0.15)), float(rng.uniform(60.0, 150.0)), float(rng.uniform(0.0, 2 * np.pi)))
        out.append(_Leg(index=k, heading_deg=0.0 if north else 180.0, start_e_m=k * LEG_SPACING_M,
                        start_n_m=0.0 if north else (pings - 1) * dx, pings=pings,
                        t0_s=EPOCH_S + k * ((pings - 1) * dt + TURN_S),
                        nav_offset_m=(float(mag * math.sin(ang)), float(mag * math.cos(ang))),
                        nav_drift_m_per_100m=(float(dmag * math.sin(dang)), float(dmag * math.cos(dang))),
                        nav_wobble=wob, dx_m=dx, max_range_m=v.max_range_m))
    return out


def _target(rng: np.random.Generator, shape: str, kind: str = "target") -> _Object:
    full_h = float(rng.uniform(0.3, 0.7))
    p: dict[str, float] = {}
    if shape == "cylinder":
        p.update(length_m=rng.uniform(0.8, 2.5), diameter_m=full_h)
        size, ext = p["length_m"], math.hypot(p["length_m"] / 2, full_h / 2)
    elif shape == "truncated_cone":
        b = rng.uniform(0.8, 1.6)
        p.update(base_diameter_m=b, top_diameter_m=b * rng.uniform(0.25, 0.6))
        size, ext = b, b / 2
    elif shape == "wedge":
        wb = rng.uniform(0.6, 1.2)
        p.update(length_m=rng.uniform(0.8, 2.5), base_width_m=wb, top_width_m=wb * rng.uniform(0.0, 0.5))
        size, ext = p["length_m"], math.hypot(p["length_m"] / 2, wb / 2)
    else:
        full_h = min(full_h, 0.6)
        p.update(base_diameter_m=rng.uniform(0.8, 1.6))
        size, ext = p["base_diameter_m"], p["base_diameter_m"] / 2
    burial = full_h * rng.uniform(0.1, 0.4) if rng.random() < 0.3 else 0.0
    p.update(full_height_m=full_h, burial_m=burial)
    return _Object(kind=kind, shape=shape, east_m=0.0, north_m=0.0, heading_deg=float(rng.uniform(0, 360)),
                   height_m=full_h - burial, size_m=float(size), reflectivity_db=float(rng.uniform(3.0, 15.0)),
                   extent_m=float(ext), params={k: float(v) for k, v in p.items()})


def _rock(rng: np.random.Generator, target_like: bool) -> _Object:
    if target_like:
        size, height, refl = rng.uniform(0.8, 2.5), rng.uniform(0.3, 0.7), rng.uniform(3.0, 15.0)
    else:
        size = math.exp(rng.uniform(math.log(0.3), math.log(3.0)))
        height, refl = float(np.clip(size * rng.uniform(0.15, 0.4), 0.06, 1.0)), rng.uniform(-2.0, 8.0)
    k = int(rng.integers(2, 6))
    r, a = size * 0.25 * np.sqrt(rng.random(k)), rng.uniform(0, 2 * np.pi, k)
    s_major = size * rng.uniform(0.12, 0.25, k)
    blobs = np.column_stack([r * np.cos(a), r * np.sin(a), s_major, s_major * rng.uniform(0.4, 1.0, k),
                             rng.uniform(0, np.pi, k), rng.uniform(0.5, 1.0, k)])
    ext = float(np.max(r + 3 * s_major))
    rock = _Object(kind="rock", shape="rock", east_m=0.0, north_m=0.0, heading_deg=0.0, height_m=float(height),
                   size_m=float(size), reflectivity_db=float(refl), extent_m=ext, blobs=blobs,
                   params={"target_like": float(target_like)})
    g = np.linspace(-ext, ext, 81)
    peak = float(rock.heights(g[None, :] + 0 * g[:, None], g[:, None] + 0 * g[None, :]).max())
    blobs[:, 5] *= height / peak  # so the rock's highest point is exactly its height
    return rock


class _Placer:
    """Random sequential placement keeping every object clear of the others."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.placed: list[_Object] = []

    def free(self, e: float, n: float, ext: float) -> bool:
        return all(math.hypot(e - o.east_m, n - o.north_m) >= max(MIN_SEPARATION_M, ext + o.extent_m + 0.3)
                   for o in self.placed)

    def place(self, obj: _Object, draw: Callable[[], tuple[float, float]], tries: int = 400) -> bool:
        for _ in range(tries):
            e, n = draw()
            if self.free(e, n, obj.extent_m):
                obj.east_m, obj.north_m = float(e), float(n)
                self.placed.append(obj)
                return True
        return False


def _populate(rng: np.random.Generator, legs: list[_Leg], leg_length_m: float,
              max_range_m: float = MAX_RANGE_M) -> list[_Object]:
    nl = len(legs)
    margin = min(8.0, leg_length_m / 5)
    e_max = LEG_SPACING_M * (nl - 1)
    pl = _Placer(rng)

    def north() -> float:
        return float(rng.uniform(margin, leg_length_m - margin))

    def interior() -> tuple[float, float]:  # seen by 2-3 legs: between two legs, off the nadir lines
        while True:
            e = float(rng.uniform(0.0, e_max))
            if all(abs(e - lg.start_e_m) >= NADIR_GAP_M + 1.0 for lg in legs):
                return e, north()

    def edge_gap() -> tuple[float, float]:  # the first or last leg's nadir gap: only one other leg sees it
        base = 0.0 if rng.random() < 0.5 else e_max
        return base + float(rng.uniform(-2.5, 2.5)), north()

    def outside() -> tuple[float, float]:  # beyond the first or last leg: one look
        d = float(rng.uniform(NADIR_GAP_M + 3.0, max_range_m - 5.0))
        return (-d if rng.random() < 0.5 else e_max + d), north()

    shapes = ["cylinder"] * 5 + ["truncated_cone"] * 4 + ["wedge"] * 4 + ["dome"] * 3
    rng.shuffle(shapes)
    for i, shape in enumerate(shapes):
        draw = edge_gap if i < 2 else outside if i == 2 else interior
        if not pl.place(_target(rng, shape), draw):
            raise ValueError(f"could not place target {i}: the scene is too small (leg_length_m={leg_length_m})")
    for i in range(int(rng.integers(4, 7))):
        obj = _target(rng, TARGET_SHAPES[int(rng.integers(len(TARGET_SHAPES)))], kind="one_leg")
        if not pl.place(obj, interior):
            raise ValueError(f"could not place one-leg object {i}: the scene is too small")
        seen = [lg.index for lg in legs if lg.covers(obj.east_m, obj.north_m)]
        obj.shown_on_leg = int(seen[int(rng.integers(len(seen)))])
    area_m2 = (e_max + 2 * max_range_m) * (leg_length_m - 2 * margin)
    n_rocks = max(40, min(int(rng.integers(40, 111)), int(area_m2 / 80.0)))
    for i in range(n_rocks):
        rock = _rock(rng, target_like=i < 10)
        ok = pl.place(rock, lambda: (float(rng.uniform(-max_range_m + 2, e_max + max_range_m - 2)), north()))
        if not ok and i < 40:
            raise ValueError(f"could not place rock {i}: the scene is too small")
    return pl.placed


# ----------------------------------------------------------------------------------------
# Rendering


NU_VARIATION = 0.15
"""nu(e, n) = nu * exp(NU_VARIATION * S(e, n)), S a slow unit-variance field."""


def _render_side(leg: _Leg, side: str, rows: np.ndarray, objects: list[_Object], seabed: _Seabed,
                 altitude_m: np.ndarray, nu: float, nu_field: Callable, rng: np.random.Generator,
                 v: Variant = Variant()) -> np.ndarray:
    """Intensity (rows, cols) of one side of the pings ``rows`` of ``leg``, float32, NaN in the nadir gap."""
    dr, dx = v.dr_m, v.dx_m
    r = dr * np.arange(int(round(v.max_range_m / dr)) + 1)
    along = rows * dx
    su = leg.side_unit(side)
    pe = leg.start_e_m + along * leg.along[0]
    pn = leg.start_n_m + along * leg.along[1]
    e = pe[:, None] + r[None, :] * su[0]
    n = pn[:, None] + r[None, :] * su[1]
    height = seabed.height(e, n)
    refl = seabed.reflectivity(e, n)
    for o in objects:  # local height patches on the ground-range samples
        a_o, c_o = leg.leg_coords(o.east_m, o.north_m, side)
        i0 = max(int(math.floor((a_o - o.extent_m - along[0]) / dx)), 0)
        i1 = min(int(math.ceil((a_o + o.extent_m - along[0]) / dx)) + 1, rows.size)
        j0 = max(int(math.floor((c_o - o.extent_m) / dr)), 0)
        j1 = min(int(math.ceil((c_o + o.extent_m) / dr)) + 1, r.size)
        if i0 >= i1 or j0 >= j1:
            continue
        sl = (slice(i0, i1), slice(j0, j1))
        z = o.heights(e[sl], n[sl])
        height[sl] += z
        refl[sl] = np.where(z > 0.005, 10.0 ** (o.reflectivity_db / 10.0), refl[sl])
    h = altitude_m[:, None]
    r_safe = np.maximum(r, 0.5 * dr)[None, :]
    # Lit iff the depression slope to the point is no steeper than to any nearer sample.
    slope = (h - height) / r_safe
    lit = slope <= np.minimum.accumulate(slope, axis=1)
    # Lambert's law on the local incidence from the slope along range, over a flat bed's.
    g = np.gradient(height, dr, axis=1)
    dz = h - height
    cos_loc = np.clip((dz + r_safe * g) / (np.hypot(r_safe, dz) * np.sqrt(1.0 + g * g)), 0.0, None)
    cos_flat = h / np.hypot(r_safe, h)
    mean = LEVEL * refl * (cos_loc / cos_flat) ** 2 * _gain(r, v.max_range_m)[None, :] * lit
    nu_px = nu * np.exp(NU_VARIATION * nu_field(e, n))
    k = k_intensity_correlated(mean, nu_px, rng, texture_px=(v.texture_m / dx, v.texture_m / dr),
                               speckle_px=v.speckle_px)
    px = k + NOISE_FLOOR * LEVEL * rng.exponential(1.0, mean.shape)
    px[:, r < NADIR_GAP_M] = np.nan
    return px.astype(np.float32)


def to_byte_amplitude(px: np.ndarray, full_scale: float) -> np.ndarray:
    """Intensity ``px`` as an 8-bit recorder stores it: amplitude ``sqrt(px / full_scale)`` on
    0-255, rounded, clipped at 255 (full scale) and raised to 1 (0 means no data on the wire);
    NaN (no data) stays NaN. Float32 pixels holding the integers the ``uint8`` wire sends."""
    with np.errstate(invalid="ignore"):
        a = np.rint(255.0 * np.sqrt(np.asarray(px, dtype=np.float64) / float(full_scale)))
    return np.where(np.isnan(a), np.nan, np.clip(a, 1.0, 255.0)).astype(np.float32)


# ----------------------------------------------------------------------------------------
# The scene


def _rng(seed: int, seabed: str) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), SEABEDS.index(seabed), 17]))


def _g(x: Any) -> str:
    """A number, or a pair of numbers as ``a-b``, for help texts."""
    return "-".join(f"{v:g}" for v in x) if isinstance(x, tuple) else f"{x:g}"


def _r(x: float, nd: int = 6) -> float:
    return float(round(float(x), nd))


def generate_scene(out_dir: str | os.PathLike[str], *, seabed: str, seed: int, legs: int = 5,
                   leg_length_m: float = 200.0, progress: Progress | None = None,
                   textures_dir: str | os.PathLike[str] | None = None, variant: str = "base") -> HeldoutScene:
    """Render one held-out lawnmower mission into ``out_dir``.

    Parameters
    ----------
    out_dir
        Folder (made if missing) that receives ``mission.atrlog``, ``truth.csv`` (targets),
        ``clutter.csv`` (rocks), ``one_leg.csv`` (objects imaged on one leg only) and
        ``scene.json`` (every parameter, the seed, per-leg nav offsets, generator version).
        Each is written under a hidden temporary name beside its final one
        (:func:`~atr_node.io.atomic.atomic_path`) and renamed when the scene is complete,
        ``scene.json`` last: a failed or interrupted run leaves the folder as it was (without
        its old ``scene.json`` if the renames had begun), never a half-written file; only a
        killed process leaves its temporary files behind.
    seabed
        One of :data:`SEABEDS`.
    seed
        The same (seabed, seed) and sizes give byte-identical files.
    legs, leg_length_m
        Lawnmower legs, 40 m apart, alternately north and south; at least 2 legs of 30 m.
    progress
        Called as ``progress(tiles_done, tiles_total)`` after every tile pair.
    textures_dir
        Folder of SAS texture PNGs for ``seabed="sassed"``; default ``$ATR_SAS_TEXTURES`` or
        ``shared/data/real/sas_textures`` beside the repository.
    variant
        A name of :data:`VARIANTS`: ``base`` (the benchmark's scenes) or a stress variant of
        the same seed (other pixel size, seabed statistics, altitude and range).

    Raises
    ------
    ValueError
        A bad argument, or a scene too small to hold its objects.
    FileNotFoundError
        ``seabed="sassed"`` and the texture folder is missing.
    """
    if seabed not in SEABEDS:
        raise ValueError(f"seabed must be one of {', '.join(SEABEDS)}, got {seabed!r}")
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if not isinstance(legs, (int, np.integer)) or not 2 <= legs <= 200:
        raise ValueError(f"legs must be an integer in [2, 200], got {legs!r}")
    if not (math.isfinite(leg_length_m) and 30.0 <= leg_length_m <= 20000.0):
        raise ValueError(f"leg_length_m must be in [30, 20000], got {leg_length_m!r}")
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {', '.join(VARIANTS)}, got {variant!r}")
    v = VARIANTS[variant]
    # an 8-bit recorder's full scale (intensity), from draws of its own: the scene's other
    # draws, and so its seabed, objects and speckle, stay those of the base scene
    byte_db = (None if v.byte_headroom_db is None else
               float(np.random.default_rng(np.random.SeedSequence([int(seed), SEABEDS.index(seabed), 23]))
                     .uniform(*v.byte_headroom_db)))
    tex_dir = Path(textures_dir) if textures_dir is not None else default_textures_dir()
    rng = _rng(seed, seabed)
    lines = _make_legs(rng, int(legs), float(leg_length_m), v)
    e_max = LEG_SPACING_M * (legs - 1)
    box = (-v.max_range_m - 5.0, e_max + v.max_range_m + 5.0, -5.0, leg_length_m + 5.0)
    bed = _Seabed(seabed, rng, tex_dir, box)
    nu = float(math.exp(rng.uniform(math.log(v.nu_range[0]), math.log(v.nu_range[1]))))
    nu_field = _slow_field(rng, 4, (30.0, 90.0))
    swell_period_s, swell_phase = float(rng.uniform(40.0, 90.0)), float(rng.uniform(0.0, 2 * np.pi))
    objects = _populate(rng, lines, float(leg_length_m), v.max_range_m)
    dropouts = {lg.index: sorted({int(p0 + d) for p0, w in zip(rng.integers(0, lg.pings - 3, int(rng.integers(3, 7))),
                                                              rng.integers(1, 4, 7)) for d in range(int(w))})
                for lg in lines}

    final = Path(out_dir)
    if final.exists() and not final.is_dir():
        raise ValueError(f"{final} exists and is not a folder")
    made = not final.exists()
    final.mkdir(parents=True, exist_ok=True)
    # every file is written under a hidden temporary name in the scene's folder (atomic_path: on
    # its file system, so the moves are renames) and renamed into place when the whole scene is
    # done, scene.json last (entered first, left last): an interrupted or failed run leaves no
    # half-written scene, and a reader that sees scene.json sees the rest whole
    atrlog, truth, clutter, one_leg_csv, scene_json = (final / f for f in SCENE_FILES)
    try:
        with contextlib.ExitStack() as stack:
            tmp = {p: stack.enter_context(atomic_path(p)) for p in (scene_json, atrlog, truth, clutter, one_leg_csv)}
            name = f"heldout-{seabed}-{seed}" + ("" if v.name == "base" else f"-{v.name}")
            frame = MissionFrame("ltp", ORIGIN_LAT_DEG, ORIGIN_LON_DEG)
            dt = v.dx_m / SPEED_M_S
            tile_pings = v.tile_pings
            seq = {"port": 0, "stbd": 0}
            total = sum(-(-lg.pings // tile_pings) for lg in lines)
            done = 0
            with AtrLogWriter(tmp[atrlog], flush_every=64) as writer:
                for lg in lines:
                    shown = [o for o in objects if o.shown_on_leg in (None, lg.index)]
                    drop = np.array(dropouts[lg.index], dtype=np.int64)
                    for row0 in range(0, lg.pings, tile_pings):
                        rows = np.arange(row0, min(row0 + tile_pings, lg.pings), dtype=np.float64)
                        t = lg.t0_s + rows * dt
                        alt = v.altitude_m + SWELL_M * np.sin(2 * np.pi * (t - EPOCH_S) / swell_period_s + swell_phase)
                        along = rows * v.dx_m
                        ee, en = lg.nav_error(along)
                        lat, lon = frame.to_latlon(lg.start_e_m + along * lg.along[0] + ee,
                                                   lg.start_n_m + along * lg.along[1] + en)
                        nav = TileNav(lat_deg=lat, lon_deg=lon, heading_deg=np.full(rows.size, lg.heading_deg % 360.0),
                                      altitude_m=alt)
                        lost = drop[(drop >= row0) & (drop < row0 + rows.size)] - row0
                        for j, side in enumerate(("port", "stbd")):
                            px = _render_side(lg, side, rows, shown, bed, alt, nu, nu_field, rng, v)
                            px[lost] = np.nan
                            if byte_db is None:
                                kind, wire = "intensity", "float32"
                            else:
                                px = to_byte_amplitude(px, LEVEL * 10.0 ** (byte_db / 10.0))
                                kind, wire = "amplitude", "uint8"
                            tile = Tile(mission=name, leg=lg.index, side=side, seq=seq[side], pixels=px, kind=kind,
                                        range0_m=0.0, dr_m=v.dr_m, dx_m=v.dx_m, slant=False, ping_time=t, nav=nav,
                                        sensor=SENSOR, wire_dtype=wire)
                            seq[side] += 1
                            writer.write(float(t[-1]) + TILE_LATENCY_S + 0.01 * j, "sonar", tile.to_map())
                        done += 1
                        if progress is not None:
                            progress(done, total)

            targets = [o for o in objects if o.kind == "target"]
            rocks = [o for o in objects if o.kind == "rock"]
            one_leg = [o for o in objects if o.kind == "one_leg"]
            _write_csv(tmp[truth], targets, lines, frame, ["burial_m", "size_m", "heading_deg"])
            _write_csv(tmp[clutter], rocks, lines, frame, ["size_m", "target_like"])
            _write_csv(tmp[one_leg_csv], one_leg, lines, frame, ["size_m"],
                       first=["lat_deg", "lon_deg", "shape", "shown_on_leg", "covered_by_legs"])
            scene = {
                "generator": "atr_node.evaluation.heldout", "generator_version": GENERATOR_VERSION,
                "use": "evaluation only: never calibrate on it or choose a setting with it",
                "mission": name, "seabed": bed.info, "seed": int(seed), "legs": int(legs), "leg_length_m": _r(leg_length_m),
                "frame": frame.to_dict(), "leg_spacing_m": LEG_SPACING_M, "nadir_gap_m": NADIR_GAP_M,
                "max_range_m": v.max_range_m, "dr_m": v.dr_m, "dx_m": v.dx_m, "tile_pings": tile_pings,
                "speed_m_s": SPEED_M_S, "altitude_m": v.altitude_m, "swell_m": SWELL_M,
                "swell_period_s": _r(swell_period_s), "swell_phase_rad": _r(swell_phase),
                "speckle": {"model": "K: mean * Gamma(nu, 1/nu) * Exp(1)" if not (v.texture_m or v.speckle_px) else
                            "K: mean * Gamma(nu, 1/nu) (copula, correlated over texture_m) * |c|^2 (smoothed over "
                            "speckle_px, mean 1)", "nu": _r(nu), "nu_variation": NU_VARIATION},
                "level": LEVEL, "noise_floor": NOISE_FLOOR,
                "gain": f"(0.55 + 0.45 min(r/15, 1)) (1 - 0.4 (r/{v.max_range_m:g})^2), times (cos t_loc / cos t_flat)^2",
                "sensor": {k: getattr(SENSOR, k) for k in ("frequency_hz", "bandwidth_hz", "tx_length_m", "rx_length_m",
                                                          "n_rx", "sas")},
                "per_leg": [{"leg": lg.index, "heading_deg": lg.heading_deg, "start_east_m": _r(lg.start_e_m),
                             "start_north_m": _r(lg.start_n_m), "pings": lg.pings, "t0_s": _r(lg.t0_s),
                             "nav_offset_east_m": _r(lg.nav_offset_m[0]), "nav_offset_north_m": _r(lg.nav_offset_m[1]),
                             "nav_drift_east_m_per_100m": _r(lg.nav_drift_m_per_100m[0]),
                             "nav_drift_north_m_per_100m": _r(lg.nav_drift_m_per_100m[1]),
                             "nav_wobble_m": _r(lg.nav_wobble[0]), "nav_wobble_wavelength_m": _r(lg.nav_wobble[1]),
                             "nav_wobble_phase_rad": _r(lg.nav_wobble[2]),
                             "dropout_pings": dropouts[lg.index]} for lg in lines],
                "counts": {"tiles": 2 * total, "targets": len(targets), "rocks": len(rocks),
                           "rocks_target_like": sum(1 for o in rocks if o.params["target_like"]), "one_leg": len(one_leg)},
            }
            if v.name != "base":  # the base scenes' scene.json stays as it was
                scene["variant"] = v.info()
            if byte_db is not None:
                scene["recorder"] = {"samples": "amplitude, uint8, 0 = no data", "headroom_db": _r(byte_db),
                                     "full_scale_intensity": _r(LEVEL * 10.0 ** (byte_db / 10.0)),
                                     "rule": "round(255 sqrt(I / full_scale)), clipped to 1-255"}
            tmp[scene_json].write_text(json.dumps(scene, indent=1, sort_keys=True) + "\n")
            scene_json.unlink(missing_ok=True)  # an older scene there: never half old, half new
    except BaseException:
        if made:
            with contextlib.suppress(OSError):
                final.rmdir()  # the folder this call made, if nothing else is in it
        raise
    return HeldoutScene(out_dir=final, atrlog=atrlog, truth=truth, clutter=clutter, one_leg=one_leg_csv,
                        scene_json=scene_json, seabed=seabed, seed=int(seed), legs=int(legs),
                        tiles=2 * total, targets=len(targets), rocks=len(rocks), one_leg_objects=len(one_leg),
                        nu=_r(nu))


def _write_csv(path: Path, objs: list[_Object], legs: list[_Leg], frame: MissionFrame, extra: list[str],
               first: Sequence[str] = ("lat_deg", "lon_deg", "shape")) -> None:
    """CSV of objects: true positions, then ``east_m,north_m,height_m,reflectivity_db,looks,
    seen_by_legs`` (legs whose swath, 5 m to the maximum range, covers the object, joined by ';')
    and ``extra``."""
    cols = list(first) + [c for c in ["east_m", "north_m", "height_m", "reflectivity_db", "looks", "seen_by_legs"]
                          + extra if c not in first]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(cols)
        for o in objs:
            lat, lon = frame.to_latlon(o.east_m, o.north_m)
            seen = [lg.index for lg in legs if lg.covers(o.east_m, o.north_m)]
            vals: dict[str, Any] = {
                "lat_deg": f"{float(lat):.9f}", "lon_deg": f"{float(lon):.9f}", "shape": o.shape,
                "east_m": f"{o.east_m:.3f}", "north_m": f"{o.north_m:.3f}", "height_m": f"{o.height_m:.3f}",
                "reflectivity_db": f"{o.reflectivity_db:.2f}", "looks": len(seen),
                "seen_by_legs": ";".join(map(str, seen)), "size_m": f"{o.size_m:.3f}",
                "heading_deg": f"{o.heading_deg:.1f}", "burial_m": f"{o.params.get('burial_m', 0.0):.3f}",
                "target_like": int(o.params.get("target_like", 0.0)), "shown_on_leg": o.shown_on_leg,
                "covered_by_legs": ";".join(str(k) for k in seen if k != o.shown_on_leg),
            }
            w.writerow([vals[c] for c in cols])


# ----------------------------------------------------------------------------------------
# Command line


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m atr_node.evaluation.heldout OUT --seabed sand --seed 101``.

    Exit codes: 0 written, 1 bad input (a scene too small, textures missing), 2 usage.
    """
    ap = argparse.ArgumentParser(
        prog="python -m atr_node.evaluation.heldout",
        description="Write a held-out evaluation scene (mission.atrlog, truth.csv, clutter.csv, one_leg.csv, "
                    "scene.json) rendered independently of atr_node.simulation. For evaluation only: never "
                    "calibrate on it or choose a setting with it.")
    ap.add_argument("out", help="output folder (made if missing; its scene files are overwritten)")
    ap.add_argument("--seabed", required=True, choices=SEABEDS)
    ap.add_argument("--seed", required=True, type=int)
    ap.add_argument("--legs", type=int, default=5, help="lawnmower legs, 40 m apart (default 5)")
    ap.add_argument("--leg-length-m", type=float, default=200.0, help="length of each leg (default 200)")
    ap.add_argument("--textures", default=None, help=f"SAS texture folder for --seabed sassed (default ${TEXTURES_ENV} "
                                                     f"or {default_textures_dir()})")
    ap.add_argument("--variant", default="base", choices=list(VARIANTS),
                    help="base (default: the benchmark's scenes) or a stress variant of the same seed: "
                         + "; ".join(f"{v.name}: " + ", ".join(f"{k} {_g(x)}" for k, x in vars(v).items()
                                                                if k != "name" and x != getattr(Variant(), k))
                                     for v in VARIANTS.values() if v.name != "base"))
    ap.add_argument("--quiet", action="store_true", help="no progress line")
    args = ap.parse_args(argv)

    def show(done: int, total: int) -> None:
        print(f"\rtiles {2 * done}/{2 * total}", end="" if done < total else "\n", file=sys.stderr, flush=True)
    try:
        sc = generate_scene(args.out, seabed=args.seabed, seed=args.seed, legs=args.legs,
                            leg_length_m=args.leg_length_m, progress=None if args.quiet else show,
                            textures_dir=args.textures, variant=args.variant)
    except (ValueError, OSError) as exc:
        print(f"heldout: error: {exc}", file=sys.stderr)
        return 1
    print(f"{sc.out_dir}: {sc.tiles} tiles, {sc.targets} targets, {sc.rocks} rocks, {sc.one_leg_objects} one-leg "
          f"objects, nu {sc.nu:g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
