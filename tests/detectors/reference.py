"""Slow, obvious float64 references for the detectors: window by window, written from SPEC 1-2.

Nothing here uses the package's engine: geometry is recomputed from the SPEC formulas, column
statistics with ``np.nanmean`` / ``np.nanmedian``, and every window is cut out of the image
and reduced with numpy, pixel by pixel of the anchor grid.
"""

from __future__ import annotations

import warnings

import numpy as np

from atr_node.config import DetectorSettings, TemplateSettings


def reference_geometry(cols: int, *, range0_m: float, dr_m: float, dx_m: float, altitude_m: float,
                       template: TemplateSettings) -> dict:
    """Window sizes straight from SPEC section 1 and the shared anchor contract."""
    w = max(1, round(template.echo_width_m / dr_m))
    ln = max(1, round(template.length_m / dx_m))
    shadow = []
    for j in range(cols):
        r = range0_m + j * dr_m
        h = template.height_m
        s_m = template.shadow_max_m if altitude_m <= h else h * r / (altitude_m - h)
        s_m = min(max(s_m, template.shadow_min_m), template.shadow_max_m)
        shadow.append(max(1, round(s_m / dr_m)))
    cf = template.context_factor
    ctx_len = max(ln, round(cf * ln))
    return {"W": w, "L": ln, "S": shadow, "ctx_len": ctx_len,
            "ctx_w": [max(w + s, round(cf * (w + s))) for s in shadow]}


def segment(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    """SMF segmentation of SPEC 2.3, float64; NaN pixels stay NaN."""
    conds = [x < 0.3 * m, x < 0.6 * m, x > 4 * m, x > 2 * m]
    s = np.select(conds, [-1.0, -0.5, 1.0, 0.5], default=0.0)
    return np.where(np.isfinite(x), s, np.nan)


def reference_scores(x: np.ndarray, *, range0_m: float, dr_m: float, dx_m: float, altitude_m: float,
                     template: TemplateSettings, detectors: DetectorSettings,
                     background: np.ndarray | None = None, median: np.ndarray | None = None) -> dict:
    """gamma of the four detectors at every anchor of ``x``, window by window, in float64."""
    x = np.asarray(x, dtype=np.float64)
    x = np.where(np.isfinite(x), x, np.nan)
    rows, cols = x.shape
    g = reference_geometry(cols, range0_m=range0_m, dr_m=dr_m, dx_m=dx_m, altitude_m=altitude_m,
                           template=template)
    with warnings.catch_warnings():  # all-NaN columns give NaN, as intended
        warnings.simplefilter("ignore", RuntimeWarning)
        b = np.nanmean(x, axis=0) if background is None else np.asarray(background, np.float64)
        m = np.nanmedian(x, axis=0) if median is None else np.asarray(median, np.float64)
    b = np.where(np.isfinite(b) & (b > 0), b, 1.0)
    i_n = x / b
    jj = i_n - np.where(np.isfinite(m), m / b, 1.0)
    seg = segment(x, m)
    w, ln, frac = g["W"], g["L"], detectors.min_valid_fraction
    zfrac = max(detectors.min_valid_fraction_zones, frac)  # echo and shadow zones
    out = {d: np.full((rows, cols), np.nan) for d in ("mf", "lac", "smf", "z")}

    def cut(img, r0, r1, c0, c1):
        """Valid values of img over rows [r0, r1) x cols [c0, c1), clipped to the tile."""
        v = img[max(r0, 0):max(min(r1, rows), 0), max(c0, 0):max(min(c1, cols), 0)].ravel()
        return v[np.isfinite(v)]

    for i in range(rows):
        r0 = i - ln // 2
        r1 = r0 + ln
        cr0 = r0 - (g["ctx_len"] - ln) // 2
        cr1 = cr0 + g["ctx_len"]
        for j in range(cols):
            s = g["S"][j]
            cw = g["ctx_w"][j]
            cc0 = j - w - (cw - w - s) // 2
            e_ok = cut(x, r0, r1, j - w, j).size >= zfrac * ln * w
            s_ok = cut(x, r0, r1, j, j + s).size >= zfrac * ln * s
            c_ok = cut(x, cr0, cr1, cc0, cc0 + cw).size >= frac * g["ctx_len"] * cw
            ie, ish = cut(i_n, r0, r1, j - w, j), cut(i_n, r0, r1, j, j + s)
            if s_ok:
                mean = ish.mean()
                out["lac"][i, j] = ish.var() / max(mean * mean, detectors.lacunarity_floor)
            if e_ok and s_ok:
                out["mf"][i, j] = cut(jj, r0, r1, j - w, j).mean() - cut(jj, r0, r1, j, j + s).mean()
                out["z"][i, j] = (ie.mean() - ish.mean()) / max(ish.std(), detectors.sigma_floor)
                if c_ok:
                    raw = cut(seg, r0, r1, j - w, j).mean() - cut(seg, r0, r1, j, j + s).mean()
                    n = np.abs(cut(seg, cr0, cr1, cc0, cc0 + cw)).mean()
                    out["smf"][i, j] = raw / (1.0 + 10.0 * n)
    return out
