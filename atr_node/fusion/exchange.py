"""Evidence deltas between nodes: the record, its wire format, dedupe and exact reduction (SPEC section 7).

A committed leg adds, per chunk it covered, ``d_lt`` and ``d_ln`` to the accumulators
(Dempster's rule is a sum of logs). An :class:`EvidenceDelta` is exactly those increments,
for one *part* of one leg (a leg commits in parts: chunks behind the vehicle early, the rest
when the leg closes), with the leg's coverage bits, its detections and where it came from.
It is identified by ``(node, mission, leg, seq)``; a delta seen again (duplicated, replayed)
is recognised by that id and never counted twice (:class:`DeltaSet`).

Exactness. Float addition is not associative, so the order of the sums is part of the
result. Every reduction here adds deltas in the **canonical order** ``(mission, leg, node,
seq)``, chunk by chunk, with the same numpy expression as :meth:`EvidenceGrid._commit`. A
node surveying its legs in increasing leg order commits them in that order too, so:
``reduce_deltas(deltas of A and B)`` equals, bit for bit, the grid of one node that saw both
surveys, whatever the order and the duplicates in which the deltas arrive (``docs/scaleout.md``).

Wire format v1 (one msgpack map, ``use_bin_type=True``; arrays little-endian, row-major;
K chunks of ``nn = chunk_cells**2`` cells; on ZeroMQ the two frames ``[b"evidence", map]``)::

    type "evidence"   v 1             node str, mission str, leg int, seq int, final bool
    t float (last ping time of the part)                      n_clamped int
    frame {kind, origin_lat_deg, origin_lon_deg, proj4}       cell_m, eps float, chunk_cells int
    detectors [str]  (the fixed order of the sums)
    keys      bin int64   (K, 2) chunk (cy, cx)
    ln        bin float64 (K, nn) increments of L_N (<= 0, finite)
    lt_rows   bin int64   (J,)    rows of ``keys`` that received T evidence
    lt        bin float64 (J, nn) increments of L_T there
    cover_all bin uint8   (K,)    1: the leg covered every cell of the chunk
    cover_bits bin uint8  (K - sum(cover_all), ceil(nn/8)) numpy packbits of covered cells
    det       map of bins (D,): detector uint8 (index in detectors), east_m, north_m, t,
              confidence, gamma float64
    digest    str  sha256 hex of the id and every bin above, in this order (integrity)
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

import msgpack
import numpy as np

from ..config import FusionSettings
from ..errors import FusionError
from .grid import DetectionRecord, EvidenceGrid

VERSION = 1
TOPIC = b"evidence"
_DET_FIELDS = ("east_m", "north_m", "t", "confidence", "gamma")


@dataclass(frozen=True, order=True)
class DeltaId:
    """Identity of a delta; its field order *is* the canonical reduction order."""

    mission: str
    leg: int
    node: str
    seq: int

    def __str__(self) -> str:
        return f"node {self.node!r} mission {self.mission!r} leg {self.leg} part {self.seq}"


@dataclass(frozen=True, eq=False)
class EvidenceDelta:
    """Accumulator increments of one committed part of a leg (see the module docstring).

    Arrays: ``keys`` (K, 2) int64, ``d_ln`` (K, nn), ``lt_rows`` (J,) int64, ``d_lt`` (J, nn),
    ``cover_all`` (K,) bool, ``cover_bits`` (K - sum(cover_all), ceil(nn / 8)) uint8.
    """

    id: DeltaId
    final: bool
    t: float
    frame: Mapping[str, Any]
    cell_m: float
    chunk_cells: int
    eps: float
    detectors: tuple[str, ...]
    keys: np.ndarray
    d_ln: np.ndarray
    lt_rows: np.ndarray
    d_lt: np.ndarray
    cover_all: np.ndarray
    cover_bits: np.ndarray
    n_clamped: int = 0
    detections: tuple[DetectionRecord, ...] = ()
    digest: str = field(default="")

    def __post_init__(self) -> None:
        if not self.digest:
            object.__setattr__(self, "digest", _digest(self))

    @property
    def nn(self) -> int:
        return self.chunk_cells * self.chunk_cells

    def chunk_keys(self) -> list[tuple[int, int]]:
        return [(int(a), int(b)) for a, b in self.keys.tolist()]

    def compatible(self, grid: EvidenceGrid, proj4: str | None) -> str | None:
        """Why this delta cannot be added to ``grid`` in frame ``proj4`` (None: it can)."""
        if (self.cell_m, self.chunk_cells, self.eps) != (grid.cell_m, grid.n, grid.fusion.eps):
            return (f"grid (cell {self.cell_m} m, chunk {self.chunk_cells}, eps {self.eps}) differs from this "
                    f"node's (cell {grid.cell_m} m, chunk {grid.n}, eps {grid.fusion.eps})")
        if self.detectors != tuple(grid.detectors):
            return f"detectors {list(self.detectors)} differ from this node's {list(grid.detectors)}"
        if proj4 is not None and self.frame.get("proj4") != proj4:
            return f"frame {self.frame.get('proj4')!r} differs from the grid's {proj4!r}"
        return None


def _bins(d: EvidenceDelta) -> list[bytes]:
    det = d.detections
    cols = [np.array([d.detectors.index(r.detector) for r in det], dtype=np.uint8).tobytes()]
    cols += [np.array([getattr(r, f) for r in det], dtype="<f8").tobytes() for f in _DET_FIELDS]
    return [np.ascontiguousarray(d.keys, dtype="<i8").tobytes(), np.ascontiguousarray(d.d_ln, dtype="<f8").tobytes(),
            np.ascontiguousarray(d.lt_rows, dtype="<i8").tobytes(), np.ascontiguousarray(d.d_lt, dtype="<f8").tobytes(),
            np.ascontiguousarray(d.cover_all, dtype=np.uint8).tobytes(),
            np.ascontiguousarray(d.cover_bits, dtype=np.uint8).tobytes(), *cols]


def _digest(d: EvidenceDelta) -> str:
    h = hashlib.sha256(f"{d.id.node}\0{d.id.mission}\0{d.id.leg}\0{d.id.seq}\0".encode())
    for b in _bins(d):
        h.update(len(b).to_bytes(8, "little"))
        h.update(b)
    return h.hexdigest()


# ------------------------------------------------------------------ codec
def encode_delta(d: EvidenceDelta) -> bytes:
    """The v1 msgpack map of a delta (module docstring)."""
    b = _bins(d)
    return msgpack.packb({
        "type": "evidence", "v": VERSION, "node": d.id.node, "mission": d.id.mission, "leg": int(d.id.leg),
        "seq": int(d.id.seq), "final": bool(d.final), "t": float(d.t), "n_clamped": int(d.n_clamped),
        "frame": dict(d.frame), "cell_m": float(d.cell_m), "chunk_cells": int(d.chunk_cells), "eps": float(d.eps),
        "detectors": list(d.detectors), "keys": b[0], "ln": b[1], "lt_rows": b[2], "lt": b[3], "cover_all": b[4],
        "cover_bits": b[5], "det": {"detector": b[6], **dict(zip(_DET_FIELDS, b[7:]))}, "digest": d.digest,
    }, use_bin_type=True)


def _field(m: Mapping[str, Any], key: str, tp: type | tuple[type, ...], where: str) -> Any:
    if key not in m:
        raise FusionError(f"evidence delta ({where}): missing key {key!r}")
    v = m[key]
    if not isinstance(v, tp) or (tp is int and isinstance(v, bool)):
        raise FusionError(f"evidence delta ({where}): key {key!r} is {type(v).__name__}, expected {tp}")
    return v


def _array(raw: bytes, dtype: str, shape: tuple[int, ...], key: str, where: str) -> np.ndarray:
    need = math.prod(shape) * np.dtype(dtype).itemsize
    if len(raw) != need:
        raise FusionError(f"evidence delta ({where}): {key!r} holds {len(raw)} bytes, expected {need} for shape {shape}")
    return np.frombuffer(raw, dtype=dtype).reshape(shape).astype(dtype[1:] if dtype[0] in "<>" else dtype)


def decode_delta(payload: bytes) -> EvidenceDelta:
    """Parse and validate a v1 delta.

    Raises
    ------
    FusionError
        Not msgpack, not an evidence delta, an unknown version, a missing or ill-typed key,
        arrays of the wrong length, increments > 0 or not finite, or a digest mismatch; the
        message names the delta (node, mission, leg, part) and the key.
    """
    try:
        m = msgpack.unpackb(payload, raw=False)
    except Exception as exc:  # msgpack raises several unrelated types
        raise FusionError(f"evidence delta: not a msgpack map ({type(exc).__name__}: {exc})") from None
    if not isinstance(m, dict) or m.get("type") != "evidence":
        raise FusionError("evidence delta: not a map of type 'evidence'")
    where = f"node {m.get('node')!r} mission {m.get('mission')!r} leg {m.get('leg')!r} part {m.get('seq')!r}"
    v = m.get("v")
    if v != VERSION:
        raise FusionError(f"evidence delta ({where}): version {v!r} is not supported; this node reads v{VERSION}")
    did = DeltaId(_field(m, "mission", str, where), _field(m, "leg", int, where), _field(m, "node", str, where),
                  _field(m, "seq", int, where))
    n = _field(m, "chunk_cells", int, where)
    if n < 1:
        raise FusionError(f"evidence delta ({where}): chunk_cells {n} < 1")
    nn, nn8 = n * n, (n * n + 7) // 8
    raw = {k: _field(m, k, bytes, where) for k in ("keys", "ln", "lt_rows", "lt", "cover_all", "cover_bits")}
    k = len(raw["keys"]) // 16
    keys = _array(raw["keys"], "<i8", (k, 2), "keys", where)
    d_ln = _array(raw["ln"], "<f8", (k, nn), "ln", where)
    j = len(raw["lt_rows"]) // 8
    lt_rows = _array(raw["lt_rows"], "<i8", (j,), "lt_rows", where)
    d_lt = _array(raw["lt"], "<f8", (j, nn), "lt", where)
    cover_all = _array(raw["cover_all"], "u1", (k,), "cover_all", where).astype(bool)
    cover_bits = _array(raw["cover_bits"], "u1", (k - int(cover_all.sum()), nn8), "cover_bits", where)
    if j and (lt_rows.min() < 0 or lt_rows.max() >= k or np.any(np.diff(lt_rows) <= 0)):
        raise FusionError(f"evidence delta ({where}): 'lt_rows' must be increasing rows of 'keys' (0..{k - 1})")
    for name, a in (("ln", d_ln), ("lt", d_lt)):
        if not (np.isfinite(a).all() and (a <= 0.0).all()):
            raise FusionError(f"evidence delta ({where}): {name!r} increments must be finite and <= 0 "
                              f"(log1p of a mass clamped below 1)")
    detectors = tuple(_field(m, "detectors", list, where))
    det = _field(m, "det", dict, where)
    d_idx = _array(_field(det, "detector", bytes, where), "u1", (len(det["detector"]),), "det.detector", where)
    if d_idx.size and d_idx.max() >= len(detectors):
        raise FusionError(f"evidence delta ({where}): 'det.detector' index beyond the {len(detectors)} detectors")
    cols = {f: _array(_field(det, f, bytes, where), "<f8", (d_idx.size,), f"det.{f}", where) for f in _DET_FIELDS}
    dets = tuple(DetectionRecord(did.leg, detectors[int(i)], *(float(cols[f][r]) for f in _DET_FIELDS))
                 for r, i in enumerate(d_idx.tolist()))
    frame = _field(m, "frame", dict, where)
    d = EvidenceDelta(did, bool(_field(m, "final", bool, where)), float(_field(m, "t", (int, float), where)), frame,
                      float(_field(m, "cell_m", (int, float), where)), n, float(_field(m, "eps", (int, float), where)),
                      detectors, keys, d_ln, lt_rows, d_lt, cover_all, cover_bits,
                      int(_field(m, "n_clamped", int, where)), dets)
    sent = _field(m, "digest", str, where)
    if sent != d.digest:
        raise FusionError(f"evidence delta ({where}): digest mismatch (corrupted in transit or edited)")
    return d


# ------------------------------------------------------------------ dedupe
class DeltaSet:
    """The deltas accepted so far, by id: a delta seen again is recognised, not counted twice."""

    def __init__(self) -> None:
        self.deltas: dict[DeltaId, EvidenceDelta] = {}
        self.duplicates = 0

    def __len__(self) -> int:
        return len(self.deltas)

    def __contains__(self, did: DeltaId) -> bool:
        return did in self.deltas

    def add(self, d: EvidenceDelta) -> bool:
        """True: new. False: a duplicate (same id, same digest), ignored.

        Raises
        ------
        FusionError
            The same id with other content: two nodes share a node id, or a node restarted
            and re-committed a leg differently; counting either would be wrong.
        """
        old = self.deltas.get(d.id)
        if old is not None:
            if old.digest != d.digest:
                raise FusionError(f"evidence delta {d.id}: seen before with other content "
                                  f"(digest {old.digest[:12]} vs {d.digest[:12]}): node ids must be unique")
            self.duplicates += 1
            return False
        self.deltas[d.id] = d
        return True

    def ordered(self) -> list[EvidenceDelta]:
        """Every delta in the canonical order."""
        return [self.deltas[k] for k in sorted(self.deltas)]


# ------------------------------------------------------------------ apply and reduce
def apply_delta(grid: EvidenceGrid, d: EvidenceDelta, *, rows: np.ndarray | None = None, leg: int | None = None,
                accumulators: bool = True) -> None:
    """Add a delta to ``grid`` exactly as :meth:`EvidenceGrid._commit` adds a leg's terms.

    ``rows``: only these chunk rows' accumulators (default all); ``leg``: the leg number to
    record coverage and detections under (default the delta's); ``accumulators=False``:
    coverage, times, detections and counters only (the caller re-reduces the sums).
    """
    leg = d.id.leg if leg is None else leg
    keys = d.chunk_keys()
    grid.stamp += 1
    if accumulators and keys:
        sel = np.arange(len(keys)) if rows is None else np.asarray(rows, dtype=np.int64)
        if sel.size:
            slots = np.array([grid._ln.get(keys[i]) for i in sel.tolist()], dtype=np.int64)
            grid._ln.arr[slots] += d.d_ln[sel]
            t_sel = np.flatnonzero(np.isin(d.lt_rows, sel))
            if t_sel.size:
                tslots = np.array([grid._lt.get(keys[int(r)]) for r in d.lt_rows[t_sel].tolist()], dtype=np.int64)
                grid._lt.arr[tslots] += d.d_lt[t_sel]
    b = 0
    for i, key in enumerate(keys):
        bits = None
        if not d.cover_all[i]:
            bits, b = d.cover_bits[b].copy(), b + 1
        legs = grid.cover.setdefault(key, {})
        old = legs.get(leg, bits) if leg in legs else bits
        legs[leg] = None if (old is None or bits is None) else np.bitwise_or(old, bits)
        grid.last_t[key] = max(grid.last_t.get(key, -np.inf), d.t)
        grid.changed[key] = grid.stamp
    grid.detections.extend(DetectionRecord(leg, r.detector, r.east_m, r.north_m, r.t, r.confidence, r.gamma)
                           for r in d.detections)
    grid.n_clamped += d.n_clamped


def leg_numbers(ids: Iterable[DeltaId]) -> dict[tuple[str, str, int], int]:
    """Leg number of each (mission, node, leg) in a reduced grid.

    Legs keep their numbers when no two (mission, node) pairs share one (one vehicle's
    mission, or vehicles numbering their legs apart); otherwise they become
    ``rank * 10000 + leg``, rank = place of (mission, node) in sorted order, so that looks and
    legs of contacts still count each pass once.
    """
    trip = sorted({(i.mission, i.node, i.leg) for i in ids})
    owners: dict[int, set[tuple[str, str]]] = {}
    for mission, node, leg in trip:
        owners.setdefault(leg, set()).add((mission, node))
    if all(len(v) == 1 for v in owners.values()):
        return {t: t[2] for t in trip}
    rank = {mn: r for r, mn in enumerate(sorted({(m, n) for m, n, _ in trip}))}
    return {(m, n, leg): rank[(m, n)] * 10000 + leg for m, n, leg in trip}


def reduce_deltas(deltas: Iterable[EvidenceDelta], *, fusion: FusionSettings, gate_m: float,
                  detectors: Iterable[str]) -> tuple[EvidenceGrid, DeltaSet]:
    """The grid holding a set of deltas, summed in the canonical order (bit-exact, see the
    module docstring); duplicates are dropped. Every leg is committed (closed) in it.

    Raises
    ------
    FusionError
        Deltas of different grid settings, detectors or frames, or one id with two contents.
    """
    grid = EvidenceGrid(fusion, gate_m=gate_m, detectors=detectors)
    dset = DeltaSet()
    for d in deltas:
        dset.add(d)
    ordered = dset.ordered()
    proj4 = ordered[0].frame.get("proj4") if ordered else None
    legs = leg_numbers(dset.deltas)
    for d in ordered:
        why = d.compatible(grid, proj4)
        if why:
            raise FusionError(f"evidence delta {d.id}: {why}")
        leg = legs[(d.id.mission, d.id.node, d.id.leg)]
        apply_delta(grid, d, leg=leg)
        grid.closed_legs.add(leg)
    return grid, dset


def committed_state(grid: EvidenceGrid) -> dict[tuple[int, int], np.ndarray]:
    """chunk -> (2, nn) committed [L_T, L_N], for comparisons bit for bit."""
    keys = sorted(grid._ln.keys)
    return dict(zip(keys, grid.chunk_accumulators(keys, include_open=False)))
