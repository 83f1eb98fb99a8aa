"""Warming the node's processes up: fresh memory, the worker's first tile (issue 7).

Huge pages. NumPy asks the kernel for transparent huge pages on every array of 4 MB or more
(``madvise``). On the target VM (``transparent_hugepage/defrag = madvise``) each such fault
compacts memory first: touching 200 MB of fresh memory took 0.375 s of system time with the
advice and 0.081 s without, and the first 8-Mpx unit scored in 2.09 s with it, 0.48 s
without (0.22 s once warm either way). The node allocates tens of megabytes per tile (the
tile, the strip, the job and its pickled copy, coverage masks), so :func:`keep_small_pages`
turns the advice off in both node processes, unless ``NUMPY_MADVISE_HUGEPAGE`` is set
explicitly. No result changes: only how the kernel backs the memory.

The detectors keep their buffers in a per-process workspace (``atr_node.detectors.sat``),
so only the first unit of a given size pays for fresh memory. On the target VM that first
touch is expensive: scoring the first 8-Mpx unit took 1.9 s instead of 0.22 s, 1.6 s of it
system time in page faults (``/tmp`` measurement, 2026-11-23). A live node has time before
the first tile, so the worker scores a synthetic unit of ``node.warm_up_mpx`` megapixels when
it starts: the buffers are then mapped, and the first real tiles up to that size cost what
every later tile costs. The synthetic unit is built in the worker (nothing crosses the
process boundary) on the sonar's nominal range axis; its result is discarded.
"""

from __future__ import annotations

import math
import os

import numpy as np

from ..config import DetectorSettings, SensorSettings, Settings, TemplateSettings
from ..detectors.sat import Workspace
from .detect import DetectJob, detect, warm_up, worker_init


def keep_small_pages() -> bool:
    """Turn NumPy's huge-page advice off in this process (see the module docstring), unless
    ``NUMPY_MADVISE_HUGEPAGE`` is set. Returns whether it was turned off."""
    if os.environ.get("NUMPY_MADVISE_HUGEPAGE") is not None:
        return False
    try:
        from numpy._core.multiarray import _set_madvise_hugepage
    except ImportError:  # numpy < 2
        try:
            from numpy.core.multiarray import _set_madvise_hugepage
        except ImportError:
            return False
    _set_madvise_hugepage(False)
    return True


def node_worker_init() -> None:
    """The detection worker's initializer: :func:`~atr_node.node.detect.worker_init` plus
    small pages."""
    keep_small_pages()
    worker_init()


def warm_up_shape(sensor: SensorSettings, mpx: float) -> tuple[int, int]:
    """(rows, cols) of the synthetic unit: the nominal range axis (``max_range_m / dr_m + 1``
    columns) and enough rows for ``mpx`` megapixels plus an eighth (units of the same pixel
    count but other aspect ratios need slightly larger padded buffers)."""
    cols = int(round(sensor.max_range_m / sensor.dr_m)) + 1
    rows = int(math.ceil(1.125 * mpx * 1e6 / cols))
    return rows, cols


def warm_up_worker(sensor: SensorSettings, template: TemplateSettings, detectors: DetectorSettings,
                   enabled: tuple[str, ...], mpx: float, workspace: Workspace | None = None) -> tuple[int, int]:
    """Run in the worker at start: the small warm-up (imports, first calls), then, if
    ``mpx > 0``, score a synthetic unit of about ``mpx`` megapixels (in ``workspace``; default:
    the process's). Returns its shape."""
    warm_up()
    if mpx <= 0:
        return 0, 0
    rows, cols = warm_up_shape(sensor, mpx)
    # a flat seabed: every score map is computed in full, nothing is detected
    pixels = np.ones((rows, cols), np.float32)
    ones = np.ones(cols)
    job = DetectJob(key=-1, pixels=pixels, core=(0, rows), range0_m=0.0, dr_m=sensor.dr_m, dx_m=sensor.dx_m,
                    altitude_m=sensor.altitude_m, background=ones, median=ones,
                    taus={d: getattr(detectors.threshold, d) for d in enabled}, enabled=enabled,
                    template=template, detectors=detectors)
    detect(job, workspace)
    return rows, cols


def fusion_reserve_chunks(settings: Settings) -> int:
    """Chunks of the evidence grid a live node maps at start (``EvidenceGrid.reserve``).

    An open leg's layer holds the chunks touched by its last ``fusion.commit_after_obs`` units
    (older ones are committed and their slots reused), so in steady state about
    ``commit_after_obs + 2`` units' worth: a unit of ``node.warm_up_mpx`` megapixels covers
    ``mpx * dr_m * dx_m`` square metres, a chunk ``(cell_m * chunk_cells)^2``, plus a quarter
    for chunks cut by the unit's edges. 2.5 thousand chunks (180 MB) for the defaults.
    """
    unit_m2 = settings.node.warm_up_mpx * 1e6 * settings.sensor.dr_m * settings.sensor.dx_m
    chunk_m2 = (settings.fusion.cell_m * settings.fusion.chunk_cells) ** 2
    return int(math.ceil(1.25 * unit_m2 / chunk_m2 * (settings.fusion.commit_after_obs + 2)))
