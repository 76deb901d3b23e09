"""Collision shapes and their packing into device arrays.

Shapes are immutable host objects in their local frame, which is also their
principal frame of inertia (hulls are re-centred and rotated when cooked; see
`rbgen.hull` and `rbgen.mass`). `ShapeTable` packs the shapes a world uses into
the `Shape` layout plus the shared hull arrays (vertices, faces, face indices,
edge directions), deduplicating identical shapes so that 100k boxes of one
size share one entry. Boxes carry their hull topology too, so every
convex-convex kernel can treat them as hulls.
"""
from __future__ import annotations

import dataclasses
import functools

import numpy as np

from . import hull as hull_cooking
from . import layouts
from . import mass as mass_props
from .errors import RbgenError


def _finite_vector(value, n: int, what: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise RbgenError(f"{what} must be {n} finite numbers, got {value!r}")
    return arr


class Shape:
    """Base class; subclasses set ``type_code`` and fill `pack`.

    A shape is an immutable value: once its constructor has validated it, its
    attributes cannot be set and its arrays are read-only. So one shape object
    may be added to any number of Worlds (each copies it into its own
    `ShapeTable`), and a shape already added cannot change under a World
    behind its back (its dedup key, mass properties and device record would
    disagree). Make a new shape instead of changing one.
    """

    type_code: int = -1
    type_name: str = "shape"

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        init = cls.__dict__.get("__init__")
        if init is None:
            return

        @functools.wraps(init)
        def init_then_freeze(self, *args, **kw):
            init(self, *args, **kw)
            if type(self).__init__ is cls.__init__:  # the outermost constructor has finished
                for value in vars(self).values():
                    if isinstance(value, np.ndarray):
                        value.flags.writeable = False
                object.__setattr__(self, "_frozen", True)

        cls.__init__ = init_then_freeze

    def __setattr__(self, name, value):
        if self.__dict__.get("_frozen", False):
            raise RbgenError(f"{type(self).__name__} shapes are immutable (a World may share "
                             f"this one); make a new shape instead of setting {name!r}")
        object.__setattr__(self, name, value)

    def pack(self, record: np.void, hull_vertices: list) -> None:
        raise NotImplementedError

    def key(self) -> tuple:
        """Identity for deduplication in a `ShapeTable`."""
        raise NotImplementedError

    def local_vertices(self) -> np.ndarray:
        """Vertices whose convex hull is the shape (boxes, hulls); tests use it."""
        raise RbgenError(f"{self.type_name} has no vertex representation")

    def cooked(self) -> "hull_cooking.CookedHull | None":
        """Polygon topology for the convex-convex kernels (boxes and hulls), else None."""
        return None

    def mass_properties(self, density: float | None = None, mass: float | None = None
                        ) -> mass_props.MassProperties:
        """Mass, centre of mass, principal inertia diagonal and principal rotation.

        Give exactly one of ``density`` and ``mass``. The local frame of every
        shape is principal, so ``com`` and ``rotation`` say where that frame
        sits in the frame the shape was described in (identity except for hulls).
        """
        raise RbgenError(f"{self.type_name} has no mass (static only)")

    def _solid(self, volume, unit_inertia, density, mass, com=(0.0, 0.0, 0.0),
               rotation=mass_props.IDENTITY_QUATERNION) -> mass_props.MassProperties:
        m = mass_props.resolve_mass(volume, density, mass, self.type_name)
        return mass_props.MassProperties(m, tuple(float(c) for c in com),
                                         tuple(float(m * i) for i in unit_inertia),
                                         tuple(float(c) for c in rotation))


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

    def mass_properties(self, density=None, mass=None):
        volume = 4.0 / 3.0 * np.pi * self.radius ** 3
        return self._solid(volume, mass_props.sphere_unit_inertia(self.radius), density, mass)


class Box(Shape):
    type_code = layouts.SHAPE_BOX
    type_name = "box"

    def __init__(self, half_extents):
        he = _finite_vector(half_extents, 3, "Box half_extents")
        if np.any(he <= 0):
            raise RbgenError(f"Box half_extents must all be positive, got {tuple(he)}")
        self.half_extents = he
        self._cooked = hull_cooking.box_hull(he)

    def pack(self, record, hull_vertices):
        record["extents"] = (*self.half_extents, 0)

    def key(self):
        return ("box", *self.half_extents)

    def local_vertices(self):
        return self._cooked.vertices

    def cooked(self):
        return self._cooked

    def mass_properties(self, density=None, mass=None):
        volume = 8.0 * float(np.prod(self.half_extents))
        return self._solid(volume, mass_props.box_unit_inertia(self.half_extents), density, mass)


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

    def mass_properties(self, density=None, mass=None):
        volume = mass_props.capsule_volume(self.radius, self.half_height)
        return self._solid(volume, mass_props.capsule_unit_inertia(self.radius, self.half_height),
                           density, mass)


class ConvexHull(Shape):
    """Convex hull of a point cloud, cooked into polygons in its principal frame.

    ``vertices`` are the hull's vertices re-centred on the centre of mass and
    rotated into the principal frame; `mass_properties` gives the centre of
    mass and rotation that place this frame in the frame of ``points``.
    ``name`` appears in error messages (degenerate input, limits exceeded).
    """

    type_code = layouts.SHAPE_HULL
    type_name = "convex hull"

    def __init__(self, points, name: str = "ConvexHull"):
        self.name = str(name)
        self._cooked = hull_cooking.cook(points, self.name)
        self.vertices = self._cooked.vertices

    @classmethod
    def from_trimesh(cls, mesh, name: str | None = None) -> "ConvexHull":
        """The convex hull of a ``trimesh.Trimesh``'s vertices."""
        vertices = getattr(mesh, "vertices", None)
        if vertices is None:
            raise RbgenError(f"ConvexHull.from_trimesh expects a trimesh.Trimesh, "
                             f"got {type(mesh).__name__}")
        label = name or f"ConvexHull.from_trimesh({getattr(mesh, 'metadata', {}).get('name', 'mesh')})"
        return cls(np.asarray(vertices, np.float64), name=label)

    def pack(self, record, hull_vertices):
        pass  # topology and vertices are packed by ShapeTable from cooked()

    def key(self):
        return ("hull", self.vertices.tobytes())

    def local_vertices(self):
        return self.vertices

    def cooked(self):
        return self._cooked

    def mass_properties(self, density=None, mass=None):
        c = self._cooked
        return self._solid(c.volume, c.unit_inertia, density, mass, c.com, c.rotation)


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

    def max_face_vertices(self) -> int:
        """Most vertices on one face of any box or hull (sizes the clipping buffers)."""
        return max((max(len(f) for f in s.cooked().faces) for s in self.shapes
                    if s.cooked() is not None), default=0)

    def pack(self) -> tuple[np.ndarray, np.ndarray]:
        """(Shape records, hull vertices as float4; at least one of each for OpenCL)."""
        packed = self.pack_all()
        return packed.shapes, packed.vertices

    def pack_all(self) -> "PackedShapes":
        """Every device array of the shapes: records and cooked hull topology."""
        records = layouts.SHAPE.zeros(max(1, len(self.shapes)))
        vertices, faces, indices, edges, adjacency = [], [], [], [], []
        counts = dict(v=0, f=0, i=0, e=0, a=0)
        for i, shape in enumerate(self.shapes):
            rec = records[i]
            rec["type"] = shape.type_code
            shape.pack(rec, [])
            cooked = shape.cooked()
            if cooked is None:
                continue
            rec["vertex_offset"], rec["vertex_count"] = counts["v"], len(cooked.vertices)
            rec["face_offset"], rec["face_count"] = counts["f"], len(cooked.faces)
            rec["edge_offset"], rec["edge_count"] = counts["e"], len(cooked.edge_directions)
            rec["adjacency_offset"], rec["adjacency_count"] = counts["a"], len(cooked.edges)
            face_records = layouts.HULL_FACE.zeros(len(cooked.faces))
            for k, polygon in enumerate(cooked.faces):
                face_records[k]["plane"] = cooked.planes[k]
                face_records[k]["index_offset"] = counts["i"]
                face_records[k]["index_count"] = len(polygon)
                indices.append(np.asarray(polygon, np.uint32))
                counts["i"] += len(polygon)
            vertices.append(cooked.vertices)
            faces.append(face_records)
            edges.append(cooked.edge_directions)
            edge_records = layouts.HULL_EDGE.zeros(len(cooked.edges))
            for k, field in enumerate(("v0", "v1", "f0", "f1")):
                edge_records[field] = cooked.edges[:, k]
            adjacency.append(edge_records)
            counts["a"] += len(cooked.edges)
            counts["v"] += len(cooked.vertices)
            counts["f"] += len(cooked.faces)
            counts["e"] += len(cooked.edge_directions)
        return PackedShapes(
            shapes=records,
            vertices=_float4(vertices),
            faces=_records(layouts.HULL_FACE, faces),
            face_indices=np.concatenate(indices) if indices else np.zeros(1, np.uint32),
            edges=_float4(edges),
            adjacency=_records(layouts.HULL_EDGE, adjacency),
        )


def _records(layout, chunks) -> np.ndarray:
    """Concatenate record arrays into the layout's dtype (np.concatenate drops padding)."""
    out = layout.zeros(max(1, sum(len(c) for c in chunks)))
    start = 0
    for c in chunks:
        out[start:start + len(c)] = c
        start += len(c)
    return out


def _float4(chunks) -> np.ndarray:
    total = sum(len(c) for c in chunks)
    out = np.zeros((max(1, total), 4), np.float32)
    if total:
        out[:total, :3] = np.concatenate(chunks)
    return out


@dataclasses.dataclass
class PackedShapes:
    """Host arrays of a `ShapeTable` (each has at least one element for OpenCL)."""

    shapes: np.ndarray        # Shape records
    vertices: np.ndarray      # (V, 4) float32 hull/box vertices, w unused
    faces: np.ndarray         # HullFace records
    face_indices: np.ndarray  # uint32 polygon vertex indices (relative to vertex_offset)
    edges: np.ndarray         # (E, 4) float32 unique edge directions, w unused
    adjacency: np.ndarray     # HullEdge records: every edge with its two faces

    def to_device(self, queue) -> "PackedShapes":
        """The same arrays as pyopencl arrays on ``queue``'s device."""
        import pyopencl.array as cla

        return PackedShapes(*(cla.to_device(queue, np.ascontiguousarray(a))
                              for a in (self.shapes, self.vertices, self.faces,
                                        self.face_indices, self.edges, self.adjacency)))
