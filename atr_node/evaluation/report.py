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


def _save(plt, fig, path: str | os.PathLike[str], *, tight: bool = True) -> Path:
    if tight:
        fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def _save_map(plt, fig, ax, path: str | os.PathLike[str], title: str, *, tight: bool = True) -> Path:
    """A map in the mission frame: axis labels, title, saved."""
    _map_labels(ax, title)
    return _save(plt, fig, path, tight=tight)


def _map_labels(ax, title: str) -> None:
    ax.set_xlabel("east (m, mission frame)")
    ax.set_ylabel("north (m)")
    ax.set_title(title)


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


LABEL_FONT_PT = 7.0
"""Contact labels on the mosaic."""


def plot_mosaic(mosaic: Mosaic, path: str | os.PathLike[str], *, truth_en: np.ndarray, contacts: Sequence[dict],
                title: str, report_bel: float, max_labels: int = 60, clutter_en: np.ndarray | None = None) -> Path:
    """The mosaic with the truth targets and the node's contacts at Bel(T) >= ``report_bel``
    (and with ``clutter_en`` the known objects that are not targets, as grey squares).

    Contacts matched to a target (ICD section 5) are green, false alarms red; targets that no
    reported contact matches are magenta ("missed"). Labels (``id: Bel``) must stay readable
    at mission scale, where a hard seabed gives hundreds of contacts: the matched contacts
    are labelled first, then the others by decreasing Bel(T); each label takes the first of a
    few places around its contact (farther ones with a leader line) where it overlaps no
    label already placed, and is left out when none is free or ``max_labels`` are placed.
    How many were left out is in the legend: every contact is in ``contacts.jsonl``.
    """
    from .scoring import match

    plt = _pyplot()
    img, ext = mosaic.raster()
    # a fixed layout (no tight_layout after the labels are placed: it would move the axes and
    # the labels' pixel boxes with them); the legend below the map, where it hides nothing
    width_in, left_in, right_in, top_in, bottom_in = 10.0, 1.1, 0.3, 0.5, 1.6
    aspect = (ext[3] - ext[2]) / max(ext[1] - ext[0], 1e-9)
    ax_w_in = width_in - left_in - right_in
    ax_h_in = min(max(ax_w_in * aspect, 3.0), 14.0)  # a long single leg: no 1-m-tall figure
    height_in = ax_h_in + top_in + bottom_in
    fig = plt.figure(figsize=(width_in, height_in))
    ax = fig.add_axes((left_in / width_in, bottom_in / height_in, ax_w_in / width_in, ax_h_in / height_in))
    _map_labels(ax, title)
    ax.imshow(_display(img), origin="lower", extent=ext, cmap="copper", interpolation="nearest")
    ax.ticklabel_format(useOffset=False, style="plain")  # metres of the frame, not "+4.881e6"
    truth_en = np.asarray(truth_en, dtype=np.float64).reshape(-1, 2)
    if clutter_en is not None and len(clutter_en):
        k = np.asarray(clutter_en, dtype=np.float64).reshape(-1, 2)
        ax.scatter(k[:, 0], k[:, 1], marker="s", s=90, facecolors="none", edgecolors="silver", linewidths=1.0,
                   label=f"known clutter ({len(k)})")
    live = [c for c in contacts if c["state"] != "withdrawn"]
    hi = [c for c in live if c["bel"] >= report_bel]
    c_en = np.array([(c["east_m"], c["north_m"]) for c in hi]).reshape(-1, 2)
    pairs = match(c_en, truth_en)
    hit_c = {i for i, _ in pairs}
    hit_t = {k for _, k in pairs}
    found = np.array([k in hit_t for k in range(len(truth_en))], dtype=bool)
    if found.any():
        ax.scatter(truth_en[found, 0], truth_en[found, 1], s=200, facecolors="none", edgecolors="cyan",
                   linewidths=1.5, label=f"target, found ({found.sum()})")
    if (~found).any():
        ax.scatter(truth_en[~found, 0], truth_en[~found, 1], s=200, facecolors="none", edgecolors="magenta",
                   linewidths=2.0, linestyle="--", label=f"target, missed ({(~found).sum()})")
    tp = np.array([i in hit_c for i in range(len(hi))], dtype=bool)
    if tp.any():
        ax.scatter(c_en[tp, 0], c_en[tp, 1], marker="+", s=110, c="lime", linewidths=1.8,
                   label=f"contact on a target, Bel(T) >= {report_bel:g} ({tp.sum()})")
    if (~tp).any():
        ax.scatter(c_en[~tp, 0], c_en[~tp, 1], marker="x", s=35, c="red", linewidths=1.2,
                   label=f"false alarm, Bel(T) >= {report_bel:g} ({(~tp).sum()})")
    order = sorted(range(len(hi)), key=lambda i: (i not in hit_c, -hi[i]["bel"], hi[i]["id"]))
    ax.set_xlim(ext[0], ext[1])
    ax.set_ylim(ext[2], ext[3])
    placed = _place_labels(fig, ax, [(c_en[i], f"{hi[i]['id']}: {hi[i]['bel']:.2f}", i in hit_c) for i in order],
                           max_labels=max_labels)
    left = len(hi) - placed
    handles, labels = ax.get_legend_handles_labels()
    if left:
        handles.append(plt.Line2D([], [], linestyle="none"))
        labels.append(f"{left} of {len(hi)} contacts not labelled (crowded)")
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=9, frameon=False)
    return _save(plt, fig, path, tight=False)


def _place_labels(fig, ax, items: Sequence[tuple[np.ndarray, str, bool]], *, max_labels: int) -> int:
    """Place text labels next to points without overlaps; returns how many were placed.

    ``items``: (east/north point, text, on a target), in order of priority. Each label tries
    offsets around its point, nearest first, and takes the first whose box (in display
    pixels) overlaps no label placed before and lies inside the axes; the farther offsets get
    a leader line to the point.
    """
    fig.canvas.draw()  # the transforms below need the final layout of the axes
    to_px = ax.transData.transform
    box = ax.get_window_extent()
    px_per_pt = fig.dpi / 72.0
    h_px = LABEL_FONT_PT * 1.25 * px_per_pt
    near = [(5, 4), (5, -4 - LABEL_FONT_PT * 1.25), (-5, 4), (-5, -4 - LABEL_FONT_PT * 1.25)]
    far = [(dx, dy) for r in (18, 30) for dx, dy in ((r, r), (r, -r), (-r, r), (-r, -r), (0, r), (0, -r))]
    taken: list[tuple[float, float, float, float]] = []
    for xy, text, on_target in items:
        if len(taken) >= max_labels:
            break
        x, y = to_px(xy)
        w_px = len(text) * LABEL_FONT_PT * 0.62 * px_per_pt
        for dx_pt, dy_pt in near + far:
            # the label's box: left-aligned to the right of the point, right-aligned to the left
            x0 = x + dx_pt * px_per_pt - (w_px if dx_pt < 0 else (w_px / 2 if dx_pt == 0 else 0.0))
            y0 = y + dy_pt * px_per_pt
            b = (x0 - 1, y0 - 1, x0 + w_px + 1, y0 + h_px + 1)
            if b[0] < box.x0 or b[2] > box.x1 or b[1] < box.y0 or b[3] > box.y1:
                continue
            if any(b[0] < t[2] and t[0] < b[2] and b[1] < t[3] and t[1] < b[3] for t in taken):
                continue
            taken.append(b)
            leader = (dx_pt, dy_pt) not in near
            ax.annotate(text, xy, xytext=(dx_pt, dy_pt), textcoords="offset points", fontsize=LABEL_FONT_PT,
                        color="lime" if on_target else "yellow",
                        ha="right" if dx_pt < 0 else ("center" if dx_pt == 0 else "left"), va="bottom",
                        bbox=dict(boxstyle="square,pad=0.1", fc="black", ec="none", alpha=0.75),
                        arrowprops=dict(arrowstyle="-", color="white", lw=0.6, alpha=0.8) if leader else None)
            break
    return len(taken)


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
             covered_km2: float, title: str, fused: Sequence[RocCurve] = ()) -> Path:
    """Left: each detector alone; right: the fusion schemes and the logical operators.

    ``curves`` whose name starts with "DS", and every curve of ``fused`` (e.g. the node's own
    contacts), go to the fusion panel. With no single-detector curve the figure has the
    fusion panel only (``atr-node evaluate --contacts``)."""
    plt = _pyplot()
    singles = [c for c in curves if not c.name.startswith("DS")]
    fused = [c for c in curves if c.name.startswith("DS")] + list(fused)
    if singles:
        fig, axes = plt.subplots(1, 2, figsize=(13, 5.5), sharey=True)
        panels = ((axes[0], singles, "each detector alone"), (axes[1], fused, "fusion"))
    else:
        fig, ax = plt.subplots(figsize=(7, 5.5))
        axes = [ax]
        panels = ((ax, fused, "fusion"),)
    styles = {0: ":", 1: "-", 2: "-."}
    for ax, group, ttl in panels:
        for i, c in enumerate(group):
            fa, pd = c.false_alarms, c.pd
            order = np.lexsort((pd, fa))
            node = not c.name.startswith("DS") and group is fused  # the node's contacts: drawn boldest
            ax.step(fa[order], np.maximum.accumulate(pd[order]), where="post", label=c.name,
                    linestyle=styles.get(i, "-") if group is fused and not node else "-",
                    linewidth=2.6 if node else 1.6, color="black" if node else None)
        ax.set_title(ttl)
        ax.set_xlabel("false alarms (number)")
        ax.grid(alpha=0.3)
    markers = ["s", "^", "v", "o"]
    for i, p in enumerate(points):
        q = p.points[0]
        axes[-1].plot([q.false_alarms], [q.pd], markers[i % len(markers)], markersize=9, label=p.name)
    axes[0].set_ylabel("probability of detection")
    for ax in axes:
        ax.set_ylim(-0.02, 1.05)
        if ax.get_legend_handles_labels()[0]:  # an empty legend is a matplotlib warning
            ax.legend(fontsize=7, loc="lower right")
        if covered_km2 > 0:
            sec = ax.secondary_xaxis("top", functions=(lambda x: x / covered_km2, lambda y: y * covered_km2))
            sec.set_xlabel("false alarms per km$^2$")
    fig.suptitle(title)
    return _save(plt, fig, path)
