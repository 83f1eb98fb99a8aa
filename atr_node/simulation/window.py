"""The window a placed target can reach in a tile, and its traced surface (SPEC section 4).

:func:`trace_window` is cheap (the mesh's bounding box): an injector checks a placement on
the window before paying for a trace. The facets' normals, the degenerate ones dropped and
whether the mesh is closed (for culling the faces turned away from the sensor) are worked
out for a whole batch of windows at once by :func:`surfaces`, which the signature engine
(:func:`~.raytrace.trace_many`) calls.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import GeometryError
from .meshes import Mesh

_AREA_EPS = 1e-12   # m^2: smaller triangles are degenerate and skipped


def _facet_normals(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit normals (m', 3) of the non-degenerate triangles, their keep-mask (m,), and each
    triangle's six times signed volume term ``v0 . (e1 x e2)`` (m,): summed over a closed
    mesh, > 0 when its normals point outward."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.column_stack([e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1],
                         e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2],
                         e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]])
    norm = np.sqrt((n * n).sum(axis=1))
    keep = 0.5 * norm > _AREA_EPS
    return n[keep] / norm[keep, None], keep, (n * tri[:, 0]).sum(axis=1)


_CLOSED: dict[int, tuple[np.ndarray, bool]] = {}
"""Per faces array (meshes scaled, tilted and placed share theirs; the array is held, so its
id cannot be reused): whether it closes a surface."""


def _closed_faces(faces: np.ndarray) -> bool:
    """:func:`_closed` of ``faces``, worked out once per faces array."""
    hit = _CLOSED.get(id(faces))
    if hit is not None and hit[0] is faces:
        return hit[1]
    if len(_CLOSED) >= 256:
        _CLOSED.clear()
    closed = _closed(faces)
    _CLOSED[id(faces)] = (faces, closed)
    return closed


def surfaces(windows: "Sequence[TraceWindow]") -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The traced surface of many windows at once: their non-degenerate triangles (m, 3, 3)
    and unit normals (m, 3), concatenated; the triangles per window (J,); and each window's
    facing (+1 / -1: a closed mesh with normals outward / inward; 0: open)."""
    counts = np.array([len(w.tri_all) for w in windows], dtype=np.int64)
    tri_all = np.concatenate([w.tri_all for w in windows]) if windows else np.zeros((0, 3, 3))
    normals, keep, vol = _facet_normals(tri_all)
    starts = np.cumsum(counts) - counts
    kept = np.add.reduceat(keep.astype(np.int64), starts) if tri_all.size else counts
    vol6 = np.add.reduceat(vol, starts) if tri_all.size else np.zeros(len(windows))
    facing = np.zeros(len(windows), dtype=np.int64)
    for j, w in enumerate(windows):
        kept_j = keep[starts[j]:starts[j] + counts[j]]
        closed = _closed_faces(w.faces) if kept_j.all() else _closed(w.faces[kept_j])
        if vol6[j] != 0.0 and closed:
            facing[j] = 1 if vol6[j] > 0 else -1
    return tri_all[keep], normals, kept, facing


def _closed(f: np.ndarray) -> bool:
    """Whether triangles (int (m, 3) vertex indices) close a surface with consistent winding:
    every directed edge once, and its reverse once."""
    if f.size == 0:
        return False
    a, b = f.reshape(-1), np.roll(f, -1, axis=1).reshape(-1)
    n = int(f.max()) + 1
    edge = np.sort(a * n + b)
    if np.any(edge[1:] == edge[:-1]):
        return False
    return bool(np.isin(b * n + a, edge, assume_unique=True).all())


@dataclass(frozen=True, eq=False)
class TraceWindow:
    """What :func:`trace` needs of a placed target before it traces a ray: its triangles, and
    the window of the tile it can reach (rows ``i0 .. i1``, columns ``c0 .. c1``; seabed points
    ``cs0 .. cs1``). Cheap (the mesh's bounding box): a caller can reject a placement on the
    window before paying for the trace, whose normals :func:`trace_many` works out for a
    whole batch at once."""

    tri_all: np.ndarray
    faces: np.ndarray
    lo: np.ndarray
    i0: int
    i1: int
    c0: int
    c1: int
    cs0: int
    cs1: int

    @property
    def footprint(self) -> tuple[int, int, int, int]:
        """(row0, row1, col0, col1), half-open: the traced :class:`Signature`'s footprint."""
        return self.i0, self.i1, self.c0, self.c1


def trace_window(mesh: Mesh, *, range0_m: float, dr_m: float, dx_m: float, rows: int, cols: int,
                 altitude_m: float) -> TraceWindow | None:
    """The window :func:`trace` traces a placed target into, or None when the trace is empty
    (outside the tile, entirely buried, on the other side of the track). Parameters as
    :func:`trace`."""
    if not (altitude_m > 0 and math.isfinite(altitude_m)):
        raise GeometryError(f"altitude must be finite and > 0, got {altitude_m!r}")
    if dr_m <= 0 or dx_m <= 0:
        raise GeometryError(f"pixel spacing must be > 0, got dr={dr_m}, dx={dx_m}")
    H = float(altitude_m)
    tri_all = mesh.triangles_m
    if len(tri_all) == 0:
        return None
    lo, hi = mesh.bounds_m  # the triangles' bounding box: over the vertices the faces use
    zmax = min(hi[2], H)
    if zmax <= 0.0 or hi[1] <= 0.0:
        return None  # entirely buried, or on the other side of the track
    # Rows the target spans (pixel i covers x in [(i - 1/2) dx, (i + 1/2) dx)).
    i0 = max(int(math.floor(lo[0] / dx_m + 0.5)), 0)
    i1 = min(int(math.floor(hi[0] / dx_m + 0.5)) + 1, rows)
    # Seabed points that can be hidden: from the nearest ground range to the end of the shadow.
    y_near = max(lo[1], 0.0)
    y_far = hi[1] * H / (H - zmax) if zmax < H else math.inf
    edge0 = range0_m - dr_m / 2
    cs0 = max(int(math.floor((y_near - edge0) / dr_m)), 0)
    cs1 = min(int(math.floor((y_far - edge0) / dr_m)) + 1, cols) if math.isfinite(y_far) else cols
    # Echo bins: the smallest slant range any point of the bounding box can have.
    r_min = math.sqrt(y_near ** 2 + (H - zmax) ** 2)
    g_min = math.sqrt(max(r_min ** 2 - H ** 2, 0.0))
    ce0 = max(int(math.floor((g_min - edge0) / dr_m)), 0)
    c0, c1 = min(cs0, ce0), cs1
    if i1 <= i0 or c1 <= c0 or cs1 <= cs0:
        return None
    return TraceWindow(tri_all, mesh.faces, lo, i0, i1, c0, c1, cs0, cs1)
