"""The georeferenced evidence grid (SPEC section 7): sparse chunks of log accumulators.

Layout. The mission's metric frame is cut into cells of ``cell_m``; global cell (iy, ix)
covers ``[ix, ix+1) * cell_m`` east and ``[iy, iy+1) * cell_m`` north. Cells are stored in
chunks of ``n x n`` (``n = chunk_cells``), allocated only where some detector covered a cell.
Per cell the grid keeps ``L_N`` and ``L_T`` (float64, SPEC section 6), ``L_T`` only in chunks
that received T evidence (8-16 bytes per cell). Per chunk it keeps the last update time and,
per leg that covered it, either "all cells" or a bitmap of the covered cells (1 bit per
cell), from which looks and legs of a position are read.

One piece of evidence per (leg, detector) per cell. Many pixels fall in one cell and a cell
can straddle two tile cores of a leg, so evidence of a leg that is still open is not added at
once: it goes to a transient *open layer* holding, per (detector, cell), the maximum T mass
(over detections whose gate covers the cell) and the maximum Pd over the covered pixels.
Maximum is commutative, associative and exact, so the layer does not depend on how the leg
was cut into tiles. When the leg closes (:meth:`EvidenceGrid.close_leg`, or automatically
when a tile of another leg arrives), each (detector, cell) contributes once: T evidence where
a detection's gate reached it and the detector covered it, else notT evidence where the
detector covered it (SPEC section 7), and the sums are *added* to the accumulators. One
footprint (SPEC 6.1): a gate's T mass stops at the leg's coverage (the cells of its Pd
layer), so a detection at the end of a leg puts no belief on ground that leg never saw.
Belief read while a leg is open includes its layer, so contacts appear as soon as the
evidence does.

Merge (SPEC section 7): committed accumulators add; open layers of the same leg combine by
maximum. See ``docs/fusion.md`` for what is bit-exact and what is exact to rounding.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from ..config import DETECTOR_NAMES, FusionSettings
from ..errors import FusionError
from .chunks import ChunkStack, Key, LegLayer, layer_terms, layer_terms_covered
from .deposit import PdReducer
from .mass import TNMasses, closed_form
from .merge import merge_into  # one way: merge.py names EvidenceGrid for type checkers only
from .observation import DetectionRecord, Observation, association_gate_m, gate_cells, record_extent

__all__ = ["DetectionRecord", "EvidenceGrid", "association_gate_m"]

BLOCK_PIXELS = 1 << 20
"""Pixels per block of rows: chunks are looked up (and allocated, in chunk order) per block;
within a block :class:`~atr_node.fusion.deposit.PdReducer` works in smaller sub-blocks."""


class EvidenceGrid:
    """Sparse evidence grid over the mission's metric frame (SPEC section 7).

    Parameters
    ----------
    fusion : FusionSettings
        Cell size, chunk size, eps, diagnostics.
    gate_m : float
        Association gate radius (see :func:`association_gate_m`).
    detectors : sequence of str
        Detector names, in the fixed order used for sums (and of the detection records).
    layers : sequence of str, optional
        The evidence layers, one piece per (leg, layer) and cell: the detectors (default,
        the paper's form) or ``("look",)`` for look-level evidence (SPEC 6.1).
    auto_close : bool
        Close every other open leg when an observation of a new leg arrives.
    """

    def __init__(self, fusion: FusionSettings, *, gate_m: float, detectors: Iterable[str] = DETECTOR_NAMES,
                 auto_close: bool = True, layers: Iterable[str] | None = None) -> None:
        self.fusion = fusion
        self.cell_m = float(fusion.cell_m)
        self.n = int(fusion.chunk_cells)
        self.nn = self.n * self.n
        self.gate_m = float(gate_m)
        self.detectors = tuple(detectors)
        self.layers = tuple(layers) if layers is not None else self.detectors
        self.auto_close = auto_close
        self._det_index = {d: i for i, d in enumerate(self.layers)}
        # L_N lives in every chunk that was covered; L_T only in chunks that received T
        # evidence (near detections): most of the seabed holds 8 bytes per cell, not 16
        self._ln = ChunkStack((self.nn,), 0.0)
        self._lt = ChunkStack((self.nn,), 0.0)
        self._diag = ChunkStack((len(self.layers), 2, self.nn), 0.0) if fusion.diagnostics else None
        self.last_t: dict[tuple[int, int], float] = {}
        self.cover: dict[tuple[int, int], dict[int, np.ndarray | None]] = {}
        self.open: dict[int, LegLayer] = {}
        self.closed_legs: set[int] = set()
        self.detections: list[DetectionRecord] = []
        self.n_clamped = 0
        """Masses clamped to 1 - eps (SPEC section 6: counted and reported)."""
        self.n_reopened = 0
        """Chunks an open leg touched again after committing them early (its evidence there
        then counts twice for that leg: a leg that came back over its own ground)."""
        self.n_observations = 0
        self.stamp = 0
        self.changed: dict[tuple[int, int], int] = {}
        """chunk -> stamp of its last change (contact extraction recomputes only those)."""
        self._reducer = PdReducer(self.cell_m)
        self._spare: np.ndarray | None = None
        """Array of the last closed leg's layer, reused by the next leg (pages mapped)."""

    def __getstate__(self) -> dict:
        """Pickled (sent to another process) without the spare layer array."""
        state = self.__dict__.copy()
        state["_spare"] = None
        return state

    def reserve(self, chunks: int) -> None:
        """Map memory now for ``chunks`` chunks of an open leg's layer and of the accumulators.

        For a node at start (``node.warm_up_mpx``): without it, the first tiles of a mission
        page-fault in the leg's layer (64 kB per chunk with four detectors) and copy it each
        time it doubles, which on the target VM added 0.2-0.4 s to every 8-Mpx unit's fusion
        until the layer reached its steady size. Nothing observable changes.
        """
        chunks = int(chunks)
        if chunks <= 0:
            return
        if self.open:
            for layer in self.open.values():
                layer.chunks.reserve(chunks)
        elif getattr(self, "_spare", None) is None or self._spare.shape[0] < chunks:
            self._spare = np.full((chunks, len(self.layers), 2, self.nn), -1.0)
        # the accumulators keep every chunk ever covered: room for as many more
        self._ln.reserve(self._ln.high + chunks)

    # ------------------------------------------------------------------ indexing
    def cell_of(self, east_m: np.ndarray | float, north_m: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Global (iy, ix) of points."""
        return (np.floor(np.asarray(north_m, dtype=np.float64) / self.cell_m).astype(np.int64),
                np.floor(np.asarray(east_m, dtype=np.float64) / self.cell_m).astype(np.int64))

    def cell_centre(self, iy: np.ndarray, ix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(east_m, north_m) of cell centres."""
        return (np.asarray(ix) + 0.5) * self.cell_m, (np.asarray(iy) + 0.5) * self.cell_m

    def _flat(self, chunks: ChunkStack, iy: np.ndarray, ix: np.ndarray, stride: int,
              layer: LegLayer | None = None, valid: np.ndarray | None = None) -> np.ndarray:
        """Flat index ``slot * stride + cell`` of cells in ``chunks``, allocating the chunks of
        the ``valid`` cells only (default all) and marking them touched by ``layer``.

        Cells that are not valid and fall in no allocated chunk get an index into some
        allocated chunk: callers write only no-op values there (-1 under a maximum).
        """
        n = self.n
        if n & (n - 1) == 0:  # power of two: shifts and masks (floor for negatives too)
            sh = n.bit_length() - 1
            cy, cx = iy >> sh, ix >> sh
            cell = ((iy & (n - 1)) << sh) | (ix & (n - 1))
        else:
            cy, cx = iy // n, ix // n
            cell = (iy - cy * n) * n + (ix - cx * n)
        if iy.size == 0:
            return cell
        cy0, cx0 = int(cy.min()), int(cx.min())
        wc = int(cx.max()) - cx0 + 1
        if (int(cy.max()) - cy0 + 1) * wc > max(1 << 22, cy.size):
            # a footprint far wider than a tile (a nav jump): dense chunk codes would not fit
            uniq, code = np.unique((cy - cy0) * wc + (cx - cx0), return_inverse=True)
            code = code.reshape(cy.shape)
        else:
            uniq = None
            code = (cy - cy0) * wc + (cx - cx0)
        hits = np.bincount(code.ravel(), weights=None if valid is None else valid.ravel(),
                           minlength=int(code.max()) + 1)
        touched = np.flatnonzero(hits)
        lut = np.zeros(hits.size, dtype=np.int64)
        for c in touched.tolist():  # one Python step per chunk, not per pixel
            g = c if uniq is None else int(uniq[c])
            lut[c] = self._touch(chunks, (cy0 + g // wc, cx0 + g % wc), layer)
        return lut[code] * stride + cell

    def _touch(self, chunks: ChunkStack, key: Key, layer: LegLayer | None) -> int:
        """Slot of chunk ``key`` (allocated if new), marked changed and touched by ``layer``."""
        s = chunks.get(key)
        self.changed[key] = self.stamp
        if layer is not None:
            layer.touched[key] = layer.n_obs
            if key in layer.retired:
                layer.retired.discard(key)
                self.n_reopened += 1
        return s

    def _layer(self, leg: int, t: float) -> LegLayer:
        if leg in self.closed_legs:
            raise FusionError(f"leg {leg} is already closed: its evidence was committed; a leg is one observation")
        if leg not in self.open:
            if self.auto_close:
                for other in sorted(self.open):
                    self.close_leg(other)
            spare, self._spare = getattr(self, "_spare", None), None
            self.open[leg] = LegLayer(len(self.layers), self.nn, buffer=spare)
        layer = self.open[leg]
        layer.t = max(layer.t, t)
        return layer

    def _det(self, detector: str) -> int:
        try:
            return self._det_index[detector]
        except KeyError:
            raise FusionError(f"unknown detector {detector!r}; this grid's evidence layers are {list(self.layers)}") from None

    # ------------------------------------------------------------------ input
    def add_observation(self, obs: Observation) -> None:
        """Deposit one tile core of one leg (SPEC section 7): Pd over covered cells, detection
        confidence over each detection's gate; committed when the leg closes."""
        det_idx = [self._det(d.detector) for d in obs.detectors]  # validate before any change
        self.stamp += 1
        layer = self._layer(obs.leg, obs.t)
        layer.n_obs += 1
        self._deposit_pd(layer, obs, det_idx)
        self._deposit_detections(layer, obs, det_idx)
        self.n_observations += 1
        self._commit(obs.leg, layer, layer.stale(self.fusion.commit_after_obs))

    def _deposit_pd(self, layer: LegLayer, obs: Observation, det_idx: list[int]) -> None:
        """notT side of an observation: per (detector, cell) the maximum Pd over the cell's
        covered pixels, into the leg's layer (SPEC section 7). Each block of rows is reduced
        to its cells first (:class:`~atr_node.fusion.deposit.PdReducer`, bit-exact), so
        chunk lookup and the scatter into the layer work on cells, not pixels."""
        rows, cols = obs.shape
        covs = [d.covered for d in obs.detectors]
        if not covs:
            return
        any_cov = covs[0].copy()
        for c in covs[1:]:
            any_cov |= c
        used_cols = np.flatnonzero(any_cov.any(axis=0))
        if not used_cols.size:
            return
        c0, c1 = int(used_cols[0]), int(used_cols[-1]) + 1  # skip never-covered near/far range
        stride = len(self.layers) * 2 * self.nn
        pds = [d.pd for d in obs.detectors]
        block = max(1, BLOCK_PIXELS // (c1 - c0))
        for r0 in range(0, rows, block):
            sl = slice(r0, min(rows, r0 + block))
            if not any_cov[sl, c0:c1].any():
                continue
            # cells with a covered pixel of some detector: exactly the cells (so the chunks,
            # allocated per block in chunk order) a per-pixel deposit touches
            iy, ix, vmax = self._reducer.reduce(obs.geometry, covs, pds, sl, slice(c0, c1))
            base = self._flat(layer.chunks, iy, ix, stride, layer)
            flat = layer.chunks.arr.reshape(-1)
            for j, k in enumerate(det_idx):
                # -1 (this detector covered no pixel there) is a no-op under the maximum: layer
                # values are -1 or masses >= 0, and every cell's chunk is allocated
                np.maximum.at(flat, base + (2 * k + 1) * self.nn, vmax[j])

    def _deposit_detections(self, layer: LegLayer, obs: Observation, det_idx: list[int]) -> None:
        """T side of an observation: each detection's confidence over its gate, the maximum
        per (detector, cell), and the georeferenced detection records (SPEC section 7). The
        whole gate goes into the layer; it counts only on cells the leg covered, clipped when
        the terms are formed (:func:`~atr_node.fusion.chunks.layer_terms`, SPEC 6.1).

        All gates go in one scatter (maximum: order-free); their chunks are looked up in
        the order of one lookup per detection (each detection's chunks in chunk order), so
        that chunks are allocated, and listed, exactly as gate by gate."""
        gates: list[tuple[int, np.ndarray, np.ndarray, float]] = []
        for d, k in zip(obs.detectors, det_idx):
            for det in d.detections:
                e, n = obs.geometry.world(det.row, det.col)
                iy, ix = gate_cells(float(e), float(n), gate_m=self.gate_m, cell_m=self.cell_m)
                gates.append((k, iy, ix, det.confidence))
                self.detections.append(DetectionRecord(obs.leg, det.source or d.detector, float(e), float(n), float(obs.t),
                                                       float(det.confidence), float(det.gamma),
                                                       **record_extent(obs.geometry, det)))
        if not gates:
            return
        n = self.n
        iy = np.concatenate([g[1] for g in gates])
        ix = np.concatenate([g[2] for g in gates])
        sizes = [g[1].size for g in gates]
        gate_of = np.repeat(np.arange(len(gates)), sizes)
        cy, cx = iy // n, ix // n
        cy0, cx0 = int(cy.min()), int(cx.min())
        wc = int(cx.max()) - cx0 + 1
        code = (cy - cy0) * wc + (cx - cx0)  # row-major in (cy, cx): one lookup's chunk order
        ncode = int(code.max()) + 1
        pairs = np.unique(gate_of * ncode + code)  # by gate, then chunk order
        uniq, inv = np.unique(code, return_inverse=True)
        slot_of: dict[int, int] = {}
        for c in (pairs % ncode).tolist():
            if c not in slot_of:
                key = (cy0 + c // wc, cx0 + c % wc)
                slot_of[c] = self._touch(layer.chunks, key, layer)
        slots = np.array([slot_of[c] for c in uniq.tolist()], dtype=np.int64)
        stride = len(self.layers) * 2 * self.nn
        cell = (iy - cy * n) * n + (ix - cx * n)
        ks = np.array([g[0] for g in gates], dtype=np.int64)[gate_of]
        conf = np.array([g[3] for g in gates], dtype=np.float64)[gate_of]
        # T evidence once per (leg, detector) over the gate: the maximum over detections there
        np.maximum.at(layer.chunks.arr.reshape(-1), slots[inv.reshape(-1)] * stride + cell + 2 * ks * self.nn, conf)

    def deposit(self, leg: int, detector: str, t: float, iy: np.ndarray, ix: np.ndarray, *,
                m_t: np.ndarray | float | None = None, m_n: np.ndarray | float | None = None) -> None:
        """Low-level deposit of one (leg, detector)'s masses at cells (iy, ix) into the leg's
        open layer: ``m_t`` on {T}, ``m_n`` on {notT} (maximum per cell, as for observations).

        The cells are covered by this (leg, detector): T mass counts only where the same
        (leg, detector) covered a cell (SPEC 6.1), so ``m_t`` without ``m_n`` also marks the
        cells covered, with Pd 0 (no notT evidence). Contacts need detections behind them
        (SPEC 7): this deposit adds none (``detections`` lists the grid's detection records).
        """
        k = self._det(detector)
        iy = np.asarray(iy, dtype=np.int64).ravel()
        ix = np.asarray(ix, dtype=np.int64).ravel()
        if iy.shape != ix.shape:
            raise FusionError(f"deposit: iy {iy.shape} and ix {ix.shape} differ")
        vals = []
        for name, m in (("m_t", m_t), ("m_n", m_n)):
            if m is None:
                vals.append(None)
                continue
            v = np.broadcast_to(np.asarray(m, dtype=np.float64), iy.shape).ravel()
            if not np.all((v >= 0.0) & (v <= 1.0)):
                raise FusionError(f"deposit leg {leg}, detector {detector!r}: {name} outside [0, 1] or NaN")
            vals.append(v)
        self.stamp += 1
        layer = self._layer(leg, t)
        layer.n_obs += 1
        base = self._flat(layer.chunks, iy, ix, len(self.layers) * 2 * self.nn, layer)
        flat = layer.chunks.arr.reshape(-1)
        for which, v in enumerate(vals):
            if v is not None:
                np.maximum.at(flat, base + (2 * k + which) * self.nn, v)
        if vals[0] is not None and vals[1] is None:
            # T here says this (leg, detector) looked here: covered, Pd 0 (a no-op where
            # some Pd is already held: maximum)
            np.maximum.at(flat, base + (2 * k + 1) * self.nn, 0.0)

    def close_leg(self, leg: int) -> None:
        """Commit an open leg: add its log terms to the accumulators (pure addition)."""
        layer = self.open.pop(leg, None)
        self.closed_legs.add(leg)
        if layer is not None:
            self._commit(leg, layer, layer.chunks.keys)
            self._spare = layer.chunks.arr  # the layer is gone: its array serves the next leg

    def _commit(self, leg: int, layer: LegLayer, keys: list[Key]) -> None:
        """Add the log terms of some chunks of a leg's layer, then release them from the layer.

        Chunks are committed when the leg closes, or earlier once ``commit_after_obs``
        observations of the leg went by without touching them (the vehicle has moved on):
        this bounds the transient memory of a long leg to the chunks near the vehicle.
        """
        if not keys:
            return
        self.stamp += 1
        p = layer.chunks.view(keys)  # read before the release below
        d_lt, d_ln, n_cl, per_det, covered = layer_terms_covered(p, self.fusion.eps,
                                                                 per_detector=self._diag is not None)
        self.n_clamped += n_cl
        slots = np.array([self._ln.get(k) for k in keys], dtype=np.int64)
        self._ln.arr[slots] += d_ln
        with_t = (d_lt != 0.0).any(axis=1)
        if with_t.any():
            tslots = np.array([self._lt.get(k) for k, w in zip(keys, with_t) if w], dtype=np.int64)
            self._lt.arr[tslots] += d_lt[with_t]
        if self._diag is not None:
            dslots = np.array([self._diag.get(k) for k in keys], dtype=np.int64)
            self._diag.arr[dslots] += per_det
        for key, cov in zip(keys, covered):
            legs = self.cover.setdefault(key, {})
            bits = None if cov.all() else np.packbits(cov)
            old = legs.get(leg, bits) if leg in legs else bits  # a reopened chunk: union
            legs[leg] = None if (old is None or bits is None) else np.bitwise_or(old, bits)
            self.last_t[key] = max(self.last_t.get(key, -np.inf), layer.t)
            self.changed[key] = self.stamp
            layer.touched.pop(key, None)
        if self.open.get(leg) is not layer:  # close_leg: the whole layer goes, no slot to free
            return
        layer.retired.update(keys)
        layer.chunks.release(keys)

    def close_all(self) -> None:
        """Commit every open leg (end of mission, before a merge or an exchange)."""
        for leg in sorted(self.open):
            self.close_leg(leg)

    def add_accumulators(self, iy: np.ndarray, ix: np.ndarray, d_lt: np.ndarray, d_ln: np.ndarray, *,
                         t: float) -> None:
        """Add log-accumulator deltas at cells (the exchange path; SPEC section 7). Duplicated
        cells add in the order given."""
        iy = np.asarray(iy, dtype=np.int64).ravel()
        ix = np.asarray(ix, dtype=np.int64).ravel()
        d_lt = np.broadcast_to(np.asarray(d_lt, dtype=np.float64), iy.shape).ravel()
        d_ln = np.broadcast_to(np.asarray(d_ln, dtype=np.float64), iy.shape).ravel()
        if iy.shape != ix.shape or np.any(d_lt > 0) or np.any(d_ln > 0) or np.isnan(d_lt).any() or np.isnan(d_ln).any():
            raise FusionError("add_accumulators: need equal-length cells and deltas <= 0 (not NaN)")
        self.stamp += 1
        flat = self._flat(self._ln, iy, ix, self.nn)  # allocates: index the array after
        np.add.at(self._ln.arr.reshape(-1), flat, d_ln)
        with_t = d_lt != 0.0
        if with_t.any():
            flat = self._flat(self._lt, iy[with_t], ix[with_t], self.nn)
            np.add.at(self._lt.arr.reshape(-1), flat, d_lt[with_t])
        for key in {(int(a), int(b)) for a, b in zip(iy // self.n, ix // self.n)}:
            self.last_t[key] = max(self.last_t.get(key, -np.inf), t)

    # ------------------------------------------------------------------ read-out
    def chunk_keys(self) -> list[tuple[int, int]]:
        """Every allocated chunk: committed or in an open layer."""
        keys = dict.fromkeys(self._ln.keys)
        for layer in self.open.values():
            keys.update(dict.fromkeys(layer.chunks.keys))
        return list(keys)

    def chunk_accumulators(self, keys: list[tuple[int, int]], *, include_open: bool = True) -> np.ndarray:
        """(K, 2, nn) accumulators [L_T, L_N] of chunks, open legs included by default."""
        out = np.zeros((len(keys), 2, self.nn))
        for i, key in enumerate(keys):
            s = self._ln.slot.get(key)
            if s is not None:
                out[i, 1] = self._ln.arr[s]
            s = self._lt.slot.get(key)
            if s is not None:
                out[i, 0] = self._lt.arr[s]
        if include_open:
            for layer in self.open.values():
                idx = [(i, layer.chunks.slot[k]) for i, k in enumerate(keys) if k in layer.chunks.slot]
                if idx:
                    rows, slots = (np.array(v, dtype=np.int64) for v in zip(*idx))
                    d_lt, d_ln, _, _ = layer_terms(layer.chunks.arr[slots], self.fusion.eps, per_detector=False)
                    out[rows, 0] += d_lt
                    out[rows, 1] += d_ln
        return out

    def has_t_evidence(self, keys: list[Key]) -> list[bool]:
        """Per chunk, whether it may hold T evidence (committed ``L_T``, or a T mass in an
        open layer): a chunk without is Bel(T) = 0 everywhere, no need to evaluate it."""
        out = [key in self._lt.slot for key in keys]
        for layer in self.open.values():
            idx = [(i, layer.chunks.slot[k]) for i, k in enumerate(keys) if not out[i] and k in layer.chunks.slot]
            if idx:
                rows, slots = zip(*idx)
                # one gather of the T planes of these chunks: any T mass >= 0
                found = (layer.chunks.arr[np.array(slots), :, 0] >= 0.0).any(axis=(1, 2))
                for i, f in zip(rows, found.tolist()):
                    out[i] = f
        return out

    def detector_accumulators(self, keys: list[Key]) -> np.ndarray:
        """(K, n_det, 2, nn) committed per-detector [L_T, L_N] of chunks (diagnostics on)."""
        if self._diag is None:
            raise FusionError("per-detector accumulators need fusion.diagnostics = true")
        out = np.zeros((len(keys), len(self.layers), 2, self.nn))
        for i, key in enumerate(keys):
            s = self._diag.slot.get(key)
            if s is not None:
                out[i] = self._diag.arr[s]
        return out

    def accumulators(self, iy: np.ndarray, ix: np.ndarray, *, include_open: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(L_T, L_N) at cells (iy, ix); 0, 0 (no evidence) where nothing was deposited."""
        iy = np.asarray(iy, dtype=np.int64)
        ix = np.asarray(ix, dtype=np.int64)
        cy, cx = iy // self.n, ix // self.n
        keys = list(dict.fromkeys(zip(cy.ravel().tolist(), cx.ravel().tolist())))
        acc = self.chunk_accumulators(keys, include_open=include_open)
        pos = {k: i for i, k in enumerate(keys)}
        ki = np.array([pos[k] for k in zip(cy.ravel().tolist(), cx.ravel().tolist())], dtype=np.int64)
        cell = ((iy - cy * self.n) * self.n + (ix - cx * self.n)).ravel()
        return acc[ki, 0, cell].reshape(iy.shape), acc[ki, 1, cell].reshape(iy.shape)

    def masses_at(self, east_m: np.ndarray | float, north_m: np.ndarray | float, *,
                  include_open: bool = True) -> TNMasses:
        """Combined masses (Bel(T) = m_t, Pl(T) = 1 - m_n, m_theta) at points of the frame."""
        iy, ix = self.cell_of(east_m, north_m)
        return closed_form(*self.accumulators(iy, ix, include_open=include_open))

    def legs_at(self, iy: int, ix: int) -> list[int]:
        """Legs (committed or open) whose coverage includes cell (iy, ix)."""
        key = (iy // self.n, ix // self.n)
        cell = (iy - key[0] * self.n) * self.n + (ix - key[1] * self.n)
        byte, bit = cell >> 3, 7 - (cell & 7)  # np.packbits order: first cell in the high bit
        legs = [leg for leg, bits in self.cover.get(key, {}).items()
                if bits is None or (int(bits[byte]) >> bit) & 1]
        for leg, layer in self.open.items():
            s = layer.chunks.slot.get(key)
            if s is not None and (layer.chunks.arr[s, :, 1, cell] >= 0.0).any():  # a Pd: covered
                legs.append(leg)
        return sorted(set(legs))

    def covered_cells(self) -> int:
        """Cells covered by at least one committed leg."""
        total = 0
        for legs in self.cover.values():
            if any(b is None for b in legs.values()):
                total += self.nn
            else:
                union = np.zeros(self.nn, dtype=bool)
                for b in legs.values():
                    union |= np.unpackbits(b, count=self.nn).astype(bool)
                total += int(union.sum())
        return total

    def nbytes(self) -> dict[str, int]:
        """Persistent memory by part (allocated chunks only, open layers counted apart)."""
        k = len(self._ln)
        return {"accumulators": (len(self._ln) + len(self._lt)) * self.nn * 8,
                "diagnostics": 0 if self._diag is None else len(self._diag) * self._diag.arr[0].nbytes,
                "coverage_bitmaps": sum(b.nbytes for legs in self.cover.values() for b in legs.values() if b is not None),
                "chunk_metadata": k * (8 + 8 + 16) + sum(8 * len(v) for v in self.cover.values()),
                "open_layers": sum(len(l.chunks) * l.chunks.arr[0].nbytes for l in self.open.values())}

    def changed_since(self, stamp: int) -> list[tuple[int, int]]:
        """Chunks changed after ``stamp`` (contacts re-extract only these)."""
        return [k for k, s in self.changed.items() if s > stamp]

    # ------------------------------------------------------------------ merge
    def merge(self, other: "EvidenceGrid") -> None:
        """Add another grid's evidence to this one: see :func:`atr_node.fusion.merge.merge_into`."""
        merge_into(self, other)
