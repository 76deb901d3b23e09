"""Collision shapes and their packing into device arrays.

Shapes are immutable host objects in their local frame. `ShapeTable` packs the
shapes a world uses into the `Shape` layout plus the shared hull vertex array,
deduplicating identical shapes so that 100k boxes of one size share one entry.
"""
from __future__ import annotations

import numpy as np

from . import layouts
from .errors import RbgenError


def _finite_vector(value, n: int, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise RbgenError(f"{what} must be {n} finite numbers, got {value!r}")
    return arr


class Shape:
    """Base class; subclasses set ``type_code`` and fill `pack`."""

    type_code: int = -1
    type_name: str = "shape"

    def pack(self, record: np.void, hull_vertices: list) -> None:
        raise NotImplementedError

    def key(self) -> tuple:
        """Identity for deduplication in a `ShapeTable`."""
        raise NotImplementedError

    def local_vertices(self) -> np.ndarray:
        """Vertices whose convex hull is the shape (boxes, hulls); tests use it."""
        raise RbgenError(f"{self.type_name} has no vertex representation")


class Sphere(Shape):
    type_code = layouts.SHAPE_SPHERE
    type_name = "sphere"

    def __init__(self, radius: float):
        radius = float(radius)
        if not np.isfinite(radius) or radius <= 0:
            raise RbgenError(f"Sphere radius must be a positive finite number, got {radius!r}")
        self.radius = radius

    def pack(self, record, hull_vertices):
        record["extents"] = (self.radius, 0, 0, 0)

    def key(self):
        return ("sphere", self.radius)


class Box(Shape):
    type_code = layouts.SHAPE_BOX
    type_name = "box"

    def __init__(self, half_extents):
        he = _finite_vector(half_extents, 3, "Box half_extents")
        if np.any(he <= 0):
            raise RbgenError(f"Box half_extents must all be positive, got {tuple(he)}")
        self.half_extents = he

    def pack(self, record, hull_vertices):
        record["extents"] = (*self.half_extents, 0)

    def key(self):
        return ("box", *self.half_extents)

    def local_vertices(self):
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
        return signs * self.half_extents


class Capsule(Shape):
    type_code = layouts.SHAPE_CAPSULE
    type_name = "capsule"

    def __init__(self, radius: float, half_height: float):
        if not (np.isfinite(radius) and radius > 0 and np.isfinite(half_height) and half_height >= 0):
            raise RbgenError(f"Capsule needs radius > 0 and half_height >= 0, got "
                             f"radius={radius!r}, half_height={half_height!r}")
        self.radius, self.half_height = float(radius), float(half_height)

    def pack(self, record, hull_vertices):
        record["extents"] = (self.radius, self.half_height, 0, 0)

    def key(self):
        return ("capsule", self.radius, self.half_height)


class ConvexHull(Shape):
    """Convex hull of a point cloud (vertices only here; cooking adds faces)."""

    type_code = layouts.SHAPE_HULL
    type_name = "convex hull"

    def __init__(self, points):
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 4 or not np.all(np.isfinite(pts)):
            raise RbgenError("ConvexHull needs at least 4 finite 3-D points, got array of shape "
                             f"{pts.shape}")
        from scipy.spatial import ConvexHull as _QHull, QhullError
        try:
            qhull = _QHull(pts)
        except QhullError as err:
            raise RbgenError(f"ConvexHull points are degenerate (coplanar or collinear): {err}") from None
        self.vertices = pts[qhull.vertices]

    def pack(self, record, hull_vertices):
        record["vertex_offset"] = sum(len(v) for v in hull_vertices)
        record["vertex_count"] = len(self.vertices)
        hull_vertices.append(self.vertices)

    def key(self):
        return ("hull", self.vertices.tobytes())

    def local_vertices(self):
        return self.vertices


class Plane(Shape):
    """Static half-space n.x <= offset (solid below); the normal is normalised."""

    type_code = layouts.SHAPE_PLANE
    type_name = "plane"

    def __init__(self, normal=(0, 1, 0), offset: float = 0.0):
        n = _finite_vector(normal, 3, "Plane normal")
        length = np.linalg.norm(n)
        if length < 1e-12:
            raise RbgenError("Plane normal must not be zero")
        if not np.isfinite(offset):
            raise RbgenError(f"Plane offset must be finite, got {offset!r}")
        self.normal, self.offset = n / length, float(offset)

    def pack(self, record, hull_vertices):
        record["extents"] = (*self.normal, self.offset)

    def key(self):
        return ("plane", *self.normal, self.offset)


class ShapeTable:
    """The shapes of one world, packed for the device and deduplicated."""

    def __init__(self):
        self.shapes: list[Shape] = []
        self._index: dict[tuple, int] = {}

    def add(self, shape: Shape) -> int:
        if not isinstance(shape, Shape):
            raise RbgenError(f"expected an rbgen shape, got {type(shape).__name__}")
        key = shape.key()
        if key not in self._index:
            self._index[key] = len(self.shapes)
            self.shapes.append(shape)
        return self._index[key]

    def type_names(self) -> tuple[str, ...]:
        """Template names of the shape types present, e.g. ("box", "plane")."""
        names = {Sphere: "sphere", Box: "box", Capsule: "capsule", ConvexHull: "hull", Plane: "plane"}
        return tuple(sorted({names[type(s)] for s in self.shapes}))

    def pack(self) -> tuple[np.ndarray, np.ndarray]:
        """(Shape records, hull vertices as float4; at least one of each for OpenCL)."""
        records = layouts.SHAPE.zeros(max(1, len(self.shapes)))
        hull_vertices: list[np.ndarray] = []
        for i, shape in enumerate(self.shapes):
            records[i]["type"] = shape.type_code
            shape.pack(records[i], hull_vertices)
        verts = np.zeros((max(1, sum(len(v) for v in hull_vertices)), 4), np.float32)
        if hull_vertices:
            verts[: sum(len(v) for v in hull_vertices), :3] = np.concatenate(hull_vertices)
        return records, verts
