"""A node's evidence grid that publishes its committed legs as deltas and ingests other nodes'.

:class:`ExchangeGrid` is an :class:`~atr_node.fusion.grid.EvidenceGrid` that

- turns every commit of its own legs (early parts, then the final part when the leg closes)
  into an :class:`~atr_node.fusion.exchange.EvidenceDelta` handed to ``on_delta`` (the node
  publishes it) and kept in ``outbox``;
- ingests deltas of other nodes (:meth:`ingest`): checked against the grid's settings and
  frame, deduplicated by id (a duplicated or replayed delta changes nothing), and added so
  that the committed accumulators are always the canonical reduction of every delta it holds
  (its own and the others'): a delta that arrives out of the canonical order
  ``(mission, leg, node, seq)`` for a chunk makes that chunk be summed again from the ledger,
  in order. The grid therefore equals, bit for bit, ``reduce_deltas`` of the same deltas,
  whatever the arrival order (``docs/scaleout.md``).

Cost: the ledger keeps every delta (8 bytes per covered cell and leg, 16 near detections),
which is what re-summing needs; the re-sum is per chunk and only for out-of-order arrivals.
"""

from __future__ import annotations

from collections import Counter
from typing import Any, Callable, Iterable

import numpy as np

from ..config import DETECTOR_NAMES, FusionSettings
from ..errors import FusionError
from .chunks import Key, LegLayer, layer_terms
from .exchange import DeltaId, DeltaSet, EvidenceDelta, apply_delta, decode_delta
from .grid import EvidenceGrid
from .observation import Observation

Context = Callable[[], tuple[str, Any]]
"""Returns (mission name, MissionFrame or None) of the node's current input."""


class ExchangeGrid(EvidenceGrid):
    """Evidence grid with evidence exchange (see the module docstring).

    Parameters
    ----------
    fusion, gate_m, detectors, auto_close
        As :class:`EvidenceGrid`.
    node : str
        This node's id (unique among the nodes that exchange).
    context : callable
        ``() -> (mission, frame)``, asked at a leg's first observation and at each commit.
    on_delta : callable, optional
        Called with each of this node's deltas, in commit order.
    """

    def __init__(self, fusion: FusionSettings, *, gate_m: float, detectors: Iterable[str] = DETECTOR_NAMES,
                 auto_close: bool = True, node: str, context: Context,
                 on_delta: Callable[[EvidenceDelta], None] | None = None, layers: Iterable[str] | None = None) -> None:
        super().__init__(fusion, gate_m=gate_m, detectors=detectors, auto_close=auto_close, layers=layers)
        if not node:
            raise FusionError("an exchanging grid needs a non-empty node id")
        self.node = node
        self.context = context
        self.on_delta = on_delta
        self.outbox: list[EvidenceDelta] = []
        self.ledger = DeltaSet()
        self.counters: Counter = Counter()
        self.leg_mission: dict[int, str] = {}
        self._seq: dict[int, int] = {}
        self._final: set[int] = set()
        self._det_sent = 0
        self._leg_t: dict[int, float] = {}
        self._top: dict[Key, DeltaId] = {}
        """chunk -> the largest id (canonical order) added to it."""
        self._index: dict[Key, list[tuple[DeltaId, int]]] = {}
        """chunk -> (delta id, row) of every delta that touched it."""

    @classmethod
    def adopt(cls, grid: EvidenceGrid, state: dict[str, Any], deltas: Iterable[EvidenceDelta], *, node: str,
              context: Context, on_delta: Callable[[EvidenceDelta], None] | None = None) -> "ExchangeGrid":
        """An exchanging grid holding the state of ``grid`` (restored from a snapshot) and the
        ledger ``deltas`` and bookkeeping ``state`` saved with it (:meth:`exchange_state`)."""
        new = cls.__new__(cls)
        new.__dict__.update(grid.__dict__)
        new.node, new.context, new.on_delta = node, context, on_delta
        new.ledger, new.counters = DeltaSet(), Counter()
        new._top, new._index = {}, {}
        for d in sorted(deltas, key=lambda x: x.id):  # canonical order: nothing is late
            new.ledger.add(d)
            new._note(d)
        new.outbox = [d for d in new.ledger.ordered() if d.id.node == node]
        new.leg_mission = {int(k): str(v) for k, v in state["leg_mission"].items()}
        new._seq = {int(k): int(v) for k, v in state["seq"].items()}
        new._leg_t = {int(k): float(v) for k, v in state["leg_t"].items()}
        new._final = {int(x) for x in state["final"]}
        new._det_sent = int(state["det_sent"])
        return new

    def exchange_state(self) -> dict[str, Any]:
        """Bookkeeping beside the ledger that :meth:`adopt` needs (plain types)."""
        return {"leg_mission": {str(k): v for k, v in self.leg_mission.items()},
                "seq": {str(k): v for k, v in self._seq.items()}, "leg_t": {str(k): v for k, v in self._leg_t.items()},
                "final": sorted(self._final), "det_sent": self._det_sent}

    # ------------------------------------------------------------------ own legs
    def add_observation(self, obs: Observation) -> None:
        self.leg_mission.setdefault(obs.leg, self.context()[0])
        super().add_observation(obs)

    def close_leg(self, leg: int) -> None:
        was_open = leg in self.open
        super().close_leg(leg)
        if was_open and leg not in self._final:  # every part went early: still say the leg is complete
            self._emit(leg, [], np.zeros((0, self.nn)), np.zeros((0, self.nn)), np.zeros((0, self.nn), bool),
                       0, self._leg_t.get(leg, 0.0))

    def _commit(self, leg: int, layer: LegLayer, keys: list[Key]) -> None:
        if not keys:
            return
        p = layer.chunks.gather(keys)
        # the same pure function on the same layer as the parent: the same terms bit for bit
        d_lt, d_ln, n_cl, _ = layer_terms(p, self.fusion.eps)
        covered = (p[:, :, 1] >= 0.0).any(axis=1)  # a Pd: covered (a gate alone is not, SPEC 6.1)
        t = layer.t
        super()._commit(leg, layer, keys)
        self._leg_t[leg] = t
        self._emit(leg, list(keys), d_lt, d_ln, covered, n_cl, t)

    def _emit(self, leg: int, keys: list[Key], d_lt: np.ndarray, d_ln: np.ndarray, covered: np.ndarray,
              n_cl: int, t: float) -> None:
        mission, frame = self.context()
        mission = self.leg_mission.get(leg, mission)
        if frame is None:
            raise FusionError("evidence exchange: the node has no mission frame yet")
        final = leg not in self.open
        seq = self._seq.get(leg, 0)
        self._seq[leg] = seq + 1
        if final:
            self._final.add(leg)
        # the leg's detections not sent yet go with this part: the list is kept as [sent | pending]
        # (its order does not matter to contacts); other legs' detections stay pending (an
        # open leg cannot commit while another leg adds detections, but this does not rely on it)
        pending = self.detections[self._det_sent:]
        mine = tuple(r for r in pending if r.leg == leg)
        self.detections[self._det_sent:] = [r for r in pending if r.leg != leg]
        self.detections[self._det_sent:self._det_sent] = list(mine)
        self._det_sent += len(mine)
        with_t = (d_lt != 0.0).any(axis=1) if len(keys) else np.zeros(0, bool)
        full = covered.all(axis=1) if len(keys) else np.zeros(0, bool)
        nn8 = (self.nn + 7) // 8
        bits = np.packbits(covered[~full], axis=1) if (~full).any() else np.zeros((0, nn8), np.uint8)
        d = EvidenceDelta(DeltaId(mission, leg, self.node, seq), final, float(t),
                          {**frame.to_dict(), "proj4": frame.proj4}, self.cell_m, self.n, self.fusion.eps,
                          self.detectors, np.array(keys, dtype=np.int64).reshape(-1, 2), d_ln,
                          np.flatnonzero(with_t).astype(np.int64), d_lt[with_t], full, bits, n_cl, mine)
        self.ledger.add(d)
        late = self._note(d)
        if late:
            self._resum(late)
        self.counters["own_deltas"] += 1
        self.outbox.append(d)
        if self.on_delta is not None:
            self.on_delta(d)

    # ------------------------------------------------------------------ others' legs
    def ingest(self, delta: EvidenceDelta | bytes) -> bool:
        """Add another node's delta; True if it was new, False for a duplicate (no change).

        Raises
        ------
        FusionError
            Undecodable, of other grid settings or frame, this node's own id, or a known id
            with other content. Nothing changes then.
        """
        d = decode_delta(delta) if isinstance(delta, (bytes, bytearray, memoryview)) else delta
        if d.id.node == self.node and d.id not in self.ledger:
            raise FusionError(f"evidence delta {d.id}: carries this node's id but this node never made it")
        frame = self.context()[1]
        why = d.compatible(self, None if frame is None else frame.proj4)
        if why:
            self.counters["rejected"] += 1
            raise FusionError(f"evidence delta {d.id}: {why}")
        if not self.ledger.add(d):
            self.counters["duplicates"] += 1
            return False
        late = self._note(d)
        rows = np.array([i for i, k in enumerate(d.chunk_keys()) if k not in late], dtype=np.int64)
        n0 = len(self.detections)
        apply_delta(self, d, rows=rows)
        # others' detections join the "sent" side of [sent | own pending]: never re-sent as ours
        theirs = self.detections[n0:]
        del self.detections[n0:]
        self.detections[self._det_sent:self._det_sent] = theirs
        self._det_sent += len(theirs)
        if late:
            self._resum(late)
        self.counters["ingested"] += 1
        return True

    # ------------------------------------------------------------------ canonical order
    def _note(self, d: EvidenceDelta) -> set[Key]:
        """Index ``d``; return the chunks where it arrived after a delta it sorts before."""
        late: set[Key] = set()
        for row, key in enumerate(d.chunk_keys()):
            self._index.setdefault(key, []).append((d.id, row))
            top = self._top.get(key)
            if top is not None and top > d.id:
                late.add(key)
            else:
                self._top[key] = d.id
        return late

    def _resum(self, keys: set[Key]) -> None:
        """Sum the accumulators of ``keys`` again from the ledger, in the canonical order."""
        self.counters["resummed_chunks"] += len(keys)
        for key in sorted(keys):
            ln = np.zeros(self.nn)
            lt = np.zeros(self.nn)
            any_t = False
            for did, row in sorted(self._index[key]):
                d = self.ledger.deltas[did]
                ln += d.d_ln[row]
                hit = np.flatnonzero(d.lt_rows == row)
                if hit.size:
                    lt += d.d_lt[int(hit[0])]
                    any_t = True
            self._ln.arr[self._ln.get(key)] = ln
            if any_t or key in self._lt.slot:
                self._lt.arr[self._lt.get(key)] = lt
            self.changed[key] = self.stamp
