"""The map engine of batch runs: a Dask cluster (local by default, any scheduler address) or
one process, with retries, progress and a report of every failure.

The same function runs in both modes on the same items, so a serial run is the reference a
cluster run is compared with. A task that raises is resubmitted (``retries`` times, under a
new key, possibly on another worker); each attempt's error is kept, and a task that still
fails is reported in :class:`TaskOutcome`, never dropped silently. Worker deaths surface as
errors of the tasks they held (``KilledWorker``) and are retried the same way.
"""

from __future__ import annotations

import contextlib
import logging
import time
import traceback
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence

log = logging.getLogger(__name__)

Progress = Callable[[int, int, int], None]
"""``progress(done, total, failed)``, called after each task ends (success or final failure)."""


@dataclass(frozen=True)
class TaskOutcome:
    """What became of one item: its result, or the errors of every attempt."""

    name: str
    result: Any = None
    attempts: int = 1
    errors: tuple[str, ...] = ()
    """One line per failed attempt: ``ExceptionType: message``."""
    seconds: float = 0.0
    """From the first submission to the end (queue waits and retries included)."""
    ok: bool = True
    traceback: str = ""


def dask_log_level(level: int) -> None:
    """Set the level of Dask's loggers in this process (its configuration sets each one)."""
    import distributed  # noqa: F401  (configures its loggers on import)

    for name in ["distributed", *logging.root.manager.loggerDict]:
        if name.startswith("distributed"):
            logging.getLogger(name).setLevel(level)


def worker_setup() -> None:
    """Run once on every worker: one OpenCV thread per worker process (a worker owns one core;
    more threads only oversubscribe), and the heavy imports done before the first task."""
    import cv2

    cv2.setNumThreads(1)
    # grids' heavy dependencies, not grids itself: grids imports this module (no circle)
    import atr_node.fusion  # noqa: F401
    import atr_node.node.pipeline  # noqa: F401


@dataclass
class Engine:
    """Where tasks run.

    Parameters
    ----------
    scheduler : str or None
        ``None``: a ``LocalCluster`` of ``workers`` processes with one thread each (started
        here, closed by :meth:`close`); ``"serial"``: this process, one task at a time; any
        other string: the address of a running Dask scheduler (``tcp://host:8786``).
    workers : int
        Local cluster size.
    retries : int
        Resubmissions of a failed task.
    """

    scheduler: str | None = None
    workers: int = 2
    retries: int = 2
    client: Any = field(default=None, init=False)
    cluster: Any = field(default=None, init=False)

    def __post_init__(self) -> None:
        if self.retries < 0 or self.workers < 1:
            raise ValueError(f"batch engine: retries {self.retries} must be >= 0 and workers {self.workers} >= 1")

    @property
    def serial(self) -> bool:
        return self.scheduler == "serial"

    def start(self) -> "Engine":
        if self.serial or self.client is not None:
            return self
        from distributed import Client, LocalCluster

        if self.scheduler is None:
            import dask

            # one thread per worker: our tasks are numpy/OpenCV-bound and each pins a core.
            # Dask's nannies set MALLOC_TRIM_THRESHOLD_=65536, which turns off glibc's dynamic
            # mmap threshold: every large numpy temporary is then mmap'ed and page-faulted
            # afresh, and our tasks ran 1.5-4 times slower than in one process (measured,
            # docs/scaleout.md). None unsets it for the workers of this cluster.
            with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
                self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                            dashboard_address=None, silence_logs=logging.ERROR)
            self.client = Client(self.cluster)
        else:
            self.client = Client(self.scheduler, timeout="20s")
        self.client.run(worker_setup)
        return self

    def describe(self) -> str:
        if self.serial:
            return "serial (this process)"
        if self.cluster is not None:
            return f"local Dask cluster, {self.workers} worker processes x 1 thread"
        return f"Dask scheduler {self.scheduler}"

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None
        if self.cluster is not None:
            self.cluster.close()
            self.cluster = None

    def __enter__(self) -> "Engine":
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ map
    def map(self, fn: Callable[..., Any], items: Sequence[tuple[str, tuple]], *, progress: Progress | None = None,
            **kwargs: Any) -> list[TaskOutcome]:
        """Run ``fn(*args, **kwargs)`` for each ``(name, args)``; outcomes in item order."""
        if self.serial:
            return self._map_serial(fn, items, progress, kwargs)
        return self._map_dask(fn, items, progress, kwargs)

    def _map_serial(self, fn, items, progress, kwargs) -> list[TaskOutcome]:
        out, failed = [], 0
        for i, (name, args) in enumerate(items):
            errors: list[str] = []
            t0 = time.perf_counter()
            for attempt in range(1, self.retries + 2):
                try:
                    res = fn(*args, **kwargs)
                except Exception as exc:  # reported below, never dropped
                    errors.append(f"{type(exc).__name__}: {exc}")
                    tb = traceback.format_exc()
                    log.warning("%s: attempt %d failed: %s", name, attempt, errors[-1])
                    continue
                out.append(TaskOutcome(name, res, attempt, tuple(errors), time.perf_counter() - t0))
                break
            else:
                failed += 1
                out.append(TaskOutcome(name, None, self.retries + 1, tuple(errors), time.perf_counter() - t0,
                                       ok=False, traceback=tb))
            if progress is not None:
                progress(i + 1, len(items), failed)
        return out

    def _map_dask(self, fn, items, progress, kwargs) -> list[TaskOutcome]:
        from distributed import as_completed

        self.start()
        stamp = f"{int(time.time() * 1e3):x}"
        t0 = {i: time.perf_counter() for i in range(len(items))}

        def submit(i: int, attempt: int):
            name, args = items[i]
            fut = self.client.submit(fn, *args, key=f"atr-{stamp}-{i}-{attempt}", pure=False, **kwargs)
            owner[fut.key] = (i, attempt)
            return fut

        owner: dict[str, tuple[int, int]] = {}
        errors: dict[int, list[str]] = {i: [] for i in range(len(items))}
        outcomes: dict[int, TaskOutcome] = {}
        pending = as_completed([submit(i, 1) for i in range(len(items))])
        failed = 0
        for fut in pending:
            i, attempt = owner.pop(fut.key)
            name = items[i][0]
            if fut.status == "finished":
                outcomes[i] = TaskOutcome(name, fut.result(), attempt, tuple(errors[i]), time.perf_counter() - t0[i])
            else:
                try:
                    exc = fut.exception()
                except BaseException as lost:  # cancelled: the scheduler or the client lost it
                    exc = lost
                errors[i].append(f"{type(exc).__name__}: {exc}")
                log.warning("%s: attempt %d failed: %s", name, attempt, errors[i][-1])
                if attempt <= self.retries:
                    pending.add(submit(i, attempt + 1))
                    fut.release()
                    continue
                failed += 1
                try:
                    tb = "".join(traceback.format_exception(type(exc), exc, fut.traceback()))
                except BaseException:
                    tb = "".join(traceback.format_exception(exc))
                outcomes[i] = TaskOutcome(name, None, attempt, tuple(errors[i]), time.perf_counter() - t0[i],
                                          ok=False, traceback=tb)
            fut.release()
            if progress is not None:
                progress(len(outcomes), len(items), failed)
        return [outcomes[i] for i in range(len(items))]


@contextlib.contextmanager
def engine(scheduler: str | None = None, *, workers: int = 2, retries: int = 2) -> Iterator[Engine]:
    """``with engine(...) as e: e.map(...)``: starts and always closes the cluster."""
    e = Engine(scheduler, workers, retries)
    try:
        yield e.start()
    finally:
        e.close()
