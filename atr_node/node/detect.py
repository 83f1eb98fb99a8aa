"""The detect stage: one strip unit in, each enabled detector's coverage and detections out.

Runs in the node's worker process (or in-process with ``workers = 0``): everything it needs
travels with the :class:`DetectJob`, and the result is small (coverage as packed bits,
detections as records), so the main process spends its time on ingest and fusion while the
second core scores. Pure function of its inputs: the same job gives the same result.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..config import DetectorSettings, TemplateSettings
from ..detectors import Detection, find_detections, place_at_peak, score_strip
from ..detectors.objects import find_objects, group_detections
from ..detectors.sat import Workspace


@dataclass(frozen=True, eq=False)
class DetectJob:
    """What the worker needs to score one unit's core."""

    key: int
    """Position of the unit in the node's sequence (results are consumed in this order)."""
    pixels: np.ndarray
    core: tuple[int, int]
    range0_m: float
    dr_m: float
    dx_m: float
    altitude_m: float
    background: np.ndarray
    median: np.ndarray
    taus: dict[str, float]
    enabled: tuple[str, ...]
    template: TemplateSettings
    detectors: DetectorSettings
    sweep: dict[str, tuple[float, ...]] | None = None
    """Evaluation only: further thresholds per detector at which to extract detections too."""
    full_scale: float | None = None
    """The recording's clip level in intensity (:attr:`~atr_node.records.tile.Tile.saturation`):
    with ``background``, each detection's headroom; None: unknown."""


@dataclass(frozen=True, eq=False)
class DetectResult:
    key: int
    shape: tuple[int, int]
    """(core rows, cols)."""
    covered_bits: dict[str, np.ndarray]
    """Per detector, the core's covered mask (score not NaN) as ``np.packbits``. Detectors
    whose masks are equal share one array (MF and Z use the same windows), which the result's
    pickle then carries once."""
    detections: dict[str, list[Detection]]
    """Per detector, detections with rows relative to the core."""
    seconds: float
    sweep: dict[str, dict[float, list[Detection]]] | None = None
    """Detections at the job's sweep thresholds (evaluation only)."""

    def covered(self, detector: str) -> np.ndarray:
        """The covered mask of ``detector``: a new bool array, shape (core rows, cols)."""
        rows, cols = self.shape
        # unpackbits gives 0 or 1 only: a bool view of its fresh array, no copy
        return np.unpackbits(self.covered_bits[detector], count=rows * cols).reshape(rows, cols).view(bool)


def detect(job: DetectJob, workspace: Workspace | None = None) -> DetectResult:
    """Score the core of ``job`` with every enabled detector and extract detections (SPEC 2-3),
    in ``workspace`` (default: this process's, for one thread at a time)."""
    import time

    t0 = time.perf_counter()
    scores = score_strip(job.pixels, core_rows=job.core, range0_m=job.range0_m, dr_m=job.dr_m, dx_m=job.dx_m,
                         altitude_m=job.altitude_m, template=job.template, detectors=job.detectors,
                         enabled=job.enabled, background=job.background, median=job.median,
                         workspace=_WORKSPACE if workspace is None else workspace)
    covered, dets = {}, {}
    shape = (job.core[1] - job.core[0], job.pixels.shape[1])
    sweep: dict[str, dict[float, list[Detection]]] | None = {} if job.sweep else None
    ds = job.detectors
    upper_m = ds.max_object_length_m if ds.objects else ds.max_extent_m
    # components up to an object's length: one too long for a mine may lie on a wreck
    raw: dict[tuple[str, float | None], list[Detection]] = {}
    for d in job.enabled:
        s = scores[d]
        bits = np.packbits(np.isnan(s))
        np.invert(bits, out=bits)  # covered = not NaN, inverted packed (the padding bits are never read)
        covered[d] = next((b for b in covered.values() if np.array_equal(b, bits)), bits)
        for tau in (None, *(job.sweep.get(d, ()) if sweep is not None else ())):
            raw[d, tau] = find_detections(s, job.taus[d] if tau is None else tau, detector=d, range0_m=job.range0_m,
                                          dr_m=job.dr_m, dx_m=job.dx_m, min_extent_m=ds.min_extent_m,
                                          max_extent_m=upper_m)
    # extended objects (a wreck) and bands, once per unit for every detector
    # (detectors/objects.py), and only when there is something to regroup: about 17 ms per
    # 1.5-Mpx unit, spent on the few units with a detection; without them, the extent filter
    # alone, as find_detections applies it
    objects = find_objects(job.pixels, job.background, dr_m=job.dr_m, dx_m=job.dx_m,
                           template_length_m=job.template.length_m, echo_width_m=job.template.echo_width_m,
                           highlight=ds.object_highlight, shadow=ds.object_shadow,
                           max_length_m=ds.max_object_length_m) if ds.objects and any(raw.values()) else None

    def grouped(found: list[Detection]) -> list[Detection]:
        if not ds.objects:
            return found
        return group_detections(found, objects, core_start=job.core[0], core_rows=shape[0], range0_m=job.range0_m,
                                dr_m=job.dr_m, min_extent_m=ds.min_extent_m, max_extent_m=ds.max_extent_m,
                                patches=ds.patch_one_look)

    joints: dict = {}  # one window read per place and detector, whichever detector found it
    moved = set(ds.relocate) if "mf" in scores else set()

    def placed(d: str, found: list[Detection]) -> list[Detection]:
        # after the joint responses are read at the detector's own peak: the look's score
        # stays the detector's, only its place moves to the matched filter's peak. Where the
        # recording clips (the seabed within relocate_headroom_db of full scale) the detection
        # stays: there the clipped echo already places the lacunarity about as near as the
        # matched filter would, and moving it cost targets (docs/detectors.md)
        if d not in moved or not found:
            return found
        g = _geometry(job, joints)
        head = _headroom(job, joints)
        cols = head.size
        free = [i for i, x in enumerate(found)
                if not head[min(max(int(x.col), 0), cols - 1)] < ds.relocate_headroom_db]
        if not free:
            return found
        out = list(found)
        for i, x in zip(free, place_at_peak([found[i] for i in free], scores["mf"], row0=g.row0,
                                            length_px=g.length_px, echo_px=g.echo_px, shadow_px=g.shadow_px,
                                            range0_m=job.range0_m, dr_m=job.dr_m)):
            out[i] = x
        return out

    for d in job.enabled:
        dets[d] = placed(d, with_joint(grouped(raw[d, None]), scores, job, joints))
        if sweep is not None:
            sweep[d] = {float(tau): placed(d, grouped(raw[d, tau])) for tau in job.sweep.get(d, ())}
    return DetectResult(job.key, shape, covered, dets, time.perf_counter() - t0, sweep)


def with_joint(found: list[Detection], scores: dict[str, np.ndarray], job: DetectJob,
               cache: dict[tuple, tuple] | None = None) -> list[Detection]:
    """``found`` with each detection's joint responses (SPEC 6.1): per enabled detector the
    maximum of its score over the template window of the detection's anchor (rows
    ``[i + row0, i + row0 + L)``, columns ``[j - W, j + S(j))``), the window the calibration
    measures injected targets on (``calibration.responses.window_max``). ``cache`` (shared by
    the calls of one unit) holds the window geometry and the joints already read, keyed by
    place: detections of several detectors on one object read its windows once."""
    if not found:
        return found
    import dataclasses

    from ..calibration.responses import window_max

    cache = {} if cache is None else cache
    cols = job.pixels.shape[1]
    geom = _geometry(job, cache)
    head = _headroom(job, cache)
    out = []
    for x in found:
        key = (int(x.row), int(x.col), x.length_m)
        j = min(max(int(x.col), 0), cols - 1)
        if key in cache:
            out.append(dataclasses.replace(x, joint=cache[key], headroom_db=float(head[j])))
            continue
        if x.length_m is not None:
            # an extended object (a wreck): its anchor is the object's centre, where the
            # detectors need not respond; each detector's response is its maximum over the
            # object's extent (a square of its length around the centre)
            half_r, half_c = int(np.ceil(0.5 * x.length_m / job.dx_m)), int(np.ceil(0.5 * x.length_m / job.dr_m))
            joint = tuple((d, window_max(scores[d], int(x.row), int(x.col) + half_c, row0=-half_r,
                                         length_px=2 * half_r + 1, echo_px=2 * half_c, shadow_px=1))
                          for d in job.enabled)
        else:
            joint = tuple((d, window_max(scores[d], int(x.row), int(x.col), row0=geom.row0,
                                         length_px=geom.length_px, echo_px=geom.echo_px,
                                         shadow_px=int(geom.shadow_px[j]))) for d in job.enabled)
        cache[key] = joint
        out.append(dataclasses.replace(x, joint=joint, headroom_db=float(head[j])))
    return out


def _geometry(job: DetectJob, cache: dict):
    """The template windows of the unit's columns, computed once per unit (in ``cache``)."""
    if "geometry" not in cache:
        from ..detectors.windows import window_geometry

        ranges = job.range0_m + job.dr_m * np.arange(job.pixels.shape[1], dtype=np.float64)
        cache["geometry"] = window_geometry(ranges, template=job.template, dr_m=job.dr_m, dx_m=job.dx_m,
                                            altitude_m=job.altitude_m)
    return cache["geometry"]


def _headroom(job: DetectJob, cache: dict) -> np.ndarray:
    """Per column, dB from the seabed's mean intensity to the recording's full scale (inf:
    unknown or float data), computed once per unit (in ``cache``)."""
    if "headroom" not in cache:
        from ..calibration.looks import headroom_db

        cache["headroom"] = np.broadcast_to(np.asarray(headroom_db(job.full_scale, job.background), dtype=np.float64),
                                            (job.pixels.shape[1],))
    return cache["headroom"]


_WORKSPACE = Workspace()
"""Buffers reused from unit to unit in this process (units of one leg have the same shape)."""


def worker_init(threads: int = 1) -> None:
    """Worker process start: one OpenCV thread (the main process has the other core), and a
    watch on the parent: when the node is SIGKILLed the worker would otherwise live on as an
    orphan holding its memory (found by tools/soak/kill_restart.py), so it exits when its parent
    changes."""
    cv2.setNumThreads(threads)
    import multiprocessing
    import os
    import threading

    # the pid the node had when it started this worker (not getppid(): the node may already be
    # dead while this worker was still importing, and then getppid() is already init's)
    spawner = multiprocessing.parent_process()
    parent = spawner.pid if spawner is not None and spawner.pid else os.getppid()

    def watch() -> None:
        while True:
            threading.Event().wait(0.5)
            if os.getppid() != parent:
                os._exit(0)

    threading.Thread(target=watch, name="atr-parent-watch", daemon=True).start()


def warm_up() -> None:
    """Run the detectors once on a tiny image, so the first real tile pays no import or
    first-call cost (called in the worker when the node starts)."""
    from ..config import Settings

    s = Settings()
    px = np.ones((64, 64), np.float32)
    score_strip(px, core_rows=(0, 64), range0_m=10.0, dr_m=s.sensor.dr_m, dx_m=s.sensor.dx_m,
                altitude_m=s.sensor.altitude_m, template=s.template, detectors=s.detectors)
