"""The signature engine (issue 19): :func:`trace_many` against the dense tracer it replaced
(``dense_trace.py``, every plane x segment x ray tested) and against a fine trace.

* ``engine="rays"`` gives the dense tracer's maps bit for bit, one target or a tile's batch;
* ``engine="strips"`` integrates each sub-row plane exactly along range: against the fine
  trace (16 x 16 sub-rays) it is closer than rays at the same k, and targets it cannot
  integrate exactly (open meshes, taller than the sensor) are traced by rays.
"""

from __future__ import annotations

import numpy as np
import pytest

from atr_node.config import PopulationSettings
from atr_node.errors import GeometryError
from atr_node.simulation.inject import _mesh_for, draw_placement
from atr_node.simulation.meshes import Mesh, box, builtin_mesh, place
from atr_node.simulation.raytrace import trace_many, trace_window
from atr_node.simulation.window import surfaces

from .dense_trace import dense_trace, l1_error

DR = DX = 0.1
RANGE0 = 5.0
ROWS, COLS = 300, 700


def _targets(seed: int, n: int) -> list[Mesh]:
    """Varied targets (size, tilt, burial), some across the tile's edges or beyond them."""
    rng = np.random.default_rng(seed)
    pop = PopulationSettings(mode="varied")
    out = []
    for _ in range(n):
        p = draw_placement(rng, row_span=(-15.0, ROWS + 15.0), range_span_m=(RANGE0 - 2.0, RANGE0 + COLS * DR + 3.0),
                           population=pop)
        out.append(place(_mesh_for(p), along_m=p.row * DX, range_m=p.range_m, heading_deg=p.heading_deg,
                         burial_m=p.burial_m))
    return out


def _geo(H: float) -> dict:
    return dict(range0_m=RANGE0, dr_m=DR, dx_m=DX, altitude_m=H)


def _windows(meshes: list[Mesh], H: float) -> list:
    return [trace_window(m, rows=ROWS, cols=COLS, **_geo(H)) for m in meshes]


@pytest.mark.parametrize("H", [14.0, 2.5])
@pytest.mark.parametrize("k", [1, 2, 3])
def test_rays_are_the_dense_tracer_bit_for_bit(H, k):
    meshes = _targets(int(H * 10) + k, 60)
    sigs = trace_many(_windows(meshes, H), subrays=k, engine="rays", **_geo(H))
    traced = 0
    for m, sig in zip(meshes, sigs):
        ref = dense_trace(m, rows=ROWS, cols=COLS, subrays=k, **_geo(H))
        assert sig.footprint == ref.footprint
        np.testing.assert_array_equal(sig.p_shadow, ref.p_shadow)
        np.testing.assert_array_equal(sig.echo, ref.echo)
        traced += not ref.empty and ref.p_shadow.max() > 0
    assert traced > 40


@pytest.mark.parametrize("engine", ["rays", "strips"])
def test_a_batch_is_its_targets_one_by_one(engine):
    meshes = _targets(7, 40)
    ws = _windows(meshes, 9.0)
    batch = trace_many(ws, subrays=2, engine=engine, **_geo(9.0))
    for w, sig in zip(ws, batch):
        alone = trace_many([w], subrays=2, engine=engine, **_geo(9.0))[0]
        assert alone.footprint == sig.footprint
        np.testing.assert_array_equal(alone.p_shadow, sig.p_shadow)
        np.testing.assert_array_equal(alone.echo, sig.echo)
    assert trace_many([], subrays=2, engine=engine, **_geo(9.0)) == []
    assert trace_many([None], subrays=2, engine=engine, **_geo(9.0))[0].empty


@pytest.mark.parametrize("H", [14.0, 3.0])
def test_strips_are_closer_to_the_fine_trace_than_rays(H):
    meshes = _targets(21 + int(H), 30)
    ws = _windows(meshes, H)
    fine = [dense_trace(m, rows=ROWS, cols=COLS, subrays=16, **_geo(H)) for m in meshes]
    rays = l1_error(trace_many(ws, subrays=2, engine="rays", **_geo(H)), fine)
    strips = l1_error(trace_many(ws, subrays=2, engine="strips", **_geo(H)), fine)
    assert strips[0] < rays[0] and strips[1] < rays[1], (strips, rays)
    assert strips[0] < 0.04 and strips[1] < 0.06, strips
    # and they converge with k: 4 strips a row against 16 x 16 rays
    s4 = l1_error(trace_many(ws, subrays=4, engine="strips", **_geo(H)), fine)
    assert s4[0] < strips[0] and s4[1] < strips[1] and s4[0] < 0.02 and s4[1] < 0.03, s4


def test_strips_conserve_the_echo_of_a_plate_facing_the_sensor():
    """A flat box top seen at range: the echo total is the integral of |n . d| over the rays
    that meet it, which the strips compute in closed form (n = z up: sin of the grazing angle
    H / sqrt(p^2 + H^2)), per metre of seabed times the rows the box spans."""
    H, L, r0, r1 = 10.0, 2.0, 30.0, 31.0
    m = place(box(L, r1 - r0, 0.05), along_m=10.0, range_m=(r0 + r1) / 2)
    w = trace_window(m, rows=ROWS, cols=COLS, **_geo(H))
    sig = trace_many([w], subrays=1, engine="strips", **_geo(H))[0]
    # The top face z = h, y in [r0, r1] shadows the seabed points from r0 H/(H - h) to r1 H/(H - h);
    # the front face (y = r0, z in [0, h]) the points from r0 to r0 H/(H - h).
    h = 0.05
    p0, p1 = r0 * H / (H - h), r1 * H / (H - h)
    top = H * (np.arcsinh(p1 / H) - np.arcsinh(p0 / H))            # integral of H / sqrt(p^2 + H^2)
    front = np.hypot(p0, H) - np.hypot(r0, H)                      # integral of p / sqrt(p^2 + H^2)
    rows = L / DX
    assert sig.echo.sum() == pytest.approx((top + front) * rows / DR, rel=1e-6)  # float32 maps
    assert sig.p_shadow.sum() == pytest.approx((p1 - r0) * rows / DR, rel=1e-6)


def test_strips_leave_what_they_cannot_integrate_to_rays():
    """An open mesh (one plate) and a box taller than the sensor: strips give the rays' maps."""
    H = 8.0
    plate = Mesh(np.array([[5.0, 20.0, 0.2], [7.0, 20.0, 0.2], [5.0, 21.0, 1.0], [7.0, 21.0, 1.0]]),
                 np.array([[0, 1, 2], [1, 3, 2]]))
    tall = place(box(2.0, 1.0, 12.0), along_m=10.0, range_m=40.0)
    cyl = place(builtin_mesh("cylinder"), along_m=20.0, range_m=30.0, heading_deg=20.0)
    ws = _windows([plate, tall, cyl], H)
    assert surfaces(ws)[3].tolist() == [0, 1, 1]
    rays = trace_many(ws, subrays=2, engine="rays", **_geo(H))
    strips = trace_many(ws, subrays=2, engine="strips", **_geo(H))
    for i in (0, 1):
        np.testing.assert_array_equal(rays[i].p_shadow, strips[i].p_shadow)
        np.testing.assert_array_equal(rays[i].echo, strips[i].echo)
    assert not np.array_equal(rays[2].echo, strips[2].echo)  # the cylinder is integrated


def test_the_engine_is_checked():
    with pytest.raises(GeometryError, match="engine"):
        trace_many([], subrays=2, engine="fast", **_geo(9.0))
