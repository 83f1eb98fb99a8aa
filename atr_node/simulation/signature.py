"""From proportion maps to pixels: SAS beam, gray levels, speckle and blending (SPEC section 4).

The ray tracer gives, per pixel, the hidden fraction ``p_shadow`` and the echo strength ``e``
(:class:`~.raytrace.Signature`). This module turns them into pixels of a host image:

1. **Along-track beam.** Both maps are convolved along-track with the beam of the sensor at
   the target's range: a receive array of ``n_rx`` elements over ``L_R``, focused at range
   r, simulated as ``n_rx * Q_SAS`` elements, ``Q_SAS = 2 lambda r / (L_T L_R)`` (at least
   1), i.e. an aperture ``Q_SAS L_R``: along-track resolution ``L_T / 2`` at every range for
   SAS, ``lambda r / L_R`` for a real aperture. The array factor is integrated over each
   pixel, so a beam narrower than a pixel leaves the maps nearly unchanged.
2. **Gray levels.** ``g(r)`` = mean intensity of the host image at range r (its background
   curve, smoothed over range). Shadow intensity = ``rho_shadow(r) g(r)``; echo intensity =
   ``rho_echo(r) e g(r)``: contrast ratios are the acoustic ones whatever the image's gain.
3. **Speckle and blending**, in intensity: exponential speckle (Rayleigh in amplitude) at the
   shadow level and at the echo level;
   ``out = p_seabed * host + p_shadow * shadow + echo``. Amplitude images are squared
   first and square-rooted after. NaN (no data) pixels stay NaN.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..config import SensorSettings
from .performance import q_sas
from .raytrace import Signature


def along_track_kernel(range_m: float, *, dx_m: float, sensor: SensorSettings, oversample: int = 16) -> np.ndarray:
    """Along-track intensity beam pattern at ``range_m``, integrated over pixels, summing to 1.

    Parameters
    ----------
    range_m
        Range of the target (m).
    dx_m
        Ping spacing (m).
    sensor
        ``tx_length_m``, ``rx_length_m``, ``n_rx``, ``sas``, ``frequency_hz``, ``sound_speed_m_s``.

    Returns
    -------
    ndarray, shape (2 h + 1,)
        Odd-length kernel over pixels -h .. h, covering the main lobe and the first side lobes.
    """
    lam = sensor.sound_speed_m_s / sensor.frequency_hz
    r = max(float(range_m), 1e-3)
    q = float(q_sas(r, wavelength_m=lam, tx_length_m=sensor.tx_length_m, rx_length_m=sensor.rx_length_m)) \
        if sensor.sas else 1.0
    n = max(int(round(sensor.n_rx * q)), 1)          # elements of the (synthetic) array
    d = sensor.rx_length_m / sensor.n_rx              # element spacing
    x_null = lam * r / (n * d)                        # first null of the array factor (m)
    h = max(int(math.ceil(3.0 * x_null / dx_m)), 1)
    x = (np.arange((2 * h + 1) * oversample) + 0.5) / oversample - (h + 0.5)   # pixel units
    s = np.sin(np.arctan2(x * dx_m, r))
    psi = np.pi * d * s / lam
    with np.errstate(invalid="ignore", divide="ignore"):
        af = np.where(np.abs(np.sin(psi)) < 1e-12, 1.0, np.sin(n * psi) / (n * np.sin(psi)))
    k = (af ** 2).reshape(2 * h + 1, oversample).mean(axis=1)
    return k / k.sum()


def blurred_footprint(footprint: tuple[int, int, int, int], kernel: np.ndarray, rows: int
                      ) -> tuple[int, int, int, int]:
    """The footprint :func:`blur_along_track` gives a signature of ``footprint`` (non-empty)."""
    r0, r1, c0, c1 = footprint
    if kernel.size == 1:
        return footprint
    h = kernel.size // 2
    return max(r0 - h, 0), min(r1 + h, rows), c0, c1


def blur_along_track(sig: Signature, kernel: np.ndarray, rows: int) -> Signature:
    """Convolve a signature's maps along-track (rows) with ``kernel``, growing the window by
    the kernel's half-length (clipped to the tile's ``rows``)."""
    if sig.empty or kernel.size == 1:
        return sig
    h = kernel.size // 2
    r0 = max(sig.row0 - h, 0)
    r1 = min(sig.row0 + sig.shape[0] + h, rows)
    pad_top, pad_bot = sig.row0 - r0, r1 - (sig.row0 + sig.shape[0])
    k2 = kernel.reshape(-1, 1).astype(np.float32)

    def conv(a: np.ndarray) -> np.ndarray:
        padded = np.zeros((pad_top + a.shape[0] + pad_bot, a.shape[1]), dtype=a.dtype)
        padded[pad_top:pad_top + a.shape[0]] = a
        return cv2.filter2D(padded, cv2.CV_32F, k2, borderType=cv2.BORDER_CONSTANT)

    return Signature(r0, sig.col0, np.clip(conv(sig.p_shadow), 0.0, 1.0), np.maximum(conv(sig.echo), 0.0))


def background_curve(intensity: np.ndarray, *, smooth_cols: int = 31) -> np.ndarray:
    """Mean intensity per column (range), NaN-aware, smoothed over ``smooth_cols`` columns.

    Parameters
    ----------
    intensity : ndarray, shape (rows, cols)
        Linear intensity, NaN = no data.

    Returns
    -------
    ndarray, shape (cols,), float64
        g(r); NaN for columns with no data within the smoothing window.
    """
    a = np.asarray(intensity, dtype=np.float64)
    valid = ~np.isnan(a)
    s = np.where(valid, a, 0.0).sum(axis=0)
    n = valid.sum(axis=0).astype(np.float64)
    if smooth_cols > 1:
        box = np.ones(int(smooth_cols))
        s = np.convolve(s, box, mode="same")
        n = np.convolve(n, box, mode="same")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, s / np.maximum(n, 1), np.nan)


def draw_speckle(rng: np.random.Generator, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The speckle :func:`render` draws for a signature of ``shape``: unit exponentials for the
    shadow, then for the echo (the order fixes a seed's pixels)."""
    return rng.exponential(1.0, shape), rng.exponential(1.0, shape)


def render(host: np.ndarray, sig: Signature, *, g: np.ndarray, rho_shadow: np.ndarray, rho_echo: np.ndarray,
           rng: np.random.Generator | None, kind: str = "intensity",
           speckle: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Blend a signature into ``host`` in place and return the modified window.

    Parameters
    ----------
    host : ndarray, shape (rows, cols), float32
        The whole tile (modified in place inside the signature's window).
    sig
        Proportion maps (after the along-track beam).
    g, rho_shadow, rho_echo : ndarray, shape (cols,)
        Background intensity curve and the model's intensity ratios, per tile column.
    kind
        ``"intensity"`` or ``"amplitude"`` (then the blend is done on squared pixels).
    speckle
        The unit exponential speckle of the shadow and of the echo, of the signature's shape,
        drawn by the caller (:func:`draw_speckle`); None: drawn here from ``rng``.
    """
    if sig.empty:
        return host[0:0, 0:0]
    r0, r1, c0, c1 = sig.footprint
    win = host[r0:r1, c0:c1]
    h = win.astype(np.float64)
    if kind == "amplitude":
        h = h * h
    gw = g[c0:c1][None, :]
    shadow_mean = rho_shadow[c0:c1][None, :] * gw
    echo_mean = rho_echo[c0:c1][None, :] * sig.echo * gw
    s_shadow, s_echo = speckle if speckle is not None else draw_speckle(rng, sig.shape)
    shadow = s_shadow * shadow_mean
    echo = s_echo * echo_mean
    out = sig.p_seabed * h + sig.p_shadow * shadow + echo
    if kind == "amplitude":
        out = np.sqrt(out)
    # No data stays no data; columns with no background curve are left as they were.
    keep = np.isnan(win) | ~np.isfinite(gw)
    out = np.where(keep, win, out).astype(np.float32)
    host[r0:r1, c0:c1] = out
    return out
