"""Target meshes: built-in shapes are closed with outward normals; STL/OBJ loading; placement."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from atr_node.errors import GeometryError
from atr_node.simulation.meshes import BUILTIN_SHAPES, Mesh, box, builtin_mesh, cylinder, load_mesh, place, sphere


def signed_volume(m: Mesh) -> float:
    """Divergence theorem: sum of v0 . (v1 x v2) / 6, positive for a closed outward mesh."""
    t = m.triangles_m
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)


@pytest.mark.parametrize("shape", BUILTIN_SHAPES)
def test_builtin_shapes_closed_outward_on_seabed(shape):
    m = builtin_mesh(shape)
    lo, hi = m.bounds_m
    assert lo[2] == pytest.approx(0.0, abs=1e-12)  # resting on the seabed
    assert abs(lo[0] + hi[0]) < 1e-9 and abs(lo[1] + hi[1]) < 1e-9  # centred
    # every edge used exactly twice, in opposite directions: closed and consistently wound
    e = np.concatenate([m.faces[:, [0, 1]], m.faces[:, [1, 2]], m.faces[:, [2, 0]]])
    fwd = {tuple(x) for x in e.tolist()}
    assert len(fwd) == len(e)
    assert all((b, a) in fwd for a, b in fwd)
    assert signed_volume(m) > 0


def test_volumes_against_closed_forms():
    # Polygonal approximations converge to the closed forms from below.
    b = box(2.0, 1.0, 0.5)
    assert signed_volume(b) == pytest.approx(1.0, rel=1e-12)
    c = cylinder(2.0, 0.25, segments=64)
    assert signed_volume(c) == pytest.approx(np.pi * 0.25 ** 2 * 2.0, rel=5e-3)
    s = sphere(0.5, segments=64)
    assert signed_volume(s) == pytest.approx(4 / 3 * np.pi * 0.125, rel=1e-2)
    w = builtin_mesh("wedge")
    assert signed_volume(w) == pytest.approx(0.5 * 1.0 * 0.5 * 2.0, rel=1e-12)


def test_place_rotates_and_buries():
    m = place(box(2.0, 1.0, 0.5), along_m=10.0, range_m=30.0, heading_deg=90.0, burial_m=0.2)
    lo, hi = m.bounds_m
    np.testing.assert_allclose(lo, [9.5, 29.0, -0.2], atol=1e-12)
    np.testing.assert_allclose(hi, [10.5, 31.0, 0.3], atol=1e-12)
    with pytest.raises(GeometryError, match="burial"):
        place(box(), along_m=0, range_m=1, burial_m=-1)


def test_flipped_reverses_volume():
    m = cylinder()
    assert signed_volume(m.flipped()) == pytest.approx(-signed_volume(m))


def test_load_stl_binary_ascii_and_obj(tmp_path):
    b = box(1.0, 1.0, 1.0)
    tri = b.triangles_m.astype(np.float32)
    # binary STL: 80-byte header, uint32 count, 50 bytes per triangle
    data = b"\0" * 80 + struct.pack("<I", len(tri))
    for t in tri:
        data += struct.pack("<3f", 0, 0, 0) + t.tobytes() + b"\0\0"
    (tmp_path / "b.stl").write_bytes(data)
    lines = ["solid x"]
    for t in tri:
        lines += ["facet normal 0 0 0", "outer loop"] + [f"vertex {v[0]} {v[1]} {v[2]}" for v in t]
        lines += ["endloop", "endfacet"]
    (tmp_path / "a.stl").write_text("\n".join(lines + ["endsolid x"]))
    obj = ["v " + " ".join(map(str, v)) for v in b.vertices_m] + \
          ["f " + " ".join(f"{i + 1}/1/1" for i in f) for f in b.faces]
    (tmp_path / "b.obj").write_text("\n".join(obj))
    for name in ("b.stl", "a.stl", "b.obj"):
        m = load_mesh(tmp_path / name)
        assert len(m.faces) == 12
        assert abs(signed_volume(m)) == pytest.approx(1.0, rel=1e-6)
        lo, hi = m.bounds_m
        assert lo[2] == pytest.approx(0.0, abs=1e-6)
    # quads are fanned into triangles
    (tmp_path / "q.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    assert len(load_mesh(tmp_path / "q.obj").faces) == 2


def test_bad_mesh_files_say_where(tmp_path):
    with pytest.raises(GeometryError, match="not found"):
        load_mesh(tmp_path / "none.stl")
    (tmp_path / "x.ply").write_text("ply")
    with pytest.raises(GeometryError, match="unknown type"):
        load_mesh(tmp_path / "x.ply")
    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 zero\n")
    with pytest.raises(GeometryError, match="line 2"):
        load_mesh(tmp_path / "bad.obj")
    (tmp_path / "idx.obj").write_text("v 0 0 0\nf 1 2 3\n")
    with pytest.raises(GeometryError, match="vertex"):
        load_mesh(tmp_path / "idx.obj")
    (tmp_path / "bad.stl").write_bytes(b"garbage that is not stl")
    with pytest.raises(GeometryError, match="STL"):
        load_mesh(tmp_path / "bad.stl")
    with pytest.raises(GeometryError, match="unknown target shape"):
        builtin_mesh("torpedo")


def test_copies_share_the_checked_faces_and_bounds_skip_unused_vertices():
    """Scaled and tilted copies share their faces array, whose check and used-vertex set are
    worked out once (``meshes._used_vertices``); the checks still hold per vertex count, and
    bounds ignore vertices no face uses, as ``np.unique`` over the faces does."""
    m = builtin_mesh("cone")
    for copy in (m.scaled(1.3, 0.8, 1.1), m.tilted(roll_deg=12.0, pitch_deg=-7.0)):
        assert copy.faces is m.faces
        used = copy.vertices_m[np.unique(copy.faces)]
        np.testing.assert_array_equal(copy.bounds_m[0], used.min(axis=0))
        np.testing.assert_array_equal(copy.bounds_m[1], used.max(axis=0))
    # a stray vertex far away that no face uses does not count
    stray = Mesh(np.vstack([m.vertices_m, [[50.0, 50.0, 50.0]]]), m.faces, "stray")
    np.testing.assert_array_equal(stray.bounds_m[1], m.bounds_m[1])
    # the same faces with too few vertices are still refused, after they were accepted above
    with pytest.raises(GeometryError, match="outside"):
        Mesh(m.vertices_m[:3], m.faces, "short")
