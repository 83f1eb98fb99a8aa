"""Re-cut a recording's sonar tiles along-track, keeping every ping (SPEC section 0 check).

SPEC section 0 says contacts must not depend on where tiles are cut. This module rebuilds a
recording with the same pings cut differently: the tiles of each run of one (mission, leg,
side) with one geometry are joined ping by ping (pixels, ping times, per-ping nav) and split
again into tiles of the requested sizes; ``seq`` is renumbered per side (ICD section 1: +1 per
tile and side). Every other record (NMEA, CAN, ...) is kept as it is. A new tile is recorded
as long after its last ping as the original tile that held that ping was, so the links stay
interleaved as aboard.

Command line (exit status 0 done, 1 bad input, 2 usage)::

    python -m atr_node.io.recut IN.atrlog OUT.atrlog --pings 32
    python -m atr_node.io.recut IN.atrlog OUT.atrlog --random 1 128 --seed 3
    python -m atr_node.io.recut --compare A.jsonl B.jsonl [--truth truth.csv]

``--compare`` matches two ``atr-node replay --contacts-out`` files one to one (nearest first,
within ``--gate`` metres) and prints the agreement, the largest position and Bel differences
and, with ``--truth``, each file's Pd at ``fusion.report_bel``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import AtrError
from ..records.tile import NAV_KEYS, Tile, TileNav
from .atrlog import AtrLogWriter, LogRecord, read_atrlog

Sizes = Callable[[], int]
"""Gives the number of pings of the next tile (>= 1)."""


def fixed(pings: int) -> Sizes:
    """Tiles of ``pings`` pings each (the last tile of a run takes what is left)."""
    if int(pings) < 1:
        raise AtrError(f"recut: pings per tile must be >= 1, got {pings}")
    return lambda: int(pings)


def random_sizes(lo: int, hi: int, seed: int) -> Sizes:
    """Tiles of a uniformly random ``lo..hi`` pings each, reproducible from ``seed``."""
    if not 1 <= int(lo) <= int(hi):
        raise AtrError(f"recut: need 1 <= lo <= hi, got {lo}..{hi}")
    rng = np.random.default_rng(seed)
    return lambda: int(rng.integers(int(lo), int(hi) + 1))


def _geometry(t: Tile) -> tuple:
    """What must not change within a run of tiles joined into one (everything but the pings)."""
    return (t.mission, t.leg, t.side, t.kind, t.range0_m, t.dr_m, t.dx_m, t.slant, t.cols, t.wire_dtype,
            t.sensor, t.nav is None)


def _split(run: list[tuple[float, int, Tile]], sizes: Sizes) -> Iterator[tuple[float, int, Tile]]:
    """The tiles of one run, joined and cut again: (record time, source record index, tile)."""
    tiles = [t for _, _, t in run]
    px = np.concatenate([t.pixels for t in tiles])
    times = np.concatenate([t.ping_time for t in tiles])
    # per ping: how long after it its tile was recorded (the tile's delay after its last ping)
    delay = np.concatenate([np.full(t.rows, rt - float(t.ping_time[-1])) for rt, _, t in run])
    source = np.concatenate([np.full(t.rows, i) for _, i, t in run])
    nav = None if tiles[0].nav is None else {k: np.concatenate([getattr(t.nav, k) for t in tiles]) for k in NAV_KEYS}
    first = tiles[0]
    i = 0
    while i < len(times):
        n = max(1, int(sizes()))
        rows = slice(i, min(i + n, len(times)))
        last = rows.stop - 1
        tile = first.replace(pixels=px[rows], ping_time=times[rows],
                             nav=None if nav is None else TileNav(**{k: v[rows] for k, v in nav.items()}))
        yield float(times[last] + delay[last]), int(source[last]), tile
        i = rows.stop


def recut_records(records: Iterable[LogRecord], sizes: Sizes) -> list[LogRecord]:
    """The records with every run of sonar tiles re-cut by ``sizes`` (see the module docstring).

    Raises
    ------
    AtrError
        A sonar record is not a valid tile (the recording is re-cut as it would be replayed,
        so a tile the node would reject is an error here, named with its record).
    """
    others: list[tuple[float, int, int, LogRecord]] = []
    runs: dict[str, list[tuple[float, int, Tile]]] = {}
    done: list[list[tuple[float, int, Tile]]] = []
    for k, rec in enumerate(records):
        if rec.link != "sonar":
            others.append((rec.t, k, 0, rec))
            continue
        try:
            tile = Tile.from_map(rec.msg)
        except AtrError as exc:
            raise AtrError(f"recut: record at byte {rec.offset}: {exc}") from None
        run = runs.get(tile.side)
        if run and _geometry(run[-1][2]) != _geometry(tile):
            done.append(run)
            run = None
        if not run:
            run = runs[tile.side] = []
        run.append((rec.t, k, tile))
    done.extend(r for r in runs.values() if r)
    cut: list[tuple[float, int, int, Tile]] = []
    for run in done:
        for j, (t, src, tile) in enumerate(_split(run, sizes)):
            cut.append((t, src, j, tile))
    # seq +1 per tile and side, in recording order
    cut.sort(key=lambda x: (x[0], x[1], x[2]))
    seq: dict[str, int] = {}
    out = list(others)
    for t, src, j, tile in cut:
        n = seq.get(tile.side, 0)
        seq[tile.side] = n + 1
        out.append((t, src, j + 1, LogRecord(t, "sonar", tile.replace(seq=n).to_map())))
    out.sort(key=lambda x: (x[0], x[1], x[2]))
    return [r for *_, r in out]


def recut_file(src: str | Path, dst: str | Path, sizes: Sizes) -> int:
    """Write ``src`` re-cut by ``sizes`` to ``dst``; return the number of sonar tiles written."""
    records = recut_records(read_atrlog(src), sizes)
    with AtrLogWriter(dst, flush_every=1000) as w:
        for rec in records:
            w.write_record(rec)
    return sum(r.link == "sonar" for r in records)


# -- comparing two runs' contacts ------------------------------------------------------------
def read_contacts(path: str | Path) -> list[dict[str, Any]]:
    """The live contacts of an ``atr-node replay --contacts-out`` file, each in its latest state
    (:func:`atr_node.operators.book.read_contacts`: checked against the ICD, withdrawn ones left out)."""
    from ..operators.book import read_contacts as read_book

    return read_book(path).contacts()


def match_contacts(a: list[dict], b: list[dict], gate_m: float) -> list[tuple[int, int, float]]:
    """One-to-one matches (index in a, index in b, distance m) within ``gate_m``: the
    evaluation's maximum matching (:func:`atr_node.evaluation.scoring.match`)."""
    from ..evaluation.scoring import match

    pa = np.array([[c["east_m"], c["north_m"]] for c in a], dtype=np.float64).reshape(-1, 2)
    pb = np.array([[c["east_m"], c["north_m"]] for c in b], dtype=np.float64).reshape(-1, 2)
    return [(i, j, float(np.hypot(*(pa[i] - pb[j])))) for i, j in match(pa, pb, radius_m=gate_m)]


def compare(a: list[dict], b: list[dict], *, gate_m: float = 1.0) -> dict[str, Any]:
    """Agreement of two contact lists: matched within ``gate_m``, largest differences.

    ``agreement`` is matched / max(len(a), len(b)): 1 only when both have the same contacts.
    """
    m = match_contacts(a, b, gate_m)
    return {"a": len(a), "b": len(b), "matched": len(m),
            "agreement": len(m) / max(len(a), len(b)) if (a or b) else 1.0,
            "max_offset_m": max((d for *_, d in m), default=0.0),
            "max_bel_diff": max((abs(a[i]["bel"] - b[j]["bel"]) for i, j, _ in m), default=0.0)}


def _pd(contacts: list[dict], truth: Path, bel: float) -> float:
    from ..evaluation.scoring import read_truth, score_contacts  # only for --truth

    return score_contacts(contacts, read_truth(truth), bel=bel).point.pd


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m atr_node.io.recut", description=__doc__.split("\n\n")[0])
    ap.add_argument("paths", nargs=2, metavar="PATH", help="IN.atrlog OUT.atrlog (or, with --compare, A.jsonl B.jsonl)")
    how = ap.add_mutually_exclusive_group(required=True)
    how.add_argument("--pings", type=int, help="pings per tile")
    how.add_argument("--random", type=int, nargs=2, metavar=("LO", "HI"), help="random pings per tile, LO..HI")
    how.add_argument("--compare", action="store_true", help="compare two --contacts-out files")
    ap.add_argument("--seed", type=int, default=0, help="seed of --random (default 0)")
    ap.add_argument("--gate", type=float, default=1.0, help="--compare: match within this many metres (default 1)")
    ap.add_argument("--truth", type=Path, help="--compare: truth CSV (ICD section 5) for each file's Pd")
    args = ap.parse_args(argv)
    try:
        if args.compare:
            a, b = (read_contacts(p) for p in args.paths)
            r = compare(a, b, gate_m=args.gate)
            line = (f"{r['a']} and {r['b']} contacts, {r['matched']} matched within {args.gate:g} m: agreement "
                    f"{r['agreement']:.2f}, largest offset {r['max_offset_m']:.3g} m, largest Bel difference "
                    f"{r['max_bel_diff']:.3g}")
            if args.truth is not None:
                line += f"; Pd {_pd(a, args.truth, 0.5):.2f} and {_pd(b, args.truth, 0.5):.2f} at Bel >= 0.5"
            print(line)
            return 0
        sizes = fixed(args.pings) if args.pings is not None else random_sizes(*args.random, args.seed)
        n = recut_file(args.paths[0], args.paths[1], sizes)
        print(f"{args.paths[1]}: {n} tiles")
        return 0
    except (AtrError, OSError) as exc:
        print(f"recut: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
