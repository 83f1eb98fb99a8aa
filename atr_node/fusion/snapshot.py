"""Atomic snapshot and restore of an evidence grid and its contact tracker (SPEC section 7).

Format: one uncompressed ``.npz`` (numpy's zip of ``.npy`` arrays, read with
``allow_pickle=False``), arrays listed below plus ``meta``, a UTF-8 JSON document stored as
a uint8 array (settings, counters, closed legs, tracker state)::

    ln_keys (K, 2) int64 chunk (cy, cx)       ln (K, nn) float64 L_N of every committed chunk
    lt_keys (J, 2)                             lt (J, nn) float64 L_T of chunks with T evidence
    diag_keys, diag (K, n_det, 2, nn)          when diagnostics are on
    cover_rows (P, 4) int64 cy, cx, leg, bits-row (-1: every cell)
    cover_bits (B, nn/8) uint8                 packed coverage bitmaps
    last_keys (M, 2), last_t (M,)              per-chunk last update
    open_rows (Q, 3) int64 leg, cy, cx         open_arr (Q, n_det, 2, nn), open_legs, open_t,
    open_n_obs, open_touched (leg, cy, cx, n), open_retired (leg, cy, cx)
    det_* (D,)                                 the detection log
    changed_keys (C, 2), changed_stamp (C,)

Atomicity: the snapshot is written to a temporary file in the same folder, flushed and
fsync'ed, then renamed over the previous one with ``os.replace`` (atomic on POSIX), and the
folder is fsync'ed. A crash at any point leaves either the previous snapshot or the new one,
never a mixture.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ..config import FusionSettings
from ..errors import FusionError
from .contacts import ContactTracker
from .chunks import LegLayer
from .grid import DetectionRecord, EvidenceGrid

FORMAT = "atr-node evidence grid"
VERSION = 1
_EXTENT = ("length_m", "width_m", "heading_deg")
"""Detection record fields of an extended object (optional arrays ``det_<field>``, NaN: none)."""


def _keys(keys: list[tuple[int, int]]) -> np.ndarray:
    return np.array(keys, dtype=np.int64).reshape(-1, 2)


def grid_arrays(grid: EvidenceGrid, tracker: ContactTracker | None = None) -> dict[str, np.ndarray]:
    """Every array of a snapshot (the grid's complete state, open legs included)."""
    nn8 = grid.nn // 8 + (grid.nn % 8 > 0)
    a: dict[str, np.ndarray] = {"ln_keys": _keys(grid._ln.keys), "ln": grid._ln.gather(),
                                "lt_keys": _keys(grid._lt.keys), "lt": grid._lt.gather()}
    if grid._diag is not None:
        a["diag_keys"], a["diag"] = _keys(grid._diag.keys), grid._diag.gather()
    rows, bits = [], []
    for (cy, cx), legs in grid.cover.items():
        for leg, b in legs.items():
            rows.append((cy, cx, leg, -1 if b is None else len(bits)))
            if b is not None:
                bits.append(b)
    a["cover_rows"] = np.array(rows, dtype=np.int64).reshape(-1, 4)
    a["cover_bits"] = np.array(bits, dtype=np.uint8).reshape(-1, nn8)
    a["last_keys"], a["last_t"] = _keys(list(grid.last_t)), np.array(list(grid.last_t.values()), dtype=np.float64)
    orows, oarr, touched, retired = [], [], [], []
    for leg, layer in grid.open.items():
        orows += [(leg, cy, cx) for cy, cx in layer.chunks.keys]
        oarr.append(layer.chunks.gather())
        touched += [(leg, cy, cx, n) for (cy, cx), n in layer.touched.items()]
        retired += [(leg, cy, cx) for cy, cx in sorted(layer.retired)]
    a["open_rows"] = np.array(orows, dtype=np.int64).reshape(-1, 3)
    a["open_touched"] = np.array(touched, dtype=np.int64).reshape(-1, 4)
    a["open_retired"] = np.array(retired, dtype=np.int64).reshape(-1, 3)
    a["open_n_obs"] = np.array([layer.n_obs for layer in grid.open.values()], dtype=np.int64)
    a["open_arr"] = (np.concatenate(oarr) if oarr else np.zeros((0, len(grid.layers), 2, grid.nn)))
    a["open_legs"] = np.array(list(grid.open), dtype=np.int64)
    a["open_t"] = np.array([layer.t for layer in grid.open.values()], dtype=np.float64)
    dets = grid.detections
    a["det_leg"] = np.array([r.leg for r in dets], dtype=np.int64)
    a["det_detector"] = np.array([grid.detectors.index(r.detector) for r in dets], dtype=np.int64)
    for f in ("east_m", "north_m", "t", "confidence", "gamma"):
        a[f"det_{f}"] = np.array([getattr(r, f) for r in dets], dtype=np.float64)
    for f in _EXTENT:  # an extended object's extent (NaN: none)
        a[f"det_{f}"] = np.array([math.nan if getattr(r, f) is None else getattr(r, f) for r in dets], dtype=np.float64)
    a["changed_keys"] = _keys(list(grid.changed))
    a["changed_stamp"] = np.array(list(grid.changed.values()), dtype=np.int64)
    meta = {"format": FORMAT, "version": VERSION, "fusion": dataclasses.asdict(grid.fusion), "gate_m": grid.gate_m,
            "detectors": list(grid.detectors), "layers": list(grid.layers), "auto_close": grid.auto_close,
            "closed_legs": sorted(grid.closed_legs), "n_clamped": grid.n_clamped, "n_reopened": grid.n_reopened,
            "n_observations": grid.n_observations, "stamp": grid.stamp,
            "tracker": None if tracker is None else tracker.state()}
    a["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    return a


def save(path: str | os.PathLike[str], grid: EvidenceGrid, tracker: ContactTracker | None = None) -> Path:
    """Write a snapshot atomically (see the module docstring); returns the path."""
    path = Path(path)
    arrays = grid_arrays(grid, tracker)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
    return path


def load(path: str | os.PathLike[str]) -> tuple[EvidenceGrid, dict[str, Any] | None]:
    """Read a snapshot; returns the grid and the tracker state (or None).

    Raises
    ------
    FusionError
        Missing, truncated or foreign file, or an unsupported version (the message names the file).
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            a = {k: z[k] for k in z.files}
        meta = json.loads(a["meta"].tobytes().decode())
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
        raise FusionError(f"evidence-grid snapshot {path}: unreadable ({type(exc).__name__}: {exc})") from None
    if meta.get("format") != FORMAT or meta.get("version") != VERSION:
        raise FusionError(f"evidence-grid snapshot {path}: format {meta.get('format')!r} v{meta.get('version')!r}, "
                          f"expected {FORMAT!r} v{VERSION}")
    names = {f.name for f in dataclasses.fields(FusionSettings)}
    fusion = FusionSettings(**{k: v for k, v in meta["fusion"].items() if k in names})
    grid = EvidenceGrid(fusion, gate_m=meta["gate_m"], detectors=meta["detectors"], auto_close=meta["auto_close"],
                        layers=meta.get("layers"))  # snapshots before SPEC 6.1: one layer per detector
    for name in ("ln", "lt"):
        stack = getattr(grid, f"_{name}")
        for key, v in zip(map(tuple, a[f"{name}_keys"].tolist()), a[name]):
            slot = stack.get(key)  # may grow the stack: index the array after
            stack.arr[slot] = v
    if grid._diag is not None and "diag" in a:
        for key, v in zip(map(tuple, a["diag_keys"].tolist()), a["diag"]):
            slot = grid._diag.get(key)
            grid._diag.arr[slot] = v
    for cy, cx, leg, b in a["cover_rows"].tolist():
        grid.cover.setdefault((cy, cx), {})[leg] = None if b < 0 else a["cover_bits"][b].copy()
    grid.last_t = {tuple(k): float(t) for k, t in zip(a["last_keys"].tolist(), a["last_t"])}
    for leg, t, n_obs in zip(a["open_legs"].tolist(), a["open_t"], a["open_n_obs"].tolist()):
        layer = grid.open[leg] = LegLayer(len(grid.layers), grid.nn)
        layer.t, layer.n_obs = float(t), n_obs
    for leg, cy, cx, n in a["open_touched"].tolist():
        grid.open[leg].touched[(cy, cx)] = n
    for leg, cy, cx in a["open_retired"].tolist():
        grid.open[leg].retired.add((cy, cx))
    for (leg, cy, cx), v in zip(a["open_rows"].tolist(), a["open_arr"]):
        chunks = grid.open[leg].chunks
        slot = chunks.get((cy, cx))
        chunks.arr[slot] = v
    grid.detections = [DetectionRecord(int(l), grid.detectors[int(d)], float(e), float(n), float(t), float(c), float(g))
                       for l, d, e, n, t, c, g in zip(a["det_leg"], a["det_detector"], a["det_east_m"],
                                                      a["det_north_m"], a["det_t"], a["det_confidence"],
                                                      a["det_gamma"])]
    if "det_length_m" in a:  # snapshots written before extents were kept have none
        grid.detections = [r if math.isnan(x[0]) else dataclasses.replace(r, **dict(zip(_EXTENT, map(float, x))))
                           for r, x in zip(grid.detections, zip(*(a[f"det_{f}"] for f in _EXTENT)))]
    grid.changed = {tuple(k): int(s) for k, s in zip(a["changed_keys"].tolist(), a["changed_stamp"])}
    grid.closed_legs = set(meta["closed_legs"])
    grid.n_clamped, grid.n_observations, grid.stamp = meta["n_clamped"], meta["n_observations"], meta["stamp"]
    grid.n_reopened = meta["n_reopened"]
    return grid, meta["tracker"]
