"""Triangle meshes of rbgen's shapes, in each shape's body frame.

One function per shape kind returns a `Mesh` (float32 vertices and normals,
uint32 triangles wound counter-clockwise seen from outside); `mesh_for`
picks it by type. The renderer draws every body of one shape as instances of
its mesh, and the USD writer stores the same meshes, so a picture and a USD
file show the same geometry. Flat-faced shapes (boxes, hulls) get one vertex
per face corner so that their faces shade flat; round ones share vertices
so that they shade smooth. A plane is a half-space: its mesh is a square of
a given half size on the boundary, centred on the point of the plane nearest
a given centre, because the renderer sizes it to the scene.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..errors import RbgenError
from ..shapes import Box, Capsule, ConvexHull, Plane, Shape, Sphere

#: segments around a sphere's or capsule's axis, and rings from pole to pole (a sphere
#: of 16 x 10 has 288 triangles: round at a pile's scale, cheap for thousands)
ROUND_SEGMENTS = 16
ROUND_RINGS = 10


@dataclasses.dataclass(frozen=True)
class Mesh:
    """Triangles in a body's frame: ``vertices`` and ``normals`` (V, 3) float32,
    ``triangles`` (T, 3) uint32, counter-clockwise seen from outside."""

    vertices: np.ndarray
    normals: np.ndarray
    triangles: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "vertices", np.ascontiguousarray(self.vertices, np.float32))
        object.__setattr__(self, "normals", np.ascontiguousarray(self.normals, np.float32))
        object.__setattr__(self, "triangles", np.ascontiguousarray(self.triangles, np.uint32))


def flat_polygons(vertices, faces, normals) -> Mesh:
    """A mesh of convex polygons (index lists into ``vertices``, counter-clockwise from
    outside), each with its own corners and its ``normals`` row, fan-triangulated."""
    vertices = np.asarray(vertices, float)
    out_v: list[np.ndarray] = []
    out_n: list[Any] = []  # the rows of ``normals``, as given
    tris: list[tuple[int, int, int]] = []
    for polygon, normal in zip(faces, normals):
        start = len(out_v)
        out_v.extend(vertices[list(polygon)])
        out_n.extend([normal] * len(polygon))
        tris.extend((start, start + k, start + k + 1) for k in range(1, len(polygon) - 1))
    return Mesh(np.array(out_v), np.array(out_n), np.array(tris, np.int64).reshape(-1, 3))


def box_mesh(half_extents) -> Mesh:
    """The box [-h, h]: 24 vertices, 12 triangles."""
    h = np.asarray(half_extents, float)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * h
    # corner index = 4 * (x > 0) + 2 * (y > 0) + (z > 0); each face counter-clockwise from outside
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    normals = [(-1, 0, 0), (1, 0, 0), (0, -1, 0), (0, 1, 0), (0, 0, -1), (0, 0, 1)]
    return flat_polygons(corners, faces, normals)


def _round(radius: float, half_height: float, segments: int, rings: int) -> Mesh:
    """A sphere (half_height 0) or a capsule along y: hemispheres pushed apart by
    ``half_height``, the equator ring doubled so that the cylinder between them is straight."""
    rings += rings % 2  # an equator ring
    lat = np.linspace(np.pi / 2, -np.pi / 2, rings + 1)
    if half_height > 0:
        lat = np.insert(lat, rings // 2 + 1, 0.0)
    shift = np.where(np.arange(len(lat)) <= rings // 2, half_height, -half_height)
    lon = np.linspace(0, 2 * np.pi, segments + 1)
    cl, sl = np.cos(lat)[:, None], np.sin(lat)[:, None]
    normals = np.stack(
        [cl * np.cos(lon), np.broadcast_to(sl, (len(lat), len(lon))), -cl * np.sin(lon)], axis=-1
    )
    vertices = normals * radius
    vertices[..., 1] += shift[:, None]
    cols = len(lon)
    tris: list[tuple[int, int, int]] = []
    for r in range(len(lat) - 1):
        for s in range(segments):
            a, b = r * cols + s, (r + 1) * cols + s
            tris.append((a, b, b + 1))
            tris.append((a, b + 1, a + 1))
    triangles = np.array(tris)
    # drop the triangles collapsed at the poles (both their top or bottom corners coincide)
    v = vertices.reshape(-1, 3)
    area = np.linalg.norm(
        np.cross(v[triangles[:, 1]] - v[triangles[:, 0]], v[triangles[:, 2]] - v[triangles[:, 0]]),
        axis=1,
    )
    return Mesh(v, normals.reshape(-1, 3), triangles[area > 1e-12 * radius * radius])


def sphere_mesh(radius: float, segments: int = ROUND_SEGMENTS, rings: int = ROUND_RINGS) -> Mesh:
    """A UV sphere of ``radius`` about the origin, smooth normals."""
    return _round(float(radius), 0.0, segments, rings)


def capsule_mesh(
    radius: float, half_height: float, segments: int = ROUND_SEGMENTS, rings: int = ROUND_RINGS
) -> Mesh:
    """A capsule along the body's y axis: the segment from -half_height to +half_height
    swept by a sphere of ``radius`` (the narrowphase's convention)."""
    return _round(float(radius), float(half_height), segments, rings)


def hull_mesh(shape: ConvexHull) -> Mesh:
    """A cooked hull's polygons in its principal (body) frame, flat normals."""
    cooked = shape.cooked()
    return flat_polygons(cooked.vertices, cooked.faces, cooked.planes[:, :3])


def plane_mesh(normal, offset: float, half_size: float, centre=(0.0, 0.0, 0.0)) -> Mesh:
    """The square of half size ``half_size`` on the plane n.x = offset, centred on the
    plane's point nearest ``centre``, facing along ``normal`` (the half-space's outside)."""
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    c = np.asarray(centre, float)
    c = c - (n @ c - float(offset)) * n
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    w = np.cross(u, n)  # (w, u, n) right-handed: w x u = n
    s = float(half_size)
    corners = [c - s * w - s * u, c + s * w - s * u, c + s * w + s * u, c - s * w + s * u]
    return flat_polygons(corners, [(0, 1, 2, 3)], [n])


def triangle_mesh(shape) -> Mesh:
    """A `rbgen.TriangleMesh` as it is (two-sided in the World; drawn from its front),
    its vertices shading smooth (area-weighted normals)."""
    vertices = np.asarray(shape.vertices, np.float64)
    triangles = np.asarray(shape.triangles, np.int64)
    p = vertices[triangles]
    face = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, triangles[:, k], face)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.where(length > 0, normals / np.maximum(length, 1e-30), (0.0, 1.0, 0.0))
    return Mesh(vertices, normals, triangles)


def compound_mesh(shape) -> Mesh:
    """A `rbgen.Compound`: its children's meshes, placed."""
    from ..compound import _rotation

    vertices, normals, triangles, start = [], [], [], 0
    for child, position, orientation in zip(shape.children, shape.positions, shape.orientations):
        mesh = mesh_for(child)
        r = _rotation(orientation)
        vertices.append(mesh.vertices @ r.T + position)
        normals.append(mesh.normals @ r.T)
        triangles.append(mesh.triangles.astype(np.int64) + start)
        start += len(mesh.vertices)
    return Mesh(np.concatenate(vertices), np.concatenate(normals), np.concatenate(triangles))


def mesh_for(shape: Shape, plane_half_size: float = 100.0, plane_centre=(0.0, 0.0, 0.0)) -> Mesh:
    """The mesh of any rbgen shape (a plane as a square; see `plane_mesh`)."""
    from ..compound import Compound
    from ..mesh import TriangleMesh

    if isinstance(shape, TriangleMesh):
        return triangle_mesh(shape)
    if isinstance(shape, Compound):
        return compound_mesh(shape)
    if isinstance(shape, Box):
        return box_mesh(shape.half_extents)
    if isinstance(shape, Sphere):
        return sphere_mesh(shape.radius)
    if isinstance(shape, Capsule):
        return capsule_mesh(shape.radius, shape.half_height)
    if isinstance(shape, ConvexHull):
        return hull_mesh(shape)
    if isinstance(shape, Plane):
        return plane_mesh(shape.normal, shape.offset, plane_half_size, plane_centre)
    raise RbgenError(
        f"no mesh for shape {type(shape).__name__}; drawable: Sphere, Box, "
        f"Capsule, ConvexHull, Plane, TriangleMesh, Compound"
    )


def local_bounds(shape: Shape) -> tuple[np.ndarray, np.ndarray] | None:
    """(lower, upper) of a shape in its body frame; None for a plane (unbounded)."""
    if isinstance(shape, Plane):
        return None
    if isinstance(shape, Sphere):
        r = np.full(3, shape.radius)
        return -r, r
    if isinstance(shape, Capsule):
        r = np.array([shape.radius, shape.radius + shape.half_height, shape.radius])
        return -r, r
    v = np.asarray(mesh_for(shape).vertices, float)
    return v.min(axis=0), v.max(axis=0)
