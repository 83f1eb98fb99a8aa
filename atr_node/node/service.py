"""The node as a service: a record source through the pipeline, publishing, heartbeats,
snapshots, signals and the systemd watchdog. Shared by ``atr-node run`` and ``atr-node replay``.

Operations (ICD section 6, SPEC section 7):

- Heartbeat at ``node.heartbeat_s`` (at least once a second) from a thread, with the
  pipeline's counters, queue depth, latency percentiles and mode.
- Snapshots to ``state_dir`` every ``node.snapshot_every_tiles`` tiles, taken when the worker
  is drained, with the input position they account for (``atr_node.node.state``).
- SIGTERM / SIGINT: stop reading, drain the worker, snapshot, exit 0; the next start resumes
  from that snapshot. SIGKILL loses at most the work since the last snapshot, which the
  resume redoes from the input (the live node's own recording, or the replayed log).
- systemd: ``READY=1`` once running, ``WATCHDOG=1`` from the main loop, ``STOPPING=1``.
"""

from __future__ import annotations

import json
import logging
import signal
import threading
import time
from pathlib import Path
from typing import Any, Callable, Iterable

from ..calibration.model import PerformanceModel
from ..config import Settings
from ..errors import AtrError, describe
from ..io.atomic import atomic_open
from ..io.atrlog import LogRecord
from . import state as node_state
from . import wire
from .pipeline import Pipeline
from .publisher import Publisher
from .sdnotify import Notifier
from .snapshot_endpoint import ContactView, SnapshotServer

log = logging.getLogger(__name__)


class NodeService:
    """One node: a pipeline plus its publisher, heartbeat, snapshots and signal handling.

    Parameters
    ----------
    settings, model, mode, workers, online
        See :class:`~atr_node.node.pipeline.Pipeline`.
    publish
        ZeroMQ endpoint to bind the PUB socket to, or None for no publishing.
    state_dir
        Where snapshots go (None: no snapshots, no resume).
    on_contact
        Also called with every contact message (for ``--contacts-out`` and tests).
    snapshot
        (ICD v1.1) ZeroMQ endpoint to bind the snapshot endpoint for late joiners to
        (:mod:`~atr_node.node.snapshot_endpoint`), or None for none; only with ``publish``.
    snapshot_setting
        The option or key that set ``snapshot``, named if it cannot be bound.
    source_name, source_id
        The recording replayed: its path (for messages) and its identity
        (:func:`~atr_node.node.state.recording_identity`), kept in snapshots: a state
        directory of another recording is set aside, not resumed.
    """

    def __init__(self, settings: Settings, *, model: PerformanceModel, mode: str = "replay", workers: int = 1,
                 online: Any = None, publish: str | None = None, state_dir: str | Path | None = None,
                 on_contact: Callable[[dict], None] | None = None, source_name: str = "",
                 snapshot: str | None = None, snapshot_setting: str = "links.snapshot_endpoint",
                 source_id: dict[str, Any] | None = None) -> None:
        self.settings = settings
        from ..security import curve_from_settings

        self.curve = curve_from_settings(settings)
        self.publisher = Publisher(publish, curve=self.curve) if publish else None
        self.contact_view = ContactView()
        self.snapshot_server: SnapshotServer | None = None
        if self.publisher is not None and snapshot:
            try:
                self.snapshot_server = SnapshotServer(snapshot, self.contact_view, curve=self.curve,
                                                      setting=snapshot_setting)
            except AtrError:
                self.publisher.close()
                raise
        self.on_contact = on_contact
        self.pipeline = Pipeline(settings, model=model, emit=self._emit, workers=workers, mode=mode, online=online)
        self._stop = threading.Event()
        self.pipeline.should_stop = self._stop.is_set  # a signal ends a wait for the on-line model
        self.exchange = None
        if settings.node.exchange_publish or settings.node.exchange_peers:  # evidence exchange (issue 11)
            import socket

            from .exchange import NodeExchange

            self.exchange = NodeExchange(self.pipeline, node=settings.node.node_id or socket.gethostname(),
                                         publish=settings.node.exchange_publish, peers=settings.node.exchange_peers)
        self.state_dir = Path(state_dir) if state_dir else None
        self.source_name = source_name
        self.source_id = source_id
        self.notifier = Notifier()
        self.position = 0
        self.resumed_from: int | None = None
        self._hb_stop = threading.Event()
        self._t0 = time.monotonic()
        self._hb_thread: threading.Thread | None = None
        self._last_snap_tiles = 0
        self.snapshots = 0
        self.snapshot_failures = 0

    # -- lifecycle ---------------------------------------------------------------------------
    def resume(self) -> int:
        """Restore the newest snapshot in ``state_dir`` if any; return the input position to resume at."""
        if self.state_dir is None:
            return 0
        # a damaged snapshot falls back to the previous one, and another recording's state is
        # set aside, before anything reaches the pipeline (state.restore)
        meta = node_state.restore(self.state_dir, self.pipeline, source=self.source_name, source_id=self.source_id)
        if meta is None:
            return 0
        self.position = self.resumed_from = int(meta["position"])
        self.sync_contact_view()
        if self.exchange is not None and not self.exchange.restore(node_state.read_current(self.state_dir)):
            log.warning("evidence exchange off after this resume: the snapshot holds no usable delta ledger")
            self.exchange.close()
            self.exchange = None
        self._last_snap_tiles = self.pipeline.stats.tiles_in
        log.warning("resumed from snapshot at input record %d (%d tiles in)", self.position,
                    self.pipeline.stats.tiles_in)
        return self.position

    def sync_contact_view(self) -> None:
        """After the pipeline's state was restored: the snapshot endpoint answers with the
        restored live contacts and last seq (until the next message)."""
        self.contact_view.reset(self.pipeline.contact_seq, self.pipeline.live_contacts())

    def install_signal_handlers(self) -> None:
        def stop(signum, _frame):
            # an asked-for stop is normal operation, not a warning
            log.info("%s: draining, snapshotting and stopping", signal.Signals(signum).name)
            self._stop.set()

        signal.signal(signal.SIGTERM, stop)
        signal.signal(signal.SIGINT, stop)

    def stop(self) -> None:
        self._stop.set()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def run(self, records: Iterable[LogRecord], *, start: int = 0, finish: bool = True) -> bool:
        """Feed ``records``, the input from record number ``start`` on (the resume position);
        return True when the input ended, False when stopped by a signal (then a snapshot was
        written and nothing flushed)."""
        self._start_heartbeat()
        self.notifier.ready()
        every = self.settings.node.snapshot_every_tiles
        ended = True
        try:
            for i, rec in enumerate(records, start=start):
                self.pipeline.feed(rec)
                self.position = i + 1
                self._after_step(every)
                if self._stop.is_set():
                    ended = False
                    break
            if ended and finish:
                self.pipeline.finish()
                if self.pipeline.calibration_held:  # a signal while waiting for the on-line model
                    ended = False
                    self.notifier.stopping()
                if self.state_dir is not None:
                    self.snapshot()
            elif not ended:
                self.notifier.stopping()
                if self.state_dir is not None:
                    self.snapshot()
        finally:
            self._end_heartbeat()
        return ended

    def run_live(self, link: Any, *, poll_s: float = 0.2, finish_at_end: bool = False) -> None:
        """Feed a live link until a signal (or the link's end): never blocks longer than
        ``poll_s`` without feeding the watchdog and letting held tiles go stale, and polls the
        worker every 10 ms while it has units, so evidence is published as soon as it is ready.
        ``finish_at_end``: when the link ends (a paced recording), flush and fuse everything."""
        self._start_heartbeat()
        self.notifier.ready()
        every = self.settings.node.snapshot_every_tiles
        tiles_before = self.pipeline.stats.tiles_in  # restored by a resume: the first tile is the first of this run
        log.info("running: waiting for the first tile")
        try:
            while not self._stop.is_set() and not link.at_end:
                rec = link.recv(timeout=0.01 if self.pipeline.inflight else poll_s)
                if rec is not None:
                    self.pipeline.feed(rec)
                    self.position += 1
                    if tiles_before is not None and self.pipeline.stats.tiles_in > tiles_before:
                        tiles_before = None  # said once
                        m = rec.msg if isinstance(rec.msg, dict) else {}
                        log.info("first tile in: %s/leg %s/%s, seq %s", m.get("mission"), m.get("leg"),
                                 m.get("side"), m.get("seq"))
                else:
                    self.pipeline.tick(time.time())
                self._after_step(every)
            if finish_at_end and link.at_end and not self._stop.is_set():
                self.pipeline.finish()
            self.notifier.stopping()
            if self.state_dir is not None:
                self.snapshot()
        finally:
            self._end_heartbeat()

    def _end_heartbeat(self) -> None:
        """A last heartbeat (the final counters), then stop the heartbeat thread."""
        self._send_heartbeat()
        self._hb_stop.set()
        if self._hb_thread is not None:
            self._hb_thread.join(timeout=2.0)

    def _after_step(self, every: int) -> None:
        """After each record (or idle poll): peers' evidence, the watchdog, a snapshot when due."""
        if self.exchange is not None:
            self.exchange.pump()
        self.notifier.watchdog()
        if self.state_dir is not None and self.pipeline.stats.tiles_in - self._last_snap_tiles >= every:
            self.snapshot()

    def snapshot(self) -> None:
        self.pipeline.drain()
        try:
            node_state.save(self.state_dir, self.pipeline, position=self.position, source=self.source_name,
                            source_id=self.source_id)
        except OSError as exc:
            # disk full or I/O error: the previous snapshot stays current (state.save guarantees
            # it); the node goes on and tries again after the next snapshot_every_tiles tiles
            self.snapshot_failures += 1
            self._last_snap_tiles = self.pipeline.stats.tiles_in
            log.error("snapshot to %s failed (%s); the previous one stays current", self.state_dir, describe(exc))
            return
        if self.exchange is not None:  # beside the snapshot it belongs to (none: exchange off on resume)
            try:
                self.exchange.save(node_state.read_current(self.state_dir))
            except OSError as exc:
                log.error("evidence-exchange ledger not saved (%s): a resume from this snapshot turns "
                          "the exchange off", describe(exc))
        self._last_snap_tiles = self.pipeline.stats.tiles_in
        self.snapshots += 1

    def close(self) -> None:
        self._hb_stop.set()
        self.pipeline.close()
        if self.exchange is not None:
            self.exchange.close()
        if self.snapshot_server is not None:
            self.snapshot_server.close()
        if self.publisher is not None:
            self.publisher.close()
        self.notifier.close()

    # -- outputs -----------------------------------------------------------------------------
    def _emit(self, msg: dict) -> None:
        # the view first: a snapshot taken between the two already holds this message, and a
        # late joiner then drops it from the stream by its seq (and applies it once)
        self.contact_view.published(msg)
        if self.publisher is not None:
            self.publisher.contact(msg)
        if self.on_contact is not None:
            self.on_contact(msg)

    def heartbeat(self) -> dict[str, Any]:
        st = self.pipeline.stats
        p50, p99 = st.latency_ms()
        return wire.heartbeat_message(t=time.time(), uptime_s=time.monotonic() - self._t0, tiles_in=st.tiles_in,
                                      tiles_done=st.tiles_done, tiles_dropped=st.tiles_dropped,
                                      tiles_rejected=st.tiles_rejected, queue_depth=self.pipeline.queue_depth,
                                      p50_ms=p50, p99_ms=p99, mode="degraded" if self.pipeline.degraded else "nominal")

    def _send_heartbeat(self) -> None:
        if self.publisher is not None:
            self.publisher.heartbeat(self.heartbeat())

    def _start_heartbeat(self) -> None:
        if self.publisher is None or self._hb_thread is not None:
            return
        period = self.settings.node.heartbeat_s

        def loop() -> None:
            while not self._hb_stop.wait(period):
                try:
                    self._send_heartbeat()
                except Exception as exc:  # a heartbeat must never take the node down
                    log.warning("heartbeat failed: %s", describe(exc))

        self._hb_thread = threading.Thread(target=loop, name="atr-heartbeat", daemon=True)
        self._hb_thread.start()

    def summary(self) -> dict[str, Any]:
        st = self.pipeline.stats
        nc = self.pipeline.navcheck
        p50, p99 = st.latency_ms()
        return {"records": st.records, "tiles_in": st.tiles_in, "tiles_done": st.tiles_done,
                "tiles_rejected": st.tiles_rejected, "tiles_dropped": st.tiles_dropped,
                "drop_reasons": dict(st.drop_reasons), "units": st.units,
                "units_degraded": st.units_degraded, "pixels": st.pixels, "detect_s": round(st.detect_s, 3),
                "fuse_s": round(st.fuse_s, 3), "latency_p50_ms": round(p50, 1), "latency_p99_ms": round(p99, 1),
                "contacts": len(self.pipeline.contacts), "nav": self.pipeline.decoder.stats(),
                "navmerge": vars(self.pipeline.merger.stats), "rejections": dict(st.rejections),
                "snapshots": self.snapshots, "snapshot_failures": self.snapshot_failures,
                "resumed_from": self.resumed_from, "model": self.pipeline.model_report(),
                "contact_seq": self.pipeline.contact_seq,
                # do the legs see the same objects within the association gate? (fusion.navcheck)
                "leg_shifts": nc.figures(), "navigation": nc.summary(),
                # DS masses clamped to 1 - eps (SPEC section 6): evidence the grid had to cap
                "clamped": int(self.pipeline.grid.n_clamped),
                "seq_repeats": 0 if self.pipeline.strips is None else self.pipeline.strips.seq_repeats,
                # strips ended early within a leg, by reason (a gap in ping time, another dx_m)
                "strip_breaks": {} if self.pipeline.strips is None else dict(self.pipeline.strips.breaks),
                "frame": None if self.pipeline.frame is None else {**self.pipeline.frame.to_dict(),
                                                                   "name": self.pipeline.frame.name},
                "snapshot_endpoint": None if self.snapshot_server is None else {
                    "endpoint": self.snapshot_server.endpoint, "served": self.snapshot_server.served,
                    "refused": self.snapshot_server.refused},
                "exchange": None if self.exchange is None else {**self.exchange.counters, **self.exchange.grid.counters}}


def write_contacts(path: str | Path, contacts: list[dict]) -> None:
    """``--contacts-out``: the final state of every contact, one JSON object per line, written
    atomically (whole or not at all)."""
    with atomic_open(path, "w") as fh:
        for c in contacts:
            fh.write(json.dumps(c, sort_keys=True) + "\n")


def write_detections(path: str | Path, pipeline: Pipeline) -> None:
    """``--detections-out``: every detection the grid received, one JSON object per line,
    written atomically (whole or not at all)."""
    frame = pipeline.frame
    with atomic_open(path, "w") as fh:
        for r in pipeline.grid.detections:
            lat, lon = frame.to_latlon(r.east_m, r.north_m) if frame is not None else (float("nan"),) * 2
            fh.write(json.dumps({"detector": r.detector, "leg": r.leg, "t": r.t, "lat_deg": float(lat),
                                 "lon_deg": float(lon), "east_m": r.east_m, "north_m": r.north_m,
                                 "gamma": r.gamma, "confidence": r.confidence}) + "\n")
