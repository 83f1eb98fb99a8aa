"""Sonar altitude from the first seabed return of slant-range pings (bottom tracking).

Side-scan recordings carry the altitude of a separate altimeter (a DVL beam, an echo sounder),
mounted elsewhere on the vehicle and sometimes pointing through a pitched hull. Slant-to-ground
conversion (SPEC section 0, ``r = sqrt(R^2 - H^2)``) needs the altitude of the side-scan
transducers themselves: when the two differ by dH, the water column between them lands on the
ground axis as a dark band of width about ``sqrt(2 H dH)`` next to the nadir, which looks like
a shadow to the detectors. The first seabed return in the pings measures that altitude
directly, as every side-scan processing package does.

Per ping and side: amplitude smoothed over ``smooth_m`` of range; threshold = ``fraction`` x
the median of the ping's outer half (the seabed level); the first return is the first sample
at or above the threshold after at least one sample below it (so the transmit ring-down at
the start of the ping is passed over). The altitude of a ping is the larger of the two sides'
first-return ranges (a proud object near the nadir on one side returns early; the seabed on
the other does not), then a running median over ``median_pings`` pings removes outliers.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage as ndi

from ..records.tile import Tile


def first_return_m(tile: Tile, *, fraction: float = 0.3, smooth_m: float = 0.15) -> np.ndarray:
    """Slant range of the first seabed return of each ping of a slant-range tile.

    Parameters
    ----------
    tile
        Slant-range tile, columns from the nadir outwards.
    fraction
        Threshold as a fraction of the seabed level (median of the outer half of the ping).
    smooth_m
        Length of the range smoothing window.

    Returns
    -------
    np.ndarray
        (rows,) float64 slant range in metres; NaN where no return was found.
    """
    if not tile.slant:
        raise ValueError(f"{tile.ident}: bottom tracking needs slant-range pings")
    k = max(int(round(smooth_m / tile.dr_m)), 1)
    px = np.nan_to_num(tile.pixels.astype(np.float64), nan=0.0)
    smooth = ndi.uniform_filter1d(px, size=k, axis=1, mode="nearest")
    level = np.median(px[:, tile.cols // 2:], axis=1)
    above = smooth >= fraction * level[:, None]
    seen_below = np.maximum.accumulate(~above, axis=1)
    hit = above & seen_below
    idx = np.argmax(hit, axis=1)
    found = hit[np.arange(tile.rows), idx] & (level > 0)
    return np.where(found, tile.range0_m + tile.dr_m * idx, np.nan)


def bottom_altitude_m(port: Tile | None, stbd: Tile | None, *, fraction: float = 0.3, smooth_m: float = 0.15,
                      median_pings: int = 7) -> np.ndarray:
    """Sonar altitude per ping from both sides' first returns (module docstring).

    Returns
    -------
    np.ndarray
        (rows,) float64 metres; NaN where neither side found the seabed.
    """
    sides = [first_return_m(t, fraction=fraction, smooth_m=smooth_m) for t in (port, stbd) if t is not None]
    if not sides:
        raise ValueError("bottom tracking needs at least one side")
    stacked = np.vstack(sides)
    alt = np.full(stacked.shape[1], np.nan)
    ok = ~np.all(np.isnan(stacked), axis=0)
    alt[ok] = np.nanmax(stacked[:, ok], axis=0)
    if median_pings > 1 and alt.size > 1:
        # NaN-aware running median: gaps are filled from their neighbours, never invented past them
        filled = np.where(np.isnan(alt), np.interp(np.arange(alt.size), np.flatnonzero(ok), alt[ok]) if ok.any()
                          else np.nan, alt)
        alt = np.where(ok, ndi.median_filter(filled, size=median_pings, mode="nearest"), np.nan)
    return alt
