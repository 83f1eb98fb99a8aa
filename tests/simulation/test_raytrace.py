"""Ray tracer (SPEC section 4) against closed forms and a slow 3-D Moeller-Trumbore reference."""

from __future__ import annotations

import math

import numpy as np
import pytest

from atr_node.errors import GeometryError
from atr_node.simulation.meshes import Mesh, box, builtin_mesh, place
from atr_node.simulation.raytrace import ENGINES, trace, trace_window

H = 14.0
DR = DX = 0.1
GRID = dict(range0_m=0.0, dr_m=DR, dx_m=DX, rows=120, cols=1200)


def reference_trace(mesh: Mesh, *, altitude_m: float, k: int, rows: int, cols: int):
    """Obvious per-ray 3-D Moeller-Trumbore over every triangle, in float64 (slow)."""
    tri = mesh.triangles_m
    p_shadow = np.zeros((rows, cols))
    echo = np.zeros((rows, cols))
    lo, hi = mesh.bounds_m
    i0, i1 = max(int(lo[0] / DX) - 2, 0), min(int(hi[0] / DX) + 3, rows)
    j1 = min(int(hi[1] * altitude_m / (altitude_m - min(hi[2], altitude_m - 1e-3)) / DR) + 3, cols)
    for i in range(i0, i1):
        for a in range(k):
            x = (i - 0.5 + (a + 0.5) / k) * DX
            for j in range(0, j1):
                for b in range(k):
                    y = (j - 0.5 + (b + 0.5) / k) * DR
                    if y <= 0:
                        continue
                    s = np.array([x, 0.0, altitude_m])
                    d = np.array([x, y, 0.0]) - s
                    # Moeller-Trumbore, vectorised over the triangles only.
                    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
                    n = np.cross(e1, e2)
                    nn = np.linalg.norm(n, axis=1)
                    p = np.cross(d, e2)
                    det = np.einsum("ij,ij->i", e1, p)
                    ok = (nn > 2e-12) & (np.abs(det) >= 1e-12 * np.linalg.norm(d) * nn)
                    det = np.where(ok, det, 1.0)
                    tv = s - tri[:, 0]
                    u = np.einsum("ij,ij->i", tv, p) / det
                    q = np.cross(tv, e1)
                    v = (q @ d) / det
                    t = np.einsum("ij,ij->i", e2, q) / det
                    ok &= (u >= -1e-12) & (v >= -1e-12) & (u + v <= 1 + 1e-12) & (t > 0) & (t < 1 - 1e-9)
                    best, nrm = math.inf, None
                    if ok.any():
                        m = int(np.argmin(np.where(ok, t, np.inf)))
                        best, nrm = t[m], n[m] / nn[m]
                    if best < math.inf:
                        p_shadow[i, j] += 1.0 / (k * k)
                        dn = d / np.linalg.norm(d)
                        slant = best * np.linalg.norm(d)
                        g = math.sqrt(max(slant ** 2 - altitude_m ** 2, 0.0))
                        jj = int(math.floor((g + DR / 2) / DR))
                        if 0 <= jj < cols:
                            echo[i, jj] += abs(nrm @ dn) / (k * k)
    return p_shadow, echo


def full(sig, rows, cols):
    ps, ec = np.zeros((rows, cols)), np.zeros((rows, cols))
    r0, r1, c0, c1 = sig.footprint
    ps[r0:r1, c0:c1] = sig.p_shadow
    ec[r0:r1, c0:c1] = sig.echo
    return ps, ec


@pytest.mark.parametrize("shape,heading,burial", [("cylinder", 30.0, 0.0), ("sphere", 0.0, 0.15), ("wedge", 75.0, 0.0)])
def test_matches_3d_reference(shape, heading, burial):
    m = place(builtin_mesh(shape, segments=8) if shape != "wedge" else builtin_mesh(shape), along_m=2.0,
              range_m=6.0, heading_deg=heading, burial_m=burial)
    rows, cols = 40, 120
    sig = trace(m, range0_m=0.0, dr_m=DR, dx_m=DX, rows=rows, cols=cols, altitude_m=5.0, subrays=2)
    ps, ec = full(sig, rows, cols)
    rps, rec = reference_trace(m, altitude_m=5.0, k=2, rows=rows, cols=cols)
    # Ties at exact edges may differ by one sub-ray; nothing else may.
    assert np.abs(ps - rps).max() <= 0.25 + 1e-9
    assert np.abs(ps - rps).sum() <= 0.25 * 4
    assert ps.sum() == pytest.approx(rps.sum(), abs=1.0)
    assert ec.sum() == pytest.approx(rec.sum(), rel=2e-2)
    assert np.abs(ec - rec).sum() <= 0.05 * rec.sum()  # same pixels, not just the same total


@pytest.mark.parametrize("r", [8.0, 25.0, 60.0, 110.0])
@pytest.mark.parametrize("h", [0.3, 0.5, 1.0])
@pytest.mark.parametrize("engine", ENGINES)
def test_box_shadow_length_closed_form(r, h, engine):
    """SPEC section 4: the shadow of a box of height h at range r is h r / (H - h) within a pixel."""
    width = 1.0
    m = place(box(3.0, width, h), along_m=6.0, range_m=r, heading_deg=0.0)
    sig = trace(m, altitude_m=H, subrays=4, engine=engine, **GRID)
    ps, _ = full(sig, GRID["rows"], GRID["cols"])
    far = r + width / 2  # the box's far edge casts the shadow
    cols = np.arange(GRID["cols"]) * DR
    length = ps[60, cols > far].sum() * DR
    assert length == pytest.approx(h * far / (H - h), abs=DR)


@pytest.mark.parametrize("engine", ENGINES)
def test_box_taller_than_sensor_shadows_to_the_end(engine):
    m = place(box(2.0, 1.0, 20.0), along_m=6.0, range_m=30.0)
    sig = trace(m, altitude_m=H, subrays=1, engine=engine, **GRID)
    assert sig.footprint[3] == GRID["cols"]
    ps, _ = full(sig, GRID["rows"], GRID["cols"])
    assert ps[60, 400:].min() == 1.0


def test_outside_swath_or_tile_changes_nothing():
    """No window: the trace is empty before any engine runs (so one engine tests both)."""
    for m in (place(box(), along_m=6.0, range_m=200.0),       # beyond the last column
              place(box(), along_m=-30.0, range_m=30.0),      # before the first row
              place(box(), along_m=6.0, range_m=-20.0),       # the other side of the track
              place(box(2, 1, 0.3), along_m=6.0, range_m=30.0, burial_m=0.5)):  # fully buried
        assert trace_window(m, altitude_m=H, **GRID) is None
        sig = trace(m, altitude_m=H, subrays=2, **GRID)
        assert sig.empty or (sig.p_shadow.max() == 0 and sig.echo.max() == 0)


@pytest.mark.parametrize("engine", ENGINES)
def test_flipped_normals_and_degenerate_triangles_are_harmless(engine):
    m = place(builtin_mesh("cylinder"), along_m=6.0, range_m=30.0, heading_deg=40.0)
    ref = trace(m, altitude_m=H, subrays=2, engine=engine, **GRID)
    flipped = trace(m.flipped(), altitude_m=H, subrays=2, engine=engine, **GRID)
    np.testing.assert_array_equal(ref.p_shadow, flipped.p_shadow)
    np.testing.assert_allclose(ref.echo, flipped.echo, rtol=1e-6)
    v = m.vertices_m
    extra = np.vstack([v, v[:1] + [0, 0, 0], v[:1] + [1e-20, 0, 0]])
    n = len(v)
    faces = np.vstack([m.faces, [[0, 0, 1], [n, n + 1, 0], [0, 1, 0]]])  # repeated and collinear vertices
    degen = trace(Mesh(extra, faces), altitude_m=H, subrays=2, engine=engine, **GRID)
    np.testing.assert_array_equal(ref.p_shadow, degen.p_shadow)
    np.testing.assert_allclose(ref.echo, degen.echo, rtol=1e-6)
    assert np.all(np.isfinite(degen.echo))


@pytest.mark.parametrize("engine", ENGINES)
def test_rays_parallel_to_facets_and_grazing(engine):
    """SPEC section 8: a box whose end caps lie exactly in sub-ray planes (rays parallel to
    and inside the facets), and a ramp facet along the ray direction, give finite maps
    bounded like any other."""
    # End caps at x = 5.95 and 8.05: sub-ray planes of k = 2 are at (i +- 0.25) * 0.1 -> 5.95 is one.
    m = Mesh(box(2.1, 1.0, 0.5).vertices_m + [7.0, 30.0, 0.0], box().faces)
    sig = trace(m, altitude_m=H, subrays=2, engine=engine, **GRID)
    assert np.all(np.isfinite(sig.p_shadow)) and np.all(np.isfinite(sig.echo))
    assert 0.0 <= sig.p_shadow.min() and sig.p_shadow.max() <= 1.0
    # A thin ramp whose slope follows the ray to the seabed point at y = 20: grazing angle 0.
    y0, y1 = 19.0, 20.0
    z0 = H * (1 - y0 / y1)  # on the ray from (0, H) to (y1, 0)
    v = np.array([[5.0, y0, z0], [7.0, y0, z0], [5.0, y1, 0.0], [7.0, y1, 0.0]])
    ramp = Mesh(v, np.array([[0, 1, 2], [1, 3, 2]]))
    sig = trace(ramp, altitude_m=H, subrays=1, engine=engine, **GRID)
    assert np.all(np.isfinite(sig.echo)) and sig.echo.max() < 1e-6  # zero grazing returns nothing
    # Grazing angle -> 0 overall: a target 500 m away from a sonar 1 m up.
    far = place(builtin_mesh("cylinder"), along_m=6.0, range_m=500.0, heading_deg=10.0)
    sig = trace(far, range0_m=490.0, dr_m=DR, dx_m=DX, rows=120, cols=400, altitude_m=1.0, subrays=2,
                engine=engine)
    assert np.all(np.isfinite(sig.echo)) and sig.p_shadow.max() == 1.0


@pytest.mark.parametrize("engine", ENGINES)
def test_layover_and_echo_grows_with_visible_area(engine):
    tall = place(box(2.0, 1.0, 3.0), along_m=6.0, range_m=20.0)
    sig = trace(tall, altitude_m=H, subrays=2, engine=engine, **GRID)
    _, ec = full(sig, GRID["rows"], GRID["cols"])
    front = int(round((20.0 - 0.5) / DR))
    # The top of the front face (z = 3) is at slant sqrt(19.5^2 + 11^2): ground sqrt(R^2 - H^2) < 19.5 m.
    expected = math.sqrt(19.5 ** 2 + (H - 3) ** 2 - H ** 2)
    first = int(np.flatnonzero(ec[60] > 0)[0])
    assert first < front
    assert first * DR == pytest.approx(expected, abs=DR)
    kw = dict(altitude_m=H, subrays=2, engine=engine, **GRID)
    e1 = trace(place(box(1.0, 1.0, 0.5), along_m=6.0, range_m=30.0), **kw).echo.sum()
    e2 = trace(place(box(2.0, 1.0, 0.5), along_m=6.0, range_m=30.0), **kw).echo.sum()
    assert e2 / e1 == pytest.approx(2.0, rel=0.1)


def test_bad_geometry_is_an_error():
    m = place(box(), along_m=6.0, range_m=30.0)
    for kw in (dict(altitude_m=0.0), dict(altitude_m=float("nan")), dict(altitude_m=H, subrays=0)):
        with pytest.raises(GeometryError):
            trace(m, **{**GRID, **kw})
