"""Figures and the Markdown report of an evaluation (matplotlib, imported lazily, Agg backend).

- :class:`Mosaic`: the survey's ground-range pixels georeferenced into one picture of the
  seabed (decimated samples binned on a regular grid of the mission frame);
- :func:`plot_mosaic`: the mosaic with truth targets and contacts marked;
- :func:`plot_belief`: Bel(T) over the covered cells of an evidence grid;
- :func:`plot_roc`: Pd against false alarms (and per km^2) for every method, as the paper's
  figure 6.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..fusion import EvidenceGrid, closed_form
from .scoring import RocCurve


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(plt, fig, path: str | os.PathLike[str]) -> Path:
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def _save_map(plt, fig, ax, path: str | os.PathLike[str], title: str) -> Path:
    """A map in the mission frame: axis labels, title, saved."""
    ax.set_xlabel("east (m, mission frame)")
    ax.set_ylabel("north (m)")
    ax.set_title(title)
    return _save(plt, fig, path)


class Mosaic:
    """Decimated, georeferenced samples of every unit's core, binned into a picture."""

    def __init__(self, *, step: int = 3) -> None:
        self.step = step
        self._e: list[np.ndarray] = []
        self._n: list[np.ndarray] = []
        self._v: list[np.ndarray] = []

    def add(self, pixels: np.ndarray, geometry: Any) -> None:
        s = self.step
        px = pixels[::s, ::s]
        rows = np.arange(0, pixels.shape[0], s)
        cols = np.arange(0, pixels.shape[1], s)
        e = geometry.east_m[rows, None] + geometry.ranges_m[None, cols] * geometry.ue[rows, None]
        n = geometry.north_m[rows, None] + geometry.ranges_m[None, cols] * geometry.un[rows, None]
        ok = np.isfinite(px)
        self._e.append(e[ok])
        self._n.append(n[ok])
        self._v.append(px[ok].astype(np.float32))

    def raster(self, resolution_m: float = 0.3) -> tuple[np.ndarray, tuple[float, float, float, float]]:
        """(image (ny, nx) of mean pixel value, NaN where empty; extent (e0, e1, n0, n1))."""
        if not self._e:
            return np.full((1, 1), np.nan), (0.0, 1.0, 0.0, 1.0)
        e, n, v = (np.concatenate(x) for x in (self._e, self._n, self._v))
        e0, e1, n0, n1 = e.min(), e.max(), n.min(), n.max()
        nx = max(int(math.ceil((e1 - e0) / resolution_m)), 1)
        ny = max(int(math.ceil((n1 - n0) / resolution_m)), 1)
        ix = np.minimum(((e - e0) / resolution_m).astype(np.int64), nx - 1)
        iy = np.minimum(((n - n0) / resolution_m).astype(np.int64), ny - 1)
        s = np.bincount(iy * nx + ix, weights=v, minlength=nx * ny)
        c = np.bincount(iy * nx + ix, minlength=nx * ny)
        with np.errstate(invalid="ignore", divide="ignore"):
            img = (s / c).reshape(ny, nx)
        return img, (float(e0), float(e0 + nx * resolution_m), float(n0), float(n0 + ny * resolution_m))


def _display(img: np.ndarray) -> np.ndarray:
    """Log intensity, clipped at the 1st and 99.5th percentiles, for display."""
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.log10(np.where(img > 0, img, np.nan))
    if np.isfinite(d).any():
        lo, hi = np.nanpercentile(d, [1, 99.5])
        d = np.clip((d - lo) / max(hi - lo, 1e-9), 0, 1)
    return d


def plot_mosaic(mosaic: Mosaic, path: str | os.PathLike[str], *, truth_en: np.ndarray, contacts: Sequence[dict],
                title: str, report_bel: float) -> Path:
    plt = _pyplot()
    img, ext = mosaic.raster()
    fig, ax = plt.subplots(figsize=(9, 9))
    ax.imshow(_display(img), origin="lower", extent=ext, cmap="copper", interpolation="nearest")
    if len(truth_en):
        ax.scatter(truth_en[:, 0], truth_en[:, 1], s=160, facecolors="none", edgecolors="cyan", linewidths=1.5,
                   label="truth target")
    live = [c for c in contacts if c["state"] != "withdrawn"]
    hi = [c for c in live if c["bel"] >= report_bel]
    if hi:
        ax.scatter([c["east_m"] for c in hi], [c["north_m"] for c in hi], marker="+", s=120, c="red",
                   linewidths=1.5, label=f"contact, Bel(T) >= {report_bel:g}")
        for c in hi:
            ax.annotate(f"{c['id']}: {c['bel']:.2f}", (c["east_m"], c["north_m"]), xytext=(4, 4),
                        textcoords="offset points", fontsize=7, color="yellow")
    ax.legend(loc="upper right", fontsize=8)
    return _save_map(plt, fig, ax, path, title)


def belief_raster(grid: EvidenceGrid) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """Bel(T) of every covered cell on a raster of the grid's cells (NaN: never covered)."""
    keys = grid.chunk_keys()
    if not keys:
        return np.full((1, 1), np.nan), (0.0, 1.0, 0.0, 1.0)
    n = grid.n
    acc = grid.chunk_accumulators(keys)
    ky = np.array([k[0] for k in keys])
    kx = np.array([k[1] for k in keys])
    y0, x0 = ky.min(), kx.min()
    ny, nx = (ky.max() - y0 + 1) * n, (kx.max() - x0 + 1) * n
    img = np.full((ny, nx), np.nan)
    for (cy, cx), a in zip(keys, acc):
        m = closed_form(a[0], a[1])
        bel = m.m_t.reshape(n, n).copy()
        bel[~_covered(grid, (cy, cx)).reshape(n, n)] = np.nan
        img[(cy - y0) * n:(cy - y0 + 1) * n, (cx - x0) * n:(cx - x0 + 1) * n] = bel
    c = grid.cell_m
    return img, (x0 * n * c, (x0 * n + nx) * c, y0 * n * c, (y0 * n + ny) * c)


def _covered(grid: EvidenceGrid, key: tuple[int, int]) -> np.ndarray:
    """Cells of a chunk that some leg covered (from the grid's per-leg coverage bitmaps)."""
    legs = grid.cover.get(key, {})
    out = np.zeros(grid.nn, dtype=bool)
    for bits in legs.values():
        if bits is None:  # the leg covered the whole chunk
            return np.ones(grid.nn, dtype=bool)
        out |= np.unpackbits(bits, count=grid.nn).astype(bool)
    return out


def plot_belief(grid: EvidenceGrid, path: str | os.PathLike[str], *, truth_en: np.ndarray, title: str) -> Path:
    plt = _pyplot()
    img, ext = belief_raster(grid)
    fig, ax = plt.subplots(figsize=(9, 9))
    im = ax.imshow(img, origin="lower", extent=ext, cmap="viridis", vmin=0, vmax=1, interpolation="nearest")
    fig.colorbar(im, ax=ax, label="Bel(T)", shrink=0.8)
    if len(truth_en):
        ax.scatter(truth_en[:, 0], truth_en[:, 1], s=160, facecolors="none", edgecolors="red", linewidths=1.2,
                   label="truth target")
        ax.legend(loc="upper right", fontsize=8)
    return _save_map(plt, fig, ax, path, title)


def plot_roc(curves: Sequence[RocCurve], points: Sequence[RocCurve], path: str | os.PathLike[str], *,
             covered_km2: float, title: str) -> Path:
    """Left: each detector alone; right: the fusion schemes and the logical operators."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5), sharey=True)
    singles = [c for c in curves if not c.name.startswith("DS")]
    fused = [c for c in curves if c.name.startswith("DS")]
    styles = {0: ":", 1: "-", 2: "-."}
    for ax, group, ttl in ((axes[0], singles, "each detector alone"), (axes[1], fused, "fusion")):
        for i, c in enumerate(group):
            fa, pd = c.false_alarms, c.pd
            order = np.lexsort((pd, fa))
            ax.step(fa[order], np.maximum.accumulate(pd[order]), where="post", label=c.name,
                    linestyle=styles.get(i, "-") if group is fused else "-", linewidth=1.6)
        ax.set_title(ttl)
        ax.set_xlabel("false alarms (number)")
        ax.grid(alpha=0.3)
    markers = ["s", "^", "v", "o"]
    for i, p in enumerate(points):
        q = p.points[0]
        axes[1].plot([q.false_alarms], [q.pd], markers[i % len(markers)], markersize=9, label=p.name)
    axes[0].set_ylabel("probability of detection")
    for ax in axes:
        ax.set_ylim(-0.02, 1.05)
        ax.legend(fontsize=7, loc="lower right")
        if covered_km2 > 0:
            sec = ax.secondary_xaxis("top", functions=(lambda x: x / covered_km2, lambda y: y * covered_km2))
            sec.set_xlabel("false alarms per km$^2$")
    fig.suptitle(title)
    return _save(plt, fig, path)
