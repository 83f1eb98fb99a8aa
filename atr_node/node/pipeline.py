"""The node's pipeline: link records in, contact messages out (ICD sections 1-3).

::

    record -+- nmea / can --> NavDecoder --> NavTrack
            +- sonar ------> Tile.from_map (rejected: counted) --> NavMerger (nav, ground range)
                                 --> StripAssembler (margins) --> units
    unit --> detect (worker process: score maps, detections, coverage)
         --> fuse (EvidenceGrid: confidence from the model, missed detections from Pd(r))
         --> ContactTracker --> contact messages (new / update / withdrawn)

Unit pixels reach the worker through shared memory (``pixelshm.py``: the strip writes each
unit straight into its slot), both processes run with small pages, a live node's worker warms
up at full tile size and the evidence grid's memory is mapped while the worker starts
(``warmup.py``); each unit's stage times are kept in ``stats.stages`` (``timing.py``,
``tools/latency_breakdown.py``).

The pipeline is a deterministic function of the record sequence: units are fused in the
order they were formed, whatever the worker's timing, and the on-line calibration switch
happens at a point of the record sequence: in replay the first ``calibration.online_tiles``
tiles (all of a shorter recording) are held, after they are offered to the calibration
worker and before they reach the strips, until the worker has them all; the node then waits
for the on-line model and processes every tile with it (:meth:`Pipeline._release_held`). A
live node cannot hold tiles: it switches when the model arrives. Two modes:

- ``replay``: never degrades. When the units in flight hold more than
  :data:`REPLAY_INFLIGHT_MPX`, ``feed`` fuses the oldest before it goes on (back-pressure),
  so a replay at any speed gives the same contacts. Rather than wait there, or at the end,
  the main process takes back the newest units the worker has not started and scores them
  itself (``node.replay_main_scores``, :meth:`Pipeline._steal`).
- ``live``: never waits. While the worker scores a unit, the next ones wait in this process,
  which scores them itself when the links are quiet (``node.live_main_scores``: the second
  side of a ping need not wait for the first). When ``node.queue_tiles`` tiles' worth of units
  are in flight (the latest tile's units per tile, at least one) the node enters the *degraded* mode: new units are scored at decimation 2 (four times less
  work, slightly coarser scores); at twice that many, whole units are dropped and counted as
  ``tiles_dropped``. It returns to nominal when the queue is below half the limit. The
  mode is in every heartbeat.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections import Counter, deque
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable

import multiprocessing as mp
import threading

import numpy as np

from ..calibration.model import PerformanceModel
from ..config import Settings, resolve_relative
from ..detectors import BackgroundTracker, column_mean, column_median, required_margin, window_geometry
from ..detectors.sat import Workspace
from ..errors import AtrError, TileError
from ..fusion import ContactTracker, EvidenceGrid, Observation
from .evidence import evidence_layers, unit_observations
from ..fusion import association_gate_m
from ..fusion.navcheck import NavCheck
from ..geo import MissionFrame, OriginEstimator, tile_geometry
from ..io.atrlog import LogRecord
from ..records.nav import NavFix, NavTrack
from ..records.tile import Tile
from .detect import DetectJob, DetectResult, detect, warm_up
from .navmerge import NavMerger
from .strip import StripAssembler, StripUnit
from .pixelshm import SlotChannel
from .timing import UnitTiming
from .warmup import fusion_reserve_chunks, keep_small_pages, node_worker_init, warm_up_worker

log = logging.getLogger(__name__)

REPLAY_INFLIGHT_MPX = 24.0
"""Replay: megapixels of the units in flight (submitted, not yet fused) beyond which
:meth:`Pipeline.feed` stops ingesting until the oldest unit is fused (back-pressure; at least
:data:`REPLAY_INFLIGHT_MIN` units). With ``node.replay_main_scores`` the main process does not
sit idle there: it *steals* the newest unit the worker has not started and scores it itself
(:meth:`Pipeline._steal`), and does the same while draining at the end, so each core scores
only what the other would have left it waiting for. A deep queue lets the main process run
ahead on ingest and fusion while the worker scores (at a limit of 4 units instead, the main
process stole a median of 6 of the 32-Mpx mission's 24 units, and of 3 at 16; at 12 and 6 Mpx
the median rate was lower, 19.5 and 18.8 against 21.1 Mpx/s over 8 runs each); 24 Mpx bound
the shared memory the units in flight hold to about 110 MB."""

REPLAY_INFLIGHT_MIN = 3
"""Units in flight kept at least (the worker holds two it cannot give back: the one it scores
and the next, already in the executor's call queue)."""

NAV_KEEP_S = 300.0
"""INS fixes kept before the ping time of the last tile released (tiles arrive seconds late)."""


@dataclass
class PipelineStats:
    records: int = 0
    tiles_in: int = 0
    tiles_done: int = 0
    tiles_rejected: int = 0
    tiles_dropped: int = 0
    """Tiles accepted and then dropped: for navigation (no usable nav, an impossible slant
    axis: :mod:`.navmerge`) and, live, for load; by reason in ``drop_reasons``."""
    units: int = 0
    units_degraded: int = 0
    units_main: int = 0
    """Units the main process scored itself (replay, ``node.replay_main_scores``)."""
    detect_s: float = 0.0
    fuse_s: float = 0.0
    pixels: int = 0
    rejections: Counter = field(default_factory=Counter)
    drop_reasons: Counter = field(default_factory=Counter)
    """``tiles_dropped`` by reason (``no usable nav``, ``queue full``, ...)."""
    latency_s: deque = field(default_factory=lambda: deque(maxlen=2000))
    stages: deque = field(default_factory=lambda: deque(maxlen=2000))
    """Per-unit stage times (:class:`~atr_node.node.timing.UnitTiming`), the last 2000."""

    def latency_ms(self) -> tuple[float, float]:
        # tuple() copies the deque in one C call under the GIL: safe while the pipeline thread
        # appends (the heartbeat thread calls this)
        lat = tuple(self.latency_s)
        if not lat:
            return 0.0, 0.0
        a = np.asarray(lat) * 1000.0
        return float(np.percentile(a, 50)), float(np.percentile(a, 99))


def _trackers(memory_m: float) -> tuple[BackgroundTracker, BackgroundTracker]:
    """The leg's b(j) and m(j) trackers, forgetting per metre along track (SPEC section 2)."""
    return (BackgroundTracker(memory_m=memory_m),
            BackgroundTracker(memory_m=memory_m, statistic=column_median))


def unit_statistics(unit: StripUnit, bg_tracker: BackgroundTracker,
                    med_tracker: BackgroundTracker) -> tuple[np.ndarray, np.ndarray]:
    """b(j) and m(j) a unit is scored against, the trackers updated with its core.

    The trackers go on over the whole (leg, side): per ping for the mean, per unit for the
    median. A strip's first unit carries a lookahead (its strip's first metres); it stands in
    for the history only where the trackers have none, at the start of a leg or after a change
    of range axis reset them. A strip that starts again in the middle of a leg (the ping
    spacing changed by more than ``DX_TOLERANCE``, as a vehicle's speed does between a
    recorder's tiles, or a gap in ping time) keeps the leg's background: scored against its
    own first metres, a unit that lies in a dark patch of seabed (a rock field, a mud patch)
    made that patch the background, and the scatterers in it stood out as bright as targets
    (river-000_1236: 7 contacts on its rocky patch).
    """
    history = bg_tracker.background
    if history is not None and history.shape[0] != unit.pixels.shape[1]:
        # the strip of this leg and side restarted on another range axis (a tile of another
        # mission name or range axis in the same leg; found by fuzzing): start the
        # background afresh rather than fail
        bg_tracker.reset()
        med_tracker.reset()
        history = None
    core_px = unit.pixels[unit.core]
    # per ping (the mean) and per unit of fixed pings (the median): the same whatever the cut
    background = bg_tracker.update(core_px, dx_m=unit.dx_m)
    median = med_tracker.update(core_px, dx_m=unit.dx_m)
    if unit.lookahead is not None and history is None:
        # the first unit of a leg: scored against the statistics of the strip's first
        # node.first_unit_length_m (its core's and the pings after it, as the trackers would
        # have them there), not of its own core alone; the trackers go on from its core
        background, median = column_mean(unit.lookahead), column_median(unit.lookahead)
    return background, median


class Pipeline:
    """Records in (:meth:`feed`), contact messages out (``emit``).

    Parameters
    ----------
    settings
        All settings.
    model
        Performance model (thresholds, confidence, Pd); with ``online`` it is replaced by the
        on-line model when that is ready.
    emit
        Called with every contact message (ICD section 3 map), in order.
    workers
        1: detection in a worker process (uses the second core); 0: in this process.
    mode
        ``"replay"`` (back-pressure, deterministic) or ``"live"`` (degrades, never waits).
    online
        An :class:`~atr_node.calibration.online.OnlineCalibrator`, or None.
    """

    def __init__(self, settings: Settings, *, model: PerformanceModel, emit: Callable[[dict], None] | None = None,
                 workers: int = 1, mode: str = "replay", online: Any = None) -> None:
        if mode not in ("replay", "live"):
            raise AtrError(f"pipeline mode must be 'replay' or 'live', got {mode!r}")
        from hw.decode import NavDecoder  # the link decoders live with the drivers

        self.settings = settings
        self.model = model
        self.emit = emit or (lambda msg: None)
        self.mode = mode
        self.online = online
        self._cal_held: list[Tile] = []
        """Replay: tiles (with nav, in order) offered to the on-line calibration and held
        until its model is ready; not yet in the strips or the shared-memory slots."""
        self.should_stop: Callable[[], bool] | None = None
        """Polled while waiting for the on-line model (the service's stop request): a
        signal ends the wait at once, the tiles staying held."""
        self.model_use: dict[str, Any] | None = None
        """How the on-line calibration ended (:meth:`OnlineCalibrator.outcome`); kept in
        snapshots, since a resumed node no longer has the calibrator."""
        self.enabled = tuple(settings.detectors.enabled)
        self.stats = PipelineStats()
        self.decoder = NavDecoder(dbc=str(resolve_relative(settings, settings.links.can_dbc)))
        self.track = NavTrack(max_gap_s=settings.node.nav_max_gap_s, default_altitude_m=settings.sensor.altitude_m)
        self.merger = NavMerger(self.track, max_gap_s=settings.node.nav_max_gap_s,
                                default_altitude_m=settings.sensor.altitude_m, on_drop=self._on_nav_drop,
                                first_return_band_m=settings.sensor.first_return_band_m,
                                first_return_level=settings.sensor.first_return_level,
                                first_return_band_max_m=settings.sensor.first_return_band_max_m,
                                max_pixels=settings.node.max_tile_pixels)
        self.strips: StripAssembler | None = None
        self.frame: MissionFrame | None = None
        self.origin = OriginEstimator()
        """The first plausible fixes, for the frame origin (no ``mission.origin_*``): the frame
        is fixed once it has enough, or at the first tile (:meth:`_fix_frame`)."""
        self.tracker: ContactTracker | None = None
        self.contact_seq = 0
        """(ICD v1.1) ``seq`` of the last contact message emitted: +1 per message, kept in snapshots."""
        self.contact_seq_of: dict[int, int] = {}
        """Contact id -> ``seq`` of its last message (``--contacts-out`` carries it)."""
        self.gate_m = association_gate_m(settings.fusion, settings.template)
        self.layers = evidence_layers(settings.fusion.evidence, model, self.enabled)
        """The grid's evidence layers: ("look",) for look-level evidence (SPEC 6.1), else the detectors."""
        self.grid = EvidenceGrid(settings.fusion, gate_m=self.gate_m, detectors=self.enabled, layers=self.layers)
        self.navcheck = NavCheck(gate_m=self.gate_m, gate_sigmas=settings.fusion.gate_sigmas,
                                 nav_sigma_m=settings.fusion.nav_sigma_m, length_m=settings.template.length_m)
        """Do the legs see the same objects within the gate? (:mod:`~atr_node.fusion.navcheck`:
        each closed leg against those before it; logs a shift beyond the gate, changes nothing)"""
        self._bg: dict[tuple[int, str], tuple[BackgroundTracker, BackgroundTracker]] = {}
        """Per (leg, side): trackers of the background b(j) and the median m(j)."""
        self._arrival: dict[tuple[str, int], float] = {}
        self._inflight: deque[tuple[StripUnit, PerformanceModel, Future | None, DetectJob]] = deque()
        """Units submitted and not yet fused, oldest first; the future is None for a unit held
        in this process (live, ``node.live_main_scores``)."""
        self._inflight_px = 0
        """Pixels of the units in flight (replay back-pressure)."""
        self._units_per_tile = 1
        """Units the latest tile makes (its rows over a unit's, at least 1): the live queue
        limit is ``node.queue_tiles`` tiles of them."""
        self._timing: dict[int, UnitTiming] = {}
        """id(unit) -> its stage times, from submit to fuse."""
        self.sweep: dict[str, tuple[float, ...]] | None = None
        """Evaluation: extra thresholds per detector whose detections are kept too."""
        self.on_fused: Callable[[StripUnit, PerformanceModel, DetectResult], None] | None = None
        """Evaluation: called with every unit after it is fused."""
        self.tiles_merged = 0
        self._seq_repeat_said = False
        """The warning that tile seq numbers repeat was logged (once a run)."""
        self._strip_leg: int | None = None
        self.degraded = False
        self.leg: int | None = None
        # the node allocates tens of MB per tile: huge-page advice makes each fresh page fault
        # compact memory first, which doubled the node's time on the target VM (warmup.py)
        keep_small_pages()
        self._pool: ProcessPoolExecutor | None = None
        self._steals = False
        """Replay: this process scores units the worker has not started rather than wait (``_steal``)."""
        self._live_steals = False
        """Live (``node.live_main_scores``): units wait in this process while the worker scores
        another, and this process scores them itself when it is idle (:meth:`tick`)."""
        self.main_warming: threading.Event | None = None
        """Live with ``node.live_main_scores``: set once this process's own warm-up is over."""
        self.warming: Future | None = None
        """The worker's warm-up (done when the worker is ready for full-size tiles)."""
        self.channel: SlotChannel | None = None
        """Jobs to the worker: unit pixels through shared memory (pixelshm.py: 0.1-0.2 s per
        8-Mpx unit less than through the pipe)."""
        if workers:
            self._pool = ProcessPoolExecutor(max_workers=1, mp_context=mp.get_context("spawn"),
                                             initializer=node_worker_init)
            self.channel = SlotChannel(self._pool)
            self._steals = mode == "replay" and settings.node.replay_main_scores
            self._live_steals = mode == "live" and settings.node.live_main_scores and settings.node.warm_up_mpx > 0
            if self._live_steals:
                # this process scores full-size units too: its detector memory is warmed up
                # like the worker's, in a thread, while the worker warms up (no steal before)
                self.main_warming = threading.Event()
                self._workspace = Workspace()  # this pipeline's own: the thread below fills it

                def warm_main() -> None:
                    try:
                        warm_up_worker(settings.sensor, settings.template, settings.detectors, self.enabled,
                                       settings.node.warm_up_mpx, self._workspace)
                    finally:
                        self.main_warming.set()

                threading.Thread(target=warm_main, name="atr-main-warm-up", daemon=True).start()
            if self._steals or self._live_steals:
                import cv2

                cv2.setNumThreads(1)  # the other core is the worker's
            # start the worker and import the detectors there now, not on the first tile; a live
            # node also maps the detectors' buffers for tiles of node.warm_up_mpx (the first
            # touch of that memory would otherwise add ~1.5 s to the first tiles' latency)
            if mode == "live" and settings.node.warm_up_mpx > 0:
                self.warming = self._pool.submit(warm_up_worker, settings.sensor, settings.template,
                                                 settings.detectors, self.enabled, settings.node.warm_up_mpx)
            else:
                self.warming = self._pool.submit(warm_up)
        self.reserve_fusion()

    def wait_ready(self, timeout: float | None = None) -> None:
        """Block until the node's warm-up is over: the worker's, and live with
        ``node.live_main_scores`` this process's own (a node aboard starts minutes before the
        survey's first tile)."""
        if self.warming is not None:
            self.warming.result(timeout=timeout)
        if self.main_warming is not None:
            self.main_warming.wait(timeout)

    def reserve_fusion(self) -> None:
        """Map the evidence grid's memory for units of ``node.warm_up_mpx`` now, while the worker
        process starts, not during the first tiles (:func:`~.warmup.fusion_reserve_chunks`).
        Live, for the first tiles' latency; in replay, for throughput: the grid would otherwise
        page-fault its layer in and copy it each time it doubles, while the worker waits for
        units (32-Mpx mission, 5 interleaved pairs of ``tools/bench_node.py`` runs: median
        23.7 Mpx/s against 20.4, the node's start 0.27 s against 0.25). Called again after a
        restart from a snapshot replaces the grid."""
        if self.settings.node.warm_up_mpx > 0:
            self.grid.reserve(fusion_reserve_chunks(self.settings))

    # -- input ------------------------------------------------------------------------------
    def feed(self, rec: LogRecord) -> None:
        """Process one record (never raises on bad input: it is counted and logged)."""
        self.stats.records += 1
        if rec.link == "sonar":
            try:
                tile = Tile.from_map(rec.msg, max_pixels=self.settings.node.max_tile_pixels)
            except TileError as exc:
                self.stats.tiles_rejected += 1
                key = f"tile field {exc.field}"
                self.stats.rejections[key] += 1
                if self.stats.rejections[key] == 1:  # one line per reason; the rest are counted
                    log.warning("rejected %s (further tiles rejected for field %s are counted, not logged)",
                                exc, exc.field)
                return
            self.stats.tiles_in += 1
            self._arrival[(tile.side, tile.seq)] = time.monotonic()
            ready = self.merger.push(tile, rec.t)
        else:
            for ev in self.decoder.feed(rec):
                if isinstance(ev, NavFix):
                    self.track.add(ev)
                    if self.frame is None and ev.lat_deg is not None and ev.lon_deg is not None:
                        if self.origin.add(ev.lat_deg, ev.lon_deg):
                            self._fix_frame()
                else:  # a leg change from the vehicle's CAN bus
                    self.leg = int(ev.leg)
            ready = self.merger.poll(rec.t)
        for tile in ready:
            self._on_tile(tile)
        self._collect(block=False)

    def replay(self, records) -> "Pipeline":
        """Feed every record, then :meth:`finish` (a whole recording in replay mode)."""
        for rec in records:
            self.feed(rec)
        self.finish()
        return self

    def tick(self, now: float) -> None:
        """Periodic work with no record: release held tiles whose INS went silent, fuse what
        the worker finished (the live loop calls it when the links are quiet)."""
        for tile in self.merger.poll(now):
            self._on_tile(tile)
        self._collect(block=False)
        if self._steal_held():
            self._collect(block=False)

    def finish(self) -> None:
        """End of input: release held tiles, flush strips, drain the worker, commit every leg."""
        for tile in self.merger.poll(math.inf, flush=True):
            self._on_tile(tile)
        if self._cal_held and not self._release_held():
            return  # a signal while waiting for the on-line model: the tiles stay held
        if self.strips is not None:
            for unit in self.strips.flush():
                self._submit(unit)
        self._collect(block=True)
        self.grid.close_all()
        self._check_nav()
        self._update_contacts(self._last_t)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        if self.channel is not None:
            self.channel.close()
            self.channel = None
        if self.online is not None:
            self.online.close()

    @property
    def inflight(self) -> int:
        """Units in the worker, not yet fused."""
        return len(self._inflight)

    def drain(self) -> None:
        """Wait for every unit in the worker and fuse it (before a snapshot)."""
        self._collect(block=True)

    @property
    def queue_depth(self) -> int:
        return len(self._inflight) + self.merger.held + len(self._cal_held)

    @property
    def calibration_held(self) -> int:
        """Tiles held for the on-line calibration (replay), not processed yet."""
        return len(self._cal_held)

    def hold_for_calibration(self, tiles: list[Tile]) -> None:
        """A snapshot's held tiles, restored: offered again to this run's calibrator (the
        same tiles in the same order give the same model) and held as before."""
        for tile in tiles:
            if self.online is not None and self.online.deterministic:
                self.online.offer(tile)
            self._cal_held.append(tile)

    def model_report(self) -> dict[str, Any]:
        """Which model each part of the run used and why (:func:`~atr_node.calibration.online.model_report`)."""
        from ..calibration.online import model_name, model_report

        outcome = self.model_use
        if outcome is None and self.online is not None:
            outcome = self.online.outcome()  # not finished yet
        fallback = outcome["fallback"] if outcome else model_name(self.model)
        return model_report(outcome, tiles=self.tiles_merged, fallback=fallback)

    @property
    def contacts(self) -> list[dict[str, Any]]:
        """The final (latest) message of every contact ever published, with its ``seq``
        (none for a contact of a snapshot written before ICD v1.1)."""
        if self.tracker is None:
            return []
        return [self._with_seq(c.to_message()) for c in sorted(self.tracker.history.values(), key=lambda c: c.id)]

    def live_contacts(self) -> list[dict[str, Any]]:
        """The last message of every live (not withdrawn) contact: the snapshot endpoint's list."""
        return [m for m in self.contacts if m["state"] != "withdrawn"]

    def _with_seq(self, m: dict[str, Any]) -> dict[str, Any]:
        seq = self.contact_seq_of.get(m["id"])
        return m if seq is None else {**m, "seq": seq}

    # -- stages ---------------------------------------------------------------------------
    _last_t = 0.0
    mission = ""

    def _fix_frame(self) -> None:
        """Fix the mission frame: at the configured origin, else at the robust origin of the
        first fixes (one outlier first fix must not set it; issue 21)."""
        self.frame = MissionFrame.from_settings(self.settings.mission, first_fix=self.origin.estimate())
        self.tracker = ContactTracker(self.settings.fusion, self.frame, gate_m=self.gate_m)
        log.debug("mission frame: %s", self.frame.name)

    def _on_tile(self, tile: Tile) -> None:
        # amplitude tiles (XTF and JSF files) are scored, calibrated on and shown as intensity,
        # as every other tile: the detectors' levels are intensity levels (SPEC 2)
        tile = tile.as_intensity()
        # bound the INS track on long missions (it grew by every fix for the whole mission;
        # found by tools/soak.py): older fixes could only serve a tile arriving that late
        self.track.forget_before(float(tile.ping_time[0]) - NAV_KEEP_S)
        if self.frame is None:
            # the first tile needs the frame now: the fixes so far and the tile's own pings
            self.origin.add_track(tile.nav.lat_deg, tile.nav.lon_deg)
            self._fix_frame()
        oc = self.online
        if oc is not None and oc.deterministic and not oc.done:
            # replay: held (nav attached, not in the strips) until the worker has its images
            oc.offer(tile)
            self._cal_held.append(tile)
            if not oc.gathering:
                self._release_held()
            return
        if self._cal_held and not self._release_held():  # tiles of a snapshot, no calibrator now
            return
        if oc is not None:
            oc.offer(tile)  # live: the first tiles go to the worker, the node does not wait
        self._process(tile)

    def _release_held(self) -> bool:
        """Replay: wait for the on-line model (ending the worker's input if it still
        gathers: a short recording), then process the held tiles with it, in order. False
        when a signal ended the wait (the tiles stay held)."""
        oc = self.online
        if oc is not None and oc.deterministic and not oc.done:
            if not oc.wait(self.should_stop, from_tile=self.tiles_merged + 1):
                return False
        self._note_model()
        held, self._cal_held = self._cal_held, []
        for tile in held:
            self._process(tile)
        return True

    def _note_model(self) -> None:
        if self.online is not None and self.online.done and self.model_use is None:
            self.model = self.online.model
            self.model_use = self.online.outcome()

    def _process(self, tile: Tile) -> None:
        """A tile with nav into the strips (and the units it completes to the detectors)."""
        if self.strips is None:
            self.strips = StripAssembler(self._strip_geometry(tile)[0], max_gap_s=self.settings.node.nav_max_gap_s,
                                         alloc=self._unit_pixels, geometry=self._strip_geometry)
        elif self.strips.geometry is None:  # resumed from a snapshot: new strips as a fresh node makes them
            self.strips.geometry = self._strip_geometry
        self.tiles_merged += 1
        # the live queue's limit counts tiles: units of the latest tile's length (node.queue_tiles)
        self._units_per_tile = max(1, math.ceil(tile.rows / self._unit_rows(tile)))
        self.mission = tile.mission  # evidence deltas name their mission (atr_node.node.exchange)
        if self._strip_leg is not None and tile.leg != self._strip_leg:
            # a new leg: end the old leg's strips on both sides before any of the new leg's
            # evidence, so the old leg is complete when the grid closes it: right after its
            # last unit is fused (the new leg's first unit may wait for node.first_unit_length_m
            # of pings; the old leg's evidence and its exchange delta do not wait for it)
            units = self.strips.flush()
            for i, unit in enumerate(units):
                self._submit(dataclasses.replace(unit, closes_leg=True) if i == len(units) - 1 else unit)
        self._strip_leg = tile.leg
        repeats, breaks = self.strips.seq_repeats, dict(self.strips.breaks)
        for unit in self.strips.push(tile):
            self._submit(unit)
        for why, n in self.strips.breaks.items():
            if n > breaks.get(why, 0) and not breaks.get(why):  # once per reason; the rest are counted
                log.warning("%s: %s (dx_m %g); a new strip starts here, with margins of its own (further "
                            "strip breaks are counted in the summary's strip_breaks, not logged)", tile.ident, why,
                            tile.dx_m)
        if self.strips.seq_repeats > repeats and not self._seq_repeat_said:
            self._seq_repeat_said = True  # once a run: a recorder that never sets seq repeats it on every tile
            log.warning("%s: seq %d does not increase on the previous tile of its leg and side (ICD section 1: "
                        "+1 per tile and side); tiles are counted by arrival, not by seq (further repeats are "
                        "counted in the summary's seq_repeats, not logged)", tile.ident, tile.seq)

    def _strip_geometry(self, tile: Tile) -> tuple[int, int, int]:
        """(margin rows, unit rows, first unit rows) of a strip starting with ``tile``: from its ping spacing and
        the settings only, so that neither depends on where the tiles were cut (SPEC section 0)
        nor on the first tile the node saw. The row margin does not depend on the altitude
        (``required_margin``: the template's along-track windows), so the sonar's nominal
        altitude stands in for it."""
        node = self.settings.node
        geom = window_geometry(tile.ranges_m[-1:], dr_m=tile.dr_m, dx_m=tile.dx_m,
                               altitude_m=self.settings.sensor.altitude_m, template=self.settings.template)
        margin = required_margin(geom)[0] + int(math.ceil(node.tile_margin_m / tile.dx_m))
        k = self._unit_rows(tile)
        return margin, k, max(k, int(round(node.first_unit_length_m / tile.dx_m)))

    def _unit_rows(self, tile: Tile) -> int:
        """Core rows of a unit of a strip of ``tile``'s ping spacing (``node.unit_length_m``)."""
        return max(1, int(round(self.settings.node.unit_length_m / tile.dx_m)))

    def _unit_pixels(self, shape: tuple[int, int]) -> np.ndarray:
        """Memory for a unit's pixels: a shared-memory slot when units go to the worker in
        slots (the strip writes the unit there once, and the slot travels without a copy),
        ordinary memory with no worker, or when ``on_fused`` may keep the pixels."""
        if self.channel is not None and self.on_fused is None:
            return self.channel.alloc(shape, np.float32)
        return np.empty(shape, np.float32)

    def _on_nav_drop(self, tile: Tile, reason: str) -> None:
        """A tile the nav merge dropped: counted with the tiles dropped for load."""
        self.stats.tiles_dropped += 1
        self.stats.drop_reasons[reason] += 1

    def _current_model(self) -> PerformanceModel:
        if self.online is not None and not self.online.done:
            # live: switches when the worker has delivered (the unit is of tile tiles_merged)
            self.model = self.online.model_for(self.tiles_merged)
            self._note_model()
        return self.model

    def _submit(self, unit: StripUnit) -> None:
        timing = UnitTiming(unit.side, unit.seq, unit.core_rows, self._arrival.get((unit.side, unit.seq)),
                            time.monotonic())
        limit = self.settings.node.queue_tiles * self._units_per_tile
        if self.mode == "live":
            depth = len(self._inflight)
            if depth >= 2 * limit:
                if self.channel is not None:
                    self.channel.discard(unit.pixels)
                self.stats.tiles_dropped += len(unit.completed)
                self.stats.drop_reasons["queue full"] += len(unit.completed)
                log.warning("dropped leg %d %s core of %d rows: %d units in flight", unit.leg, unit.side,
                            unit.core_rows, depth)
                return
            if depth >= limit and not self.degraded:
                self.degraded = True
                log.warning("degraded mode: %d units in flight (limit %d)", depth, limit)
            elif depth < limit // 2 and self.degraded:
                self.degraded = False
                log.warning("back to nominal mode")
        key = (unit.leg, unit.side)
        if key not in self._bg:
            self._bg = {k: v for k, v in self._bg.items() if k[0] == unit.leg}  # a new leg: forget older ones
            self._bg[key] = _trackers(self.settings.detectors.background_memory_m)
        background, median = unit_statistics(unit, *self._bg[key])
        model = self._current_model()
        taus = {d: float(model.tau.get(d, getattr(self.settings.detectors.threshold, d))) for d in self.enabled}
        det_settings = self.settings.detectors
        if self.degraded and det_settings.decimation == 1:
            det_settings = dataclasses.replace(det_settings, decimation=2)
            self.stats.units_degraded += 1
        job = DetectJob(self.stats.units, unit.pixels, (unit.core.start, unit.core.stop), unit.range0_m, unit.dr_m,
                        unit.dx_m, float(np.median(unit.nav.altitude_m)), background, median, taus, self.enabled,
                        self.settings.template, det_settings, self.sweep, unit.full_scale)
        self.stats.units += 1
        self.stats.pixels += unit.core_rows * unit.pixels.shape[1]
        self._timing[id(unit)] = timing
        if self._pool is None:
            timing.queued = time.monotonic()
            res = detect(job)
            timing.mark_done()
            self._fuse(unit, model, res)
            return
        if self._live_steals:
            # held here, and handed to the worker, oldest first, when it has nothing to do
            self._inflight.append((unit, model, None, job))
            self._inflight_px += job.pixels.size
            self._pump()
            self._collect(block=False)
            return
        fut = self.channel.submit(job)
        timing.queued = time.monotonic()
        fut.add_done_callback(timing.mark_done)
        self._inflight.append((unit, model, fut, job))
        self._inflight_px += job.pixels.size
        if self.mode == "replay":
            while len(self._inflight) > REPLAY_INFLIGHT_MIN and self._inflight_px > REPLAY_INFLIGHT_MPX * 1e6 \
                    or len(self._inflight) > 4 * limit:
                self._collect_one()
        self._collect(block=False)

    def _pump(self) -> None:
        """Live, units held: hand the oldest to the worker once it has nothing to do (so a
        held unit is still there for this process to take when it is idle)."""
        if not self._live_steals or any(f is not None and not f.done() for _, _, f, _ in self._inflight):
            return
        for i, (unit, model, fut, job) in enumerate(self._inflight):
            if fut is None:
                timing = self._timing.get(id(unit))
                fut = self.channel.submit(job)
                if timing is not None:
                    timing.queued = time.monotonic()
                    fut.add_done_callback(timing.mark_done)
                self._inflight[i] = (unit, model, fut, job)
                return

    def _steal_held(self) -> bool:
        """Live, idle: score the newest held unit in this process (once it is warmed up), so
        that it does not wait for the worker's unit, usually the other side of the same pings."""
        if not self._live_steals or not self.main_warming.is_set():
            return False
        for i in range(len(self._inflight) - 1, -1, -1):
            if self._inflight[i][2] is None:
                timing = self._timing.get(id(self._inflight[i][0]))
                if timing is not None:
                    timing.queued = time.monotonic()
                self._score_here(i, Future(), self._workspace)
                return True
        return False

    def _score_here(self, i: int, mine: Future, workspace: Workspace | None = None) -> None:
        """Score in-flight unit ``i`` in this process; its entry then holds ``mine``, done."""
        unit, model, _fut, job = self._inflight[i]
        timing = self._timing.get(id(unit))
        mine.set_result(detect(job, workspace))
        if timing is not None:
            timing.mark_done()
        self._inflight[i] = (unit, model, mine, job)
        self.stats.units_main += 1

    def _collect_one(self) -> None:
        """Fuse the oldest unit in flight, waiting for its result (replay: stealing meanwhile)."""
        while self._steals and not self._inflight[0][2].done() and self._steal():
            pass
        if self._inflight[0][2] is None:
            self._pump()  # the oldest unit was held: the worker is free for it
        unit, model, fut, job = self._inflight.popleft()
        self._inflight_px -= job.pixels.size
        res = fut.result()
        try:
            self._fuse(unit, model, res)
        finally:
            if self.channel is not None:
                self.channel.done(fut)  # the unit's pixels (their slot) are no longer read
                self.channel.discard(job.pixels)  # a held unit scored here: its slot was never sent
        self._pump()

    def _steal(self) -> bool:
        """Score the newest unit the worker has not started in this process; False if none.

        The worker takes jobs in order, so the units it has not started are the newest ones:
        the first, from the end, whose future cannot be cancelled (running, or already in the
        executor's call queue) ends the search. :func:`detect` is a pure function: the
        result is the same, whoever computes it."""
        for i in range(len(self._inflight) - 1, -1, -1):
            fut = self._inflight[i][2]
            if fut.done():
                continue  # done by the worker, or stolen already
            if not fut.cancel():
                return False
            mine: Future = Future()
            if self.channel is not None:
                self.channel.rekey(fut, mine)  # the slot goes with the unit, to its fusion
            self._score_here(i, mine)
            return True
        return False

    def _collect(self, *, block: bool) -> None:
        while self._inflight and (block or (self._inflight[0][2] is not None and self._inflight[0][2].done())):
            self._collect_one()
        self._pump()

    def _fuse(self, unit: StripUnit, model: PerformanceModel, res: DetectResult) -> None:
        t0 = time.perf_counter()
        timing = self._timing.pop(id(unit), None) or UnitTiming(unit.side, unit.seq, unit.core_rows, None, math.nan)
        timing.fuse_start, timing.detect_s = time.monotonic(), res.seconds
        self.stats.detect_s += res.seconds
        core = unit.core_tile()
        geometry = tile_geometry(core, self.frame)
        ranges = core.ranges_m
        observations = unit_observations(model, res.detections, res.covered, ranges, self.enabled,
                                         self.grid.layers, geometry=geometry,
                                         object_m=self.settings.template.length_m)
        t = float(unit.ping_time[unit.core][-1])
        self._last_t = max(self._last_t, t)
        t1 = time.monotonic()
        try:
            self.grid.add_observation(Observation(unit.leg, t, geometry, tuple(observations)))
            if unit.closes_leg and unit.leg in self.grid.open:
                self.grid.close_leg(unit.leg)
            if len(self.grid.closed_legs) > len(self.navcheck.checked):
                self._check_nav()
        except AtrError as exc:  # e.g. a leg number reused after the leg was closed
            self.stats.rejections[f"fusion: {type(exc).__name__}"] += 1
            log.error("leg %d %s: evidence rejected: %s", unit.leg, unit.side, exc)
        t2 = time.monotonic()
        self._update_contacts(t)
        t3 = time.monotonic()
        timing.deposit_s, timing.contacts_s = t2 - t1, t3 - t2
        if self.on_fused is not None:
            self.on_fused(unit, model, res)
        # latency (ICD heartbeat): from a tile's arrival to the evidence of the unit its arrival
        # released (all its rows but the last margin rows, which wait for the next tile)
        arrived = self._arrival.pop((unit.side, unit.seq), None)
        if arrived is not None:
            self.stats.latency_s.append(time.monotonic() - arrived)
        for seq in unit.completed:
            self._arrival.pop((unit.side, seq), None)
            self.stats.tiles_done += 1
        timing.fused = time.monotonic()
        self.stats.stages.append(timing)
        self.stats.fuse_s += time.perf_counter() - t0

    def _check_nav(self) -> None:
        """Do the legs agree (:attr:`navcheck`)? A diagnostic: whatever goes wrong in it is
        logged once and counted, never lost evidence."""
        try:
            self.navcheck.update(self.grid.detections, self.grid.closed_legs)
        except Exception as exc:  # noqa: BLE001 - the check must never stop the node
            key = f"navigation check: {type(exc).__name__}"
            if not self.stats.rejections[key]:
                log.error("navigation check failed, evidence and contacts unaffected: %s", exc)
            self.stats.rejections[key] += 1
            self.navcheck.checked |= set(self.grid.closed_legs)

    def _update_contacts(self, t: float) -> None:
        if self.tracker is None:
            return
        for c in self.tracker.update(self.grid, t):
            self.contact_seq += 1  # ICD v1.1: per node, +1 for every contact message published
            self.contact_seq_of[c.id] = self.contact_seq
            self.emit({**c.to_message(), "seq": self.contact_seq})
