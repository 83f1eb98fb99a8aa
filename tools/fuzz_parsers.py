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

The mutations are in ``tools/fuzz_mutations.py``, the parsers' seeds and outcomes in
``tools/fuzz_targets.py``; this script is the loop and the report.

Examples::

    python tools/fuzz_parsers.py --quick                  # 300 inputs per parser, ~1 min
    python tools/fuzz_parsers.py --inputs 20000 --json fuzz.json
    python tools/fuzz_parsers.py --parsers nmea,can --inputs 100000 --seed 3
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import signal
import sys
import tempfile
import time
import traceback
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import msgpack
import numpy as np

REPO = Path(__file__).resolve().parents[1]
for _p in (str(REPO), str(Path(__file__).resolve().parent)):
    if _p not in sys.path:
        sys.path.insert(0, _p)

from fuzz_mutations import INTERESTING, _sanitize, mutate_bytes, mutate_struct  # noqa: E402
from fuzz_targets import (TARGETS, AtrlogTarget, CanTarget, ConfigTarget, ModelTarget, NmeaTarget,  # noqa: E402
                          PipelineTarget, Target, TileBytesTarget, TileMapTarget, _norm, _tile_seeds)

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
    print(f"fuzz_parsers: seed {args.seed}, machine load {os.getloadavg()[0]:.1f} (2 cores, shared)")
    print_table(results)
    if args.json:
        Path(args.json).write_text(json.dumps([{**{k: v for k, v in vars(r).items() if k != "reasons"},
                                                "reasons": dict(r.reasons)} for r in results], indent=1))
    return 0 if all(r.ok for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
