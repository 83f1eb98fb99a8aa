#!/usr/bin/env python3
"""Ground-range mosaic of an XTF side-scan recording, with its marked hits, as a PNG.

Left panel: the ground-range waterfall of both sides (port mirrored to the left of the nadir,
starboard to the right; rows = pings, time downwards), log amplitude stretched between the 1st
and 99.5th percentiles, NaN (no data) in blue-grey, hits marked with a red circle. Right panel:
the same pixels georeferenced (SPEC section 0) in UTM metres around the hit, with the vehicle
track, the hits, any surveyed reference points (``--survey``) and contacts (``--contacts``,
JSON lines with ``lat_deg``/``lon_deg`` as ``atr-node replay --contacts-out`` writes them).

It prints a table of where each hit lands: slant and ground range, position, and the distance
to every surveyed point and to each survey's centroid.

    python tools/figures/xtf_mosaic.py ../shared/data/real/xtf/scotsman-iver2.xtf --out mosaic.png \\
        --survey ../shared/data/real/xtf/ScotsmanLongitudeLatitudeCaris.csv \\
        --survey ../shared/data/real/xtf/ScotsmanLongitudeLatitudeOpenSidescan2020-03-18.csv
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from atr_node.geo import MissionFrame, tile_geometry  # noqa: E402
from atr_node.commands._crs import add_frequency_argument  # noqa: E402
from atr_node.io.xtf import XtfReader  # noqa: E402
from atr_node.io.xtf_hits import channel_sides, locate_hit, read_hits, read_survey_csv  # noqa: E402
from atr_node.records.tile import Tile  # noqa: E402


def ground_waterfall(tiles: list[Tile], side: str) -> tuple[np.ndarray, float]:
    """(pings, cols) ground-range pixels of one side on one axis from 0, and its spacing."""
    ground = [t.ground_range() if t.nav is not None else None for t in tiles if t.side == side]
    dr = next(g.dr_m for g in ground if g is not None)
    cols = max(int(round(g.range0_m / dr)) + g.cols for g in ground if g is not None)
    rows = [t.rows for t in tiles if t.side == side]
    out = np.full((sum(rows), cols), np.nan, dtype=np.float32)
    r0 = 0
    for g, n in zip(ground, rows):
        if g is not None:
            c0 = int(round(g.range0_m / dr))  # ground tiles start on a multiple of dr
            out[r0:r0 + n, c0:c0 + g.cols] = g.pixels
        r0 += n
    return out, dr


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("xtf", help="XTF side-scan file")
    ap.add_argument("--out", default="xtf_mosaic.png", help="PNG to write (default xtf_mosaic.png)")
    ap.add_argument("--hits", help="hits file (default <xtf>.hits when it exists)")
    ap.add_argument("--survey", action="append", default=[], help="CSV of surveyed points (repeatable)")
    ap.add_argument("--contacts", help="JSON lines of contacts (lat_deg, lon_deg) to mark on the map")
    ap.add_argument("--detections", help="JSON lines of detections (atr-node replay --detections-out) to mark")
    ap.add_argument("--altitude", choices=("altimeter", "sonar"), default="altimeter",
                    help="altitude for slant-to-ground: the recorded altimeter (default) or the sonar's first return")
    add_frequency_argument(ap)
    ap.add_argument("--quick", action="store_true", help="smaller, coarser figure (fast check)")
    args = ap.parse_args(argv)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    reader = XtfReader(args.xtf, altitude=args.altitude, frequency=args.frequency or "high")
    tiles = [Tile.from_map(r.msg) for r in reader if r.link == "sonar"]
    if not tiles:
        print(f"{args.xtf}: no side-scan pings\n{reader.stats.summary()}", file=sys.stderr)
        return 1
    print(reader.stats.summary())
    hits_path = Path(args.hits) if args.hits else Path(args.xtf + ".hits")
    hits = read_hits(hits_path) if hits_path.is_file() else []
    sides = channel_sides(args.xtf)
    nav_tile = next(t for t in tiles if t.nav is not None)
    frame = MissionFrame("utm", float(nav_tile.nav.lat_deg[0]), float(nav_tile.nav.lon_deg[0]))
    located = [locate_hit(tiles, h, sides, frame) for h in hits]
    surveys = {Path(p).stem: read_survey_csv(p) for p in args.survey}

    print(f"\n{'hit':>14} {'side':>5} {'slant m':>8} {'alt m':>6} {'ground m':>8} {'lat':>11} {'lon':>12}")
    for h, loc in zip(hits, located):
        print(f"{h.channel:>3}/{h.sample:>4}/{h.ping:>5} {loc.side:>5} {loc.slant_range_m:8.2f} {loc.altitude_m:6.2f} "
              f"{loc.ground_range_m:8.2f} {loc.lat_deg:11.6f} {loc.lon_deg:12.6f}")
        if not np.isfinite(loc.ground_range_m):
            print("    returns before the seabed (slant range < altitude): above the seabed, no flat-seabed position")
            continue
        he, hn = frame.to_frame(loc.lat_deg, loc.lon_deg)
        for name, pts in surveys.items():
            e, n = frame.to_frame([p[1] for p in pts], [p[2] for p in pts])
            d = np.hypot(e - he, n - hn)
            print(f"    {name}: " + ", ".join(f"{p[0]} {di:.1f} m" for p, di in zip(pts, d))
                  + f"; centroid {float(np.hypot(e.mean() - he, n.mean() - hn)):.1f} m")

    step = 2 if args.quick else 1
    port, dr = ground_waterfall(tiles, "port")
    stbd, _ = ground_waterfall(tiles, "stbd")
    width = max(port.shape[1], stbd.shape[1])
    pad = lambda a: np.pad(a, ((0, 0), (0, width - a.shape[1])), constant_values=np.nan)  # noqa: E731
    both = np.hstack([pad(port)[:, ::-1], pad(stbd)])[::step, ::step]
    img = np.log10(np.where(both > 0, both, np.nan))
    lo, hi = np.nanpercentile(img, [1.0, 99.5])

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(9, 6) if args.quick else (15, 10),
                                   gridspec_kw={"width_ratios": [1.2, 1]})
    cmap = plt.get_cmap("copper").with_extremes(bad="#55606e")
    extent = (-width * dr, width * dr, both.shape[0] * step, 0)
    ax0.imshow(img, cmap=cmap, vmin=lo, vmax=hi, aspect="auto", extent=extent, interpolation="nearest")
    for h, loc in zip(hits, located):
        above = not np.isfinite(loc.ground_range_m)  # returns before the seabed: drawn at the nadir
        x = 0.0 if above else loc.ground_range_m * (-1 if loc.side == "port" else 1)
        ax0.plot([x], [h.ping], "o", ms=14, mfc="none", mec="red", mew=2)
        ax0.annotate(f"hit {h.channel} {h.sample} {h.ping}" + (" (above the seabed)" if above else ""), (x, h.ping),
                     xytext=(12, -12), textcoords="offset points", color="red")
    contacts = []
    if args.contacts:
        with open(args.contacts, encoding="utf-8") as fh:
            contacts = [json.loads(line) for line in fh if line.strip()]
    for c in contacts:  # the pixel nearest each contact, if within 2 m of the swath
        ce, cn = frame.to_frame(c["lat_deg"], c["lon_deg"])
        best = (2.0, None)
        ping0 = 0
        for t in tiles:
            if t.nav is not None:
                e, n = tile_geometry(t.ground_range(), frame).world_grid()
                d = np.hypot(e - ce, n - cn)
                k = np.unravel_index(np.argmin(d), d.shape)
                if d[k] < best[0]:
                    sign = -1 if t.side == "port" else 1
                    best = (d[k], (sign * t.ground_range().ranges_m[k[1]], ping0 + k[0]))
            if t.side == "stbd":
                ping0 += t.rows
        if best[1] is not None:
            ax0.plot([best[1][0]], [best[1][1]], "+", color="cyan", ms=16, mew=2)
            ax0.annotate(f"contact {c.get('id', '?')}", best[1], xytext=(10, 8), textcoords="offset points",
                         color="cyan")
            print(f"contact {c.get('id', '?')}: ping {best[1][1]}, ground range {best[1][0]:+.1f} m "
                  f"(nearest pixel {best[0]:.2f} m away)")
    ax0.axvline(0, color="white", lw=0.5)
    ax0.set_xlabel("ground range (m): port <- nadir -> starboard")
    ax0.set_ylabel("ping")
    ax0.set_title(f"{Path(args.xtf).name}: ground-range waterfall ({args.altitude} altitude)")

    for t in tiles:
        if t.nav is None:
            continue
        g = t.ground_range()
        geo = tile_geometry(g, frame)
        e, n = geo.world_grid()
        v = np.log10(np.where(g.pixels > 0, g.pixels, np.nan))
        s = 2 * step
        with warnings.catch_warnings():  # cell centres of a turning swath are not monotonic: fine here
            warnings.simplefilter("ignore", UserWarning)
            ax1.pcolormesh(e[::s, ::s], n[::s, ::s], v[::s, ::s], cmap=cmap, vmin=lo, vmax=hi, shading="auto",
                           rasterized=True)
        ax1.plot(geo.east_m, geo.north_m, "w-", lw=1)
    for loc in located:
        if not np.isfinite(loc.lat_deg):
            continue
        he, hn = frame.to_frame(loc.lat_deg, loc.lon_deg)
        ax1.plot([he], [hn], "o", ms=12, mfc="none", mec="red", mew=2, label="hit (georeferenced)")
    for (name, pts), mk in zip(surveys.items(), ("c^", "ms", "yD", "g*")):
        e, n = frame.to_frame([p[1] for p in pts], [p[2] for p in pts])
        ax1.plot(e, n, mk, ms=7, label=f"surveyed: {name}")
    if args.detections:
        with open(args.detections, encoding="utf-8") as fh:
            dets = [json.loads(line) for line in fh if line.strip()]
        for det_name, colour in (("mf", "tab:blue"), ("lac", "tab:orange"), ("smf", "tab:green"), ("z", "tab:red")):
            sel = [d for d in dets if d["detector"] == det_name]
            if sel:
                e, n = frame.to_frame([d["lat_deg"] for d in sel], [d["lon_deg"] for d in sel])
                ax1.plot(e, n, "x", color=colour, ms=7, mew=1.5, label=f"detections {det_name}")
    if contacts:
        e, n = frame.to_frame([c["lat_deg"] for c in contacts], [c["lon_deg"] for c in contacts])
        ax1.plot(e, n, "+", color="cyan", ms=16, mew=2, label="contacts")
    ax1.set_aspect("equal")
    ax1.set_xlabel(f"east (m, {frame.name})")
    ax1.set_ylabel("north (m)")
    ax1.set_title(f"georeferenced (flat seabed, {args.altitude} altitude)")
    ax1.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=80 if args.quick else 110)
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    from atr_node.errors import AtrError

    try:
        sys.exit(main())
    except (AtrError, OSError) as exc:  # a file that is not XTF, a bad --frequency, a missing file: one line
        print(f"xtf_mosaic: {exc}", file=sys.stderr)
        sys.exit(1)
