"""Contacts mapped back onto the recorded waterfall: ping, side, slant and ground range.

A contact is a position on the map (ICD section 3). An operator who checks it looks at the
waterfall as the sonar recorded it, in pings and slant range. :func:`locate_contacts` inverts
the georeferencing of SPEC section 0 for a recording's pings: per side, the contact's offset
from every ping position is split into an along-track part (on the grid heading) and an
across-track part (on that side's unit vector, scaled by the projection's scale factor, as
:mod:`atr_node.geo.georef` does forward); the contact belongs to the ping with the smallest
along-track offset on the side where the across-track part is positive, its ground range is
that across-track part, and its slant range ``sqrt(g^2 + H^2)`` with the altitude ``H`` the
node used for that ping (the tiles' ``nav.altitude_m``).

:func:`zone_of` says where a slant range lies in the ping: the water column (``R < H``), the
first-return band (``H <= R < H + band``: the first bottom return and its ringing) or the
seabed. :func:`draw_waterfall` draws the slant-range waterfall of both sides with the contacts
at their (ping, slant range), the tracked altitude and the first-return band, for a person to
look at before believing a count.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np

from ..geo import MissionFrame
from ..geo.georef import ping_frame
from ..records.tile import Tile, TileNav

ZONES = ("water column", "first return", "seabed")


@dataclass(frozen=True)
class SidePings:
    """The pings of one side of a recording, in order, with the nav the node used."""

    side: str
    ping_time: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    heading_deg: np.ndarray
    altitude_m: np.ndarray
    band_m: np.ndarray | None = None
    """First-return band of each ping in slant metres (None: the caller's one band)."""

    @classmethod
    def from_tiles(cls, tiles: Iterable[Tile], side: str, *, band_m: Callable[[Tile], float] | None = None
                   ) -> "SidePings":
        """Pings of ``side`` from a recording's tiles (tiles without nav count as pings with
        NaN nav, so ping numbers stay those of the file); ``band_m(tile)``, if given, is the
        first-return band the node gave each tile."""
        parts: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "lat", "lon", "hdg", "alt", "band")}
        for t in tiles:
            if t.side != side:
                continue
            parts["t"].append(np.asarray(t.ping_time, dtype=np.float64))
            parts["band"].append(np.full(t.rows, band_m(t) if band_m is not None and t.nav is not None else np.nan))
            if t.nav is None:
                nan = np.full(t.rows, np.nan)
                for k in ("lat", "lon", "hdg", "alt"):
                    parts[k].append(nan)
            else:
                parts["lat"].append(t.nav.lat_deg)
                parts["lon"].append(t.nav.lon_deg)
                parts["hdg"].append(t.nav.heading_deg)
                parts["alt"].append(t.nav.altitude_m)
        cat = {k: np.concatenate(v).astype(np.float64) if v else np.zeros(0) for k, v in parts.items()}
        return cls(side, cat["t"], cat["lat"], cat["lon"], cat["hdg"], cat["alt"],
                   cat["band"] if band_m is not None else None)

    def __len__(self) -> int:
        return int(self.ping_time.size)


@dataclass(frozen=True)
class ContactPlace:
    """Where a contact lies on the recorded waterfall."""

    id: int
    side: str
    ping: int
    """Ping index within the side, 0-based, in file order."""
    ground_range_m: float
    slant_range_m: float
    altitude_m: float
    along_offset_m: float
    """Along-track distance from the contact to the ping's across-track line (how well it fits)."""
    zone: str


def zone_of(slant_range_m: float, altitude_m: float, band_m: float) -> str:
    """``water column`` (R < H), ``first return`` (H <= R < H + band_m) or ``seabed``."""
    if not np.isfinite(altitude_m) or slant_range_m < altitude_m:
        return ZONES[0]
    if slant_range_m < altitude_m + band_m:
        return ZONES[1]
    return ZONES[2]


def _side_frame(p: SidePings, frame: MissionFrame):
    """(east, north, ue, un, grid heading) per ping (:func:`~atr_node.geo.georef.ping_frame`,
    as the forward georeferencing), NaN where a ping has no nav."""
    ok = np.isfinite(p.lat_deg) & np.isfinite(p.lon_deg) & np.isfinite(p.heading_deg)
    out = [np.full(len(p), np.nan) for _ in range(5)]
    if ok.any():
        nav = TileNav(p.lat_deg[ok], p.lon_deg[ok], p.heading_deg[ok], np.zeros(int(ok.sum())))
        for o, v in zip(out, ping_frame(nav, p.side, frame)):
            o[ok] = v
    return out


def locate_contacts(pings: Iterable[SidePings], contacts: Iterable[dict], frame: MissionFrame, *,
                    band_m: float = 0.0, max_along_m: float = 2.0) -> list[ContactPlace]:
    """Ping, side, ground and slant range of each contact (module docstring).

    Parameters
    ----------
    pings
        The recording's pings per side (:meth:`SidePings.from_tiles`).
    contacts
        Contact maps with ``id``, ``lat_deg``, ``lon_deg`` (ICD section 3).
    frame
        Any metric frame near the recording (the offsets are formed in it).
    band_m
        Width of the first-return band in slant metres, for :func:`zone_of`, where the pings
        carry none of their own (:attr:`SidePings.band_m`).
    max_along_m
        A contact farther than this along-track from every ping's line (before the first ping,
        after the last, or off a gap) is not placed.

    Returns
    -------
    list of ContactPlace
        One per contact that could be placed, in the order given.
    """
    sides = [(p, *_side_frame(p, frame)) for p in pings]
    out = []
    for c in contacts:
        ce, cn = (float(np.ravel(v)[0]) for v in frame.to_frame(c["lat_deg"], c["lon_deg"]))
        best = None
        for p, e, n, ue, un, hg in sides:
            de, dn = ce - e, cn - n
            # forward: offset = r * (ue, un), the unit vector scaled by the grid scale factor k:
            # the dot product is r k^2, and k^2 = ue^2 + un^2
            across = (de * ue + dn * un) / (ue * ue + un * un)
            along = de * np.sin(hg) + dn * np.cos(hg)
            cand = np.where(np.isfinite(across) & (across >= 0), np.abs(along), np.inf)
            if not cand.size:
                continue
            i = int(np.argmin(cand))
            if cand[i] <= max_along_m and (best is None or cand[i] < best[0]):
                best = (float(cand[i]), p, i, float(across[i]))
        if best is None:
            continue
        off, p, i, g = best
        h = float(p.altitude_m[i])
        r = float(np.hypot(g, h)) if np.isfinite(h) else g
        band = float(p.band_m[i]) if p.band_m is not None else band_m
        out.append(ContactPlace(id=int(c.get("id", -1)), side=p.side, ping=i, ground_range_m=g, slant_range_m=r,
                                altitude_m=h, along_offset_m=off, zone=zone_of(r, h, band)))
    return out


def slant_waterfall(tiles: Iterable[Tile], side: str) -> tuple[np.ndarray, float, float]:
    """(pings, samples) pixels of one side as recorded (slant range, or ground range for a
    tile recorded so), with range0_m and dr_m of the common axis: every tile of the side, in
    order, so rows are the pings of :meth:`SidePings.from_tiles`; a tile on another spacing
    is placed by nearest sample."""
    sel = [t for t in tiles if t.side == side]
    if not sel:
        return np.zeros((0, 0), np.float32), 0.0, 1.0
    dr = sel[0].dr_m
    r0 = min(t.range0_m for t in sel)
    cols = max(int(round((t.range0_m + t.dr_m * (t.cols - 1) - r0) / dr)) + 1 for t in sel)
    out = np.full((sum(t.rows for t in sel), cols), np.nan, np.float32)
    row = 0
    for t in sel:
        dest = np.rint((t.range0_m + t.dr_m * np.arange(t.cols) - r0) / dr).astype(np.int64)
        out[row:row + t.rows, dest] = t.pixels
        row += t.rows
    return out, r0, dr


def draw_waterfall(tiles: list[Tile], side_pings: list[SidePings], places: list[ContactPlace], out_png: str, *,
                   title: str, band_m: float = 0.0, contacts: dict[int, dict] | None = None, marks=(),
                   dpi: int = 100) -> None:
    """The slant-range waterfall of both sides (port mirrored left of the nadir), the node's
    altitude (dashed) and first-return band (dotted; ``side_pings``' own, else ``band_m``), and
    each contact at its (ping, slant range):
    a cross, labelled with its id (and Bel when ``contacts`` gives it). ``marks`` are
    (side, ping, slant_range_m, label) drawn as circles (objects read by eye)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    port, r0p, dr = slant_waterfall(tiles, "port")
    stbd, r0s, dr_s = slant_waterfall(tiles, "stbd")
    rows = max(port.shape[0], stbd.shape[0])
    fig, ax = plt.subplots(figsize=(11, 9))
    cmap = plt.get_cmap("copper").with_extremes(bad="#55606e")
    vals = np.concatenate([a[np.isfinite(a) & (a > 0)].ravel() for a in (port, stbd) if a.size])
    lo, hi = np.percentile(np.log10(vals), [1.0, 99.5]) if vals.size else (0.0, 1.0)
    for img, r0, d, sign in ((port, r0p, dr, -1), (stbd, r0s, dr_s, 1)):
        if not img.size:
            continue
        far = r0 + d * img.shape[1]
        ext = (-far, -r0, img.shape[0], 0) if sign < 0 else (r0, far, img.shape[0], 0)
        show = np.log10(np.where(img > 0, img, np.nan))
        ax.imshow(show[:, ::-1] if sign < 0 else show, cmap=cmap, vmin=lo, vmax=hi, aspect="auto", extent=ext,
                  interpolation="nearest")
    for pings in side_pings:
        sign = -1 if pings.side == "port" else 1
        y = np.arange(len(pings))
        ax.plot(sign * pings.altitude_m, y, "--", color="cyan", lw=0.8,
                label="altitude used (first return)" if sign > 0 else None)
        band = pings.band_m if pings.band_m is not None else np.full(len(pings), band_m)
        if np.nanmax(band, initial=0.0) > 0:
            ax.plot(sign * (pings.altitude_m + band), y, ":", color="cyan", lw=0.8,
                    label="end of the first-return band" if sign > 0 else None)
    for side, ping, r, label in marks:
        x = -r if side == "port" else r
        ax.plot([x], [ping], "o", ms=18, mfc="none", mec="lime", mew=1.5)
        ax.annotate(label, (x, ping), xytext=(12, 10), textcoords="offset points", color="lime", fontsize=8)
    colours = {"seabed": "yellow", "first return": "red", "water column": "magenta"}
    for pl in places:
        x = -pl.slant_range_m if pl.side == "port" else pl.slant_range_m
        ax.plot([x], [pl.ping], "+", color=colours[pl.zone], ms=12, mew=2)
        c = (contacts or {}).get(pl.id)
        text = f"{pl.id}" + (f" ({c['bel']:.2f})" if c is not None and "bel" in c else "")
        ax.annotate(text, (x, pl.ping), xytext=(6, -10), textcoords="offset points", color=colours[pl.zone],
                    fontsize=7)
    ax.axvline(0, color="white", lw=0.5)
    ax.set_xlabel("slant range (m): port <- nadir -> starboard")
    ax.set_ylabel("ping")
    ax.set_ylim(rows, 0)
    counts = {z: sum(1 for p in places if p.zone == z) for z in ZONES}
    ax.set_title(f"{title}\ncontacts (id, Bel): {len(places)} placed; "
                 + ", ".join(f"{n} {z}" for z, n in counts.items()), fontsize=10)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out_png, dpi=dpi)
    plt.close(fig)
