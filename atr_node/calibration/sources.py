"""Target-free images to calibrate on: recordings, seabed pictures or synthetic seabeds.

- ``.atrlog``, ``.xtf`` and ``.jsf`` recordings: their sonar tiles (ICD section 1), slant tiles
  put on ground range at their nav altitude, amplitude squared into intensity as the node
  scores it.
- ``.png`` (or any 8-bit picture OpenCV reads): display amplitude a in [0, 255]; intensity
  (a / 255)^2, pixel size and first range given by the caller (the SASSED crops of
  ``shared/data/real/sas_textures`` state no pixel size).
- Synthetic seabeds (:func:`synthetic_seabed`): fully developed speckle (exponential
  intensity, i.e. Rayleigh amplitude) over a seabed texture: a log-normal patchiness field
  for mud and silt, sand ripples for sand, stronger patchiness and ripples for gravel and rock;
  the mean falls gently with range (residual of an imperfect gain curve).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..errors import AtrError
from .responses import CalibrationImage

# (log-std of patchiness, patch size m, ripple depth, ripple wavelength m)
_SEABEDS: dict[str, tuple[float, float, float, float]] = {
    "mud": (0.15, 4.0, 0.0, 1.0),
    "silt": (0.25, 3.0, 0.0, 1.0),
    "sand": (0.2, 3.0, 0.35, 0.8),
    "gravel": (0.35, 1.5, 0.2, 1.2),
    "rock": (0.6, 1.0, 0.1, 1.5),
}


def synthetic_seabed(rows: int, cols: int, *, range0_m: float, dr_m: float, dx_m: float, seabed: str,
                     rng: np.random.Generator) -> np.ndarray:
    """A target-free ground-range intensity image, float32 (rows, cols), all valid.

    ``intensity = g(r) * texture(x, r) * speckle``, speckle ~ Exp(1), texture = exp(s F) with F
    a smoothed unit-variance Gaussian field (patch size ``l``) times ``1 + d sin(2 pi u / lambda)``
    ripples at a random angle, ``g(r) = (r_mid / r)^0.5``.
    """
    import cv2

    try:
        s, patch_m, depth, wavelength_m = _SEABEDS[seabed]
    except KeyError:
        raise AtrError(f"unknown seabed {seabed!r}; expected one of {sorted(_SEABEDS)}") from None
    if rows < 1 or cols < 1:
        raise AtrError(f"synthetic seabed: rows and cols must be >= 1, got {rows} x {cols}")
    field = rng.standard_normal((rows, cols)).astype(np.float32)
    sig_r, sig_c = max(patch_m / dx_m, 0.5), max(patch_m / dr_m, 0.5)
    field = cv2.GaussianBlur(field, (0, 0), sigmaX=sig_c, sigmaY=sig_r, borderType=cv2.BORDER_REFLECT)
    field /= max(float(field.std()), 1e-12)
    tex = np.exp(s * field - 0.5 * s * s)
    if depth > 0:
        ang = rng.uniform(0.0, np.pi)
        y = (np.arange(rows, dtype=np.float32) * dx_m)[:, None]
        x = (np.arange(cols, dtype=np.float32) * dr_m)[None, :]
        phase = (2.0 * np.pi / wavelength_m) * (np.cos(ang) * y + np.sin(ang) * x)
        tex *= 1.0 + depth * np.sin(phase)
    r = range0_m + dr_m * np.arange(cols)
    g = np.sqrt(r.mean() / np.maximum(r, dr_m)).astype(np.float32)
    speckle = rng.exponential(1.0, size=(rows, cols)).astype(np.float32)
    return (tex * speckle * g[None, :]).astype(np.float32)


def synthetic_images(n: int, *, settings: Any, rows: int, cols: int, seed: int, seabed: str,
                     range0_m: float | None = None) -> list[CalibrationImage]:
    """``n`` synthetic seabed images at the sensor's spacing and nominal altitude; image k from
    the random stream ``(seed, 1000 + k)``."""
    sen = settings.sensor
    r0 = 2.0 * sen.altitude_m if range0_m is None else float(range0_m)
    out = []
    for k in range(int(n)):
        rng = np.random.default_rng([seed, 1000 + k])
        px = synthetic_seabed(rows, cols, range0_m=r0, dr_m=sen.dr_m, dx_m=sen.dx_m, seabed=seabed, rng=rng)
        out.append(CalibrationImage(px, r0, sen.dr_m, sen.dx_m, sen.altitude_m, name=f"synthetic-{seabed}-{seed}-{k}"))
    return out


def images_from_recording(path: str | Path, *, settings: Any, max_images: int, crs: str = "") -> list[CalibrationImage]:
    """The first ``max_images`` sonar tiles of a recording (``.atrlog``, ``.xtf`` or ``.jsf``,
    read as replay reads it: :func:`atr_node.io.recording.open_recording`, positions in ``crs``
    if projected metres)."""
    from ..io.recording import open_recording
    from ..records.tile import Tile

    rec_s = settings.recording
    records = open_recording(path, crs=crs, altitude=rec_s.altitude, frequency=rec_s.frequency)
    out: list[CalibrationImage] = []
    for rec in records:
        if rec.link != "sonar":
            continue
        tile = Tile.from_map(rec.msg)
        out.append(CalibrationImage.from_tile(tile, altitude_m=settings.sensor.altitude_m))
        if len(out) >= max_images:
            break
    if not out:
        raise AtrError(f"{path}: no sonar tile in this recording")
    return out


def image_from_picture(path: str | Path, *, pixel_m: float, range0_m: float, altitude_m: float) -> CalibrationImage:
    """An 8-bit picture as a ground-range intensity image (rows = along-track)."""
    import cv2

    a = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if a is None:
        raise AtrError(f"{path}: not a picture OpenCV can read")
    px = (a.astype(np.float32) / 255.0) ** 2
    # white (255) is as bright as the picture goes: an injected echo clips there, intensity 1
    return CalibrationImage(px, float(range0_m), float(pixel_m), float(pixel_m), float(altitude_m), name=Path(path).name,
                            full_scale=1.0)


def images_from_paths(paths: Sequence[str | Path], *, settings: Any, max_images: int, pixel_m: float | None,
                      range0_m: float | None, crs: str = "") -> list[CalibrationImage]:
    """Images from recordings (``.atrlog``, ``.xtf``, ``.jsf``; ``crs`` of positions in
    projected metres, ``--crs``) and pictures (anything else OpenCV reads)."""
    sen = settings.sensor
    out: list[CalibrationImage] = []
    for p in paths:
        p = Path(p)
        if not p.exists():
            raise AtrError(f"{p}: no such file")
        if p.suffix.lower() in (".atrlog", ".xtf", ".jsf"):
            out.extend(images_from_recording(p, settings=settings, max_images=max_images, crs=crs))
        else:
            out.append(image_from_picture(p, pixel_m=pixel_m or sen.dr_m,
                                          range0_m=2.0 * sen.altitude_m if range0_m is None else range0_m,
                                          altitude_m=sen.altitude_m))
    return out
