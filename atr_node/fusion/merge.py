"""Exact merge of evidence grids by adding accumulators (SPEC section 7).

Grids from several passes, processes or vehicles combine into one: committed accumulators
add (``L_T``, ``L_N``: Dempster's rule is a sum of logs), coverage unions, and open layers of
the same leg combine by maximum, exactly as if one grid had seen every tile of that leg.

What is bit-exact (``docs/fusion.md``): a cell that only one grid holds is copied; open
layers are merged by maximum; ``0 + x == x``. What is exact only to rounding: a cell both
grids hold, whose sum ``(s1 + s2) + (s3 + s4)`` may differ in the last bit from the
sequential ``((s1 + s2) + s3) + s4`` (float addition is not associative), about 1e-16
relative per addition.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..errors import FusionError
from .chunks import LegLayer

if TYPE_CHECKING:
    from .grid import EvidenceGrid


def merge_into(dst: "EvidenceGrid", src: "EvidenceGrid") -> None:
    """Add ``src``'s evidence to ``dst`` (``src`` is not modified).

    Raises
    ------
    FusionError
        The grids differ in cell size, chunk size, eps or detectors, or a leg is open in one
        and committed in the other (its evidence could not be combined once per cell). A
        leg committed in both would count twice: callers exchange disjoint evidence.
    """
    same = ((dst.cell_m, dst.n, dst.detectors, dst.layers, dst.fusion.eps)
            == (src.cell_m, src.n, src.detectors, src.layers, src.fusion.eps))
    if not same:
        raise FusionError("merge: the grids differ in cell size, chunk size, eps, detectors or evidence layers")
    clash = (dst.closed_legs & set(src.open)) | (set(dst.open) & src.closed_legs)
    if clash:
        raise FusionError(f"merge: leg(s) {sorted(clash)} are open in one grid and committed in the other")
    dst.stamp += 1
    for stack in ("_ln", "_lt"):
        a, b = getattr(dst, stack), getattr(src, stack)
        if len(b):
            mine = np.array([a.get(k) for k in b.keys], dtype=np.int64)
            a.arr[mine] += b.gather()
    if dst._diag is not None and src._diag is not None and len(src._diag):
        mine = np.array([dst._diag.get(k) for k in src._diag.keys], dtype=np.int64)
        dst._diag.arr[mine] += src._diag.gather()
    for key, legs in src.cover.items():
        out = dst.cover.setdefault(key, {})
        for leg, bits in legs.items():
            old = out.get(leg, bits) if leg in out else bits
            out[leg] = None if (old is None or bits is None) else np.bitwise_or(old, bits)
    for key, t in src.last_t.items():
        dst.last_t[key] = max(dst.last_t.get(key, -np.inf), t)
    for leg, layer in src.open.items():
        into = dst.open.setdefault(leg, LegLayer(len(dst.layers), dst.nn))
        into.t = max(into.t, layer.t)
        into.n_obs += layer.n_obs
        for key, s in layer.chunks.slot.items():
            d = into.chunks.get(key)
            np.maximum(into.chunks.arr[d], layer.chunks.arr[s], out=into.chunks.arr[d])
            into.touched[key] = into.n_obs
        into.retired |= layer.retired
    for key in src.chunk_keys():
        dst.changed[key] = dst.stamp
    dst.closed_legs |= src.closed_legs
    dst.detections.extend(src.detections)
    dst.n_clamped += src.n_clamped
    dst.n_reopened += src.n_reopened
    dst.n_observations += src.n_observations
