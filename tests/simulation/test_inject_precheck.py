"""Placements refused before they are traced (issue 19): the trace window is the traced
footprint, and the injector's pre-check gives the same targets, pixels and draws as checking
the traced signature, with far fewer traces where the tile is full."""

from __future__ import annotations

import math

import numpy as np
import pytest

from atr_node.config import PopulationSettings, SimulationSettings
from atr_node.simulation import inject, raytrace
from atr_node.simulation.inject import _mesh_for, draw_placement, inject_targets
from atr_node.simulation.meshes import place
from atr_node.simulation.raytrace import trace, trace_window
from atr_node.simulation.seabed import seabed_pixels

H, DR, DX, RANGE0 = 12.0, 0.1, 0.1, 5.0


@pytest.mark.parametrize("mode", ["fixed", "varied"])
def test_the_window_is_the_traced_footprint_and_holds_the_centre_pixel(rng, mode):
    rows, cols = 300, 500
    pop = PopulationSettings(mode=mode)
    seen = 0
    for _ in range(300):
        p = draw_placement(rng, row_span=(-20.0, rows + 20.0), range_span_m=(RANGE0 - 2.0, RANGE0 + 52.0),
                           population=pop)
        mesh = place(_mesh_for(p), along_m=p.row * DX, range_m=p.range_m, heading_deg=p.heading_deg,
                     burial_m=p.burial_m)
        geo = dict(range0_m=RANGE0, dr_m=DR, dx_m=DX, rows=rows, cols=cols, altitude_m=H)
        w = trace_window(mesh, **geo)
        sig = trace(mesh, **geo, subrays=2)
        assert (w is None) == sig.empty
        if w is None:
            continue
        seen += 1
        assert w.footprint == sig.footprint
        # the pixel of the centre lies in the window whenever it lies in the tile
        ra = math.floor(p.row + 0.5)
        ca = math.floor((p.range_m - (RANGE0 - DR / 2)) / DR)
        if 0 <= ra < rows and 0 <= ca < cols:
            assert w.i0 <= ra < w.i1 and w.c0 <= ca < w.c1, (p, w.footprint)
    assert seen > 200


@pytest.mark.parametrize("mode", ["fixed", "varied"])
def test_the_precheck_and_the_batch_change_nothing_but_the_traces(monkeypatch, mode):
    """A small tile asked for far more targets than fit: checking the traced signature
    (reference), checking the window before tracing, and tracing the accepted placements in
    one batch give the same targets, the same pixels to the bit, and leave the generator in
    the same state."""
    host = seabed_pixels(rows=400, cols=600, range0_m=RANGE0, dr_m=DR, altitude_m=H,
                         rng=np.random.default_rng(3), k_order=20.0)
    host[:, 420:440] = np.nan  # a no-data band: refusals for missing data too
    traced = []  # signatures per trace_many call
    real = inject.trace_many

    def counting(windows, **k):
        traced.append(len(windows))
        return real(windows, **k)

    monkeypatch.setattr(inject, "trace_many", counting)
    out = {}
    for pre, batch in ((False, False), (True, False), (True, True)):
        monkeypatch.setattr(inject, "PRECHECK", pre)
        monkeypatch.setattr(inject, "BATCH", batch)
        traced.clear()
        rng = np.random.default_rng(11)
        px, targets = inject_targets(host, range0_m=RANGE0, dr_m=DR, dx_m=DX, altitude_m=H, n_targets=40, rng=rng,
                                     simulation=SimulationSettings(), population=PopulationSettings(mode=mode))
        out[pre, batch] = (px, targets, sum(traced), len(traced), rng.uniform())
    px0, t0, n0, _, u0 = out[False, False]
    assert 5 <= len(t0) < 40  # the tile is full before the 40th target
    for key in ((True, False), (True, True)):
        px1, t1, _, _, u1 = out[key]
        assert t0 == t1 and u0 == u1, key
        np.testing.assert_array_equal(px0, px1)
    n1 = out[True, False][2]
    assert n1 <= len(t0) + (n0 - len(t0)) // 10, (n0, n1)  # most refused placements are never traced
    assert out[True, True][2:4] == (len(t0), 1)  # one batch, of the placed targets only


def test_a_window_with_nothing_in_it_replays_the_sequential_order(monkeypatch):
    """When a checked placement traces to nothing, the one-by-one order draws again there.
    The batch then replays that order from the generator's state: here its third signature is
    made empty, and the result is still the one-by-one result, draws included."""
    host = seabed_pixels(rows=300, cols=500, range0_m=RANGE0, dr_m=DR, altitude_m=H,
                         rng=np.random.default_rng(4), k_order=20.0)
    real = inject.trace_many
    spoiled = []

    def spoil(windows, **k):
        sigs = real(windows, **k)
        if len(sigs) > 2:  # the batch, not the one-by-one replay
            sigs[2] = raytrace._empty()
            spoiled.append(1)
        return sigs

    out = {}
    for batch in (False, True):
        monkeypatch.setattr(inject, "BATCH", batch)
        monkeypatch.setattr(inject, "trace_many", spoil if batch else real)
        rng = np.random.default_rng(12)
        px, targets = inject_targets(host, range0_m=RANGE0, dr_m=DR, dx_m=DX, altitude_m=H, n_targets=6, rng=rng)
        out[batch] = px, targets, rng.uniform()
    assert spoiled == [1]
    px0, t0, u0 = out[False]
    px1, t1, u1 = out[True]
    assert len(t0) == 6 and t0 == t1 and u0 == u1
    np.testing.assert_array_equal(px0, px1)


def test_the_shape_draw_is_generator_choice():
    """draw_placement picks the shape with ``integers(0, n)``: the same draw as
    ``Generator.choice(shapes)``, so seeds give the targets they gave before."""
    shapes = ("cylinder", "cone", "wedge", "sphere", "dome")
    a, b = np.random.default_rng(9), np.random.default_rng(9)
    got = [draw_placement(a, row_span=(0.0, 10.0), range_span_m=(5.0, 50.0), shapes=shapes) for _ in range(500)]
    want = []
    for _ in range(500):
        shape = str(b.choice(shapes))
        want.append((shape, float(b.uniform(0.0, 10.0)), float(b.uniform(5.0, 50.0)), float(b.uniform(0.0, 360.0))))
    assert [(p.shape, p.row, p.range_m, p.heading_deg) for p in got] == want
