#!/usr/bin/env python3
"""Throughput of the XTF reader, writer and conversions on a recording (default: the Iver2 file).

Prints one row per stage: best wall time over the repetitions, pings per second and MB/s of
XTF. Stages: read (XTF -> records, tiles packed as ICD maps), read+sonar-altitude (with bottom
tracking), write (tiles -> XTF), xtf->atrlog and atrlog->xtf (files on disk, as
``atr-node convert``), ground (slant -> ground range of every tile).

    python tools/xtf_bench.py                # 5 repetitions
    python tools/xtf_bench.py --quick        # 1 repetition
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from atr_node.commands.convert import atrlog_to_xtf, xtf_to_atrlog  # noqa: E402
from atr_node.io.xtf import XtfReader  # noqa: E402
from atr_node.io.xtf_write import XtfWriter  # noqa: E402
from atr_node.records.tile import Tile  # noqa: E402

DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "xtf" / "scotsman-iver2.xtf"


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("xtf", nargs="?", default=str(DEFAULT), help=f"XTF file (default {DEFAULT.name})")
    ap.add_argument("--repeat", type=int, default=5, help="repetitions per stage (best is kept)")
    ap.add_argument("--quick", action="store_true", help="one repetition")
    args = ap.parse_args(argv)
    repeat = 1 if args.quick else max(args.repeat, 1)
    path = Path(args.xtf)
    mb = path.stat().st_size / 1e6
    reader = XtfReader(path)
    tiles = [Tile.from_map(r.msg) for r in reader if r.link == "sonar"]
    pings = reader.stats.pings
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)

        def write() -> None:
            with XtfWriter(tmp / "w.xtf") as w:
                for t in tiles:
                    w.write_tile(t)

        xtf_to_atrlog(path, tmp / "c.atrlog", tile_pings=256, mission=None, leg=None)
        stages = [
            ("read", lambda: list(XtfReader(path))),
            ("read+sonar-altitude", lambda: list(XtfReader(path, altitude="sonar"))),
            ("write", write),
            ("xtf->atrlog", lambda: xtf_to_atrlog(path, tmp / "a.atrlog", tile_pings=256, mission=None, leg=None)),
            ("atrlog->xtf", lambda: atrlog_to_xtf(tmp / "c.atrlog", tmp / "b.xtf")),
            ("ground", lambda: [t.ground_range() for t in tiles if t.nav is not None]),
        ]
        print(f"{path.name}: {pings} pings, {len(tiles)} tiles, {mb:.2f} MB; best of {repeat}")
        print(f"{'stage':<22}{'time ms':>10}{'pings/s':>12}{'MB/s':>8}")
        for name, fn in stages:
            t = best_of(fn, repeat)
            print(f"{name:<22}{t * 1e3:>10.1f}{pings / t:>12.0f}{mb / t:>8.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
