"""Where a unit's latency goes (issue 7): per-unit stage times of the node's pipeline.

The heartbeat reports the latency from a tile's arrival to its evidence being published
(``latency_ms``). To find what that time is made of, the pipeline stamps each unit as it
goes (``time.monotonic``, seconds) and keeps the last ones in ``PipelineStats.stages``::

    arrived     the sonar record of the tile that released the unit was received
    submitted   the unit left the strip assembler (tile decoding, nav, strip done)
    queued      the job was handed to the worker (background trackers, job built)
    worker_done the worker's result was ready (transfer + queueing + detection)
    fuse_start  the main process took the result (it may have been busy with other work)
    fused       grid and contacts updated, contact messages published

plus ``detect_s`` (detection inside the worker), ``deposit_s`` (``add_observation``) and
``contacts_s`` (contact extraction and publishing). :func:`breakdown` turns them into the
table ``tools/bench/node.py latency`` prints.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

STAGES = ("ingest", "submit", "worker", "wait_main", "deposit", "contacts", "other_fuse", "total")
"""Columns of :func:`breakdown`: consecutive intervals that add up to ``total``."""


@dataclass
class UnitTiming:
    """Stage times of one strip unit (see the module docstring)."""

    side: str
    seq: int
    rows: int
    arrived: float | None
    submitted: float
    queued: float = float("nan")
    worker_done: float = float("nan")
    fuse_start: float = float("nan")
    fused: float = float("nan")
    detect_s: float = float("nan")
    deposit_s: float = 0.0
    contacts_s: float = 0.0

    def mark_done(self, _future: object = None) -> None:
        """Future callback: the worker's result is ready (runs in the executor's thread)."""
        self.worker_done = time.monotonic()

    def intervals(self) -> dict[str, float]:
        """Seconds per stage of :data:`STAGES` (NaN where the unit has no arrival time)."""
        a = self.submitted if self.arrived is None else self.arrived
        fuse = self.fused - self.fuse_start
        return {"ingest": self.submitted - a if self.arrived is not None else float("nan"),
                "submit": self.queued - self.submitted,
                "worker": self.worker_done - self.queued,
                "wait_main": self.fuse_start - self.worker_done,
                "deposit": self.deposit_s,
                "contacts": self.contacts_s,
                "other_fuse": fuse - self.deposit_s - self.contacts_s,
                "total": self.fused - a if self.arrived is not None else float("nan")}


def breakdown(stages: Iterable[UnitTiming]) -> dict[str, tuple[float, float]]:
    """(median, max) seconds per stage over units that carry an arrival time."""
    rows = [u.intervals() for u in stages if u.arrived is not None]
    if not rows:
        return {k: (float("nan"), float("nan")) for k in STAGES}
    return {k: (float(np.median([r[k] for r in rows])), float(np.max([r[k] for r in rows]))) for k in STAGES}
