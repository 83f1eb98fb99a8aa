"""Property tests (Hypothesis) of the delta codec and of the canonical reduction."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st

from atr_node.config import FusionSettings
from atr_node.fusion.exchange import (DeltaId, EvidenceDelta, committed_state, decode_delta, encode_delta,
                                      reduce_deltas)
from atr_node.fusion.grid import DetectionRecord

N = 8  # chunk_cells: the smallest allowed keeps the examples small
FUSION = FusionSettings(chunk_cells=N)
FRAME = {"kind": "utm", "origin_lat_deg": 44.0, "origin_lon_deg": 9.8, "proj4": "+proj=utm +zone=32"}
DETS = ("mf", "z")


@st.composite
def deltas(draw, mission=st.sampled_from(["m1", "m2"]), node=st.sampled_from(["a", "b"])):
    k = draw(st.integers(0, 4))
    keys = draw(st.lists(st.tuples(st.integers(-3, 3), st.integers(-3, 3)), min_size=k, max_size=k, unique=True))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    # log1p(-m) of masses spread over [0, 1 - 1e-9], extremes included
    m = rng.choice([0.0, 1e-15, 0.5, 1 - 1e-9], size=(k, N * N)) * rng.uniform(0, 1, (k, N * N)) ** 0.1
    d_ln = np.log1p(-np.minimum(m, 1 - 1e-9))
    with_t = np.flatnonzero(rng.uniform(size=k) < 0.5)
    d_lt = np.log1p(-rng.uniform(0, 0.999, (with_t.size, N * N)))
    cover = rng.uniform(size=(k, N * N)) < 0.9
    full = cover.all(axis=1) | (rng.uniform(size=k) < 0.3)
    cover[full] = True
    did = DeltaId(draw(mission), draw(st.integers(0, 3)), draw(node), draw(st.integers(0, 2)))
    dets = tuple(DetectionRecord(did.leg, DETS[i % 2], float(rng.normal()), float(rng.normal()), 1.0, 0.7, 3.0)
                 for i in range(draw(st.integers(0, 3))))
    return EvidenceDelta(did, draw(st.booleans()), float(seed % 1000), FRAME, 0.5, N, 1e-9, DETS,
                         np.array(keys, dtype=np.int64).reshape(-1, 2), d_ln, with_t.astype(np.int64), d_lt, full,
                         np.packbits(cover[~full], axis=1).reshape(-1, (N * N + 7) // 8), 0, dets)


@settings(max_examples=60, deadline=None)
@given(deltas())
def test_codec_round_trip(d):
    e = decode_delta(encode_delta(d))
    assert e.id == d.id and e.digest == d.digest and e.final == d.final and e.t == d.t
    for a, b in ((e.keys, d.keys), (e.lt_rows, d.lt_rows), (e.cover_all, d.cover_all), (e.cover_bits, d.cover_bits)):
        assert np.array_equal(a, b)
    assert np.array_equal(e.d_ln.view(np.uint64), d.d_ln.view(np.uint64))
    assert np.array_equal(e.d_lt.view(np.uint64), d.d_lt.view(np.uint64))
    assert e.detections == d.detections


@settings(max_examples=40, deadline=None)
@given(st.lists(deltas(), min_size=1, max_size=8, unique_by=lambda d: d.id), st.randoms(use_true_random=False))
def test_reduction_depends_only_on_the_set(ds, rnd):
    ref, _ = reduce_deltas(ds, fusion=FUSION, gate_m=3.0, detectors=DETS)
    shuffled = ds + rnd.sample(ds, k=min(3, len(ds)))  # some duplicates
    rnd.shuffle(shuffled)
    got, dset = reduce_deltas(shuffled, fusion=FUSION, gate_m=3.0, detectors=DETS)
    a, b = committed_state(ref), committed_state(got)
    assert a.keys() == b.keys()
    assert all(np.array_equal(a[k].view(np.uint64), b[k].view(np.uint64)) for k in a)
    assert dset.duplicates == min(3, len(ds))
    assert got.covered_cells() == ref.covered_cells()
    # against an independent reference: math.fsum of each cell's increments, to rounding
    import math

    for key, acc in a.items():
        rows = [(d, i) for d in ds for i, k in enumerate(d.chunk_keys()) if k == key]
        want_ln = [math.fsum(d.d_ln[i][c] for d, i in rows) for c in range(N * N)]
        np.testing.assert_allclose(acc[1], want_ln, rtol=1e-12, atol=1e-300)
