"""Recordings to one evidence grid: map each recording to its evidence deltas, reduce them by
exact addition in the canonical order, extract contacts (issue 11).

::

    recording_1 --(task: the node's pipeline, replay mode, one process)--> deltas_1 ---+
    ...                                                                                +--> reduce_deltas
    recording_n --------------------------------------------------------> deltas_n ---+    (canonical order)
                                                                                           --> ContactTracker

A task is the node's own pipeline (``atr_node.node.pipeline.Pipeline``, ``workers=0``, a
fixed performance model, no on-line calibration) with an exchanging grid: its result is the
encoded deltas of its committed legs (``atr_node.fusion.exchange`` v1, the same bytes nodes
exchange on ZeroMQ). The reduction is a pure function of the *set* of deltas, so the grid and
the contacts do not depend on the number of workers, the order tasks end in, or retries.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from ..calibration.model import PerformanceModel
from ..config import Settings
from ..errors import AtrError
from ..fusion import ContactTracker, EvidenceGrid, association_gate_m
from ..fusion.exchange import DeltaSet, decode_delta, encode_delta, reduce_deltas
from ..geo import MissionFrame
from .engine import Engine, Progress, TaskOutcome


@dataclass(frozen=True)
class RecordingDeltas:
    """Result of one recording's task."""

    path: str
    node: str
    missions: tuple[str, ...]
    payloads: tuple[bytes, ...]
    """Encoded deltas (v1), in commit order."""
    tiles_in: int
    tiles_rejected: int
    pixels: int
    seconds: float
    cpu_s: float = 0.0
    """CPU time of the task's process (wall ``seconds`` minus this = waiting for a core)."""
    tiles_dropped: int = 0
    drop_reasons: tuple[tuple[str, int], ...] = ()
    """``tiles_dropped`` by reason (e.g. ``no usable nav``), sorted."""


def recording_deltas(path: str, settings: Settings, model: PerformanceModel, node: str) -> RecordingDeltas:
    """Replay one recording (.atrlog or .xtf) through the node's pipeline; return its deltas."""
    from ..node.exchange import attach_exchange
    from ..node.pipeline import Pipeline
    from ..io.recording import open_recording

    t0, c0 = time.perf_counter(), time.process_time()
    if not Path(path).is_file():
        raise AtrError(f"recording {path}: no such file on this worker")
    pipe = Pipeline(settings, model=model, workers=0, mode="replay")
    try:
        grid = attach_exchange(pipe, node=node)
        pipe.replay(open_recording(path, crs=settings.recording.crs, altitude=settings.recording.altitude,
                                    frequency=settings.recording.frequency))
    finally:
        pipe.close()
    st = pipe.stats
    if st.tiles_in == 0:
        # a recording that gives nothing is a failure to report, not an empty success
        raise AtrError(f"recording {path}: no sonar tile accepted ({st.records} records read, "
                       f"{st.tiles_rejected} tiles rejected): not a recording, or empty")
    return RecordingDeltas(str(path), node, tuple(sorted(set(grid.leg_mission.values()))),
                           tuple(encode_delta(d) for d in grid.outbox), st.tiles_in, st.tiles_rejected, st.pixels,
                           time.perf_counter() - t0, time.process_time() - c0, st.tiles_dropped,
                           tuple(sorted(st.drop_reasons.items())))


@dataclass
class BatchResult:
    """A batch run: the reduced grid, its contacts, and what happened to every recording."""

    grid: EvidenceGrid | None
    frame: MissionFrame | None
    contacts: list[dict[str, Any]]
    outcomes: list[TaskOutcome]
    deltas: int = 0
    duplicates: int = 0
    map_s: float = 0.0
    reduce_s: float = 0.0
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def failures(self) -> list[TaskOutcome]:
        return [o for o in self.outcomes if not o.ok]

    @property
    def retried(self) -> list[TaskOutcome]:
        return [o for o in self.outcomes if o.ok and o.attempts > 1]


def node_ids(paths: Sequence[str | Path]) -> list[str]:
    """A node id per recording: its file name, made unique by its rank when names repeat."""
    names = [Path(p).name for p in paths]
    return [n if names.count(n) == 1 else f"{n}#{i}" for i, n in enumerate(names)]


def reduce_recordings(results: Sequence[RecordingDeltas], settings: Settings) -> tuple[EvidenceGrid, DeltaSet, MissionFrame | None, float]:
    """Decode every delta and reduce them in the canonical order; (grid, deltas, frame, t_end)."""
    deltas = [decode_delta(b) for r in results for b in r.payloads]
    gate = association_gate_m(settings.fusion, settings.template)
    grid, dset = reduce_deltas(deltas, fusion=settings.fusion, gate_m=gate, detectors=settings.detectors.enabled)
    frame = MissionFrame.from_dict(deltas[0].frame) if deltas else None
    t_end = max((d.t for d in deltas), default=0.0)
    return grid, dset, frame, t_end


def contacts_of(grid: EvidenceGrid, frame: MissionFrame | None, settings: Settings, t: float) -> list[dict[str, Any]]:
    """Contacts of a finished grid, extracted once (ids by position order of extraction)."""
    if frame is None:
        return []
    tracker = ContactTracker(settings.fusion, frame, gate_m=association_gate_m(settings.fusion, settings.template))
    return [c.to_message() for c in sorted(tracker.update(grid, t), key=lambda c: c.id)]


def check_positions(paths: Sequence[str | Path], crs: str, frequency: str | float = "high") -> None:
    """Fail at once, before any task, on an XTF recording whose positions need a CRS that was
    not given, or without a side-scan channel at the frequency asked (rather than in every task
    and its retries). Files this host cannot see (a remote cluster's paths) are left to their task."""
    from ..io.xtf_packets import read_positions

    for p in paths:
        if str(p).lower().endswith(".xtf") and Path(p).is_file():
            read_positions(p, crs, frequency=frequency)


def run_recordings(paths: Sequence[str | Path], settings: Settings, model: PerformanceModel, engine: Engine, *,
                   progress: Progress | None = None) -> BatchResult:
    """Map every recording to its deltas on ``engine``, reduce, extract contacts."""
    if not paths:
        raise AtrError("batch: no recording given")
    check_positions(paths, settings.recording.crs, settings.recording.frequency)
    items = [(Path(p).name, (str(p), settings, model, node)) for p, node in zip(paths, node_ids(paths))]
    t0 = time.perf_counter()
    outcomes = engine.map(recording_deltas, items, progress=progress)
    t1 = time.perf_counter()
    done = [o.result for o in outcomes if o.ok]
    grid, dset, frame, t_end = reduce_recordings(done, settings)
    contacts = contacts_of(grid, frame, settings, t_end)
    t2 = time.perf_counter()
    reasons: dict[str, int] = {}
    for r in done:
        for k, v in r.drop_reasons:
            reasons[k] = reasons.get(k, 0) + v
    info = {"tiles_in": sum(r.tiles_in for r in done), "tiles_rejected": sum(r.tiles_rejected for r in done),
            "tiles_dropped": sum(r.tiles_dropped for r in done), "drop_reasons": reasons,
            "pixels": sum(r.pixels for r in done), "task_s": round(sum(r.seconds for r in done), 3),
            "task_cpu_s": round(sum(r.cpu_s for r in done), 3),
            "missions": sorted({m for r in done for m in r.missions}), "engine": engine.describe()}
    return BatchResult(grid, frame, contacts, outcomes, len(dset), dset.duplicates, t1 - t0, t2 - t1, info)
