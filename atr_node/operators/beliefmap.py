"""The belief map as a PNG: contacts over the coverage, for ``atr-node monitor --png``.

Two sources, drawn with what each allows:

- **The PUB stream only** (contacts, no grid): each contact a circle of radius ``sigma_m`` at
  its position in the mission's metric frame, coloured by Bel(T), labelled with its id;
  withdrawn contacts as grey crosses. The stream does not carry coverage, so the shaded
  rectangles are the *extent of the contacts each leg saw* (their positions padded by 3 sigma
  and the association gate), not the swath: the caption says so.
- **A node's state directory** (``--state-dir``): the real belief map, Bel(T) of every cell
  of the evidence grid in its newest snapshot (:mod:`atr_node.node.state`,
  :func:`atr_node.fusion.snapshot.load`, SPEC section 6 closed form on the accumulators
  L_T, L_N), over the covered cells only (cells some leg covered: committed coverage bitmaps
  and open-leg layers); uncovered ground stays blank. Large grids are reduced by the block
  maximum of Bel(T) (a power of two that divides the chunk size), so a contact stays visible.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import AtrError
from ..fusion import EvidenceGrid, closed_form
from ..fusion import snapshot as grid_snapshot

MAX_LABELS = 60
"""Contacts labelled with their id (the highest beliefs); every contact is drawn."""
MAX_CELLS = 4_000_000
"""Largest raster drawn at full resolution (cells); beyond, block maxima."""


@dataclass(frozen=True)
class BeliefRaster:
    """Bel(T) on a regular grid of the mission's metric frame.

    ``bel`` has shape (rows, cols): row i covers north ``[north0_m + i*cell_m, ... + cell_m)``,
    column j east ``[east0_m + j*cell_m, ...)``; NaN = not covered.
    """

    bel: np.ndarray
    east0_m: float
    north0_m: float
    cell_m: float

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(west, east, south, north) edges, for ``imshow(origin="lower")``."""
        rows, cols = self.bel.shape
        return (self.east0_m, self.east0_m + cols * self.cell_m, self.north0_m, self.north0_m + rows * self.cell_m)


def covered_cells(grid: EvidenceGrid, keys: Sequence[tuple[int, int]]) -> np.ndarray:
    """(K, nn) bool: cells of chunks ``keys`` covered by at least one leg (committed or open)."""
    out = np.zeros((len(keys), grid.nn), dtype=bool)
    for i, key in enumerate(keys):
        for bits in grid.cover.get(key, {}).values():
            if bits is None:
                out[i] = True
                break
            out[i] |= np.unpackbits(bits, count=grid.nn).astype(bool)
        for layer in grid.open.values():
            s = layer.chunks.slot.get(key)
            if s is not None:  # an open layer holds -1 where a (detector, cell) got nothing
                out[i] |= (layer.chunks.arr[s, :, 1] >= 0.0).any(axis=0)  # a Pd (a gate alone is no coverage)
    return out


def grid_raster(grid: EvidenceGrid, *, max_cells: int = MAX_CELLS) -> BeliefRaster | None:
    """The belief raster of ``grid`` (None when nothing is covered)."""
    keys = grid.chunk_keys()
    if not keys:
        return None
    n = grid.n
    acc = grid.chunk_accumulators(keys)  # (K, 2, nn): L_T, L_N
    bel = closed_form(acc[:, 0], acc[:, 1]).bel
    bel = np.where(covered_cells(grid, keys), bel, np.nan).reshape(len(keys), n, n)
    cy = np.array([k[0] for k in keys])
    cx = np.array([k[1] for k in keys])
    ny, nx = (cy.max() - cy.min() + 1) * n, (cx.max() - cx.min() + 1) * n
    f = 1
    while ny * nx // (f * f) > max_cells and f < n and n % (2 * f) == 0:
        f *= 2
    if f > 1:  # block maximum, NaN-aware (fmax ignores a NaN beside a number)
        bel = np.fmax.reduce(np.fmax.reduce(bel.reshape(len(keys), n // f, f, n // f, f), axis=4), axis=2)
    m = n // f
    out = np.full((ny // f, nx // f), np.nan)
    for b, y, x in zip(bel, (cy - cy.min()) * m, (cx - cx.min()) * m):
        out[y:y + m, x:x + m] = b
    return BeliefRaster(out, float(cx.min() * n * grid.cell_m), float(cy.min() * n * grid.cell_m), grid.cell_m * f)


def load_state_grid(state_dir: str | Path) -> EvidenceGrid:
    """The evidence grid of the newest snapshot in a node's ``--state-dir``.

    Raises
    ------
    AtrError
        No snapshot there yet, or an unreadable one (the message names the folder).
    """
    from ..node.state import read_current

    folder = read_current(state_dir)
    if folder is None:
        raise AtrError(f"state directory {state_dir}: no snapshot yet (no CURRENT naming a snap-<n> folder)")
    grid, _ = grid_snapshot.load(folder / "grid.npz")
    return grid


def _leg_extents(contacts: Sequence[Mapping[str, Any]], pad_m: float) -> dict[int, tuple[float, float, float, float]]:
    ext: dict[int, list[float]] = {}
    for c in contacts:
        r = 3.0 * c["sigma_m"] + pad_m
        for leg in c["legs"]:
            e = ext.setdefault(leg, [np.inf, -np.inf, np.inf, -np.inf])
            e[0], e[1] = min(e[0], c["east_m"] - r), max(e[1], c["east_m"] + r)
            e[2], e[3] = min(e[2], c["north_m"] - r), max(e[3], c["north_m"] + r)
    return {k: tuple(v) for k, v in sorted(ext.items())}


def draw_belief_map(path: str | Path, contacts: Sequence[Mapping[str, Any]], *,
                    raster: BeliefRaster | None = None, title: str = "", pad_m: float = 5.0) -> Path:
    """Write the map PNG to ``path`` atomically; returns the path.

    Parameters
    ----------
    contacts : sequence of ICD contact maps
        Drawn as circles of radius ``sigma_m`` coloured by ``bel`` (withdrawn: grey crosses).
    raster : BeliefRaster, optional
        The grid's belief map (from :func:`grid_raster`); without it, leg extents of the contacts.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Circle, Rectangle

    live = [c for c in contacts if c["state"] != "withdrawn"]
    gone = [c for c in contacts if c["state"] == "withdrawn"]
    xs = [c["east_m"] for c in contacts] + ([raster.extent_m[0]] if raster is not None else [])
    ys = [c["north_m"] for c in contacts] + ([raster.extent_m[2]] if raster is not None else [])
    e0 = float(np.floor(min(xs) / 100.0) * 100.0) if xs else 0.0
    n0 = float(np.floor(min(ys) / 100.0) * 100.0) if ys else 0.0
    cmap = plt.get_cmap("viridis")
    fig, ax = plt.subplots(figsize=(8, 7), dpi=110)
    ax.set_facecolor("#f2f2f2")
    if raster is not None:
        w, e, s, n = raster.extent_m
        im = ax.imshow(np.ma.masked_invalid(raster.bel), origin="lower", extent=(w - e0, e - e0, s - n0, n - n0),
                       cmap=cmap, vmin=0.0, vmax=1.0, interpolation="nearest")
        fig.colorbar(im, ax=ax, shrink=0.8, label="Bel(T) of the evidence grid")
        caption = "belief map from the node's snapshot; blank = not covered"
    else:
        for leg, (w, e, s, n) in _leg_extents(contacts, pad_m).items():
            ax.add_patch(Rectangle((w - e0, s - n0), e - w, n - s, facecolor="tab:blue", alpha=0.08,
                                   edgecolor="tab:blue", lw=0.8))
            ax.text(w - e0, n - n0, f" leg {leg}", va="top", fontsize=7, color="tab:blue")
        caption = "no grid in the stream: shaded = extent of the contacts each leg saw (not the swath)"
    if live:
        circles = [Circle((c["east_m"] - e0, c["north_m"] - n0), max(c["sigma_m"], 0.25)) for c in live]
        if raster is None:  # filled, coloured by the contact's Bel(T)
            pc = PatchCollection(circles, cmap=cmap, alpha=0.8, edgecolor="black", linewidth=0.8)
            pc.set_array(np.array([c["bel"] for c in live]))
            pc.set_clim(0.0, 1.0)
            fig.colorbar(pc, ax=ax, shrink=0.8, label="contact Bel(T)")
        else:  # the grid already shows Bel(T): outlines, so the map under them stays readable
            pc = PatchCollection(circles, facecolor="none", edgecolor="red", linewidth=1.4)
        ax.add_collection(pc)
        for c in sorted(live, key=lambda c: -c["bel"])[:MAX_LABELS]:  # labels cost most of the drawing
            ax.annotate(str(c["id"]), (c["east_m"] - e0, c["north_m"] - n0), xytext=(5, 5),
                        textcoords="offset points", fontsize=8, color="red" if raster is not None else "black",
                        fontweight="bold")
    if gone:
        ax.scatter([c["east_m"] - e0 for c in gone], [c["north_m"] - n0 for c in gone], marker="x", c="grey",
                   label="withdrawn")
        ax.legend(loc="lower right", fontsize=8)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel(f"east - {e0:.0f} m")
    ax.set_ylabel(f"north - {n0:.0f} m")
    ax.set_title(title or f"atr-node contacts: {len(live)} live, {len(gone)} withdrawn", fontsize=10)
    ax.text(0.0, -0.16, caption, transform=ax.transAxes, fontsize=7, color="dimgrey", va="top")
    p = Path(path)
    tmp = p.with_name(f".{p.stem}.tmp-{os.getpid()}{p.suffix}")
    try:
        fig.savefig(tmp, format="png", bbox_inches="tight")
        os.replace(tmp, p)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise AtrError(f"belief map {p}: cannot write it ({exc.strerror or exc})") from None
    finally:
        plt.close(fig)
    return p
