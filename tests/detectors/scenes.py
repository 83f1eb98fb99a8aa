"""Small scenes for the detector tests: Rayleigh seabed, planted targets, NaN regions."""

from __future__ import annotations

import numpy as np

from atr_node.config import TemplateSettings

# A small template so windows of every size fit in tiles of a few dozen pixels, with a shadow
# that grows from shadow_min to shadow_max across the tile (S = h r / (H - h), H = 3, h = 0.5).
SMALL = TemplateSettings(length_m=0.6, echo_width_m=0.3, height_m=0.5, shadow_min_m=0.3,
                         shadow_max_m=1.0, context_factor=2.0)
GEOM = dict(range0_m=1.0, dr_m=0.1, dx_m=0.1, altitude_m=3.0)


def rayleigh(rng: np.random.Generator, rows: int, cols: int, scale: float = 1.0) -> np.ndarray:
    return rng.rayleigh(scale, size=(rows, cols)).astype(np.float32)


def plant(img: np.ndarray, row: int, col: int, *, echo_cols: int, shadow_cols: int, length: int,
          echo: float = 6.0, shadow: float = 0.05) -> None:
    """A proud target whose anchor (echo/shadow boundary, along-track centre) is (row, col)."""
    r0 = row - length // 2
    img[r0:r0 + length, col - echo_cols:col] *= echo
    img[r0:r0 + length, col:col + shadow_cols] *= shadow


def structured(rng: np.random.Generator, rows: int = 40, cols: int = 60) -> np.ndarray:
    """Rayleigh seabed with a range-varying gain, two targets, a shadow band and NaN regions."""
    img = rayleigh(rng, rows, cols) * np.linspace(2.0, 0.5, cols, dtype=np.float32)
    plant(img, 12, 20, echo_cols=3, shadow_cols=5, length=6)
    plant(img, 28, 45, echo_cols=3, shadow_cols=8, length=6)
    img[20:26, 5:50] *= 0.1          # a long shadow band
    img[:, :3] = np.nan               # nadir gap
    img[30:37, 8:16] = np.nan         # a drop-out block
    img[rng.random(img.shape) < 0.03] = np.nan
    return img
