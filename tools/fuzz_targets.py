"""The parsers under fuzz (tools/fuzz_parsers.py): seeds, mutation and outcome of each."""

from __future__ import annotations

import json
import os
import re
from collections import Counter
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from fuzz_mutations import INTERESTING, _sanitize, mutate_bytes, mutate_struct

REPO = Path(__file__).resolve().parents[1]
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
        from hw.nmea import NmeaDecoder

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
