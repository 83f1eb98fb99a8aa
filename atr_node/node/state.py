"""Node snapshots: everything needed to restart where the node stopped, written atomically.

A snapshot is a folder ``snap-<n>`` in the node's state directory holding

- ``grid.npz``: the evidence grid and the contact tracker (``atr_node.fusion.snapshot``);
- ``node.npz``: strips (pending and context rows), the INS track, background trackers, the
  mission frame, counters, the on-line model if one took over (and how: ``model_use``), the
  tiles a replay holds for the on-line calibration (offered again to the resumed node's
  calibrator), the last contact ``seq`` published (ICD v1.1) and each contact's, and
  ``position``: how many input records the snapshot accounts for;

and the file ``CURRENT`` names the newest complete snapshot. A new snapshot is written to a
fresh folder, flushed and fsync'ed, and only then does ``CURRENT`` change, by an atomic
rename; older folders are removed after, but for the one ``CURRENT`` named before (the
previous snapshot). A crash at any point leaves ``CURRENT`` naming a complete snapshot (or no
file at all before the first one).

Resuming (:func:`restore`) is robust to what a crash, a bad disk or an operator can leave:

- a snapshot that does not read back (truncated, garbled: a bad zip, a bad CRC, bad JSON,
  an unreadable ``CURRENT``) is reported in one warning and the previous snapshot is tried,
  then the node starts afresh; never a traceback;
- a snapshot of another recording (``source_id``, :func:`recording_identity`: its size and a
  digest of its first MiB) is not resumed: the whole state is moved to ``previous/`` in the
  state directory (replacing an older one), one warning names both recordings, and the node
  starts afresh, truly, with nothing of the old mission's evidence.

Snapshots are taken only when nothing is in flight (no held tile, no unit in the worker), so
the state is consistent; on restart the input is resumed at ``position`` (a replay skips that
many records; the live node replays its own recording past that point first), so no accepted
tile's evidence is lost and none is counted twice.
"""

from __future__ import annotations

from collections import Counter

import hashlib
import json
import logging
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..calibration.model import PerformanceModel
from ..errors import AtrError
from ..fusion import ContactTracker
from ..fusion import snapshot as grid_snapshot
from ..geo import MissionFrame
from .strip import StripAssembler

log = logging.getLogger(__name__)

FORMAT = "atr-node node state"
VERSION = 1
PREVIOUS = "previous"
"""Where :func:`restore` moves a state directory's contents it does not resume."""
IDENTITY_HEAD_BYTES = 1 << 20
"""A recording's identity digests this much of its head (cheap for any size of file)."""
_SNAP = re.compile(r"snap-([0-9]{1,18})")


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def recording_identity(path: str | os.PathLike[str]) -> dict[str, Any]:
    """What tells one recording from another whatever its path: its size in bytes and the
    SHA-256 of its first :data:`IDENTITY_HEAD_BYTES` bytes (a recording starts with its
    mission's first records: two missions never share them)."""
    p = Path(path)
    with open(p, "rb") as fh:
        head = fh.read(IDENTITY_HEAD_BYTES)
    return {"size": p.stat().st_size, "head_sha256": hashlib.sha256(head).hexdigest()}


def _snap_number(folder: Path) -> int:
    m = _SNAP.fullmatch(folder.name)
    return int(m.group(1)) if m else -1


def save(state_dir: str | os.PathLike[str], pipeline: Any, *, position: int, source: str = "",
         source_id: dict[str, Any] | None = None) -> Path:
    """Write a snapshot of ``pipeline`` (which must be quiescent) and make it current.

    ``source``: the recording's path (for messages); ``source_id``: its identity
    (:func:`recording_identity`), which :func:`restore` checks."""
    if pipeline.inflight:
        raise AtrError("snapshot: the pipeline still has units in the worker; drain it first")
    root = Path(state_dir)
    root.mkdir(parents=True, exist_ok=True)
    current = read_current(root)
    # after every folder there, not after CURRENT's: the previous snapshot is kept, and a
    # garbled CURRENT must not make this one overwrite it
    n = max([_snap_number(f) for f in root.glob("snap-*")] + [0]) + 1
    folder = root / f"snap-{n}"
    if folder.exists():
        shutil.rmtree(folder)
    tmp = root / f".CURRENT.tmp-{os.getpid()}"
    try:
        folder.mkdir()
        grid_snapshot.save(folder / "grid.npz", pipeline.grid, pipeline.tracker)
        arrays, meta = _node_arrays(pipeline)
        meta.update(format=FORMAT, version=VERSION, position=int(position), source=source, source_id=source_id)
        arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
        with open(folder / "node.npz", "wb") as fh:
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())
        _fsync_dir(folder)
        _write_current(root, folder)
    except OSError:
        # disk full or I/O error: CURRENT still names the previous complete snapshot; free
        # the space the partial one took so the next attempt (or the recording) can succeed
        shutil.rmtree(folder, ignore_errors=True)
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(root)
    for old in root.glob("snap-*"):
        if old not in (folder, current):  # the previous one stays: restore() falls back to it
            shutil.rmtree(old, ignore_errors=True)
    return folder


def _write_current(root: Path, folder: Path) -> None:
    """Make ``folder`` current: ``CURRENT`` replaced by an atomic rename of a synced file."""
    tmp = root / f".CURRENT.tmp-{os.getpid()}"
    tmp.write_text(folder.name + "\n")
    with open(tmp, "rb+") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, root / "CURRENT")


def read_current(state_dir: str | os.PathLike[str]) -> Path | None:
    """The folder ``CURRENT`` names, or None (no ``CURRENT``, an unreadable one, or one that
    names no snapshot folder of this directory)."""
    root = Path(state_dir)
    try:
        name = (root / "CURRENT").read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):  # missing, or garbled by a bad disk
        return None
    folder = root / name
    # only a name this module writes: "snap-<n>", never a path that leads out of state_dir
    return folder if re.fullmatch(r"snap-[0-9]{1,18}", name) and folder.is_dir() else None


@dataclass
class Snapshot:
    """A snapshot read back whole (every file decoded), not yet applied to a pipeline."""

    folder: Path
    meta: dict[str, Any]
    arrays: dict[str, np.ndarray]
    grid: Any
    tracker_state: Any


def read_snapshot(folder: Path) -> Snapshot:
    """Read and decode every file of a snapshot folder; :class:`AtrError` (one line naming the
    file) if any does not read back, so nothing of a damaged snapshot reaches a pipeline."""
    where = folder / "node.npz"
    try:
        with np.load(where, allow_pickle=False) as z:
            a = {k: z[k] for k in z.files}
        meta = json.loads(a.pop("meta").tobytes().decode())
        if not isinstance(meta, dict):
            raise ValueError("meta is not a JSON object")
        if meta.get("format") != FORMAT or meta.get("version") != VERSION:
            raise AtrError(f"node snapshot {folder}: format {meta.get('format')!r} v{meta.get('version')!r}, "
                           f"expected {FORMAT!r} v{VERSION}")
        where = folder / "grid.npz"
        grid, tracker_state = grid_snapshot.load(where)
    except AtrError:
        raise
    except Exception as exc:  # a damaged zip raises BadZipFile, zlib.error, EOFError, ValueError...
        raise AtrError(f"node snapshot {where}: unreadable ({type(exc).__name__}: {exc})") from None
    return Snapshot(folder, meta, a, grid, tracker_state)


def load(state_dir: str | os.PathLike[str], pipeline: Any) -> dict[str, Any] | None:
    """Restore ``pipeline`` from the current snapshot; return its meta (None: no snapshot).
    Strict: :class:`AtrError` if it does not read back (:func:`restore` falls back instead)."""
    folder = read_current(state_dir)
    if folder is None:
        return None
    return apply(read_snapshot(folder), pipeline)


def snapshot_folders(state_dir: str | os.PathLike[str]) -> list[Path]:
    """The snapshot folders to try, best first: the one ``CURRENT`` names, then the others,
    newest first (the previous snapshot; a newer complete one if a crash hit before its
    ``CURRENT``; partial ones fail to read and are passed over)."""
    root = Path(state_dir)
    current = read_current(root)
    others = sorted((f for f in root.glob("snap-*") if f.is_dir() and _SNAP.fullmatch(f.name) and f != current),
                    key=_snap_number, reverse=True)
    return ([current] if current is not None else []) + others


def set_aside(state_dir: str | os.PathLike[str]) -> Path:
    """Move everything in the state directory into its ``previous/`` folder (an older one is
    replaced): the node then starts afresh, and nothing is lost that an engineer may want."""
    root = Path(state_dir)
    prev = root / PREVIOUS
    shutil.rmtree(prev, ignore_errors=True)
    prev.mkdir()
    for item in root.iterdir():
        if item.name != PREVIOUS:
            os.replace(item, prev / item.name)
    _fsync_dir(root)
    return prev


def _same_source(meta: dict[str, Any], source: str, source_id: dict[str, Any] | None) -> bool:
    if source_id is not None and meta.get("source_id") is not None:
        return meta["source_id"] == source_id
    # a snapshot without an identity (written before it was kept): its recording's path
    return not (source and meta.get("source") and meta["source"] != source)


def restore(state_dir: str | os.PathLike[str], pipeline: Any, *, source: str = "",
            source_id: dict[str, Any] | None = None) -> dict[str, Any] | None:
    """Resume ``pipeline`` from the best snapshot in ``state_dir``; return its meta, or None
    when the node starts afresh. Never raises on a damaged state directory.

    Tries :func:`snapshot_folders` in turn, each unreadable one reported in one warning. A
    snapshot of another recording than ``source_id`` (None: any, as the live node, whose state
    follows it from recording to recording), or no readable snapshot at all, moves the state
    to ``previous/`` (:func:`set_aside`) and starts afresh.
    """
    root = Path(state_dir)
    if not root.is_dir():
        return None
    folders = snapshot_folders(root)
    current = read_current(root)
    damaged: list[str] = []
    for folder in folders:
        try:
            snap = read_snapshot(folder)
        except AtrError as exc:  # said once, with the snapshot resumed from or with "afresh"
            damaged.append(str(exc))
            continue
        if not _same_source(snap.meta, source, source_id):
            prev = set_aside(root)
            log.warning("state %s is of recording %s, not %s: starting afresh (the old state is in %s)", root,
                        snap.meta.get("source") or "(unnamed)", source or "(unnamed)", prev)
            return None
        if folder != current:
            why = "; ".join(damaged) if damaged else "CURRENT is unreadable or names no snapshot"
            log.warning("state %s: %s; resuming from %s, the newest snapshot that reads back", root, why, folder.name)
            # CURRENT names it from now on: the next snapshot keeps it as the previous one,
            # and removes the damaged ones
            _write_current(root, folder)
        return apply(snap, pipeline)
    if folders or (root / "CURRENT").exists():
        prev = set_aside(root)  # the next snapshots start a clean numbering
        why = "; ".join(damaged) if damaged else "CURRENT names no snapshot"
        log.warning("state %s: no snapshot reads back (%s): starting afresh (the damaged state is in %s)", root, why,
                    prev)
    return None


def apply(snap: Snapshot, pipeline: Any) -> dict[str, Any]:
    """Restore ``pipeline`` from a snapshot read by :func:`read_snapshot`; return its meta."""
    meta, a, grid, tracker_state = snap.meta, snap.arrays, snap.grid, snap.tracker_state
    pipeline.grid = grid
    pipeline.reserve_fusion()
    if meta["frame"] is not None:
        pipeline.frame = MissionFrame.from_dict(meta["frame"])
        pipeline.tracker = ContactTracker(pipeline.settings.fusion, pipeline.frame, gate_m=pipeline.gate_m)
        if tracker_state is not None:
            pipeline.tracker.restore(tracker_state)
    _restore_node(pipeline, a, meta)
    return meta


def _node_arrays(p: Any) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    arrays: dict[str, np.ndarray] = {}
    meta: dict[str, Any] = {
        "frame": p.frame.to_dict() if p.frame is not None else None,
        # the fixes gathered for a frame not yet fixed: the resumed node fixes the same origin
        "origin_fixes": [list(f) for f in p.origin.fixes], "origin_implausible": p.origin.implausible,
        "tiles_merged": p.tiles_merged, "leg": p.leg, "strip_leg": p._strip_leg, "last_t": p._last_t,
        "stats": {k: getattr(p.stats, k) for k in ("records", "tiles_in", "tiles_done", "tiles_rejected",
                                                    "tiles_dropped", "units", "units_degraded", "pixels")},
        "drop_reasons": dict(p.stats.drop_reasons), "rejections": dict(p.stats.rejections),
        "model": p.model.to_dict() if getattr(p, "online", None) is not None else None,
        "online_done": bool(p.online.done) if getattr(p, "online", None) is not None else None,
        "model_use": getattr(p, "model_use", None),
        # ICD v1.1 contact seq: a resumed node goes on counting, never reusing a seq
        "contact_seq": int(p.contact_seq), "contact_seq_of": {str(k): int(v) for k, v in p.contact_seq_of.items()},
        "strips": None, "bg": [],
    }
    for k, v in p.track.state().items():
        if isinstance(v, np.ndarray):
            arrays[f"track_{k}"] = v
        else:
            meta[f"track_{k}"] = v
    if p.strips is not None:
        st = p.strips.state()
        meta["strips"] = {"margin": p.strips.m, "max_gap_s": p.strips.max_gap_s, "sides": {}}
        for side, d in st.items():
            meta["strips"]["sides"][side] = {k: v for k, v in d.items() if k not in ("context", "pending")}
            for name in ("context", "pending"):
                for k, arr in d[name].items():
                    arrays[f"strip_{side}_{name}_{k}"] = arr
    meta["held"] = len(p.merger._held)
    # the first-return band measured last per side: a later tile too short to measure uses it
    meta["band_by_side"] = dict(p.merger._band_by_side)
    for i, tile in enumerate(p.merger._held):
        arrays[f"held_{i}"] = np.frombuffer(tile.pack(), dtype=np.uint8)
    # replay: tiles held for the on-line calibration (with their nav; float32 keeps NaN pixels)
    cal_held = getattr(p, "_cal_held", [])
    meta["cal_held"] = len(cal_held)
    # the wire map has no full scale: it is kept beside (an 8-bit file's, squared)
    meta["cal_held_full_scale"] = [t.saturation for t in cal_held]
    for i, tile in enumerate(cal_held):
        arrays[f"cal_held_{i}"] = np.frombuffer(tile.replace(wire_dtype="float32").pack(), dtype=np.uint8)
    for i, ((leg, side), (bg, med)) in enumerate(p._bg.items()):
        meta["bg"].append([leg, side])
        arrays[f"bg_{i}_b"] = bg.background if bg.background is not None else np.zeros(0)
        arrays[f"bg_{i}_m"] = med.background if med.background is not None else np.zeros(0)
        arrays[f"bg_{i}_w"] = bg.weight if bg.weight is not None else np.zeros(0)
    return arrays, meta


def _restore_node(p: Any, a: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
    track = {k[len("track_"):]: v for k, v in a.items() if k.startswith("track_")}
    track.update({k[len("track_"):]: v for k, v in meta.items() if k.startswith("track_")})
    p.track.restore(track)
    p.tiles_merged = int(meta["tiles_merged"])
    p.origin.fixes = [(float(lat), float(lon)) for lat, lon in meta.get("origin_fixes", [])]
    p.origin.implausible = int(meta.get("origin_implausible", 0))
    p._last_t = float(meta.get("last_t", 0.0))  # the time of the contacts published at finish()
    p._strip_leg = meta.get("strip_leg")
    p.leg = meta["leg"]
    for k, v in meta["stats"].items():
        setattr(p.stats, k, v)
    # counted by reason: after a resume the reasons still add up to the totals
    p.stats.drop_reasons = Counter(meta.get("drop_reasons", {}))
    p.stats.rejections = Counter(meta.get("rejections", {}))
    p.model_use = meta.get("model_use")
    p.contact_seq = int(meta.get("contact_seq", 0))  # 0 and none per contact: a snapshot older than v1.1
    p.contact_seq_of = {int(k): int(v) for k, v in meta.get("contact_seq_of", {}).items()}
    if meta.get("model") is not None:
        p.model = PerformanceModel.from_dict(meta["model"], where="node snapshot")
        if p.online is not None and meta.get("online_done"):
            p.online.close()
            p.online = None  # the on-line model had taken over: keep it
    if meta["strips"] is not None:
        s = meta["strips"]
        p.strips = StripAssembler(int(s["margin"]), max_gap_s=float(s["max_gap_s"]))
        state = {}
        for side, d in s["sides"].items():
            d = dict(d)
            for name in ("context", "pending"):
                d[name] = {k: a[f"strip_{side}_{name}_{k}"] for k in ("px", "t", "nav", "src")}
            state[side] = d
        p.strips.restore(state)
    from ..records.tile import Tile
    from .pipeline import _trackers

    p.merger._held.clear()
    p.merger._band_by_side = {str(k): float(v) for k, v in meta.get("band_by_side", {}).items()}
    for i in range(int(meta.get("held", 0))):
        p.merger._held.append(Tile.unpack(a[f"held_{i}"].tobytes()))
    n_held = int(meta.get("cal_held", 0))
    scales = meta.get("cal_held_full_scale") or [None] * n_held
    p.hold_for_calibration([Tile.unpack(a[f"cal_held_{i}"].tobytes()).replace(
        full_scale=None if scales[i] is None else float(scales[i])) for i in range(n_held)])

    p._bg = {}
    f = p.settings.detectors.background_memory_m
    for i, (leg, side) in enumerate(meta["bg"]):
        bg, med = _trackers(f)
        b, m = a[f"bg_{i}_b"], a[f"bg_{i}_m"]
        w = a.get(f"bg_{i}_w")  # the mean's weight (snapshots before issue 21 item 1 have none)
        bg.restore(b if b.size else None, w if w is not None and w.size else None)
        med.restore(m if m.size else None)
        p._bg[(int(leg), side)] = (bg, med)
