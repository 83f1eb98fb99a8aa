#!/usr/bin/env python3
"""Fuzz every parser that sees outside data with structured mutations of valid inputs.

Parsers (``--parsers``, default all):

    tile-bytes  Tile.unpack on mutated msgpack bytes of valid tiles          expects TileError
    tile-map    Tile.from_map on structurally mutated tile maps              expects TileError
    pipeline    Pipeline.feed (the whole node, in-process) on mutated tiles  never raises
    nmea        hw NmeaDecoder.feed on mutated real and encoded sentences    never raises (counts)
    can         hw NavDecoder.feed on mutated CAN records (DBC frames)       never raises (counts)
    atrlog      AtrLogReader on mutated .atrlog files (real files)           never raises (strict:
                                                                             LogFormatError)
    config      load_settings on mutated TOML files                          expects ConfigError
    model       PerformanceModel.load on mutated model files                 expects ModelFileError

Mutations: bit flips, interesting bytes, truncations, insertions, deletions, duplicated
chunks, splices of two seeds (bytes); deleted keys, type swaps, huge and non-finite numbers,
long strings, path-like strings, resized binaries, unknown keys (structures); TOML lines with
swapped values, duplicated or removed; model bodies re-signed (sha256 recomputed) so the
mutation reaches the checks behind the checksum.

Every input ends as one of: accepted, rejected (the expected error, with a reason key),
unclear (the expected error, but its message does not say where: file, tile or field),
crash (any other exception) or hang (over ``--timeout-s``). The exit status is 1 when any
input crashed, hung or was unclear. A memory limit (``--max-memory-gb``) turns runaway
allocations into MemoryError (a crash) instead of the machine's OOM killer.

This one file holds the mutations (part 1), the parsers' seeds and outcomes (part 2) and the
loop and report (part 3); ``--engine atheris`` runs the same parsers under atheris, a
coverage-guided fuzzer (libFuzzer), where it is installed (``pip install atheris``).

Examples::

    python tools/fuzz.py --quick                  # 300 inputs per parser, ~1 min
    python tools/fuzz.py --inputs 20000 --json fuzz.json
    python tools/fuzz.py --parsers nmea,can --inputs 100000 --seed 3
"""

from __future__ import annotations

import sys


# ================================================================================================
# Part 1: mutations, byte-level and structured, from a seeded generator (was fuzz_mutations.py)
# ================================================================================================
# (used by part 3 below and by the Hypothesis tests in tests/reliability/test_fuzz.py)
import copy
import math
from typing import Any

import numpy as np

INTERESTING: list[Any] = [
    None, True, False, 0, -1, 1, 2, 255, 65535, 2**31 - 1, -2**31, 2**63 - 1, -2**63, 2**64 - 1,
    0.0, -0.0, 1e-320, 5e-324, 1e308, -1e308, 1e20, float("nan"), float("inf"), float("-inf"),
    "", "x", "\x00", "é\u202e", "../../../../tmp/atr-fuzz-escape", "/etc/passwd", "A" * 5000,
    b"", b"\x00" * 3, b"\xff" * 17, [], [1], [1, 2], [0, 0], [-1, 5], [2**31, 2**31], [1, 2, 3], {}, {"a": 1},
]
INTERESTING_BYTES = [0x00, 0x01, 0x7F, 0x80, 0xC0, 0xC1, 0xCA, 0xCB, 0xD9, 0xDA, 0xDB, 0xDC, 0xDE, 0xDF, 0xFF]


def mutate_bytes(rng: np.random.Generator, data: bytes, others: list[bytes]) -> bytes:
    """1 to 4 byte-level mutations of ``data``."""
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 5))):
        op = int(rng.integers(0, 8))
        n = len(b)
        if op == 0 and n:  # bit flips
            for _ in range(int(rng.integers(1, 9))):
                i = int(rng.integers(0, n))
                b[i] ^= 1 << int(rng.integers(0, 8))
        elif op == 1 and n:  # interesting byte
            b[int(rng.integers(0, n))] = INTERESTING_BYTES[int(rng.integers(0, len(INTERESTING_BYTES)))]
        elif op == 2 and n:  # truncation
            del b[int(rng.integers(0, n)):]
        elif op == 3:  # insertion of random bytes
            i = int(rng.integers(0, n + 1))
            b[i:i] = rng.integers(0, 256, int(rng.integers(1, 32)), dtype=np.uint8).tobytes()
        elif op == 4 and n:  # deletion of a chunk
            i = int(rng.integers(0, n))
            del b[i:i + int(rng.integers(1, 64))]
        elif op == 5 and n:  # duplicated chunk
            i = int(rng.integers(0, n))
            chunk = b[i:i + int(rng.integers(1, 256))]
            j = int(rng.integers(0, n + 1))
            b[j:j] = chunk
        elif op == 6 and others:  # splice with another seed
            o = others[int(rng.integers(0, len(others)))]
            i, j = int(rng.integers(0, n + 1)), int(rng.integers(0, len(o) + 1))
            b = b[:i] + bytearray(o[j:])
        elif op == 7 and n >= 4:  # overwrite 4 bytes with an extreme integer
            i = int(rng.integers(0, n - 3))
            b[i:i + 4] = int(rng.choice([0, 0xFFFFFFFF, 0x7FFFFFFF, 0x80000000])).to_bytes(4, "big")
    return bytes(b)


def _slots(obj: Any, out: list[tuple[Any, Any]]) -> list[tuple[Any, Any]]:
    """Every (container, key) of a nested structure of dicts and lists."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            out.append((obj, k))
            _slots(v, out)
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out.append((obj, i))
            _slots(v, out)
    return out


def _extreme(rng: np.random.Generator, v: Any) -> Any:
    """A value of the same type as ``v`` but extreme."""
    if isinstance(v, bool):
        return not v
    if isinstance(v, int):
        return int(rng.choice([0, -1, v + 1, v - 1, 2**31, 2**63 - 1, -2**63, v * 1000]))
    if isinstance(v, float):
        return float(rng.choice([0.0, -v, v * 1e300, v * 1e-300, 1e308, -1e308, 5e-324, math.nan, math.inf]))
    if isinstance(v, str):
        return str(rng.choice(["", v * 50, v + "\x00", "../" * 8 + v, v.upper(), "\ud7ff" + v]))
    if isinstance(v, (bytes, bytearray)):
        n = len(v)
        k = int(rng.integers(0, 4))
        if k == 0:
            return bytes(v[: int(rng.integers(0, n + 1))])
        if k == 1:
            return bytes(v) + bytes(int(rng.integers(1, 64)))
        if k == 2 and n:
            b = bytearray(v)
            b[int(rng.integers(0, n))] ^= 0xFF
            return bytes(b)
        return np.full(max(n // 8, 1), rng.choice([np.nan, np.inf, -np.inf, -1.0, 1e300]), "<f8").tobytes()[:n] or b"\x00"
    if isinstance(v, list):
        return v[:-1] if v and rng.random() < 0.5 else v + v
    return None


def mutate_struct(rng: np.random.Generator, obj: Any) -> Any:
    """1 to 3 structural mutations of a deep copy of ``obj`` (dicts, lists, scalars)."""
    out = copy.deepcopy(obj)
    for _ in range(int(rng.integers(1, 4))):
        slots = _slots(out, [])
        if not slots:
            return INTERESTING[int(rng.integers(0, len(INTERESTING)))]
        parent, key = slots[int(rng.integers(0, len(slots)))]
        op = int(rng.integers(0, 6))
        if op == 0 and isinstance(parent, dict):
            del parent[key]
        elif op == 1:
            parent[key] = copy.deepcopy(INTERESTING[int(rng.integers(0, len(INTERESTING)))])
        elif op == 2:
            parent[key] = _extreme(rng, parent[key])
        elif op == 3 and isinstance(parent, dict):
            parent[str(rng.choice(["extra", "v2", "\x00", "data2", key if isinstance(key, str) else "k"])) + "_"] = 1
        elif op == 4:  # type swap
            v = parent[key]
            parent[key] = str(v)[:100] if not isinstance(v, str) else [v]
        else:
            parent[key] = _extreme(rng, parent[key])
    return out


def _sanitize(obj: Any) -> Any:
    """Make a mutated structure packable by msgpack (ints out of 64-bit range become floats)."""
    if isinstance(obj, dict):
        return {(_sanitize(k) if isinstance(k, (str, int, bytes)) else str(k)): _sanitize(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_sanitize(v) for v in obj]
    if isinstance(obj, int) and not isinstance(obj, bool) and not -2**63 <= obj < 2**64:
        return float(obj)
    return obj


# ================================================================================================
# Part 2: the parsers under fuzz: seeds, mutation and outcome of each (was fuzz_targets.py)
# ================================================================================================
# The parsers under fuzz : seeds, mutation and outcome of each.
import json
import os
import re
from collections import Counter
from pathlib import Path

import msgpack


REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # hw/ is a top-level package of the checkout
    sys.path.insert(0, str(REPO))
REAL = Path(os.environ.get("ATR_REAL_DATA", REPO.parent / "shared" / "data" / "real"))


def _norm(msg: str, *paths: str) -> str:
    """A rejection reason key: the message without file paths, numbers and quoted values."""
    for p in paths:
        if p:
            msg = msg.replace(p, "FILE")
    msg = re.sub(r"'[^']*'|\"[^\"]*\"", "'…'", msg)
    msg = re.sub(r"b'…'|\[[^\]]*\]|\{[^}]*\}", "…", msg)
    msg = re.sub(r"-?\d+(\.\d+)?(e[-+]?\d+)?", "N", msg)
    return msg[:90]


class Target:
    """One parser under fuzz: seeds, a mutation, and a run that classifies the outcome."""

    name = ""
    expected: tuple[type[BaseException], ...] = ()
    core = 1000
    """The first ``core`` seeds (our own encodings) are mutated more often than the rest (real traffic)."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp

    def seeds(self) -> list[Any]:
        raise NotImplementedError

    def mutate(self, rng: np.random.Generator, seed: Any, seeds: list[Any]) -> Any:
        raise NotImplementedError

    def run(self, data: Any) -> str | None:
        """Parse ``data``: return None (accepted) or a rejection reason; raise the expected
        error on rejection (classified by :meth:`reason`)."""
        raise NotImplementedError

    def reason(self, exc: BaseException) -> str | None:
        """The reason key of an expected error, or None when its message does not say where."""
        return _norm(str(exc))


def _tile_seeds() -> list[Any]:
    from atr_node.records.tile import SensorInfo, Tile, TileNav

    rng = np.random.default_rng(0)
    out = []
    for k, (rows, cols, dtype, slant, nav) in enumerate([(24, 48, "float32", False, True), (16, 40, "uint16", True, True),
                                                       (8, 20, "uint8", False, False), (32, 64, "float32", False, True)]):
        px = rng.gamma(2.0, 0.5, (rows, cols)).astype(np.float32)
        px[:, :3] = np.nan
        if dtype != "float32":
            px = np.round(px * 40 + 1)
        t0 = 1.7e9 + 10 * k
        n = None
        if nav:
            n = TileNav(lat_deg=44.1 + 1e-6 * np.arange(rows), lon_deg=np.full(rows, 9.85),
                        heading_deg=np.full(rows, 90.0), altitude_m=np.full(rows, 12.0))
        info = SensorInfo(frequency_hz=120e3, bandwidth_hz=15e3, tx_length_m=0.2, rx_length_m=1.2, n_rx=24, sas=True)
        tile = Tile(mission="fuzz", leg=k // 2, side=("port", "stbd")[k % 2], seq=k, pixels=px, kind="intensity",
                    range0_m=0.5 if slant else 0.0, dr_m=0.1, dx_m=0.1, slant=slant,
                    ping_time=t0 + 0.05 * np.arange(rows), nav=n, sensor=info if k % 2 == 0 else None)
        m = tile.to_map()
        m["dtype"] = dtype
        if dtype != "float32":
            m["data"] = np.nan_to_num(px, nan=0).astype(np.dtype(dtype).newbyteorder("<")).tobytes()
        out.append(m)
    return out


class TileMapTarget(Target):
    name = "tile-map"

    def __init__(self, tmp: Path) -> None:
        super().__init__(tmp)
        from atr_node.errors import TileError
        from atr_node.records.tile import Tile

        self.expected = (TileError,)
        self.parse = Tile.from_map

    def seeds(self) -> list[Any]:
        return _tile_seeds()

    def mutate(self, rng, seed, seeds):
        return mutate_struct(rng, seed)

    def run(self, data):
        self.parse(data)
        return None

    def reason(self, exc):
        # clear: names the tile (mission, side, seq or "tile ?") and, but for "not a map", a field
        if not str(exc).startswith(("tile", getattr(exc, "tile", "?"))):
            return None
        return f"field {exc.field}" if exc.field else _norm(str(exc))


class TileBytesTarget(TileMapTarget):
    name = "tile-bytes"

    def __init__(self, tmp: Path) -> None:
        super().__init__(tmp)
        from atr_node.records.tile import Tile

        self.parse = Tile.unpack

    def seeds(self):
        return [msgpack.packb(m, use_bin_type=True) for m in _tile_seeds()]

    def mutate(self, rng, seed, seeds):
        if rng.random() < 0.3:  # a structured mutation, packed
            return msgpack.packb(_sanitize(mutate_struct(rng, msgpack.unpackb(seed, raw=False))), use_bin_type=True)
        return mutate_bytes(rng, seed, seeds)


class PipelineTarget(Target):
    """Mutated tiles (and a few nav records) through the whole in-process pipeline."""

    name = "pipeline"

    def __init__(self, tmp: Path) -> None:
        super().__init__(tmp)
        self.pipe = None
        self.n = 0

    def seeds(self):
        return _tile_seeds()

    def mutate(self, rng, seed, seeds):
        return _sanitize(mutate_struct(rng, seed))

    def _pipeline(self):
        from atr_node.calibration.model import PerformanceModel
        from atr_node.config import Settings
        from atr_node.node.pipeline import Pipeline

        if self.pipe is None or self.n % 200 == 0:
            if self.pipe is not None:
                self.pipe.finish()
                self.pipe.close()
            self.pipe = Pipeline(Settings(), model=PerformanceModel.shipped(), workers=0, mode="replay")
        self.n += 1
        return self.pipe

    def run(self, data):
        from atr_node.io.atrlog import LogRecord

        pipe = self._pipeline()
        before = pipe.stats.tiles_rejected
        pipe.feed(LogRecord(t=1.7e9 + self.n, link="sonar", msg=data))
        if pipe.stats.tiles_rejected > before:
            return "tile rejected: " + ", ".join(k for k in pipe.stats.rejections)[:60]
        return None


class NmeaTarget(Target):
    name = "nmea"
    core = 7

    def __init__(self, tmp: Path) -> None:
        super().__init__(tmp)
        from hw.nmea_decoder import NmeaDecoder

        self.decoder = NmeaDecoder()

    def seeds(self):
        from hw import nmea

        t = 1.7e9
        out = [nmea.encode_gga(t, 44.1, 9.85), nmea.encode_rmc(t, -22.0, -17.9, speed_m_s=2.0, course_deg=271.0),
               nmea.encode_hdt(359.99), nmea.encode_ths(12.5), nmea.encode_vtg(90.0, 2.0), nmea.encode_zda(t),
               nmea.encode_dpt(12.5, offset_m=0.3)]
        out = [s.rstrip() for s in out]
        for f in sorted((REAL / "nmea").glob("NBP1406_*")):
            for line in f.read_text(errors="replace").splitlines()[:200]:
                if "$" in line:
                    out.append(line.split(" ", 1)[-1].encode())
        return out

    def mutate(self, rng, seed, seeds):
        from hw.nmea import checksum

        if rng.random() < 0.5 and b"*" in seed and seed.startswith(b"$"):
            body = seed[1:seed.rindex(b"*")].split(b",")
            for _ in range(int(rng.integers(1, 3))):
                i = int(rng.integers(0, len(body)))
                body[i] = bytes(rng.choice([b"", b"-", b"999999", b"1e308", b"nan", b"inf", b"12.3.4", b"-0", b"N",
                                            b"Z", b"\xff", b"235960.00", b"000000.00", b"9" * 40, b"+1", b"0x1F",
                                            b"-9999.9", b"3600.0", b"1_0", b"\xd9\xa3"]))
            out = b",".join(body)
            cs = checksum(out) if rng.random() < 0.8 else int(rng.integers(0, 256))
            return b"$" + out + b"*%02X" % cs
        return mutate_bytes(rng, seed, seeds)

    def run(self, data):
        before = Counter(self.decoder.counts)
        self.decoder.feed(data, 1.7e9)
        diff = self.decoder.counts - before
        rej = [k for k in diff if k != "accepted"]
        return f"counted {rej[0]}" if rej else None


class CanTarget(Target):
    name = "can"
    core = 6

    def __init__(self, tmp: Path) -> None:
        super().__init__(tmp)
        from hw.decode import NavDecoder

        self.decoder = NavDecoder()

    def seeds(self):
        from hw import can_nav

        frames = [can_nav.encode_position(44.1, 9.85), can_nav.encode_attitude(271.5, speed_m_s=2.0),
                  can_nav.encode_altitude(12.0, depth_m=20.0), can_nav.encode_altitude(None),
                  can_nav.encode_time(1.7e9), can_nav.encode_leg(3)]
        out = [{"id": i, "data": d, "ext": e} for i, d, e in frames]
        p = REAL / "can" / "candumpSample3.txt"
        if p.is_file():
            for line in p.read_text().splitlines()[:300]:
                m = re.match(r"\(\S+\) \S+ ([0-9A-Fa-f]+)#([0-9A-Fa-f]*)", line)
                if m:
                    out.append({"id": int(m.group(1), 16), "data": bytes.fromhex(m.group(2)), "ext": len(m.group(1)) > 3})
        return out

    def mutate(self, rng, seed, seeds):
        r = rng.random()
        if r < 0.4:
            m = dict(seed)
            m["data"] = mutate_bytes(rng, m["data"], [s["data"] for s in seeds[:6]])[:64]
            return m
        if r < 0.6:
            m = dict(seed)
            m["id"] = int(rng.choice([s["id"] for s in seeds[:6]] + [0, 0x7FF, 0x1FFFFFFF, int(rng.integers(0, 2**29))]))
            m["ext"] = bool(rng.random() < 0.5)
            return m
        return mutate_struct(rng, seed)

    def run(self, data):
        from atr_node.io.atrlog import LogRecord

        before = Counter(self.decoder.can.counts)
        self.decoder.feed(LogRecord(t=1.7e9, link="can", msg=data))
        diff = self.decoder.can.counts - before
        rej = [k for k in diff if k != "accepted"]
        return f"counted {rej[0]}" if rej else None


class AtrlogTarget(Target):
    name = "atrlog"

    def __init__(self, tmp: Path) -> None:
        super().__init__(tmp)
        from atr_node.errors import LogFormatError

        self.expected = (LogFormatError,)
        self.path = tmp / "fuzz.atrlog"

    def seeds(self):
        from atr_node.io.atrlog import AtrLogWriter

        nmea = NmeaTarget(self.tmp).seeds()[:7]
        can = CanTarget(self.tmp).seeds()[:6]
        tiles = _tile_seeds()[:2]
        out = []
        for k in range(3):
            p = self.tmp / f"seed{k}.atrlog"
            with AtrLogWriter(p) as w:
                t = 1.7e9
                for i in range(6):
                    w.write(t + i, "nmea", nmea[(i + k) % len(nmea)])
                    w.write(t + i + 0.1, "can", can[(i + k) % len(can)])
                w.write(t + 7, "sonar", tiles[k % 2])
            out.append(p.read_bytes())
        return out

    def mutate(self, rng, seed, seeds):
        if rng.random() < 0.3:  # mutate one record's structure
            unp = msgpack.Unpacker(raw=False, strict_map_key=False)
            unp.feed(seed)
            recs = list(unp)
            i = int(rng.integers(0, len(recs)))
            recs[i] = _sanitize(mutate_struct(rng, recs[i]))
            return b"".join(msgpack.packb(r, use_bin_type=True) for r in recs)
        return mutate_bytes(rng, seed, seeds)

    def run(self, data):
        from atr_node.io.atrlog import AtrLogReader

        self.path.write_bytes(data)
        reader = AtrLogReader(self.path)
        try:
            for _ in reader:  # lenient (as the replay reads): raises only on a file with no valid record
                pass
        except self.expected as exc:
            if reader.records or str(self.path) not in str(exc) or (
                    "no valid record" not in str(exc) and "empty file" not in str(exc)):
                raise
            return "no valid record"
        for e in reader.errors:
            if str(self.path) not in e or "byte" not in e:
                raise AssertionError(f"unclear log warning (no file and byte offset): {e}")
        try:
            for _ in AtrLogReader(self.path, strict=True):
                pass
        except self.expected as exc:
            if str(self.path) not in str(exc) or "byte" not in str(exc):
                raise AssertionError(f"unclear error (no file and byte offset): {exc}") from None
        if reader.truncated:
            return "truncated last record"
        if reader.rejected:
            return _norm(reader.errors[0].split(": ", 1)[-1], str(self.path))
        return None


class ConfigTarget(Target):
    name = "config"

    VALUES = ['""', '-1', '0', '1e308', 'nan', 'inf', '-inf', 'true', '[]', '[1, "a"]', '{a = 1}', '"' + "x" * 300 + '"',
              '9223372036854775807', '-0.0', '1e-320', '"../../../../tmp/atr-fuzz"', '2026-01-01', "'''\n'''", '0x10',
              '[[]]', '"mf"', '["mf", "mf"]', '["zz"]', '1_000', '+inf']

    def __init__(self, tmp: Path) -> None:
        super().__init__(tmp)
        from atr_node.config import load_settings
        from atr_node.errors import ConfigError

        self.expected = (ConfigError,)
        self.load = load_settings
        self.path = tmp / "fuzz.toml"

    def seeds(self):
        default = (REPO / "config" / "default.toml").read_text()
        return [default, "[node]\nqueue_tiles = 4\n[links]\nnmea_url = \"loop://\"\n",
                "[detectors]\nenabled = [\"mf\", \"z\"]\n[detectors.threshold]\nmf = 1.2\n"]

    def mutate(self, rng, seed, seeds):
        if rng.random() < 0.2:
            return mutate_bytes(rng, seed.encode(), [s.encode() for s in seeds]).decode("utf-8", "replace")
        lines = seed.splitlines()
        for _ in range(int(rng.integers(1, 4))):
            i = int(rng.integers(0, len(lines)))
            op = int(rng.integers(0, 5))
            if op <= 1 and "=" in lines[i]:
                key = lines[i].split("=", 1)[0]
                lines[i] = f"{key}= {self.VALUES[int(rng.integers(0, len(self.VALUES)))]}"
            elif op == 2:
                del lines[i]
            elif op == 3:
                lines.insert(i, lines[i])  # duplicate key or table: a TOML error
            else:
                lines.insert(i, str(rng.choice(["unknown_key = 1", "[nosuch]", "[node.extra]", "include = \"nofile.toml\"",
                                                "include = \"/etc/hostname\"", "[[node]]", "x."])))
        return "\n".join(lines) + "\n"

    def run(self, data):
        self.path.write_text(data, encoding="utf-8", errors="surrogateescape")
        self.load(self.path)
        return None

    def reason(self, exc):
        # clear: names the file (this one, or the one it includes) and, when it is about a value, the key
        return _norm(str(exc), str(self.path)) if str(exc).startswith("file ") else None


class ModelTarget(Target):
    name = "model"

    def __init__(self, tmp: Path) -> None:
        super().__init__(tmp)
        from atr_node.calibration import model as m
        from atr_node.errors import ModelFileError

        self.m = m
        self.expected = (ModelFileError,)
        self.path = tmp / "fuzz_model.json"

    def seeds(self):
        return [Path(self.m.SHIPPED_MODEL).read_text()]

    def mutate(self, rng, seed, seeds):
        if rng.random() < 0.15:
            return mutate_bytes(rng, seed.encode(), []).decode("utf-8", "replace")
        body = mutate_struct(rng, json.loads(seed))
        if isinstance(body, dict) and rng.random() < 0.8:  # re-sign: reach the checks behind the checksum
            body.pop("sha256", None)
            try:
                body["sha256"] = self.m._digest(body)
            except (TypeError, ValueError):
                pass
        return json.dumps(body, allow_nan=True, default=lambda o: o.decode("latin-1") if isinstance(o, bytes) else str(o))

    def run(self, data):
        self.path.write_text(data, encoding="utf-8", errors="surrogateescape")
        model = self.m.PerformanceModel.load(self.path)
        # an accepted model must be usable: confidence strictly in (0, 1), Pd in [0, 1]
        g = np.array([-1e9, -1.0, 0.0, 0.5, 1.0, 10.0, 1e9])
        for d in model.tau:
            c = np.asarray(model.confidence(d, g))
            p = np.asarray(model.pd(d, np.array([0.0, 5.0, 50.0, 1e6])))
            if not (np.all((c > 0) & (c < 1)) and np.all((p >= 0) & (p <= 1))):
                raise AssertionError(f"accepted model gives confidence {c} or Pd {p} out of range")
        return None

    def reason(self, exc):
        return _norm(str(exc), str(self.path)) if str(self.path) in str(exc) else None


TARGETS: dict[str, type[Target]] = {t.name: t for t in (TileBytesTarget, TileMapTarget, PipelineTarget, NmeaTarget,
                                                        CanTarget, AtrlogTarget, ConfigTarget, ModelTarget)}


# ================================================================================================
# Part 3: the loop and the report (was fuzz_parsers.py)
# ================================================================================================
import argparse
import resource
import signal
import subprocess
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from typing import Callable



__all__ = ["INTERESTING", "TARGETS", "Result", "fuzz", "main", "mutate_bytes", "mutate_struct", "_sanitize",
           "_tile_seeds", "AtrlogTarget", "CanTarget", "ConfigTarget", "ModelTarget", "NmeaTarget",
           "PipelineTarget", "Target", "TileBytesTarget", "TileMapTarget", "_norm"]


class Hang(BaseException):
    """Raised by the alarm when one input takes longer than the time limit."""


@dataclass
class Result:
    """Counts and examples of one parser's run."""

    name: str
    inputs: int = 0
    accepted: int = 0
    rejected: int = 0
    unclear: int = 0
    crashes: int = 0
    hangs: int = 0
    seconds: float = 0.0
    reasons: Counter = field(default_factory=Counter)
    failures: list[dict[str, str]] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.crashes == 0 and self.hangs == 0 and self.unclear == 0


# -- the loop ---------------------------------------------------------------------------------

def _alarm(signum, frame):
    raise Hang()


def fuzz(name: str, n_inputs: int, *, seed: int = 0, timeout_s: float = 5.0, tmp: Path | None = None,
         crash_dir: Path | None = None, progress: Callable[[str], None] | None = None) -> Result:
    """Run ``n_inputs`` mutated inputs through one parser; return the counts."""
    tmp = Path(tmp or tempfile.mkdtemp(prefix="atr-fuzz-"))
    target = TARGETS[name](tmp)
    seeds = target.seeds()
    rng = np.random.default_rng([seed, sorted(TARGETS).index(name)])
    res = Result(name)
    n_seeds = min(len(seeds), max(1, n_inputs // 20))
    use_alarm = hasattr(signal, "SIGALRM") and timeout_s > 0
    if use_alarm:
        old = signal.signal(signal.SIGALRM, _alarm)
    t0 = time.perf_counter()
    try:
        for i in range(n_inputs):
            s = seeds[int(rng.integers(0, min(len(seeds), target.core))) if rng.random() < 0.6
                      else int(rng.integers(0, len(seeds)))]
            data = seeds[i] if i < n_seeds else target.mutate(rng, s, seeds)  # a few seeds as they are first
            res.inputs += 1
            try:
                if use_alarm:
                    signal.setitimer(signal.ITIMER_REAL, timeout_s)
                try:
                    why = target.run(data)
                finally:
                    if use_alarm:
                        signal.setitimer(signal.ITIMER_REAL, 0)
            except Hang:
                res.hangs += 1
                _keep(res, crash_dir, name, i, data, "hang", f"over {timeout_s} s")
                continue
            except target.expected as exc:
                key = target.reason(exc)
                if key is None:
                    res.unclear += 1
                    _keep(res, crash_dir, name, i, data, "unclear", str(exc)[:300])
                else:
                    res.rejected += 1
                    res.reasons[key] += 1
                continue
            except Exception as exc:  # the point: anything else is a crash to report
                res.crashes += 1
                tb = traceback.extract_tb(exc.__traceback__)[-1]
                _keep(res, crash_dir, name, i, data, "crash",
                      f"{type(exc).__name__}: {str(exc)[:200]} at {Path(tb.filename).name}:{tb.lineno}")
                continue
            if why is None:
                res.accepted += 1
            else:
                res.rejected += 1
                res.reasons[why] += 1
            if progress is not None and (i + 1) % 1000 == 0:
                progress(f"{name}: {i + 1}/{n_inputs}")
    finally:
        if use_alarm:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, old)
        if isinstance(target, PipelineTarget) and target.pipe is not None:
            target.pipe.close()
    res.seconds = time.perf_counter() - t0
    return res


def _keep(res: Result, crash_dir: Path | None, name: str, i: int, data: Any, kind: str, what: str) -> None:
    if len(res.failures) < 20:
        res.failures.append({"input": str(i), "kind": kind, "what": what, "data": repr(data)[:300]})
    if crash_dir is not None:
        crash_dir.mkdir(parents=True, exist_ok=True)
        payload = data if isinstance(data, bytes) else (data.encode("utf-8", "surrogateescape") if isinstance(data, str)
                                                        else msgpack.packb(_sanitize(data), use_bin_type=True))
        (crash_dir / f"{name}-{kind}-{i}.bin").write_bytes(payload)


def print_table(results: list[Result], *, top: int = 6, file=None) -> None:
    file = file or sys.stdout
    print(f"{'parser':<11} {'inputs':>8} {'accepted':>9} {'rejected':>9} {'unclear':>8} {'crashes':>8} {'hangs':>6} "
          f"{'s':>7} {'inputs/s':>9}", file=file)
    for r in results:
        print(f"{r.name:<11} {r.inputs:>8} {r.accepted:>9} {r.rejected:>9} {r.unclear:>8} {r.crashes:>8} {r.hangs:>6} "
              f"{r.seconds:>7.1f} {r.inputs / max(r.seconds, 1e-9):>9.0f}", file=file)
    tot = sum(r.inputs for r in results)
    bad = sum(r.crashes + r.hangs + r.unclear for r in results)
    print(f"{'total':<11} {tot:>8}   crashes + hangs + unclear: {bad}", file=file)
    for r in results:
        print(f"\n{r.name}: rejections by reason (top {top} of {len(r.reasons)})", file=file)
        for why, n in r.reasons.most_common(top):
            print(f"  {n:>7}  {why}", file=file)
        for f in r.failures[:5]:
            print(f"  !! {f['kind']} input {f['input']}: {f['what']}\n     {f['data'][:160]}", file=file)


def fuzz_atheris(name: str, runs: int, *, seed: int, timeout_s: float, tmp: Path, findings: Path) -> None:
    """Fuzz one parser under atheris (coverage-guided, libFuzzer) for ``runs`` inputs; never returns.

    Parsers whose seeds are bytes or text are fed libFuzzer's inputs directly, started from a
    corpus of the seeds; the others (tile maps, the pipeline) take a seed and a mutation chosen
    by the input's bytes, so coverage steers the structured mutations. An unexpected exception
    or a rejection whose message does not say where is a finding: libFuzzer stops, saves the
    input (``crash-*``) and exits non-zero.
    """
    import atheris

    target = TARGETS[name](tmp)
    seeds = target.seeds()
    kind = bytes if all(isinstance(x, bytes) for x in seeds) else str if all(isinstance(x, str) for x in seeds) else None
    corpus = tmp / f"corpus-{name}"
    corpus.mkdir(parents=True, exist_ok=True)
    if kind is not None:
        for i, x in enumerate(seeds[:200]):
            (corpus / f"seed{i}").write_bytes(x if kind is bytes else x.encode("utf-8", "surrogateescape"))

    def one_input(data: bytes) -> None:
        if kind is bytes:
            x: Any = data
        elif kind is str:
            x = data.decode("utf-8", "surrogateescape")
        else:
            fdp = atheris.FuzzedDataProvider(data)
            s = seeds[fdp.ConsumeIntInRange(0, len(seeds) - 1)]
            x = target.mutate(np.random.default_rng(list(fdp.ConsumeBytes(16)) or [0]), s, seeds)
        try:
            target.run(x)
        except target.expected as exc:
            if target.reason(exc) is None:
                raise AssertionError(f"{name}: the rejection does not say where: {exc}") from exc

    atheris.instrument_all()
    atheris.Setup([sys.argv[0], f"-runs={runs}", f"-seed={seed + 1}", f"-timeout={max(1, int(timeout_s))}",
                   "-rss_limit_mb=6144", f"-artifact_prefix={findings}/", str(corpus)], one_input)
    atheris.Fuzz()


def _run_atheris(names: list[str], n: int, args: argparse.Namespace) -> int:
    """One child process per parser (libFuzzer ends its process): 0 when none found anything."""
    try:
        import atheris  # noqa: F401  (only whether it imports)
    except ImportError as exc:
        print(f"fuzz: --engine atheris needs atheris (pip install atheris): {exc}", file=sys.stderr)
        return 2
    worst = 0
    findings = Path(args.crash_dir or tempfile.mkdtemp(prefix="atr-fuzz-findings-"))  # kept: the inputs to replay
    findings.mkdir(parents=True, exist_ok=True)
    print(f"{'parser':<12}{'inputs':>8}  result (findings, if any, saved in {findings})")
    for name in names:
        k = max(n // 10, 10) if name == "pipeline" else n
        cmd = [sys.executable, __file__, "--engine", "atheris", "--parsers", name, "--inputs", str(k),
               "--seed", str(args.seed), "--timeout-s", str(args.timeout_s), "--crash-dir", str(findings)]
        # libFuzzer ends the child with exit(), past any clean-up of its own: the parent owns its folder
        with tempfile.TemporaryDirectory(prefix="atr-fuzz-") as work:
            r = subprocess.run(cmd, env={**os.environ, "ATR_FUZZ_ATHERIS_CHILD": work}, capture_output=True, text=True)
        tail = [ln for ln in r.stderr.splitlines() if "Done" in ln or "ERROR" in ln or "Test unit written" in ln]
        print(f"{name:<12}{k:>8}  {'no finding' if r.returncode == 0 else f'FOUND (exit {r.returncode})'}"
              f"  {tail[-1] if tail else ''}")
        worst = max(worst, 0 if r.returncode == 0 else 1)
    return worst


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--parsers", default=",".join(TARGETS), help=f"comma-separated, of: {', '.join(TARGETS)}")
    ap.add_argument("--inputs", type=int, default=5000, help="inputs per parser (default 5000; pipeline: a tenth)")
    ap.add_argument("--quick", action="store_true", help="300 inputs per parser (pipeline: 60)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout-s", type=float, default=10.0, help="an input taking longer is a hang (default 10)")
    ap.add_argument("--max-memory-gb", type=float, default=6.0, help="address-space limit (0 = none)")
    ap.add_argument("--json", metavar="FILE", help="write the counts and failures as JSON")
    ap.add_argument("--crash-dir", metavar="DIR", help="save every crashing, hanging or unclear input here")
    ap.add_argument("--engine", choices=("mutation", "atheris"), default="mutation",
                    help="mutation: our structured mutations, counts per outcome (default); atheris: coverage-guided "
                         "(libFuzzer), stops at the first finding; needs 'pip install atheris'")
    args = ap.parse_args(argv)
    names = [n.strip() for n in args.parsers.split(",") if n.strip()]
    unknown = [n for n in names if n not in TARGETS]
    if unknown:
        ap.error(f"unknown parser(s) {unknown}; expected some of {list(TARGETS)}")
    if args.max_memory_gb > 0:
        lim = int(args.max_memory_gb * (1 << 30))
        resource.setrlimit(resource.RLIMIT_AS, (lim, lim))
    import logging

    import warnings

    n = 300 if args.quick else args.inputs
    if args.engine == "atheris":
        work = os.environ.get("ATR_FUZZ_ATHERIS_CHILD")
        if work:  # the parent's folder, removed by the parent once libFuzzer has ended this process
            fuzz_atheris(names[0], n, seed=args.seed, timeout_s=args.timeout_s, tmp=Path(work),
                         findings=Path(args.crash_dir or "."))
        return _run_atheris(names, n, args)
    results = []
    logging.disable(logging.CRITICAL)  # rejections are counted, not logged
    try:
        with tempfile.TemporaryDirectory(prefix="atr-fuzz-") as tmp, warnings.catch_warnings():
            warnings.simplefilter("ignore")  # overflow warnings of extreme (rejected or harmless) values
            for name in names:
                k = max(n // (5 if args.quick else 10), 10) if name == "pipeline" else n
                results.append(fuzz(name, k, seed=args.seed, timeout_s=args.timeout_s, tmp=Path(tmp),
                                    crash_dir=Path(args.crash_dir) if args.crash_dir else None,
                                    progress=lambda s: print(s, file=sys.stderr, flush=True)))
    finally:
        logging.disable(logging.NOTSET)
    print(f"fuzz: seed {args.seed}, machine load {os.getloadavg()[0]:.1f} (2 cores, shared)")
    print_table(results)
    if args.json:
        Path(args.json).write_text(json.dumps([{**{k: v for k, v in vars(r).items() if k != "reasons"},
                                                "reasons": dict(r.reasons)} for r in results], indent=1))
    return 0 if all(r.ok for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
