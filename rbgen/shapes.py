"""Collision shapes, the registry of shape types, and their packing into device arrays.

Shapes are immutable host objects in their local frame, which is also their
principal frame of inertia (hulls are re-centred and rotated when cooked; see
`rbgen.hull` and `rbgen.mass`). `ShapeTable` packs the shapes a world uses into
the `Shape` layout plus the shared hull arrays (vertices, faces, face indices,
edge directions), deduplicating identical shapes so that 100k boxes of one
size share one entry. Boxes carry their hull topology too, so every
convex-convex kernel can treat them as hulls.

Shape types: a `Shape` subclass that declares a ``type_code`` is a shape type,
and its class is the type's one entry in the registry (`shape_types`): code,
name, what its `Shape` record holds, the template of its world-AABB function,
mass properties, bounding radius, whether it is static only. The narrowphase's
pair kernels declare the pairs of type names they handle
(`rbgen.pipeline.narrowphase.kinds`). Every list of shape types (the AABB
kernel's cases, the narrowphase's queues and programs, which shapes a World
accepts) is derived from these two registries, so a new type is its class,
its AABB template (``rbgen/templates/shapes/``) and its pair kernels.
"""

from __future__ import annotations

import dataclasses
import functools
import re
from typing import TYPE_CHECKING, Generic, TypeVar

import numpy as np

from . import codegen, layouts
from . import hull as hull_cooking
from . import mass as mass_props
from .errors import RbgenError

if TYPE_CHECKING:
    import pyopencl.array as cla


def _finite_vector(value, n: int, what: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        arr = np.full(1, np.nan)  # not numbers: refused below, naming the argument
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise RbgenError(f"{what} must be {n} finite numbers, got {value!r}")
    return arr


def _finite_number(value, what: str) -> float:
    """``value`` as a float, or RbgenError naming ``what`` (strings, None, sequences and
    other non-numbers are refused here, not by numpy)."""
    if isinstance(value, (str, bytes)) or np.ndim(value) != 0:
        raise RbgenError(f"{what} must be a finite number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise RbgenError(f"{what} must be a finite number, got {value!r}") from None
    if not np.isfinite(number):
        raise RbgenError(f"{what} must be a finite number, got {value!r}")
    return number


class Shape:
    """Base class of collision shapes; a subclass that sets ``type_code`` is a shape type.

    A shape is an immutable value: once its constructor has validated it, its
    attributes cannot be set and its arrays are read-only. So one shape object
    may be added to any number of Worlds (each copies it into its own
    `ShapeTable`), and a shape already added cannot change under a World
    behind its back (its dedup key, mass properties and device record would
    disagree). Make a new shape instead of changing one.

    A shape type's class declares (checked by `register_shape_type`):
    ``type_name``, the registry key and the name kind names ("box_hull"),
    `ShapeTable.type_names` and template parameters use (lower-case letters and
    digits); ``type_code``, its `Shape.type` on the device, declared as the
    constant ``RB_SHAPE_<TYPE_NAME>`` (``type_constant``) with ``extents_doc``
    (what `pack` puts in the record's extents); ``aabb_template``, a template
    under ``rbgen/templates/`` that defines ``<type_name>_world_aabb`` (see
    ``templates/shapes/box.cl.mako``); ``static_only`` (no dynamic bodies, so
    a pair of two such types needs no kernel); and the methods `pack`, `key`,
    `mass_properties`, `bounding_radius` (and `cooked` for polygon topology).
    """

    type_name: str = "shape"
    #: the type in error messages (type_name when empty)
    label: str = ""
    type_code: int = -1
    #: set by `register_shape_type`: the name of the type code's constant
    type_constant: str = ""
    extents_doc: str = ""
    aabb_template: str = ""
    static_only: bool = False
    #: appended to the refusal of a static-only shape as a dynamic body (what to use instead)
    static_only_hint: str = ""
    #: a composite type (a compound): the midphase turns its pairs into its children's pairs
    #: (`parts`), so pairs with it need no narrowphase kernel of their own
    composite: bool = False
    #: arrays of the type's own that `pack_arrays` adds to `PackedShapes`, by the name
    #: kernels give them (what each holds); a kernel binds them by name like the hull arrays
    table_arrays: dict[str, str] = {}

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "type_code" in cls.__dict__:
            register_shape_type(cls)
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
            raise RbgenError(
                f"{type(self).__name__} shapes are immutable (a World may share "
                f"this one); make a new shape instead of setting {name!r}"
            )
        object.__setattr__(self, name, value)

    def pack(self, record: np.void, hull_vertices: list) -> None:
        """Fill the shape's `Shape` record; a shape without cooked polygons may append
        points to ``hull_vertices`` (its record's vertex_offset/vertex_count then say where
        they are: a mesh's or compound's local box)."""
        raise NotImplementedError

    def parts(self) -> tuple[Shape, ...]:
        """Shapes this one is made of (a compound's children): a `ShapeTable` adds them
        first, so they have records of their own."""
        return ()

    @classmethod
    def pack_arrays(cls, table: ShapeTable, records: np.ndarray) -> dict[str, np.ndarray]:
        """The type's `table_arrays` for the shapes of this type in ``table`` (their
        records' offsets into them set here); none by default."""
        return {}

    def key(self) -> tuple:
        """Identity for deduplication in a `ShapeTable`."""
        raise NotImplementedError

    @classmethod
    def what(cls) -> str:
        """The type's name in messages."""
        return cls.label or cls.type_name

    def local_vertices(self) -> np.ndarray:
        """Vertices whose convex hull is the shape (boxes, hulls); tests use it."""
        raise RbgenError(f"{self.what()} has no vertex representation")

    def bounding_radius(self) -> float:
        """Radius of a sphere about the shape's origin (the body's centre of mass) that
        holds the shape; by default the farthest of `local_vertices`."""
        return float(np.linalg.norm(np.asarray(self.local_vertices()), axis=1).max())

    def cooked(self) -> hull_cooking.CookedHull | None:
        """Polygon topology for the convex-convex kernels (boxes and hulls), else None."""
        return None

    def mass_properties(
        self, density: float | None = None, mass: float | None = None
    ) -> mass_props.MassProperties:
        """Mass, centre of mass, principal inertia diagonal and principal rotation.

        Give exactly one of ``density`` and ``mass``. The local frame of every
        shape is principal, so ``com`` and ``rotation`` say where that frame
        sits in the frame the shape was described in (identity except for hulls).
        """
        raise RbgenError(f"{self.what()} has no mass (static only)")

    def _solid(
        self,
        volume,
        unit_inertia,
        density,
        mass,
        com=(0.0, 0.0, 0.0),
        rotation=mass_props.IDENTITY_QUATERNION,
    ) -> mass_props.MassProperties:
        m = mass_props.resolve_mass(volume, density, mass, self.what())
        return mass_props.MassProperties(
            m,
            tuple(float(c) for c in com),
            tuple(float(m * i) for i in unit_inertia),
            tuple(float(c) for c in rotation),
        )


_SHAPE_TYPES: dict[str, type[Shape]] = {}


def register_shape_type(cls: type[Shape]) -> type[Shape]:
    """Enter a shape type's class into the registry (done for every `Shape` subclass
    that sets ``type_code``) and declare its ``RB_SHAPE_<TYPE_NAME>`` constant."""
    name = cls.type_name
    if not re.fullmatch(r"[a-z][a-z0-9]*", name or ""):
        raise RbgenError(
            f"shape type {cls.__name__}: type_name {name!r} must be lower-case "
            f"letters and digits (it is part of kind names such as 'box_hull')"
        )
    if _SHAPE_TYPES.get(name, cls) is not cls:
        raise RbgenError(
            f"shape type {cls.__name__}: type_name {name!r} is already "
            f"{_SHAPE_TYPES[name].__name__}'s"
        )
    constant = f"RB_SHAPE_{name.upper()}"
    taken = [
        k
        for k, v in layouts.constants().items()
        if k.startswith("RB_SHAPE_") and k != constant and v == cls.type_code
    ]
    if taken or not (isinstance(cls.type_code, int) and 0 <= cls.type_code < 2**31):
        raise RbgenError(
            f"shape type {cls.__name__}: type_code {cls.type_code!r} must be a "
            f"small non-negative int that no other type uses (taken: {taken})"
        )
    if not (codegen.TEMPLATE_DIR / cls.aabb_template).is_file():
        raise RbgenError(
            f"shape type {cls.__name__}: aabb_template {cls.aabb_template!r} is "
            f"not a file under {codegen.TEMPLATE_DIR}"
        )
    layouts.constant(constant, cls.type_code, cls.extents_doc)
    cls.type_constant = constant
    _SHAPE_TYPES[name] = cls
    return cls


def shape_types() -> tuple[type[Shape], ...]:
    """Every registered shape type, in registration order."""
    return tuple(_SHAPE_TYPES.values())


def shape_type_names() -> tuple[str, ...]:
    """The registered shape types' names, in registration order."""
    return tuple(_SHAPE_TYPES)


def shape_type(name: str) -> type[Shape]:
    """The registered shape type called ``name``."""
    try:
        return _SHAPE_TYPES[name]
    except (KeyError, TypeError):
        raise RbgenError(
            f"no shape type named {name!r}; registered: {list(_SHAPE_TYPES)}"
        ) from None


def registered_type(shape: Shape) -> type[Shape] | None:
    """The registered type a shape object is an instance of (None: not a shape type)."""
    cls = _SHAPE_TYPES.get(type(shape).type_name)
    return cls if cls is not None and isinstance(shape, cls) else None


class Sphere(Shape):
    type_name = "sphere"
    type_code = 0
    extents_doc = "extents.x = radius"
    aabb_template = "shapes/sphere.cl.mako"

    def __init__(self, radius: float):
        radius = _finite_number(radius, "Sphere radius")
        if radius <= 0:
            raise RbgenError(f"Sphere radius must be a positive finite number, got {radius!r}")
        self.radius = radius

    def pack(self, record, hull_vertices):
        record["extents"] = (self.radius, 0, 0, 0)

    def key(self):
        return ("sphere", self.radius)

    def mass_properties(self, density=None, mass=None):
        volume = 4.0 / 3.0 * np.pi * self.radius**3
        return self._solid(volume, mass_props.sphere_unit_inertia(self.radius), density, mass)

    def bounding_radius(self):
        return self.radius


class Box(Shape):
    type_name = "box"
    type_code = 1
    extents_doc = "extents.xyz = half extents"
    aabb_template = "shapes/box.cl.mako"

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
    type_name = "capsule"
    type_code = 4
    extents_doc = "extents.x = radius, extents.y = half height (y axis)"
    aabb_template = "shapes/capsule.cl.mako"

    def __init__(self, radius: float, half_height: float):
        radius = _finite_number(radius, "Capsule radius")
        half_height = _finite_number(half_height, "Capsule half_height")
        if not (radius > 0 and half_height >= 0):
            raise RbgenError(
                f"Capsule needs radius > 0 and half_height >= 0, got "
                f"radius={radius!r}, half_height={half_height!r}"
            )
        self.radius, self.half_height = float(radius), float(half_height)

    def pack(self, record, hull_vertices):
        record["extents"] = (self.radius, self.half_height, 0, 0)

    def key(self):
        return ("capsule", self.radius, self.half_height)

    def mass_properties(self, density=None, mass=None):
        volume = mass_props.capsule_volume(self.radius, self.half_height)
        return self._solid(
            volume, mass_props.capsule_unit_inertia(self.radius, self.half_height), density, mass
        )

    def bounding_radius(self):
        return self.radius + self.half_height


class ConvexHull(Shape):
    """Convex hull of a point cloud, cooked into polygons in its principal frame.

    ``vertices`` are the hull's vertices re-centred on the centre of mass and
    rotated into the principal frame; `mass_properties` gives the centre of
    mass and rotation that place this frame in the frame of ``points``.
    ``name`` appears in error messages (degenerate input, limits exceeded).
    """

    type_name = "hull"
    label = "convex hull"
    type_code = 2
    extents_doc = "vertices and polygons in the hull arrays (Shape.vertex_*, face_*, edge_*)"
    aabb_template = "shapes/hull.cl.mako"

    def __init__(self, points, name: str = "ConvexHull"):
        self.name = str(name)
        self._cooked = hull_cooking.cook(points, self.name)
        self.vertices = self._cooked.vertices

    @classmethod
    def from_trimesh(cls, mesh, name: str | None = None) -> ConvexHull:
        """The convex hull of a ``trimesh.Trimesh``'s vertices."""
        vertices = getattr(mesh, "vertices", None)
        if vertices is None:
            raise RbgenError(
                f"ConvexHull.from_trimesh expects a trimesh.Trimesh, got {type(mesh).__name__}"
            )
        mesh_name = getattr(mesh, "metadata", {}).get("name", "mesh")
        label = name or f"ConvexHull.from_trimesh({mesh_name})"
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

    type_name = "plane"
    type_code = 3
    extents_doc = "extents.xyz = normal, extents.w = offset; static only"
    aabb_template = "shapes/plane.cl.mako"
    static_only = True

    def __init__(self, normal=(0, 1, 0), offset: float = 0.0):
        n = _finite_vector(normal, 3, "Plane normal")
        length = np.linalg.norm(n)
        if length < 1e-12:
            raise RbgenError("Plane normal must not be zero")
        offset = _finite_number(offset, "Plane offset")
        self.normal, self.offset = n / length, offset

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
            for part in shape.parts():
                self.add(part)
            self._index[key] = len(self.shapes)
            self.shapes.append(shape)
        return self._index[key]

    def index_of(self, shape: Shape) -> int:
        """The index of a shape already in the table."""
        return self._index[shape.key()]

    def type_names(self) -> tuple[str, ...]:
        """The sorted type names of the shapes present, e.g. ("box", "plane")."""
        return tuple(sorted({type(s).type_name for s in self.shapes}))

    def max_face_vertices(self) -> int:
        """Most vertices on one face of any box or hull (sizes the clipping buffers)."""
        cooked = (s.cooked() for s in self.shapes)
        return max((max(len(f) for f in c.faces) for c in cooked if c is not None), default=0)

    def pack(self) -> tuple[np.ndarray, np.ndarray]:
        """(Shape records, hull vertices as float4; at least one of each for OpenCL)."""
        packed = self.pack_all()
        return packed.shapes, packed.vertices

    def pack_all(self) -> PackedShapes[np.ndarray]:
        """Every device array of the shapes: records and cooked hull topology."""
        records = layouts.SHAPE.zeros(max(1, len(self.shapes)))
        vertices, faces, indices, edges, adjacency = [], [], [], [], []
        counts = dict(v=0, f=0, i=0, e=0, a=0)
        for i, shape in enumerate(self.shapes):
            rec = records[i]
            rec["type"] = shape.type_code
            points: list = []
            shape.pack(rec, points)
            if points:  # (a mesh's or compound's local box)
                rec["vertex_offset"], rec["vertex_count"] = counts["v"], len(points)
                vertices.append(np.asarray(points, np.float64).reshape(-1, 3))
                counts["v"] += len(points)
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
        extra: dict[str, np.ndarray] = {}
        for cls in dict.fromkeys(type(shape) for shape in self.shapes):
            extra.update(cls.pack_arrays(self, records))
        return PackedShapes(
            extra=extra,
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
        out[start : start + len(c)] = c
        start += len(c)
    return out


def _float4(chunks) -> np.ndarray:
    total = sum(len(c) for c in chunks)
    out = np.zeros((max(1, total), 4), np.float32)
    if total:
        out[:total, :3] = np.concatenate(chunks)
    return out


#: the name every kernel gives each array of `PackedShapes` (kernels bind them by name)
KERNEL_ARGUMENTS = {
    "shapes": "shapes",
    "vertices": "hull_vertices",
    "faces": "hull_faces",
    "face_indices": "face_indices",
    "edges": "hull_edges",
    "adjacency": "hull_adjacency",
}


#: the array type of a `PackedShapes`: numpy on the host, pyopencl after `to_device`
_Arrays = TypeVar("_Arrays")


@dataclasses.dataclass
class PackedShapes(Generic[_Arrays]):
    """Host arrays of a `ShapeTable` (each has at least one element for OpenCL)."""

    shapes: _Arrays  # Shape records
    vertices: _Arrays  # (V, 4) float32 hull/box vertices, w unused
    faces: _Arrays  # HullFace records
    face_indices: _Arrays  # uint32 polygon vertex indices (relative to vertex_offset)
    edges: _Arrays  # (E, 4) float32 unique edge directions, w unused
    adjacency: _Arrays  # HullEdge records: every edge with its two faces
    #: the arrays of shape types' own (`Shape.table_arrays`), by kernel argument name;
    #: empty in a world without such types
    extra: dict = dataclasses.field(default_factory=dict)

    def kernel_arguments(self) -> dict:
        """The arrays by the names kernels give them (`KERNEL_ARGUMENTS`, then `extra`)."""
        return {
            **{
                KERNEL_ARGUMENTS[f.name]: getattr(self, f.name)
                for f in dataclasses.fields(self)
                if f.name in KERNEL_ARGUMENTS
            },
            **self.extra,
        }

    def to_device(self, queue) -> PackedShapes[cla.Array]:
        """The same arrays as pyopencl arrays on ``queue``'s device."""
        import pyopencl.array as cla

        def device(array) -> cla.Array:
            return cla.to_device(queue, np.ascontiguousarray(array))

        return PackedShapes(
            device(self.shapes),
            device(self.vertices),
            device(self.faces),
            device(self.face_indices),
            device(self.edges),
            device(self.adjacency),
            extra={name: device(a) for name, a in self.extra.items()},
        )


def table_arguments() -> dict[str, str]:
    """Every kernel argument name a registered shape type's `table_arrays` declares."""
    return {name: doc for cls in shape_types() for name, doc in cls.table_arrays.items()}
