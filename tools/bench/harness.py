"""The benchmark harness: repeats, warm-up, median/min/max, paired ratios, machine info, JSON.

Every benchmark times its work through :func:`measure` (one callable, repeated), :func:`paired`
(a candidate against a baseline, alternated in the same process) or :func:`record` (samples it
timed itself, e.g. one per child process). The results go into the active :class:`Run`, which
``atr-node bench SUBJECT --json FILE`` writes out with the machine it ran on.

Why our own and not asv or pyperf: asv benchmarks a package across commits from its own
``benchmarks/`` folder and environment builds, which the fixed top-level layout and the
offline machines rule out; pyperf spawns worker processes per benchmark and wants each
benchmark to be a small function, while ours are end-to-end runs (a replay, a mission) that
set up seconds of state. We take pyperf's statistics (warm-up runs discarded, median with
min and max, never the mean of a skewed sample) and its metadata (CPU, Python, library
versions) in about 150 lines.

Examples
--------
>>> from tools.bench import harness   # doctest: +SKIP
>>> t = harness.measure("sum 1e6", lambda: sum(range(10**6)), repeat=5)   # doctest: +SKIP
>>> t.median_s  # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any, Callable

CLOCKS: dict[str, Callable[[], float]] = {"process": time.process_time, "wall": time.perf_counter}
"""``process``: CPU time of this process (on a shared machine it leaves out the time other jobs
hold the core); ``wall``: elapsed time, for work spread over processes or waiting on I/O."""


@dataclasses.dataclass
class Timing:
    """One measurement: its samples (seconds, warm-up runs not included) and their summary."""

    name: str
    samples_s: list[float]
    clock: str
    warmup: int = 0
    unit: str = "s"
    work: float | None = None
    """Work per sample (pixels, records, ...) in ``work_unit``: the rate is work / time."""
    work_unit: str = ""

    @property
    def median_s(self) -> float:
        return statistics.median(self.samples_s)

    @property
    def min_s(self) -> float:
        return min(self.samples_s)

    @property
    def max_s(self) -> float:
        return max(self.samples_s)

    def rate(self) -> float | None:
        """Work per second at the median time (None without work)."""
        return None if self.work is None or self.median_s <= 0 else self.work / self.median_s

    def to_dict(self) -> dict[str, Any]:
        d = {"name": self.name, "kind": "timing", "clock": self.clock, "warmup": self.warmup,
             "repeat": len(self.samples_s), "samples_s": self.samples_s, "median_s": self.median_s,
             "min_s": self.min_s, "max_s": self.max_s}
        if self.work is not None:
            d.update(work=self.work, work_unit=self.work_unit, rate_per_s=self.rate())
        return d


@dataclasses.dataclass
class Paired:
    """A candidate against a baseline, run alternately: ratios candidate / baseline per pair."""

    name: str
    candidate: Timing
    baseline: Timing

    @property
    def ratios(self) -> list[float]:
        return [c / b for c, b in zip(self.candidate.samples_s, self.baseline.samples_s) if b > 0]

    def to_dict(self) -> dict[str, Any]:
        r = self.ratios
        return {"name": self.name, "kind": "paired", "candidate": self.candidate.to_dict(),
                "baseline": self.baseline.to_dict(), "ratios": r,
                "ratio_median": statistics.median(r) if r else None,
                "ratio_min": min(r) if r else None, "ratio_max": max(r) if r else None}


@dataclasses.dataclass
class Run:
    """The results of one subject's run, with the machine and settings it ran on."""

    subject: str
    options: dict[str, Any] = dataclasses.field(default_factory=dict)
    results: list[Timing | Paired] = dataclasses.field(default_factory=list)
    values: dict[str, Any] = dataclasses.field(default_factory=dict)
    """Figures that are not timings (memory, errors, counts), by name."""

    def to_dict(self) -> dict[str, Any]:
        return {"subject": self.subject, "options": self.options, "machine": machine_info(),
                "results": [r.to_dict() for r in self.results], "values": self.values}


_ACTIVE: list[Run] = []


def active() -> Run:
    """The run results go to: the one :func:`start` opened, else a throw-away one (a benchmark
    script run on its own still works)."""
    if not _ACTIVE:
        _ACTIVE.append(Run("adhoc"))
    return _ACTIVE[-1]


def start(subject: str, **options: Any) -> Run:
    run = Run(subject, dict(options))
    _ACTIVE.append(run)
    return run


def finish() -> Run:
    return _ACTIVE.pop()


def _samples(fn: Callable[[], Any], repeat: int, warmup: int, clock: Callable[[], float]) -> list[float]:
    if repeat < 1:
        raise ValueError(f"repeat must be at least 1, got {repeat}")
    for _ in range(warmup):  # first calls pay for page faults, caches and lazy imports: not kept
        fn()
    out = []
    for _ in range(repeat):
        t0 = clock()
        fn()
        out.append(clock() - t0)
    return out


def measure(name: str, fn: Callable[[], Any], *, repeat: int = 5, warmup: int = 1, clock: str = "process",
            work: float | None = None, work_unit: str = "") -> Timing:
    """Time ``fn()`` ``repeat`` times after ``warmup`` untimed calls; record and return it."""
    t = Timing(name, _samples(fn, repeat, warmup, CLOCKS[clock]), clock, warmup, work=work, work_unit=work_unit)
    active().results.append(t)
    return t


def paired(name: str, candidate: Callable[[], Any], baseline: Callable[[], Any], *, repeat: int = 5,
           warmup: int = 1, clock: str = "process", work: float | None = None, work_unit: str = "") -> Paired:
    """Time a candidate against a baseline in this process, alternating them (baseline first in
    each pair) so that drift of the machine's speed hits both alike; ratios per pair."""
    tick = CLOCKS[clock]
    for _ in range(warmup):
        baseline()
        candidate()
    bs, cs = [], []
    for _ in range(repeat):
        bs += _samples(baseline, 1, 0, tick)
        cs += _samples(candidate, 1, 0, tick)
    p = Paired(name, Timing(f"{name} (candidate)", cs, clock, warmup, work=work, work_unit=work_unit),
               Timing(f"{name} (baseline)", bs, clock, warmup, work=work, work_unit=work_unit))
    active().results.append(p)
    return p


def record(name: str, samples_s: list[float], *, clock: str = "wall", work: float | None = None,
           work_unit: str = "") -> Timing:
    """Samples the benchmark timed itself (one per child process, say)."""
    if not samples_s:
        raise ValueError(f"{name}: no samples")
    t = Timing(name, [float(s) for s in samples_s], clock, 0, work=work, work_unit=work_unit)
    active().results.append(t)
    return t


def value(name: str, v: Any) -> None:
    """A figure that is not a timing (bytes per cell, an error, a count)."""
    active().values[name] = v


def subject_main(doc: str | None, parts: dict[str, Callable[[list[str]], int]], argv: list[str] | None) -> int:
    """Command line of a subject module with several parts (``tools/bench/detectors.py`` ...).

    ``PART [options]`` runs that part with its own options; no arguments or ``--quick`` alone
    runs every part in turn (what ``atr-node bench SUBJECT`` does), the worst exit status kept;
    any other options go to the first part (each old script's command line still works there).
    """
    args = list(sys.argv[1:] if argv is None else argv)
    names = list(parts)
    if args and args[0] in parts:
        return int(parts[args[0]](args[1:]) or 0)
    if args in (["-h"], ["--help"]):
        print((doc or "").strip())
        print(f"\nparts: {', '.join(names)} (PART --help for its options; no PART: every part, or the first "
              f"part, {names[0]}, when options are given)")
        return 0
    if args in ([], ["--quick"]) and len(parts) > 1:
        worst = 0
        for name in names:
            print(f"\n== part {name}", flush=True)
            worst = max(worst, int(parts[name](list(args)) or 0))
        return worst
    return int(parts[names[0]](args) or 0)


def machine_info() -> dict[str, Any]:
    """What the figures depend on: CPU, cores, Python, numpy's BLAS, load at the time."""
    info: dict[str, Any] = {"python": sys.version.split()[0], "platform": platform.platform(),
                            "cpu_count": os.cpu_count(), "machine": platform.machine()}
    try:
        with open("/proc/cpuinfo") as f:
            info["cpu"] = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), "")
    except OSError:
        pass
    try:
        info["loadavg_1min"] = os.getloadavg()[0]
    except OSError:
        pass
    for mod in ("numpy", "scipy", "cv2"):
        m = sys.modules.get(mod)
        if m is not None:
            info[f"{mod}_version"] = getattr(m, "__version__", "")
    info["threads_env"] = {k: os.environ[k] for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                                                       "OPENBLAS_CORETYPE") if k in os.environ}
    return info


def format_table(run: Run) -> str:
    """The run's results as a plain table: median, min, max (ms), and rate or ratio."""
    rows = [("measurement", "median", "min", "max", "rate / ratio")]
    for r in run.results:
        if isinstance(r, Paired):
            ratios = r.ratios
            rows.append((r.name, f"{r.candidate.median_s * 1e3:.2f} ms", f"{r.candidate.min_s * 1e3:.2f} ms",
                         f"{r.candidate.max_s * 1e3:.2f} ms",
                         f"x{statistics.median(ratios):.2f} of baseline ({min(ratios):.2f}-{max(ratios):.2f})"
                         if ratios else "-"))
        else:
            rate = r.rate()
            rows.append((r.name, f"{r.median_s * 1e3:.2f} ms", f"{r.min_s * 1e3:.2f} ms", f"{r.max_s * 1e3:.2f} ms",
                         f"{rate:.4g} {r.work_unit}/s" if rate is not None else ""))
    widths = [max(len(row[i]) for row in rows) for i in range(5)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip() for row in rows]
    lines.insert(1, "-" * len(lines[0]))
    lines += [f"{k}: {v}" for k, v in run.values.items()]
    return "\n".join(lines)


def write_json(run: Run, path: str | Path) -> None:
    """Write the run as JSON (``-`` for stdout); the file appears whole or not at all."""
    text = json.dumps(run.to_dict(), indent=1, default=str)
    if str(path) == "-":
        print(text)
        return
    path = Path(path)
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(text + "\n")
    os.replace(tmp, path)
