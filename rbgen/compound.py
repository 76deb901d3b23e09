"""Compound shapes: several convex shapes rigidly joined, as one body.

``Compound([(shape, position, orientation), ...])``: each child is a sphere, box, capsule
or convex hull placed in the compound's frame by ``position`` and ``orientation`` (a unit
quaternion x, y, z, w; identity when left out). A child's pose places the child's own
frame, which for a hull is its principal frame (`ConvexHull.mass_properties` says where
that sits among the hull's points).

Mass: the children share one density, so the compound's mass properties are exact
sums of theirs (volumes, centre of mass, inertia by the parallel-axis theorem),
diagonalised into the compound's principal frame. As for hulls, the compound is stored
in that frame (the children's poses re-expressed in it), and `mass_properties` gives the
``com`` and ``rotation`` that place it in the frame the children were given in.
Overlapping children count their common volume twice.

Collision: the midphase gives each child of a compound body a place of its own for the
step (`rbgen.pipeline.midphase`) and turns the compound's pairs into its children's, so
every pair kernel of the children's types serves compounds too; a manifold's sub-feature
names the child (`layouts.SUB_CHILD_SHIFT`).
"""

from __future__ import annotations

import numpy as np

from . import layouts
from . import mass as mass_props
from .errors import RbgenError
from .shapes import Box, Capsule, ConvexHull, Shape, ShapeTable, Sphere

#: the shape types a compound's children may have (convex ones)
CHILD_TYPES = (Sphere, Box, Capsule, ConvexHull)


def _rotation(q) -> np.ndarray:
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _quat_mul(a, b) -> np.ndarray:
    av, aw, bv, bw = np.asarray(a[:3]), a[3], np.asarray(b[:3]), b[3]
    return np.array([*(aw * bv + bw * av + np.cross(av, bv)), aw * bw - av @ bv])


def child_box(shape: Shape, position, orientation) -> tuple[np.ndarray, np.ndarray]:
    """The box (lower, upper) of a convex shape placed at ``position`` and ``orientation``."""
    r = _rotation(orientation)
    p = np.asarray(position, np.float64)
    if isinstance(shape, Sphere):
        half = np.full(3, shape.radius)
    elif isinstance(shape, Capsule):
        half = np.abs(r[:, 1]) * shape.half_height + shape.radius
    else:
        world = shape.local_vertices() @ r.T
        return p + world.min(axis=0), p + world.max(axis=0)
    return p - half, p + half


class Compound(Shape):
    """Convex children rigidly joined (see the module docstring). ``name`` appears in
    messages."""

    type_name = "compound"
    type_code = layouts.SHAPE_COMPOUND
    extents_doc = (
        "children child_* in CompoundChild, local box vertex_offset/2 in the hull vertices"
    )
    aabb_template = "shapes/compound.cl.mako"
    composite = True
    table_arrays = {"compound_children": "CompoundChild records of every compound"}

    def __init__(self, children, name: str = "Compound"):
        self.name = str(name)
        try:
            children = list(children)
        except TypeError:
            raise RbgenError(
                f"{self.name}: children must be a list of (shape, position, orientation) tuples"
            ) from None
        if not children:
            raise RbgenError(f"{self.name}: a compound needs at least one child (got none)")
        if len(children) > layouts.MAX_COMPOUND_CHILDREN:
            raise RbgenError(
                f"{self.name}: {len(children)} children; at most "
                f"{layouts.MAX_COMPOUND_CHILDREN} (RB_MAX_COMPOUND_CHILDREN)"
            )
        shapes: list = []
        positions: list = []
        orientations: list = []
        for k, child in enumerate(children):
            shape, position, orientation = _child(k, child, self.name)
            shapes.append(shape)
            positions.append(position)
            orientations.append(orientation)
        positions = np.asarray(positions)  # type: ignore[assignment]  # (lists -> arrays)
        orientations = np.asarray(orientations)  # type: ignore[assignment]

        # unit-density sums over the children, in the frame they were given in
        volumes = np.array([s.mass_properties(density=1.0).mass for s in shapes])
        volume = float(volumes.sum())
        com = (volumes[:, None] * positions).sum(axis=0) / volume
        tensor = np.zeros((3, 3))
        for shape, v, p, q in zip(shapes, volumes, positions, orientations):
            r = _rotation(q)
            inertia = np.asarray(shape.mass_properties(density=1.0).inertia)
            d = p - com
            tensor += r @ np.diag(inertia) @ r.T + v * (d @ d * np.eye(3) - np.outer(d, d))
        moments, axes = mass_props.principal_frame(tensor)
        self.volume = volume
        self._com = com
        self._rotation = mass_props.quaternion_from_matrix(axes)
        self._unit_inertia = moments / volume
        # the children in the principal frame: p' = axes^T (p - com), q' = q_axes^-1 q
        inverse = np.array([-c for c in self._rotation[:3]] + [self._rotation[3]])
        self.children = tuple(shapes)
        self.positions = (positions - com) @ axes
        self.orientations = np.array([_quat_mul(inverse, q) for q in orientations])
        boxes = [
            child_box(s, p, q) for s, p, q in zip(self.children, self.positions, self.orientations)
        ]
        self.lower = np.min([b[0] for b in boxes], axis=0)
        self.upper = np.max([b[1] for b in boxes], axis=0)

    def parts(self):
        return self.children

    def key(self):
        return (
            "compound",
            tuple(child.key() for child in self.children),
            self.positions.tobytes(),
            self.orientations.tobytes(),
        )

    def mass_properties(self, density=None, mass=None):
        return self._solid(
            self.volume, tuple(self._unit_inertia), density, mass, self._com, self._rotation
        )

    def bounding_radius(self) -> float:
        return float(
            max(
                np.linalg.norm(p) + s.bounding_radius()
                for s, p in zip(self.children, self.positions)
            )
        )

    def pack(self, record, hull_vertices):
        hull_vertices.extend((self.lower, self.upper))

    @classmethod
    def pack_arrays(cls, table: ShapeTable, records: np.ndarray) -> dict:
        compounds = [(i, s) for i, s in enumerate(table.shapes) if isinstance(s, cls)]
        if not compounds:
            return {}
        out = layouts.COMPOUND_CHILD.zeros(sum(len(s.children) for _, s in compounds))
        at = 0
        for i, compound in compounds:
            n = len(compound.children)
            records[i]["child_offset"], records[i]["child_count"] = at, n
            out["position"][at : at + n, :3] = compound.positions
            out["orientation"][at : at + n] = compound.orientations
            out["shape"][at : at + n] = [table.index_of(c) for c in compound.children]
            at += n
        return {"compound_children": out}


def _child(k: int, child, name: str):
    """(shape, position, unit quaternion) of child k, or an error naming it."""
    if isinstance(child, Shape):
        child = (child, (0.0, 0.0, 0.0))
    if not isinstance(child, (tuple, list)) or len(child) not in (2, 3):
        raise RbgenError(
            f"{name}: child {k} must be (shape, position) or (shape, position, "
            f"orientation), got {child!r}"
        )
    shape, position = child[0], child[1]
    orientation = child[2] if len(child) == 3 and child[2] is not None else (0, 0, 0, 1)
    if not isinstance(shape, CHILD_TYPES):
        what = type(shape).__name__
        raise RbgenError(
            f"{name}: child {k} is a {what}; a compound's children must be convex "
            f"shapes ({', '.join(c.__name__ for c in CHILD_TYPES)})"
        )
    p = np.asarray(position, np.float64).reshape(-1)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise RbgenError(f"{name}: child {k} position must be 3 finite numbers, got {position!r}")
    q = np.asarray(orientation, np.float64).reshape(-1)
    if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-6:
        raise RbgenError(
            f"{name}: child {k} orientation must be a non-zero quaternion "
            f"(x, y, z, w), got {orientation!r}"
        )
    return shape, p, q / np.linalg.norm(q)
