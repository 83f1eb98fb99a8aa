#!/usr/bin/env python3
"""Ingest path, this tree against an older one: same results, and the speed-up, in one process.

An older checkout (``--base DIR``, holding ``atr_node/``, ``hw/`` and ``config/``) is copied to
a temporary directory with its packages renamed (``atr_node_base``, ``hw_base``), so both
versions load side by side. Then:

1. **Equivalence**: both versions decode the same input and must agree exactly: the events
   (``repr``, so floats bit for bit), the counters and the last reject text of every record,
   on the records of a generated mission, the real R/V Palmer NMEA logs, byte-mutated NMEA and
   CAN records, field-mutated NMEA sentences with valid checksums (every reject reason), and
   ``AtrLogReader`` (records, counters, error texts; strict and not) on mutated ``.atrlog``
   files.
2. **Speed**: each stage of ``tools/bench_ingest.py`` runs alternately on the two versions
   (paired, best of ``--repeat`` in CPU time), so load from other work hits both alike.

Usage: ``python tools/ingest_ab.py --base /path/to/old/checkout [--quick] [--repeat N]``.
Exit status 1 when any result differs.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import logging
import random
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

REAL = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "real" / "nmea"
_VALUES = ["", "x", "99999", "-1", "nan", "inf", "1e400", "N", "S", "E", "W", "V", "A", "0", "2359.99", "6000.0",
           " 12", "+5", "\u0661\u0662", "4406.5", "04406.5", "18000.0", "9000.01", "01", "13", "32", "1999",
           "12345678901234567890", "360", "359.999", "235960.5", "236000", "1_0", "12.", ".5", "T", "M"]


def renamed_copy(base: Path, dest: Path) -> None:
    """``base``'s packages under ``dest`` as ``atr_node_base`` and ``hw_base`` (imports rewritten)."""
    for src, name in (("atr_node", "atr_node_base"), ("hw", "hw_base"), ("config", "config")):
        shutil.copytree(base / src, dest / name, ignore=shutil.ignore_patterns("__pycache__"))
    for py in list((dest / "atr_node_base").rglob("*.py")) + list((dest / "hw_base").rglob("*.py")):
        text = py.read_text()
        text = re.sub(r"\batr_node\.(?!dbc)", "atr_node_base.", text)
        text = re.sub(r"\bfrom atr_node import", "from atr_node_base import", text)
        text = re.sub(r"\bhw\.", "hw_base.", text)
        text = re.sub(r"\bfrom hw import", "from hw_base import", text)
        py.write_text(text)


def load(pkg: str, hw: str) -> dict[str, Any]:
    names = {"atrlog": f"{pkg}.io.atrlog", "nav": f"{pkg}.records.nav", "pipe": f"{pkg}.node.pipeline",
             "model": f"{pkg}.calibration.model", "decode": f"{hw}.decode", "nmea": f"{hw}.nmea",
             "can": f"{hw}.can_nav", "replay": f"{hw}.replay"}
    return {k: importlib.import_module(v) for k, v in names.items()}


def _mutations(nav: list, real: list, rng: random.Random) -> tuple[list, list[bytes]]:
    """Byte-mutated nav records, and field-mutated NMEA sentences with a valid checksum."""
    from atr_node.io.atrlog import LogRecord
    from hw.nmea import checksum, encode_rmc, encode_ths, encode_vtg

    records = []
    for r in nav:
        for _ in range(3):
            if r.link == "nmea":
                b = bytearray(r.msg)
                for _ in range(rng.randint(1, 3)):
                    op = rng.random()
                    if op < 0.4 and b:
                        b[rng.randrange(len(b))] = rng.randrange(256)
                    elif op < 0.7:
                        del b[rng.randrange(len(b) + 1):]
                    else:
                        b[rng.randrange(len(b) + 1):0] = rng.randbytes(rng.randint(1, 8))
                records.append(LogRecord(r.t, "nmea", bytes(b)))
            else:
                m = dict(r.msg)
                k = rng.randrange(5)
                if k == 0:
                    m["data"] = rng.randbytes(rng.randrange(11))
                elif k == 1:
                    m["id"] = rng.randrange(0x800)
                elif k == 2:
                    m["ext"] = rng.choice([True, 1, None])
                elif k == 3:
                    m["data"] = bytearray(m["data"])
                else:
                    m.pop(rng.choice(["id", "data", "ext"]))
                records.append(LogRecord(r.t, "can", m))
    pool = [r.msg for r in nav if r.link == "nmea"] + [r.msg for r in real[:3000]]
    pool += [encode_rmc(1.7e9 + i, 44.0, 9.0, speed_m_s=1.0) for i in range(200)]
    pool += [encode_vtg(10.0, 1.0), encode_ths(3.0, mode="V"), encode_ths(3.0)] * 50
    lines = []
    for line in pool * 2:
        f = line.rstrip(b"\r\n")[1:-3].decode().split(",")
        for _ in range(rng.randint(1, 3)):
            i = rng.randrange(1, len(f)) if len(f) > 1 else 0
            op = rng.random()
            if op < 0.7:
                f[i] = rng.choice(_VALUES)
            elif op < 0.85:
                del f[i]
            else:
                f.insert(i, rng.choice(_VALUES))
        body = ",".join(f).encode("utf-8")
        lines.append(b"$" + body + b"*%02X\r\n" % checksum(body))
    return records, lines


def equivalence(old: dict, new: dict, nav: list, real: list, tmp: Path, quick: bool) -> int:
    """Print one line per input; return the number of records whose results differ."""
    rng = random.Random(5)
    mutated, lines = _mutations(nav, real, rng)
    total = 0

    def decode(mods: dict, records: list) -> tuple[list, dict]:
        d, out = mods["decode"].NavDecoder(), []
        for r in records:
            try:
                ev = repr(d.feed(r))
            except Exception as exc:  # noqa: BLE001 (an exception must match too)
                ev = f"raised {type(exc).__name__}: {exc}"
            out.append((ev, d.nmea.last_reject, d.can.last_reject))
        return out, d.stats()

    for name, records in (("mission nav records", nav), ("real NMEA (NBP1406)", real),
                          ("byte-mutated records", mutated)):
        (a, sa), (b, sb) = decode(old, records), decode(new, records)
        diff = sum(x != y for x, y in zip(a, b)) + (sa != sb)
        total += diff
        print(f"  {name:34s} {len(records):7d} records  differences {diff}")
    for dfa in (True, False):
        a, b = old["nmea"].NmeaDecoder(date_from_arrival=dfa), new["nmea"].NmeaDecoder(date_from_arrival=dfa)
        diff = 0
        for k, line in enumerate(lines):
            t = 1.7e9 + 0.1 * k
            diff += repr(a.feed(line, t)) != repr(b.feed(line, t)) or a.last_reject != b.last_reject
        diff += a.counts != b.counts or a.by_type != b.by_type
        total += diff
        print(f"  {'field-mutated NMEA, dated=' + str(dfa):34s} {len(lines):7d} lines    differences {diff}  "
              f"{dict(sorted(b.counts.items()))}")
    diff = 0
    src = b"".join(__import__("msgpack").packb({"t": r.t, "link": r.link, "msg": r.msg}, use_bin_type=True)
                   for r in nav[:400])
    logging.disable(logging.WARNING)
    try:
        files = 40 if quick else 200
        for i in range(files):
            b = bytearray(src)
            for _ in range(rng.randint(1, 6)):
                j = rng.randrange(len(b))
                b[j] = rng.choice([0x00, 0x7F, 0x80, 0xC1, 0xCB, 0xD9, 0xDE, 0xFF, rng.randrange(256)])
            if i % 3 == 0:
                del b[rng.randrange(len(b)):]
            p = tmp / f"mut{i}.atrlog"
            p.write_bytes(bytes(b))
            for strict in (False, True):
                diff += _read(old, p, strict) != _read(new, p, strict)
    finally:
        logging.disable(logging.NOTSET)
    total += diff
    print(f"  {'mutated .atrlog files (x2 strict)':34s} {files:7d} files    differences {diff}")
    return total


def _read(mods: dict, path: Path, strict: bool) -> tuple:
    reader, out = mods["atrlog"].AtrLogReader(path, strict=strict), []
    try:
        for r in reader:
            out.append((repr(r.t), r.link, repr(r.msg), r.offset))
    except Exception as exc:  # noqa: BLE001
        out.append(f"raised {type(exc).__name__}: {exc}")
    return out, reader.records, reader.rejected, reader.truncated, reader.errors


def stages(m: dict, settings: Any, nav_path: Path, all_path: Path, nav: list, warm: int) -> dict[str, tuple]:
    nmea = [r for r in nav if r.link == "nmea"]
    can = [r for r in nav if r.link == "can"]

    def read(p: Path) -> Callable[[], Any]:
        return lambda: sum(1 for _ in m["atrlog"].AtrLogReader(p))

    def nmea_run() -> None:
        d = m["nmea"].NmeaDecoder()
        for r in nmea:
            d.feed(r.msg, r.t)

    def can_run() -> None:
        d = m["can"].CanNavDecoder()
        for r in can:
            d.feed(r.msg["id"], r.msg["data"], r.msg["ext"], r.t)

    def nav_run() -> None:
        d = m["decode"].NavDecoder()
        for r in nav:
            d.feed(r)

    def read_decode() -> None:
        d = m["decode"].NavDecoder()
        for r in m["atrlog"].AtrLogReader(nav_path):
            d.feed(r)

    d = m["decode"].NavDecoder()
    fixes = [ev for r in nav for ev in d.feed(r) if type(ev).__name__ == "NavFix"]

    def track_run() -> None:
        tr = m["nav"].NavTrack()
        for f in fixes:
            tr.add(f)

    model = m["model"].PerformanceModel.shipped()

    def pipe_run() -> float:  # the feed loop only, after the first fix built the mission frame
        p = m["pipe"].Pipeline(settings, model=model, workers=0)
        for r in nav[:warm + 1]:
            p.feed(r)
        t0 = time.process_time()
        for r in nav[warm + 1:]:
            p.feed(r)
        dt = time.process_time() - t0
        p.close()
        return dt

    return {"atrlog read (nav)": (read(nav_path), len(nav)), "atrlog read (all)": (read(all_path), None),
            "nmea decode": (nmea_run, len(nmea)), "can decode": (can_run, len(can)),
            "nav decode": (nav_run, len(nav)), "read + nav decode": (read_decode, len(nav)),
            "navtrack add": (track_run, len(fixes)), "pipeline feed (nav)": (pipe_run, len(nav) - warm - 1)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", type=Path, required=True, help="older checkout: holds atr_node/, hw/, config/")
    ap.add_argument("--quick", action="store_true", help="small mission, 2 repeats")
    ap.add_argument("--repeat", type=int, default=None, help="paired runs per stage, best kept (default 9)")
    args = ap.parse_args(argv)
    repeat = args.repeat or (2 if args.quick else 9)

    with tempfile.TemporaryDirectory(prefix="ingest_ab_") as tmpdir:
        tmp = Path(tmpdir)
        renamed_copy(args.base.resolve(), tmp / "base")
        sys.path.insert(0, str(tmp / "base"))
        try:
            differences = _run(args, tmp, repeat)
        finally:  # leave the interpreter as found (the tool runs inside a test too)
            sys.path.remove(str(tmp / "base"))
            for name in [n for n in sys.modules if n.split(".")[0] in ("atr_node_base", "hw_base")]:
                del sys.modules[name]
    print(f"results: {'IDENTICAL' if differences == 0 else f'{differences} DIFFERENCES'}")
    return 0 if differences == 0 else 1


def _run(args: argparse.Namespace, tmp: Path, repeat: int) -> int:
    """Equivalence, then paired speed; the number of differing results."""
    from atr_node.config import Settings
    from atr_node.io.atrlog import AtrLogReader, AtrLogWriter
    from atr_node.records.nav import NavFix
    from atr_node.simulation.mission import generate_mission
    from hw.decode import NavDecoder
    from hw.replay import StampedNmeaLink

    old, new = load("atr_node_base", "hw_base"), load("atr_node", "hw")
    s0 = Settings()
    sim = dataclasses.replace(s0.simulation, mission_legs=1 if args.quick else 4,
                              mission_leg_length_m=100.0 if args.quick else 200.0, mission_swath_m=20,
                              mission_tile_pings=1024)
    settings = s0.replace(simulation=sim)
    files = generate_mission(settings, tmp / "m", seed=11)
    records = list(AtrLogReader(files.atrlog))
    nav = [r for r in records if r.link != "sonar"]
    nav_path = tmp / "nav.atrlog"
    with AtrLogWriter(nav_path, flush_every=1 << 20) as w:
        for r in nav:
            w.write(r.t, r.link, r.msg)
    real = [r for p in sorted(REAL.glob("NBP1406_*")) for r in StampedNmeaLink(p)]
    print(f"equivalence, {args.base} (before) against this tree (after):")
    differences = equivalence(old, new, nav, real, tmp, args.quick)
    dec = NavDecoder()
    warm = next(i for i, r in enumerate(nav)
                if any(isinstance(ev, NavFix) and ev.lat_deg is not None for ev in dec.feed(r)))
    a = stages(old, settings, nav_path, Path(files.atrlog), nav, warm)
    b = stages(new, settings, nav_path, Path(files.atrlog), nav, warm)
    print(f"speed: {len(records)} mission records, paired best of {repeat}, CPU time, us per record")
    print(f"  {'stage':22s} {'records':>8s} {'before':>8s} {'after':>8s} {'speed-up':>9s}")
    for name, (fa, n) in a.items():
        fb, n = b[name][0], n or len(records)
        best = [float("inf"), float("inf")]
        for _ in range(repeat):
            for k, f in enumerate((fa, fb)):
                t0 = time.process_time()
                r = f()
                dt = r if name.startswith("pipeline") else time.process_time() - t0
                best[k] = min(best[k], dt)
        print(f"  {name:22s} {n:8d} {best[0] / n * 1e6:8.2f} {best[1] / n * 1e6:8.2f} {best[0] / best[1]:8.2f}x")
    return differences


if __name__ == "__main__":
    sys.exit(main())
