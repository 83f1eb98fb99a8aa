"""On-line calibration: a worker process that calibrates on the mission's first tiles.

The node offers every tile to :meth:`OnlineCalibrator.offer` (a copy of the first
``calibration.online_tiles`` tiles is queued to the worker without waiting; later tiles cost
nothing). Until the on-line model is ready the node uses the model it was given (or the
shipped one). The worker runs the same injection calibration as ``atr-node calibrate``
(``online_iterations`` iterations per tile, seed ``calibration.seed``), so the same tiles give
the same model.

When the node switches:

- replay (``deterministic=True``): the node holds its tiles (offered, not yet processed)
  until the worker has its ``online_tiles`` images, or the input ends first (a short
  recording); it then waits for the model (:meth:`OnlineCalibrator.wait`), collecting the odd
  images' responses itself meanwhile while the worker collects the even ones (both cores work;
  image k draws from the stream ``(seed, k)``, so the model is the one a single process makes),
  and processes every
  tile, the held ones first, with it. The switch point, "after image N", depends only on the
  record sequence, so the same log and config always give the same contacts whatever the
  machine's speed, and every tile of a recording, however short, uses the on-line model. If
  the worker fails, the node keeps its model (logged), in every run alike.
- live (``deterministic=False``): the node cannot hold tiles; it keeps its model until the
  worker has delivered and switches at the next tile (:meth:`OnlineCalibrator.model_for`),
  never waiting.

Either way one INFO line says which model each part of the run used and why, and
:func:`model_report` gives the same for the run's summary.
"""

from __future__ import annotations

import functools
import json
import logging
import multiprocessing as mp
import os
import queue
import signal
import time
from typing import Any, Callable, Mapping

from ..config import Settings
from ..errors import ModelFileError
from .model import PerformanceModel
from .responses import CalibrationImage

log = logging.getLogger(__name__)

_STOP = "stop"
WORKER_NICE = 10
"""Niceness added to the worker process."""


def _worker(settings: Settings, n_tiles: int, tiles: Any, results: Any, progress: Any = None,
            share: bool = False) -> None:
    """Worker process: gather ``n_tiles`` images (or fewer before a stop), calibrate, reply
    ``("model", body)`` or ``("error", message)``; ``progress`` (a shared array of two ints):
    the injection rounds done and to do, for the node's progress line. ``share`` (replay): the
    node, which waits meanwhile, collects the odd images itself; the worker collects the even
    ones and replies ``("parts", {image index: responses})``."""
    try:
        # Below the node's priority: on a 2-core vehicle computer tile processing comes first.
        os.nice(WORKER_NICE)
    except OSError:
        pass
    # Ctrl-C in a terminal reaches the whole process group: the node decides (it stops this
    # worker in close()); dying here would leave a replay waiting for an answer that never comes
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # this process has no log handler (its warnings would reach stderr unformatted): the node
    # logs the outcome, skipped images and failures included
    logging.disable(logging.WARNING)
    try:
        from .estimate import estimate_model
        from .responses import collect_parts, collect_responses, usable_images

        images: list[CalibrationImage] = []
        parent = mp.parent_process()
        while len(images) < n_tiles:
            try:
                item = tiles.get(timeout=1.0)
            except queue.Empty:
                if parent is not None and not parent.is_alive():
                    return  # the node was killed: no orphan waiting for tiles forever
                continue
            if isinstance(item, str) and item == _STOP:
                break
            # Slant-to-ground conversion here, not in the node's process.
            images.append(CalibrationImage.from_tile(item, altitude_m=settings.sensor.altitude_m))
        if not images:
            results.put(("error", "no tile to calibrate on"))
            return
        cal = settings.calibration

        def tick(done: int, total: int) -> None:
            if progress is not None:
                progress[1], progress[0] = total, done

        if share:
            usable, _skipped = usable_images(images, settings=settings)
            mine = list(range(0, len(usable), 2))
            rounds = [0]

            def step() -> None:
                rounds[0] += 1
                tick(rounds[0], cal.online_iterations * len(usable))

            results.put(("parts", collect_parts(usable, settings=settings, iterations=cal.online_iterations,
                                                targets_per_image=cal.targets_per_image, seed=cal.seed, which=mine,
                                                progress=step)))
            return
        resp = collect_responses(images, settings=settings, iterations=cal.online_iterations,
                                 targets_per_image=cal.targets_per_image, seed=cal.seed, progress=tick)
        model = estimate_model(resp, calibration=cal, thresholds=settings.detectors.threshold,
                               provenance={"source": "on-line", "offered_images": [im.name for im in images]})
        results.put(("model", model.to_dict()))
    except Exception as exc:  # the worker must report, never die silently
        results.put(("error", f"{type(exc).__name__}: {exc}"))


def _start_ignoring_sigint(proc: Any) -> None:
    """Start ``proc`` with SIGINT ignored from its first instruction: a spawned child inherits
    an ignored signal through exec, so a Ctrl-C to the process group while the child is still
    importing cannot print a KeyboardInterrupt traceback there (the node stops the worker
    itself). Only the main thread can change a handler; elsewhere the child starts as it is."""
    try:
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread
        proc.start()
        return
    try:
        proc.start()
    finally:
        signal.signal(signal.SIGINT, old)


class OnlineCalibrator:
    """The node's handle on the on-line calibration worker.

    Parameters
    ----------
    settings : Settings
        ``calibration`` (tiles, iterations, seed), detectors, template, sensor.
    fallback : PerformanceModel
        The model used until the on-line one is ready, and for good if it fails (``--model``
        or the shipped one).
    deterministic : bool
        Replay mode: the node holds its first tiles and calls :meth:`wait` (see the module
        docstring); live mode: :meth:`model_for` never waits.
    timeout_s : float
        Replay mode: the longest wait for the worker's answer before keeping the fallback (a
        stuck worker must not hang a replay).
    """

    def __init__(self, settings: Settings, fallback: PerformanceModel, *, deterministic: bool,
                 timeout_s: float = 600.0) -> None:
        cal = settings.calibration
        self.settings = settings
        self.deterministic = deterministic
        self.timeout_s = timeout_s
        self.n_tiles = cal.online_tiles
        self.fallback_name = model_name(fallback)
        self._model = fallback
        self._offered = 0
        self._ended = False
        self._pending: tuple[str, Any] | None = None
        self.switched_at: int | None = None
        """Number (from 1) of the first tile processed with the on-line model (None: none)."""
        self.images: int | None = None
        """Images the on-line model was made from (tiles too small for a target are skipped)."""
        self.skipped = 0
        self.clipped_db: float | None = None
        self.weights_fitted = False
        """Whether the on-line model's look score weighs its detectors by a fit
        (``calibration.look_weights``, docs/fusion.md)."""
        self.iterations: list[int] | None = None
        self.error: str | None = None
        self.waiting_since: float | None = None
        """``time.monotonic()`` when the node began to wait for the worker's model (None: not
        waiting); progress reports read it from another thread."""
        ctx = mp.get_context("spawn")  # no fork of a process that holds sockets and threads
        self._tiles = ctx.Queue(maxsize=self.n_tiles + 1)
        self._results = ctx.Queue(maxsize=1)
        self._progress = ctx.Array("i", 2, lock=False)  # rounds done, rounds to do (one writer)
        self._held: list[Any] = []
        """Replay: the tiles offered, for the node's own share of the images (:meth:`wait`)."""
        self._main_parts: dict[int, Any] = {}
        self._main_rounds = 0
        self._local: tuple | None = None
        self._proc = ctx.Process(target=_worker, args=(settings, self.n_tiles, self._tiles, self._results,
                                                       self._progress, deterministic),
                                 name="atr-online-calibration", daemon=True)
        _start_ignoring_sigint(self._proc)
        self._done = False

    @property
    def progress(self) -> tuple[int, int]:
        """(injection rounds done, rounds to do) of the worker's calibration: one round is
        one iteration on one image; (0, 0) before it starts injecting."""
        return int(self._progress[0]) + self._main_rounds, int(self._progress[1])

    @property
    def rounds_here(self) -> int:
        """Replay: injection rounds the node's own process did while it waited (its share of
        the images, :meth:`wait`); 0 live."""
        return self._main_rounds

    @property
    def model(self) -> PerformanceModel:
        """The model in use now."""
        return self._model

    @property
    def done(self) -> bool:
        """The worker has answered (model taken, or failure recorded in ``error``); from now
        on :meth:`model_for` always returns :attr:`model`."""
        return self._done

    @property
    def offered(self) -> int:
        """Tiles given to the worker so far (at most ``online_tiles``)."""
        return self._offered

    @property
    def gathering(self) -> bool:
        """The worker still takes tiles: not done, fewer than ``online_tiles`` offered and
        the input not ended."""
        return not self._done and not self._ended and self._offered < self.n_tiles

    def ready(self) -> bool:
        """The worker has answered (the answer is taken at the next :meth:`model_for`, or
        already was). Never blocks."""
        self._poll(None)
        return self._done or self._pending is not None

    def offer(self, tile: Any) -> None:
        """Offer a tile (:class:`~atr_node.records.tile.Tile`, ground or slant range); only the
        first ``online_tiles`` are used. Never blocks."""
        if not self.gathering:
            return
        self._offered += 1
        # The queue's feeder thread pickles the tile in the background: records are never
        # modified after they are made, so no copy is needed here.
        self._tiles.put_nowait(tile)
        if self.deterministic:
            self._held.append(tile)

    def end_of_input(self) -> None:
        """No more tiles will come: calibrate on those offered so far."""
        if self.gathering:
            self._tiles.put_nowait(_STOP)
        self._ended = True

    def _poll(self, wait_s: float | None) -> None:
        if self._pending is not None or self._done:
            return
        try:
            self._pending = self._results.get(timeout=wait_s) if wait_s else self._results.get_nowait()
        except queue.Empty:
            return

    def wait(self, stop: Callable[[], bool] | None = None, *, from_tile: int = 1, poll_s: float = 0.2) -> bool:
        """Replay: end the worker's input if it is still gathering, wait for its answer and
        take it (the on-line model, or the fallback kept and ``error`` set).

        Parameters
        ----------
        stop : callable, optional
            Polled every ``poll_s``: when it returns True (a signal to the node), return False
            at once, nothing taken; a later call waits again.
        from_tile : int
            Number (from 1) of the first tile the model will be used for.

        Returns
        -------
        bool
            True when :attr:`done`.
        """
        if self._done:
            return True
        self.end_of_input()
        deadline = time.monotonic() + self.timeout_s
        self._poll(None)
        if self._pending is None or self._pending[0] == "parts":
            log.info("on-line calibration: waiting for the model from %d tile(s)", self._offered)
            self.waiting_since = time.monotonic()
        try:
            # the worker may have sent its parts already: the node's share is still to do
            if (self._pending is None or self._pending[0] == "parts") and not self._share(stop):
                return False  # a stop request during the node's own share: nothing taken
            self._wait_for_answer(stop, deadline, poll_s)
            self._pool()
        finally:
            self.waiting_since = None
        if stop is not None and self._pending is None and stop():
            # a stop request (a signal to the node): nothing taken, the tiles stay held. A
            # worker that died meanwhile died of the same signal (Ctrl-C reaches the process
            # group): not a calibration failure; a resumed node calibrates afresh
            self.error = None
            return False
        self._take(from_tile)
        return True

    def _images(self) -> tuple[list[CalibrationImage], list[CalibrationImage], list[str]]:
        """(the held tiles as images, the usable ones, the skipped names), made once: the
        node's share and the pooling read the same."""
        if self._local is None:
            from .responses import usable_images

            alt = self.settings.sensor.altitude_m
            images = [CalibrationImage.from_tile(t, altitude_m=alt) for t in self._held]
            usable, skipped = usable_images(images, settings=self.settings)
            self._local = (images, usable, skipped)
        return self._local

    def _share(self, stop: Callable[[], bool] | None) -> bool:
        """Replay: while the worker collects the even images, collect the odd ones here (both
        cores would otherwise wait for the worker). The same parts as one process makes (image
        k draws from the stream ``(seed, k)``). False when ``stop()`` asked to stop (checked
        after every iteration; the parts done are kept for the next call)."""
        from .responses import collect_parts

        cal = self.settings.calibration
        try:
            _, usable, _ = self._images()
        except Exception:  # the worker meets the same and says so
            return True

        class _Stopped(Exception):
            pass

        def step() -> None:
            self._main_rounds += 1
            if stop is not None and stop():
                raise _Stopped

        for k in range(1, len(usable), 2):
            if k in self._main_parts:
                continue
            before = self._main_rounds
            try:
                self._main_parts.update(collect_parts(usable, settings=self.settings, iterations=cal.online_iterations,
                                                      targets_per_image=cal.targets_per_image, seed=cal.seed,
                                                      which=[k], progress=step))
            except _Stopped:
                self._main_rounds = before
                return False
        return True

    def _pool(self) -> None:
        """The worker's parts and the node's own into the model (replay), as ``("model", body)``
        or ``("error", message)`` in the pending answer."""
        if self._pending is None or self._pending[0] != "parts":
            return
        from .estimate import estimate_model
        from .responses import pool_parts

        cal = self.settings.calibration
        try:
            images, usable, skipped = self._images()
            parts = {**self._pending[1], **self._main_parts}
            resp = pool_parts(parts, n_usable=len(usable), skipped=skipped, settings=self.settings,
                              iterations=cal.online_iterations, targets_per_image=cal.targets_per_image, seed=cal.seed)
            model = estimate_model(resp, calibration=cal, thresholds=self.settings.detectors.threshold,
                                   provenance={"source": "on-line", "offered_images": [im.name for im in images]})
            self._pending = ("model", model.to_dict())
        except Exception as exc:  # as the worker would report it
            self._pending = ("error", f"{type(exc).__name__}: {exc}")
        self._held, self._main_parts, self._local = [], {}, None

    def _wait_for_answer(self, stop, deadline: float, poll_s: float) -> None:
        while self._pending is None:
            if stop is not None and stop():
                return
            left = deadline - time.monotonic()
            if left <= 0:
                self.error = f"no answer after {self.timeout_s:g} s"
                return
            self._poll(min(poll_s, left))
            if self._pending is None and not self._proc.is_alive():
                self._poll(0.5)  # its answer may still be in the pipe
                if self._pending is None and not (stop is not None and stop()):
                    self.error = f"the worker exited with code {self._proc.exitcode} and no answer"
                    return

    def model_for(self, tile_no: int) -> PerformanceModel:
        """The model for tile number ``tile_no`` (from 1). Live: the fallback until the
        worker has delivered, then the on-line model (never waits). Replay: waits for the
        worker (:meth:`wait`) if its answer is not taken yet."""
        if self._done:
            return self._model
        if self.deterministic:
            self.wait(from_tile=tile_no)
            return self._model
        self._poll(None)
        if self._pending is not None:
            self._take(tile_no)
        return self._model

    def _take(self, tile_no: int) -> None:
        kind, payload = self._pending if self._pending is not None else ("error", self.error)
        self._done = True
        if kind == "model":
            try:
                model = PerformanceModel.from_dict(payload, where="on-line calibration")
            except ModelFileError as exc:
                kind, payload = "error", str(exc)
            else:
                self._model = model
                self.switched_at = tile_no
                self.images = int(model.provenance.get("n_images", self._offered))
                done = model.provenance.get("iterations_done")
                self.iterations = ([int(min(done)), int(max(done)), int(model.provenance.get("iterations", max(done)))]
                                   if done else None)
                self.skipped = len(model.provenance.get("skipped_images") or ())
                looks = model.looks
                self.clipped_db = (None if looks is None or looks.lrs_clipped is None
                                   else float(looks.clip_headroom_db))
                self.weights_fitted = looks is not None and looks.weights is not None
        if kind != "model":
            self.error = str(payload)
        self.close()
        report = model_report(self.outcome(), tiles=None, fallback=self.fallback_name)
        log.log(logging.INFO if kind == "model" else logging.WARNING, "%s", report["text"])

    def outcome(self) -> dict[str, Any]:
        """What the calibration did, as plain data (kept in node snapshots; see
        :func:`model_report`)."""
        state = "on-line" if self.switched_at is not None else "failed" if self.error else "pending"
        return {"state": state, "deterministic": self.deterministic, "fallback": self.fallback_name,
                "offered": self._offered, "of": self.n_tiles, "images": self.images, "skipped": self.skipped,
                "from_tile": self.switched_at, "error": self.error, "iterations": self.iterations,
                "clipped_db": self.clipped_db, "weights_fitted": self.weights_fitted}

    def close(self) -> None:
        """Stop the worker (idempotent)."""
        if self._proc.is_alive():
            self._proc.terminate()
        self._proc.join(timeout=5.0)
        for q in (self._tiles, self._results):
            q.cancel_join_thread()
            q.close()

    def __enter__(self) -> "OnlineCalibrator":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


@functools.lru_cache(maxsize=1)
def _shipped_provenance() -> str:
    return json.dumps(_jsonable(PerformanceModel.shipped().provenance), sort_keys=True)


def _jsonable(prov: Any) -> Any:
    return json.loads(json.dumps(dict(prov), default=str))


def model_name(model: PerformanceModel) -> str:
    """A few words naming ``model``: "on-line model", "shipped model" or "model given"."""
    prov = model.provenance
    if prov.get("source") == "on-line":
        return "on-line model"
    try:
        shipped = _shipped_provenance()
    except ModelFileError:
        shipped = None
    return "shipped model" if json.dumps(_jsonable(prov), sort_keys=True) == shipped else "model given"


def model_report(outcome: Mapping[str, Any] | None, *, tiles: int | None, fallback: str) -> dict[str, Any]:
    """Which model each part of a run used, and why: ``outcome`` (:meth:`OnlineCalibrator.outcome`;
    None: no on-line calibration) plus ``text`` (one line for the log and summary) and
    ``short`` (a few words, for the replay's end-of-run line).

    Parameters
    ----------
    outcome : mapping or None
        The calibrator's outcome.
    tiles : int or None
        Tiles processed in the run (None: not known yet).
    fallback : str
        Name of the model used without the on-line one (:func:`model_name`); the outcome's
        own ``fallback`` takes precedence.
    """
    every = f"all {tiles} tiles" if tiles is not None else "every tile"
    if outcome is None:
        return {"state": "off", "fallback": fallback, "text": f"on-line calibration off; the {fallback} for {every}",
                "short": f"{fallback} (on-line calibration off)"}
    o = dict(outcome)
    fb = o.get("fallback") or fallback
    if o["state"] == "on-line":
        notes = []
        if o["offered"] < o["of"]:
            notes.append(f"the recording has {o['offered']} tiles")
        if o["skipped"]:
            notes.append(f"{o['skipped']} too small for a target and its context window")
        it = o.get("iterations")
        if it and it[1] < it[2]:  # [fewest, most, cap] iterations per image: every image converged early
            lo, hi, cap = it
            notes.append(f"converged after {lo if lo == hi else f'{lo}-{hi}'} of {cap} iterations per image")
        if o.get("clipped_db") is not None:  # an 8-bit file's bright seabed (docs/fusion.md, "Clipped recordings")
            notes.append(f"seabed within {o['clipped_db']:g} dB of full scale scored with its own likelihood ratios")
        if o.get("weights_fitted"):  # calibration.look_weights (docs/fusion.md, "Fitted detector weights")
            notes.append("the look score's detector weights fitted on this seabed")
        images = f"{o['images']} of {o['of']} images" + (f" ({'; '.join(notes)})" if notes else "")
        t = int(o["from_tile"])
        if t <= 1:
            o["text"] = f"on-line calibration: {images}, model used from tile 1"
            o["short"] = f"on-line model ({o['images']} images)"
        else:  # live: the node could not wait for it
            o["text"] = f"tiles 1-{t - 1}: {fb}; on-line model ({images}) from tile {t}"
            o["short"] = f"{fb} to tile {t - 1}, on-line model from tile {t}"
    elif o["state"] == "failed":
        o["text"] = f"on-line calibration failed ({o['error']}); the {fb} for {every}"
        o["short"] = f"{fb} (on-line calibration failed)"
    elif not o["offered"]:
        o["text"] = "on-line calibration: no tile in the input"
        o["short"] = f"{fb} (no tile)"
    else:  # the run ended before the worker answered (live)
        o["text"] = (f"on-line calibration not finished ({o['offered']} of {o['of']} images when the run "
                     f"ended); the {fb} for {every}")
        o["short"] = f"{fb} (on-line calibration not finished)"
    return o
