"""On-line calibration: a worker process that calibrates on the mission's first tiles.

The node offers every tile to :meth:`OnlineCalibrator.offer` (a copy of the first
``calibration.online_tiles`` tiles is queued to the worker without waiting; later tiles cost
nothing) and asks :meth:`OnlineCalibrator.model_for` which model to use before processing each
tile. Until the on-line model is ready the node uses the model it was given (or the shipped
one). The worker runs the same injection calibration as ``atr-node calibrate``
(``online_iterations`` iterations per tile, seed ``calibration.seed``), so the same tiles give
the same model.

When the node switches:

- live (``deterministic=False``): at the first tile after the worker has delivered; tile
  processing never waits for it.
- replay (``deterministic=True``): exactly at tile count ``calibration.online_switch_tile``
  (0: twice ``online_tiles``), waiting for the worker there if it is not done, so the same log
  and config always give the same contacts whatever the machine's speed. If the worker fails,
  the node keeps its model (logged), in every run alike.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import queue
from typing import Any

from ..config import Settings
from ..errors import ModelFileError
from .model import PerformanceModel
from .responses import CalibrationImage

log = logging.getLogger(__name__)

_STOP = "stop"
WORKER_NICE = 10
"""Niceness added to the worker process."""


def _worker(settings: Settings, n_tiles: int, tiles: Any, results: Any) -> None:
    """Worker process: gather ``n_tiles`` images (or fewer before a stop), calibrate, reply
    ``("model", body)`` or ``("error", message)``."""
    try:
        # Below the node's priority: on a 2-core vehicle computer tile processing comes first.
        os.nice(WORKER_NICE)
    except OSError:
        pass
    try:
        from .estimate import estimate_model
        from .responses import collect_responses

        images: list[CalibrationImage] = []
        while len(images) < n_tiles:
            item = tiles.get()
            if isinstance(item, str) and item == _STOP:
                break
            # Slant-to-ground conversion here, not in the node's process.
            images.append(CalibrationImage.from_tile(item, altitude_m=settings.sensor.altitude_m))
        if not images:
            results.put(("error", "no tile to calibrate on"))
            return
        cal = settings.calibration
        resp = collect_responses(images, settings=settings, iterations=cal.online_iterations,
                                 targets_per_image=cal.targets_per_image, seed=cal.seed)
        model = estimate_model(resp, calibration=cal, thresholds=settings.detectors.threshold,
                               provenance={"source": "on-line", "images": [im.name for im in images]})
        results.put(("model", model.to_dict()))
    except Exception as exc:  # the worker must report, never die silently
        results.put(("error", f"{type(exc).__name__}: {exc}"))


class OnlineCalibrator:
    """The node's handle on the on-line calibration worker.

    Parameters
    ----------
    settings : Settings
        ``calibration`` (tiles, iterations, seed, switch tile), detectors, template, sensor.
    fallback : PerformanceModel
        The model used until the on-line one is ready (``--model`` or the shipped one).
    deterministic : bool
        Replay mode: switch exactly at the configured tile count (see the module docstring).
    timeout_s : float
        Replay mode: the longest wait for the worker at the switch tile before keeping the
        fallback (a stuck worker must not hang a replay).
    """

    def __init__(self, settings: Settings, fallback: PerformanceModel, *, deterministic: bool,
                 timeout_s: float = 600.0) -> None:
        cal = settings.calibration
        self.settings = settings
        self.deterministic = deterministic
        self.timeout_s = timeout_s
        self.n_tiles = cal.online_tiles
        self.switch_tile = cal.online_switch_tile or 2 * cal.online_tiles
        self._model = fallback
        self._offered = 0
        self._pending: tuple[str, Any] | None = None
        self.switched_at: int | None = None
        """Tile count at which the on-line model took over (None: not yet)."""
        self.error: str | None = None
        ctx = mp.get_context("spawn")  # no fork of a process that holds sockets and threads
        self._tiles = ctx.Queue(maxsize=self.n_tiles + 1)
        self._results = ctx.Queue(maxsize=1)
        self._proc = ctx.Process(target=_worker, args=(settings, self.n_tiles, self._tiles, self._results),
                                 name="atr-online-calibration", daemon=True)
        self._proc.start()
        self._done = False

    @property
    def model(self) -> PerformanceModel:
        """The model in use now."""
        return self._model

    @property
    def done(self) -> bool:
        """The worker has answered (model taken, or failure recorded in ``error``); from now
        on :meth:`model_for` always returns :attr:`model`."""
        return self._done

    def offer(self, tile: Any) -> None:
        """Offer a tile (:class:`~atr_node.records.tile.Tile`, ground or slant range); only the
        first ``online_tiles`` are used. Never blocks."""
        if self._offered >= self.n_tiles or self._done:
            return
        self._offered += 1
        # The queue's feeder thread pickles the tile in the background: records are never
        # modified after they are made, so no copy is needed here.
        self._tiles.put_nowait(tile)

    def end_of_input(self) -> None:
        """No more tiles will come: calibrate on those offered so far."""
        if self._offered < self.n_tiles and not self._done:
            self._offered = self.n_tiles
            self._tiles.put_nowait(_STOP)

    def _poll(self, wait_s: float | None) -> None:
        if self._pending is not None or self._done:
            return
        try:
            self._pending = self._results.get(timeout=wait_s) if wait_s else self._results.get_nowait()
        except queue.Empty:
            return

    def model_for(self, tiles_done: int) -> PerformanceModel:
        """The model to use for the next tile, ``tiles_done`` tiles having been processed."""
        if self._done:
            return self._model
        if self.deterministic:
            if tiles_done < self.switch_tile:
                return self._model
            if self._offered < self.n_tiles:
                self.end_of_input()
            self._poll(self.timeout_s)
            if self._pending is None:
                self.error = f"on-line calibration not done after {self.timeout_s:g} s"
        else:
            self._poll(None)
            if self._pending is None:
                return self._model
        self._take(tiles_done)
        return self._model

    def _take(self, tiles_done: int) -> None:
        kind, payload = self._pending if self._pending is not None else ("error", self.error)
        self._done = True
        if kind == "model":
            try:
                self._model = PerformanceModel.from_dict(payload, where="on-line calibration")
            except ModelFileError as exc:
                kind, payload = "error", str(exc)
            else:
                self.switched_at = tiles_done
                log.info("switched to the on-line performance model at tile %d", tiles_done)
        if kind != "model":
            self.error = str(payload)
            log.warning("on-line calibration failed (%s); keeping the model given", payload)
        self.close()

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
