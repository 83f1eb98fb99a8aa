#!/usr/bin/env python3
"""The node on the shared real side-scan recordings: contacts on the recorded waterfall.

For every XTF file with side-scan pings in ``../shared/data/real/xtf`` (or the files given), it
replays the file through the node (``atr-node replay FILE --publish none --speed max``, with
the options given after ``--``), maps each contact back to its ping and slant range
(:mod:`atr_node.evaluation.waterfall`), says whether it lies in the water column, on the
first-return band or on the seabed, and draws the slant-range waterfall with the contacts, the
altitude the node used and the objects read by eye, as ``docs/real_<file>.png``. It prints a
table per file: tiles, contacts, where they lie, contacts without detection, and the objects
read by eye found within 3 m (ICD section 5's match radius).

    python tools/figures/real_recordings.py                  # both shared files, figures into docs/
    python tools/figures/real_recordings.py --out /tmp/figs  # elsewhere
    python tools/figures/real_recordings.py FILE.xtf -- --online-calibration off

Exit codes: 0 ok, 1 a file could not be replayed, 2 usage.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from atr_node.commands._crs import add_crs_argument, add_frequency_argument, with_recording_options  # noqa: E402
from atr_node.config import load_settings  # noqa: E402
from atr_node.evaluation.waterfall import ZONES, SidePings, draw_waterfall, locate_contacts  # noqa: E402
from atr_node.geo import MissionFrame  # noqa: E402
from atr_node.records.tile import Tile  # noqa: E402

SHARED = ROOT.parent / "shared" / "data" / "real" / "xtf"
DEFAULT_FILES = ("scotsman-iver2.xtf", "river-000_1236.xtf")
"""The shared recordings with side-scan pings."""

# Objects read by eye on the waterfalls (shared/data/real/README.md, docs/xtf.md): side, ping,
# slant range (m), label. The wreck of the Iver2 file is a box: side, first and last ping,
# largest slant range.
MARKS = {
    # the port object: the shared README says "ping about 325 at 18 m slant"; on the waterfall
    # the only object with a shadow there is at 23-25 m slant, pings 320-340 (docs/xtf.md)
    "river-000_1236": [("port", 330, 23.5, "port object (by eye)"), ("stbd", 925, 29.0, "starboard object (by eye)")],
    "scotsman-iver2": [("stbd", 281, 4.06, "hit 1 138 281 (wreck)")],
}
WRECKS = {"scotsman-iver2": ("stbd", 160, 400, 16.5)}  # the hull ends at about 16 m slant
MATCH_M = 3.0


def _replay(path: Path, contacts: Path, summary: Path, extra: list[str]) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "atr_node", "replay", str(path), "--publish", "none", "--speed", "max",
           "--contacts-out", str(contacts), "--summary", str(summary), *extra]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)


def _tiles(path: Path, settings, crs: str, frequency: str | float = "high") -> list[Tile]:
    from atr_node.io.recording import open_recording

    records = open_recording(path, crs=crs, altitude=settings.recording.altitude, frequency=frequency)
    return [Tile.from_map(r.msg) for r in records if r.link == "sonar"]


def _band_merger(settings):
    """The node's nav merger, for the first-return band it gives each slant tile (measured per
    tile and side, as in replay: :mod:`atr_node.node.navmerge`)."""
    from atr_node.node.navmerge import NavMerger
    from atr_node.records.nav import NavTrack

    s = settings.sensor
    return NavMerger(NavTrack(), first_return_band_m=s.first_return_band_m, first_return_level=s.first_return_level,
                     first_return_band_max_m=s.first_return_band_max_m)


def recording_pings(tiles: list[Tile], settings) -> tuple[list[SidePings], MissionFrame, float]:
    """The pings of both sides (with the first-return band the node gives each tile), a metric
    frame near the recording, and the median ping spacing: what contacts are placed with."""
    merger = _band_merger(settings)
    pings = [SidePings.from_tiles(tiles, s, band_m=lambda t: merger._band_m(t, t.nav.altitude_m))
             for s in ("port", "stbd")]
    nav = next(t for t in tiles if t.nav is not None)
    frame = MissionFrame("utm", float(nav.nav.lat_deg[0]), float(nav.nav.lon_deg[0]))
    return pings, frame, float(np.median([t.dx_m for t in tiles]))


def match_marks(stem: str, places, dx: float) -> tuple[list[tuple[str, list[int]]], list[int] | None]:
    """Per object read by eye (``MARKS``), the ids of the placed contacts within ``MATCH_M``
    (along-track pings times ``dx`` and slant range); the ids inside the wreck's box
    (``WRECKS``), None for a recording without one."""
    found = []
    for side, ping, r, label in MARKS.get(stem, []):
        near = [p for p in places if p.side == side
                and math.hypot((p.ping - ping) * dx, p.slant_range_m - r) <= MATCH_M]
        found.append((label, [p.id for p in near]))
    wreck = None
    if stem in WRECKS:
        side, a, b, rmax = WRECKS[stem]
        wreck = [p.id for p in places if p.side == side and a <= p.ping <= b and p.slant_range_m <= rmax]
    return found, wreck


def _recording_parser() -> argparse.ArgumentParser:
    """The replay options that change what is read (given after ``--``)."""
    ap = argparse.ArgumentParser(add_help=False)
    add_crs_argument(ap)
    add_frequency_argument(ap)
    return ap


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra: list[str] = []
    if "--" in argv:
        k = argv.index("--")
        argv, extra = argv[:k], argv[k + 1:]
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*", help="XTF files (default: the shared ones with side-scan pings)")
    ap.add_argument("--out", default=str(ROOT / "docs"), help="folder for the figures (default docs/)")
    ap.add_argument("--config", help="config file (as for replay; also passed to it)")
    ap.add_argument("--json", help="write the table as JSON here")
    args = ap.parse_args(argv)
    files = [Path(f) for f in args.files] or [SHARED / name for name in DEFAULT_FILES]
    settings = load_settings(args.config)
    if args.config:
        extra = ["--config", args.config, *extra]
    band_m = settings.sensor.first_return_band_m
    # the waterfall is drawn from what the replay reads: --crs and --frequency after --, or the config's
    rec_args, _ = _recording_parser().parse_known_args(extra)
    rec = with_recording_options(rec_args, settings).recording
    crs, frequency = rec.crs, rec.frequency
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table = []
    failed = 0
    for path in files:
        with tempfile.TemporaryDirectory() as tmp:
            cpath, spath = Path(tmp) / "contacts.jsonl", Path(tmp) / "summary.json"
            print(f"{path.name}: replaying ...", file=sys.stderr)
            proc = _replay(path, cpath, spath, extra)
            if proc.returncode != 0:
                print(f"{path}: replay failed (exit {proc.returncode}): {proc.stderr.strip().splitlines()[-1:]}",
                      file=sys.stderr)
                failed += 1
                continue
            contacts = [json.loads(x) for x in cpath.read_text().splitlines() if x.strip()]
            summary = json.loads(spath.read_text())
        live = [c for c in contacts if c["state"] != "withdrawn"]
        tiles = _tiles(path, settings, crs, frequency)
        if not any(t.nav is not None for t in tiles):
            print(f"{path}: no ping has a position: nothing to place", file=sys.stderr)
            failed += 1
            continue
        pings, frame, dx = recording_pings(tiles, settings)
        places = locate_contacts(pings, live, frame, band_m=band_m)
        marks = MARKS.get(path.stem, [])
        found, wreck = match_marks(path.stem, places, dx)
        alt = np.concatenate([p.altitude_m for p in pings])
        row = {"file": path.name, "tiles": summary["tiles_in"], "tile_pings": [t.rows for t in tiles if t.side == "port"],
               "contacts": len(live), "placed": len(places),
               "zones": {z: sum(1 for p in places if p.zone == z) for z in ZONES},
               "no_detection": sum(1 for c in live if c.get("detections", 1) == 0),
               "altitude_m": [round(float(f(alt)), 2) for f in (np.nanmin, np.nanmedian, np.nanmax)],
               "found": {label: ids for label, ids in found}, "wreck_contacts": wreck,
               "model": summary.get("model")}
        table.append(row)
        png = out / f"real_{path.stem}.png"
        by_id = {int(c["id"]): c for c in live}
        draw_waterfall(tiles, pings, places, str(png), title=f"{path.name}: the node's contacts on the recorded waterfall",
                       band_m=band_m, contacts=by_id, marks=marks)
        print(f"\n{path.name}: {row['tiles']} tiles (pings per port tile: {row['tile_pings']})")
        print(f"  altitude used min/median/max: {row['altitude_m']} m")
        print(f"  contacts: {row['contacts']} live, {row['placed']} placed on the waterfall: "
              + ", ".join(f"{n} {z}" for z, n in row["zones"].items()) + f"; {row['no_detection']} without detection")
        for label, ids in found:
            print(f"  {label}: {'found, contact ' + ', '.join(map(str, ids)) if ids else 'NOT found'}")
        if wreck is not None:
            print(f"  wreck: {len(wreck)} contact(s) {wreck}")
        print(f"  figure: {png}")
    if args.json:
        Path(args.json).write_text(json.dumps(table, indent=2))
    return 1 if failed else 0


if __name__ == "__main__":
    from atr_node.errors import AtrError

    try:
        sys.exit(main())
    except AtrError as exc:  # a bad --config, --crs or --frequency: one line
        print(f"real_recordings: {exc}", file=sys.stderr)
        sys.exit(2)
