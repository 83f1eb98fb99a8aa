"""Target meshes: built-in shapes, mesh files (STL, OBJ) and placement on the seabed.

A :class:`Mesh` is a triangle soup in a local target frame (metres): ``x`` along the
target's own axis, ``y`` across it, ``z`` up, with the base resting on ``z = 0`` and the
target centred on ``x = y = 0``. :func:`place` turns it into the sensor frame of a tile
(``x`` along-track, ``y`` ground range away from the sonar, ``z`` up from the seabed) with a
heading and a burial depth (SPEC section 4).

The built-ins (cylinder, truncated cone, wedge, sphere, box) are generated here with outward
normals; the ray tracer does not rely on the winding (a flipped or degenerate facet is
harmless), so any STL or OBJ file loads as it is.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import GeometryError

BUILTIN_SHAPES: tuple[str, ...] = ("cylinder", "cone", "wedge", "sphere", "box")
"""Shapes :func:`builtin_mesh` makes; ``cone`` is a truncated cone."""


_OUT_OF_RANGE = np.zeros(0, np.int64)
_USED: dict[int, tuple[np.ndarray, int, np.ndarray | None]] = {}
"""id(faces) -> (faces, vertex count, used vertex indices or None for all): the scaled, tilted
and moved copies of a mesh share its faces array, so the calibration's tens of thousands of
drawn targets check and bound them once per shape, not once per draw."""


def _used_vertices(faces: np.ndarray, n_vertices: int) -> np.ndarray | None:
    """The vertex indices the faces use (sorted), None when they use every vertex, or
    :data:`_OUT_OF_RANGE` when a face refers to a vertex outside 0..n_vertices - 1."""
    hit = _USED.get(id(faces))
    if hit is not None and hit[0] is faces and hit[1] == n_vertices:
        return hit[2]
    if faces.size and (faces.min() < 0 or faces.max() >= n_vertices):
        return _OUT_OF_RANGE
    used = np.unique(faces) if faces.size else None
    if used is not None and used.size == n_vertices:
        used = None
    if len(_USED) >= 256:
        _USED.clear()
    _USED[id(faces)] = (faces, n_vertices, used)
    return used


def _bounds(vertices_m: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min xyz, max xyz) over the vertices the faces use (all of them without faces)."""
    used = _used_vertices(faces, len(vertices_m)) if faces.size else None
    pts = vertices_m if used is None else vertices_m[used]
    return pts.min(axis=0), pts.max(axis=0)


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh.

    Attributes
    ----------
    vertices_m : ndarray, shape (n, 3), float64
        Vertex positions (x, y, z) in metres.
    faces : ndarray, shape (m, 3), int64
        Vertex indices of each triangle.
    name : str
        Shape name reported in the truth.
    """

    vertices_m: np.ndarray
    faces: np.ndarray
    name: str = "mesh"

    def __post_init__(self) -> None:
        v = np.ascontiguousarray(self.vertices_m, dtype=np.float64)
        f = np.ascontiguousarray(self.faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3:
            raise GeometryError(f"mesh {self.name!r}: vertices must be (n, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3:
            raise GeometryError(f"mesh {self.name!r}: faces must be (m, 3), got {f.shape}")
        if _used_vertices(f, len(v)) is _OUT_OF_RANGE:
            raise GeometryError(f"mesh {self.name!r}: a face refers to a vertex outside 0..{len(v) - 1}")
        if not np.all(np.isfinite(v)):
            raise GeometryError(f"mesh {self.name!r}: non-finite vertex coordinate")
        object.__setattr__(self, "vertices_m", v)
        object.__setattr__(self, "faces", f)

    @property
    def triangles_m(self) -> np.ndarray:
        """(m, 3, 3) vertex coordinates of every triangle."""
        return self.vertices_m[self.faces]

    @property
    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        """(min xyz, max xyz) over the vertices used by faces."""
        return _bounds(self.vertices_m, self.faces)

    def flipped(self) -> "Mesh":
        """The same mesh with every facet's winding (normal) reversed."""
        return Mesh(self.vertices_m, self.faces[:, ::-1], self.name)

    def transformed(self, *, heading_deg: float = 0.0, x_m: float = 0.0, y_m: float = 0.0,
                    z_m: float = 0.0) -> "Mesh":
        """Rotate by ``heading_deg`` about z (from +x towards +y), then translate."""
        a = math.radians(heading_deg)
        c, s = math.cos(a), math.sin(a)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        v = self.vertices_m @ rot.T + np.array([x_m, y_m, z_m])
        return Mesh(v, self.faces, self.name)

    def scaled(self, x: float = 1.0, y: float = 1.0, z: float = 1.0) -> "Mesh":
        """Stretched by a factor per local axis (length, width, height) about x = y = z = 0,
        so a mesh resting on z = 0 keeps resting on it."""
        if not all(math.isfinite(f) and f > 0 for f in (x, y, z)):
            raise GeometryError(f"mesh {self.name!r}: scale factors must be finite and > 0, got {(x, y, z)}")
        return Mesh(self.vertices_m * np.array([x, y, z]), self.faces, self.name)

    def tilted(self, *, roll_deg: float = 0.0, pitch_deg: float = 0.0) -> "Mesh":
        """Rolled about the local x axis, then pitched about y (right-handed, proper rotations,
        so normals stay outward), and set back down: recentred on x = y = 0 (bounding box)
        with its lowest point on z = 0, as a tilted object rests on a flat seabed."""
        a, b = math.radians(roll_deg), math.radians(pitch_deg)
        ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
        roll = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
        pitch = np.array([[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]])
        v = self.vertices_m @ (pitch @ roll).T
        lo, hi = _bounds(v, self.faces)
        return Mesh(v - [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]], self.faces, self.name)

    @property
    def height_m(self) -> float:
        """Top of the mesh above z = 0 (its height when it rests on z = 0)."""
        return float(self.bounds_m[1][2])


# ----------------------------------------------------------------------------------------
# Built-in shapes (outward normals, base on z = 0, centred on x = y = 0)


def _ring(n: int) -> tuple[np.ndarray, np.ndarray]:
    a = 2.0 * np.pi * np.arange(n) / n
    return np.cos(a), np.sin(a)


def _frustum_x(length_m: float, r0_m: float, r1_m: float, n: int) -> Mesh:
    """A (truncated) cone or cylinder with its axis along x, end radii r0 (x<0) and r1."""
    c, s = _ring(n)
    x0, x1 = -length_m / 2, length_m / 2
    v0 = np.column_stack([np.full(n, x0), r0_m * c, r0_m * s])
    v1 = np.column_stack([np.full(n, x1), r1_m * c, r1_m * s])
    verts = np.vstack([v0, v1, [[x0, 0, 0], [x1, 0, 0]]])
    i = np.arange(n)
    j = (i + 1) % n
    side = np.vstack([np.column_stack([i, j, n + j]), np.column_stack([i, n + j, n + i])])
    cap0 = np.column_stack([np.full(n, 2 * n), j, i])
    cap1 = np.column_stack([np.full(n, 2 * n + 1), n + i, n + j])
    return Mesh(verts, np.vstack([side, cap0, cap1]), "frustum")


def cylinder(length_m: float = 2.0, radius_m: float = 0.25, *, segments: int = 16) -> Mesh:
    """A cylinder lying on the seabed, axis along x (e.g. a Manta-less ground mine)."""
    m = _frustum_x(length_m, radius_m, radius_m, segments)
    return Mesh(m.vertices_m + [0.0, 0.0, radius_m], m.faces, "cylinder")


def truncated_cone(base_radius_m: float = 0.5, top_radius_m: float = 0.2, height_m: float = 0.5, *,
                   segments: int = 16) -> Mesh:
    """A truncated cone standing on its base (a Manta-like bottom mine)."""
    m = _frustum_x(height_m, base_radius_m, top_radius_m, segments)
    # Rotation by -90 deg about y (a proper rotation, so normals stay outward): x -> z.
    x, y, z = m.vertices_m.T
    v = np.column_stack([-z, y, x + height_m / 2])
    return Mesh(v, m.faces, "cone")


def wedge(length_m: float = 2.0, width_m: float = 1.0, height_m: float = 0.5) -> Mesh:
    """A triangular prism (ridge along x) lying on a face: a wedge-shaped target."""
    L, W, h = length_m / 2, width_m / 2, height_m
    v = np.array([[-L, -W, 0], [-L, W, 0], [-L, 0, h], [L, -W, 0], [L, W, 0], [L, 0, h]], dtype=np.float64)
    f = np.array([[0, 2, 1], [3, 4, 5],            # end caps
                  [0, 1, 4], [0, 4, 3],            # bottom
                  [0, 3, 5], [0, 5, 2],            # y < 0 slope
                  [1, 2, 5], [1, 5, 4]])           # y > 0 slope
    return Mesh(v, f, "wedge")


def sphere(radius_m: float = 0.5, *, segments: int = 16) -> Mesh:
    """A UV sphere resting on the seabed."""
    n_lat = max(segments // 2, 3)
    th = np.pi * np.arange(1, n_lat) / n_lat  # polar angles without the poles
    c, s = _ring(segments)
    rings = [np.column_stack([radius_m * np.sin(t) * c, radius_m * np.sin(t) * s,
                              np.full(segments, radius_m * np.cos(t))]) for t in th]
    verts = np.vstack(rings + [[[0, 0, radius_m], [0, 0, -radius_m]]])
    top, bot = len(verts) - 2, len(verts) - 1
    i = np.arange(segments)
    j = (i + 1) % segments
    faces = [np.column_stack([np.full(segments, top), i, j])]
    for k in range(n_lat - 2):
        a, b = k * segments, (k + 1) * segments
        faces += [np.column_stack([a + i, b + i, b + j]), np.column_stack([a + i, b + j, a + j])]
    last = (n_lat - 2) * segments
    faces.append(np.column_stack([np.full(segments, bot), last + j, last + i]))
    return Mesh(verts + [0.0, 0.0, radius_m], np.vstack(faces), "sphere")


def box(length_m: float = 2.0, width_m: float = 1.0, height_m: float = 0.5) -> Mesh:
    """A rectangular box on the seabed (the closed-form shadow test of SPEC section 4)."""
    L, W = length_m / 2, width_m / 2
    v = np.array([[x, y, z] for z in (0.0, height_m) for y in (-W, W) for x in (-L, L)], dtype=np.float64)
    f = np.array([[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
                  [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]])
    return Mesh(v, f, "box")


def builtin_mesh(shape: str, **params: float) -> Mesh:
    """A built-in shape by name (see :data:`BUILTIN_SHAPES`) with its default dimensions."""
    makers = {"cylinder": cylinder, "cone": truncated_cone, "wedge": wedge, "sphere": sphere, "box": box}
    if shape not in makers:
        raise GeometryError(f"unknown target shape {shape!r}; expected one of {list(makers)} or a mesh file")
    return makers[shape](**params)


# ----------------------------------------------------------------------------------------
# Mesh files


def load_mesh(path: str | Path, *, name: str | None = None, scale: float = 1.0) -> Mesh:
    """Read a triangle mesh from an STL (binary or ASCII) or OBJ file.

    The mesh is recentred on x = y = 0 with its lowest point on z = 0. OBJ polygons with more
    than three vertices are fanned into triangles.

    Raises
    ------
    GeometryError
        The file is missing, of an unknown type, or malformed (the message names the line or
        byte offset).
    """
    p = Path(path)
    if not p.is_file():
        raise GeometryError(f"mesh file {p} not found")
    data = p.read_bytes()
    suffix = p.suffix.lower()
    if suffix == ".obj":
        v, f = _parse_obj(data.decode("utf-8", errors="replace"), str(p))
    elif suffix == ".stl":
        v, f = _parse_stl(data, str(p))
    else:
        raise GeometryError(f"mesh file {p}: unknown type {suffix!r}; expected .stl or .obj")
    if len(f) == 0:
        raise GeometryError(f"mesh file {p}: no triangles")
    v = v * scale
    lo, hi = v.min(axis=0), v.max(axis=0)
    v = v - [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]
    return Mesh(v, f, name or p.stem)


def _parse_stl(data: bytes, where: str) -> tuple[np.ndarray, np.ndarray]:
    if len(data) >= 84:
        n = struct.unpack_from("<I", data, 80)[0]
        if len(data) == 84 + 50 * n:
            rec = np.frombuffer(data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]),
                                count=n, offset=84)
            v = rec["v"].reshape(-1, 3).astype(np.float64)
            return v, np.arange(3 * n, dtype=np.int64).reshape(n, 3)
    text = data.decode("ascii", errors="replace")
    if not text.lstrip().startswith("solid"):
        raise GeometryError(f"mesh file {where}: neither binary STL (size does not match the triangle count) "
                            "nor ASCII STL (does not start with 'solid')")
    verts = []
    for k, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if parts and parts[0] == "vertex":
            try:
                verts.append([float(x) for x in parts[1:4]])
            except (ValueError, IndexError):
                raise GeometryError(f"mesh file {where}, line {k}: bad vertex {line.strip()!r}") from None
    if len(verts) % 3:
        raise GeometryError(f"mesh file {where}: {len(verts)} vertices is not a multiple of 3")
    v = np.array(verts, dtype=np.float64).reshape(-1, 3)
    return v, np.arange(len(v), dtype=np.int64).reshape(-1, 3)


def _parse_obj(text: str, where: str) -> tuple[np.ndarray, np.ndarray]:
    verts: list[list[float]] = []
    faces: list[list[int]] = []
    for k, line in enumerate(text.splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        try:
            if parts[0] == "v":
                verts.append([float(x) for x in parts[1:4]])
            elif parts[0] == "f":
                # "f 1/2/3 4 5//6": the vertex index is before the first slash; negatives count back.
                idx = [int(p.split("/")[0]) for p in parts[1:]]
                idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                faces += [[idx[0], idx[t], idx[t + 1]] for t in range(1, len(idx) - 1)]
        except (ValueError, IndexError):
            raise GeometryError(f"mesh file {where}, line {k}: cannot parse {line.strip()!r}") from None
    v = np.array(verts, dtype=np.float64).reshape(-1, 3)
    f = np.array(faces, dtype=np.int64).reshape(-1, 3)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise GeometryError(f"mesh file {where}: a face refers to a vertex that does not exist")
    return v, f


# ----------------------------------------------------------------------------------------
# Placement


def place(mesh: Mesh, *, along_m: float, range_m: float, heading_deg: float = 0.0,
          burial_m: float = 0.0) -> Mesh:
    """The mesh in a tile's sensor frame.

    Parameters
    ----------
    along_m, range_m
        Along-track position and ground range of the target's centre.
    heading_deg
        Angle of the target's x axis from the along-track axis towards increasing range.
    burial_m
        How deep the target is sunk into the seabed (0 = proud); the part below z = 0 is
        invisible to the tracer, whose rays stay above the seabed.
    """
    if burial_m < 0:
        raise GeometryError(f"burial_m must be >= 0, got {burial_m}")
    return mesh.transformed(heading_deg=heading_deg, x_m=along_m, y_m=range_m, z_m=-burial_m)
