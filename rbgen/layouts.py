"""Every struct and constant that crosses the host/device boundary, declared once.

A `Layout` is a list of typed fields. From it we derive, never by hand:

* the numpy structured dtype (explicit offsets, float4 members 16-byte
  aligned, item size rounded up to the struct's alignment, as OpenCL C does);
* the OpenCL C ``typedef struct`` that templates include;
* the C header for host programs that use exported kernels, with static
  asserts on every size and offset.

Constants (flags, sentinels) live here too, rendered as ``#define``; shape
type codes are declared through `constant` by their shape classes
(`rbgen.shapes`), so they reach the same ``#define`` list and C header.
Add a struct by calling `declare`; look one up with `layout`. An unknown struct
or field name raises `RbgenError` naming it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import numpy as np

from .errors import RbgenError

#: Scalar and vector member kinds: numpy base type, lane count, OpenCL name, C name.
_KINDS = {
    "float": (np.float32, 1, "float", "float"),
    "int": (np.int32, 1, "int", "int32_t"),
    "uint": (np.uint32, 1, "uint", "uint32_t"),
    "float2": (np.float32, 2, "float2", "rb_float2"),
    "int2": (np.int32, 2, "int2", "rb_int2"),
    "uint2": (np.uint32, 2, "uint2", "rb_uint2"),
    "float4": (np.float32, 4, "float4", "rb_float4"),
    "int4": (np.int32, 4, "int4", "rb_int4"),
    "uint4": (np.uint32, 4, "uint4", "rb_uint4"),
}


@dataclasses.dataclass(frozen=True)
class Field:
    name: str
    kind: str
    count: int = 1  # > 1: a fixed-size array member
    doc: str = ""

    @property
    def lanes(self) -> int:
        return _KINDS[self.kind][1]

    @property
    def align(self) -> int:
        # OpenCL aligns vectors to their size; 3-vectors are not used on purpose.
        return 4 * self.lanes

    @property
    def size(self) -> int:
        return 4 * self.lanes * self.count


class Layout:
    """One host/device struct. Build with `declare`, not directly."""

    def __init__(self, name: str, fields: Iterable[Field], doc: str):
        self.name = name
        self.doc = doc
        self.fields = tuple(fields)
        names = [f.name for f in self.fields]
        if len(set(names)) != len(names):
            raise RbgenError(f"layout {name}: duplicate field names in {names}")
        for f in self.fields:
            if f.kind not in _KINDS:
                raise RbgenError(
                    f"layout {name}: field {f.name!r} has unknown kind {f.kind!r}; "
                    f"known kinds: {sorted(_KINDS)}"
                )
        offsets, offset = {}, 0
        for f in self.fields:
            offset = -(-offset // f.align) * f.align
            offsets[f.name] = offset
            offset += f.size
        self.align = max(f.align for f in self.fields)
        self.itemsize = -(-offset // self.align) * self.align
        self._offsets = offsets
        formats = []
        for f in self.fields:
            base, lanes, _, _ = _KINDS[f.kind]
            shape = tuple(
                s for s in (f.count if f.count > 1 else 0, lanes if lanes > 1 else 0) if s
            )
            formats.append((base, shape) if shape else base)
        self.dtype = np.dtype(
            {
                "names": names,
                "formats": formats,
                "offsets": [offsets[n] for n in names],
                "itemsize": self.itemsize,
            }
        )

    def field(self, name: str) -> Field:
        for f in self.fields:
            if f.name == name:
                return f
        raise RbgenError(
            f"layout {self.name} has no field {name!r}; fields: {[f.name for f in self.fields]}"
        )

    def offset(self, name: str) -> int:
        self.field(name)
        return self._offsets[name]

    def zeros(self, n: int) -> np.ndarray:
        return np.zeros(int(n), dtype=self.dtype)

    def cl_source(self) -> str:
        lines = [f"/* {self.doc} */", "typedef struct {"]
        for f in self.fields:
            arr = f"[{f.count}]" if f.count > 1 else ""
            note = f"  /* {f.doc} */" if f.doc else ""
            lines.append(f"    {_KINDS[f.kind][2]} {f.name}{arr};{note}")
        lines.append(f"}} {self.name};")
        return "\n".join(lines)

    def c_source(self) -> str:
        lines = [f"/* {self.doc} */", "typedef struct {"]
        for f in self.fields:
            arr = f"[{f.count}]" if f.count > 1 else ""
            note = f"  /* {f.doc} */" if f.doc else ""
            lines.append(f"    {_KINDS[f.kind][3]} {f.name}{arr};{note}")
        lines.append(f"}} {self.name};")
        lines.append(
            f'RB_STATIC_ASSERT(sizeof({self.name}) == {self.itemsize}, "sizeof({self.name})");'
        )
        for f in self.fields:
            lines.append(
                f"RB_STATIC_ASSERT(offsetof({self.name}, {f.name}) == "
                f'{self._offsets[f.name]}, "{self.name}.{f.name}");'
            )
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"Layout({self.name}, {self.itemsize} bytes)"


_LAYOUTS: dict[str, Layout] = {}
_CONSTANTS: dict[str, tuple[int, str]] = {}


def declare(name: str, fields: Iterable[tuple], doc: str) -> Layout:
    """Declare a struct: ``fields`` are ``(name, kind[, count][, doc])`` tuples."""
    parsed = []
    for spec in fields:
        fname, kind, *rest = spec
        count = rest[0] if rest and isinstance(rest[0], int) else 1
        fdoc = rest[-1] if rest and isinstance(rest[-1], str) else ""
        parsed.append(Field(fname, kind, count, fdoc))
    if name in _LAYOUTS:
        raise RbgenError(f"layout {name} declared twice")
    layout = Layout(name, parsed, doc)
    _LAYOUTS[name] = layout
    return layout


def constant(name: str, value: int, doc: str = "") -> int:
    """Declare an integer constant shared by host and device (``#define name value``)."""
    if name in _CONSTANTS and _CONSTANTS[name][0] != value:
        raise RbgenError(f"constant {name} redeclared with another value")
    _CONSTANTS[name] = (int(value), doc)
    return int(value)


def layout(name: str) -> Layout:
    try:
        return _LAYOUTS[name]
    except KeyError:
        raise RbgenError(f"no layout named {name!r}; declared: {sorted(_LAYOUTS)}") from None


def all_layouts() -> list[Layout]:
    return list(_LAYOUTS.values())


def constants() -> dict[str, int]:
    return {k: v for k, (v, _) in _CONSTANTS.items()}


def cl_constants() -> str:
    return "\n".join(
        f"#define {k} {v}{f'  /* {d} */' if d else ''}" for k, (v, d) in _CONSTANTS.items()
    )


def cl_structs(*names: str) -> str:
    """OpenCL C definitions of the named structs (all of them when none named)."""
    chosen = [layout(n) for n in names] if names else all_layouts()
    return "\n\n".join(layout.cl_source() for layout in chosen)


def c_header() -> str:
    """A self-contained C/C++ header with every constant and struct, size-checked."""
    body = "\n\n".join(layout.c_source() for layout in all_layouts())
    return f"""/* Generated by rbgen from rbgen/layouts.py: do not edit. */
#ifndef RBGEN_LAYOUTS_H
#define RBGEN_LAYOUTS_H
#include <stddef.h>
#include <stdint.h>
#if defined(__cplusplus)
#  define RB_ALIGN(n) alignas(n)
#  define RB_STATIC_ASSERT(c, m) static_assert(c, m)
#else
#  define RB_ALIGN(n) _Alignas(n)
#  define RB_STATIC_ASSERT(c, m) _Static_assert(c, m)
#endif
/* Vector types with OpenCL's size and alignment (compatible with cl_float4 etc.). */
typedef struct {{ RB_ALIGN(8) float s[2]; }} rb_float2;
typedef struct {{ RB_ALIGN(8) int32_t s[2]; }} rb_int2;
typedef struct {{ RB_ALIGN(8) uint32_t s[2]; }} rb_uint2;
typedef struct {{ RB_ALIGN(16) float s[4]; }} rb_float4;
typedef struct {{ RB_ALIGN(16) int32_t s[4]; }} rb_int4;
typedef struct {{ RB_ALIGN(16) uint32_t s[4]; }} rb_uint4;

{cl_constants()}

{body}

#endif /* RBGEN_LAYOUTS_H */
"""


# --------------------------------------------------------------------------
# Shape type codes: each shape type's class declares its RB_SHAPE_<NAME> constant
# (rbgen.shapes.register_shape_type). These codes are reserved for types to come;
# their entries declare the same name and value.
SHAPE_COMPOUND = constant("RB_SHAPE_COMPOUND", 5, "reserved: children in the compound child array")
SHAPE_MESH = constant("RB_SHAPE_MESH", 6, "reserved: static triangle mesh with a BVH")

# --------------------------------------------------------------------------
# Core structs.
BODY = declare(
    "Body",
    [
        ("position", "float4", "centre of mass, world frame; w unused"),
        ("orientation", "float4", "unit quaternion x, y, z, w (body to world)"),
        (
            "linear_velocity",
            "float4",
            "m/s; w: the step's speculative distance (m; prepare_bodies: a fast body's "
            "travel this step, else 0)",
        ),
        ("angular_velocity", "float4", "rad/s, world frame; w unused"),
        ("inv_mass", "float", "0 for static bodies"),
        ("shape", "uint", "index into the Shape array"),
        ("friction", "float", "material friction coefficient"),
        ("restitution", "float", "material restitution coefficient"),
    ],
    "A rigid body's state, one per body (dynamic or static).",
)

SHAPE = declare(
    "Shape",
    [
        (
            "extents",
            "float4",
            "per type: radius, half extents, plane normal+offset; w, for a type that may be "
            "dynamic: the inner radius (Shape.inner_radius)",
        ),
        ("type", "uint", "RB_SHAPE_* (rbgen.shapes: the shape type's code)"),
        (
            "vertex_offset",
            "uint",
            "hull: first vertex in the hull vertex array (mesh, compound: "
            "their local box's lower and upper corners)",
        ),
        ("vertex_count", "uint", "hull: number of vertices"),
        ("face_offset", "uint", "hull: first face; mesh: first MeshTriangle"),
        ("face_count", "uint", "hull: number of faces; mesh: number of triangles"),
        ("edge_offset", "uint", "hull: first unique edge direction"),
        ("edge_count", "uint", "hull: number of unique edge directions"),
        ("child_offset", "uint", "compound: first CompoundChild; mesh: first BvhNode"),
        ("adjacency_offset", "uint", "hull: first HullEdge (edge with its two faces)"),
        ("adjacency_count", "uint", "hull: number of HullEdge records"),
        ("child_count", "uint", "compound: children; mesh: BVH nodes (2 triangles - 1)"),
    ],
    "A collision shape in its local (principal) frame. A mesh's triangles are "
    "face_offset/face_count in the MeshTriangle array and its quantization box (lower, upper "
    "corners) vertex_offset/2 in the hull vertex array; a compound's local AABB likewise.",
)

AABB = declare(
    "Aabb",
    [
        ("lower", "float4", "minimum corner; w unused"),
        ("upper", "float4", "maximum corner; w unused"),
    ],
    "An axis-aligned bounding box in the world frame.",
)

#: `Pair.sub` (and the keys that copy it) of a pair of whole bodies
WHOLE_BODY = constant("RB_WHOLE_BODY", 0, "sub-feature id of a pair of whole bodies")

PAIR = declare(
    "Pair",
    [
        ("a", "uint", "lower body index"),
        ("b", "uint", "higher body index"),
        (
            "sub",
            "uint",
            "sub-feature of the pair: RB_WHOLE_BODY for whole bodies (what the "
            "broadphase writes), else a nonzero id, unique within (a, b), of a "
            "compound child or mesh triangle pair (assigned by a midphase)",
        ),
    ],
    "A candidate pair of bodies, a < b; (a, b, sub) is unique in a pair list, which is "
    "sorted by (a, b, sub) so that everything computed per pair is in a deterministic order.",
)

# --------------------------------------------------------------------------
# Narrowphase output (consumed by the solver). Conventions, tested:
#  * normal points from body_a to body_b (world frame), unit length;
#  * points[k].xyz is the contact point on body_b's surface (world frame) and
#    points[k].w the signed separation along the normal (negative when the
#    bodies penetrate), for k < point_count <= 4;
#  * features[k] identifies the feature pair that produced point k, stable
#    across steps while the contact persists (warm-starting key);
#  * (body_a, body_b, sub) is the pair's key (`Pair`): a body pair may have one
#    manifold per sub-feature, and warm starting matches manifolds by that key.
MAX_MANIFOLD_POINTS = constant("RB_MAX_MANIFOLD_POINTS", 4, "contact points per manifold")

CONTACT_MANIFOLD = declare(
    "ContactManifold",
    [
        ("points", "float4", 4, "xyz: point on B (world); w: signed separation (< 0: penetration)"),
        ("normal", "float4", "unit normal from A to B (world); w unused"),
        ("features", "uint", 4, "feature id per point, stable across steps"),
        ("body_a", "uint", "first body (index into Body)"),
        ("body_b", "uint", "second body"),
        ("sub", "uint", "sub-feature of the pair (Pair.sub; RB_WHOLE_BODY for whole bodies)"),
        ("point_count", "uint", "valid points, 1..4"),
        ("friction", "float", "combined friction coefficient"),
        ("restitution", "float", "combined restitution coefficient"),
    ],
    "Up to four contact points between two bodies sharing one normal.",
)

# --------------------------------------------------------------------------
# Contact solver (owner: constraint solver; rbgen/pipeline/constraints.py, batching/,
# solvers/, prepare.py).
BODY_INERTIA = declare(
    "BodyInertia",
    [
        (
            "inv_inertia_local",
            "float4",
            "principal inverse inertia diagonal (body frame); 0 for static",
        ),
        (
            "inv_inertia_world",
            "float4",
            3,
            "rows of R diag(inv_inertia_local) R^T, updated every step",
        ),
    ],
    "Inverse inertia of one body, local principal diagonal and world tensor.",
)

#: prepare_bodies' force_terms: which external force arrays a step gives (`rbgen.forces`)
FORCE_FORCE = constant("RB_FORCE_FORCE", 1, "external forces: the force array is given")
FORCE_LEVER = constant(
    "RB_FORCE_LEVER", 2, "external forces: the lever-force array (forces at points) is given"
)
FORCE_MOMENT = constant("RB_FORCE_MOMENT", 4, "external forces: the moment array is given")

BODY_DELTA = declare(
    "BodyDelta",
    [
        ("linear", "float4", "displacement of the centre of mass since the step began; w unused"),
        (
            "angular",
            "float4",
            "rotation since the step began, as the sum of angular velocity "
            "times substep (world frame, first order); w unused",
        ),
    ],
    "How far a body moved in the substeps so far: contacts update their separations from it.",
)

SPLIT_VELOCITY = declare(
    "SplitVelocity",
    [
        ("linear", "float4", "push velocity of the split-impulse position pass; w unused"),
        ("angular", "float4", "push angular velocity (world frame); w unused"),
    ],
    "Pseudo-velocity that moves a body out of penetration without adding momentum.",
)

#: Marks an empty slot of the warm-starting hash table and an unassigned batch.
SOLVER_NONE = constant("RB_SOLVER_NONE", 0xFFFFFFFF, "empty table slot / unassigned batch")

# The words of a device-wide barrier's state (common/device_barrier.cl.mako,
# rbgen.pipeline.device_barrier)
BARRIER_ARRIVALS = constant(
    "RB_BARRIER_ARRIVALS", 0, "device-wide barrier: arrivals since the launch began"
)
BARRIER_DEPARTURES = constant(
    "RB_BARRIER_DEPARTURES", 1, "device-wide barrier: groups that have left"
)
BARRIER_SPIN_LIMIT = constant(
    "RB_BARRIER_SPIN_LIMIT",
    2,
    "device-wide barrier: polls before a waiting group gives up (set by the host)",
)
BARRIER_ABANDONED = constant(
    "RB_BARRIER_ABANDONED",
    3,
    "device-wide barrier: nonzero once a group gave up (reset by the host)",
)
BARRIER_WORDS = constant("RB_BARRIER_WORDS", 4, "device-wide barrier: words of its state")

#: int64 words of a body's summed warm start (solvers/pgs.cl.mako): its linear and angular
#: velocity change in fixed point
WARM_SUM_WORDS = constant(
    "RB_WARM_SUM_WORDS",
    6,
    "summed warm start: int64 words a body (linear, angular velocity change)",
)

CONTACT_CONSTRAINT = declare(
    "ContactConstraint",
    [
        ("normal", "float4", "unit normal from A to B (world); w: friction coefficient"),
        (
            "tangent1",
            "float4",
            "first friction direction, unit, orthogonal to normal; w: the body a shock "
            "sweep holds still (RB_SHOCK_HOLDS_*: the lower of two dynamic bodies whose "
            "normal is within 45 degrees of the gravity's vertical)",
        ),
        (
            "tangent2",
            "float4",
            "second friction direction, normal x tangent1; w: the manifold's restitution",
        ),
        (
            "r_a",
            "float4",
            4,
            "contact point k relative to A's centre of mass (world, fixed over "
            "the step's substeps); w: its separation at setup (m)",
        ),
        (
            "r_b",
            "float4",
            4,
            "contact point k relative to B's centre of mass (world); w: its "
            "bounce velocity (m/s, 0 below the restitution threshold)",
        ),
        ("normal_mass", "float4", "per point: 1 / (J M^-1 J^T) of the normal row"),
        ("tangent1_mass", "float4", "per point: effective mass of the tangent1 row"),
        ("tangent2_mass", "float4", "per point: effective mass of the tangent2 row"),
        (
            "velocity_target",
            "float4",
            "per point: normal velocity the solver drives to (bounce, "
            "speculative gap) this substep",
        ),
        ("position_target", "float4", "per point: split-impulse push velocity target this substep"),
        ("normal_impulse", "float4", "per point: accumulated normal impulse (warm started)"),
        ("tangent1_impulse", "float4", "per point: accumulated tangent1 impulse (warm started)"),
        (
            "tangent2_impulse",
            "float4",
            "per point: accumulated tangent2 impulse (warm started); slot 1, where the "
            "restitution is > 0: the points that pushed in this step's velocity sweeps, "
            "bit k for point k (a whole number 0-15; the restitution bounces those); slot "
            "2: the total normal impulse the warm start carried into this (sub)step, slot "
            "3: one substep of gravity on the reduced mass at the face (the sum of the "
            "normal rows' masses): the cap on the next carry (contact_targets.cl.mako: "
            "CARRY_GROWTH)",
        ),
        ("push_impulse", "float4", "per point: accumulated split (position) impulse"),
        ("features", "uint4", "feature id per point (warm-starting key)"),
        ("body_a", "uint", "first body"),
        ("body_b", "uint", "second body"),
        ("point_count", "uint", "valid points, 0..4 (0: inactive)"),
        (
            "sub",
            "uint",
            "sub-feature of the manifold (ContactManifold.sub): with body_a and "
            "body_b the warm-starting key",
        ),
    ],
    "One contact manifold prepared for the solver: up to four normal and eight friction rows.",
)

CONTACT_GEOMETRY = declare(
    "ContactGeometry",
    [
        (
            "face_u",
            "float4",
            "block solve (3-4 points): each point's offset from their centre along tangent1",
        ),
        ("face_v", "float4", "block solve: each point's offset along tangent2"),
        (
            "face_spread",
            "float4",
            "block solve: the points' second moments suu, suv, svv; w: 1 / det",
        ),
        (
            "face_arm",
            "float4",
            4,
            "block solve: A's lever arm x normal of the force, moment along u, moment along "
            "v, then B's of the force; [0].w: 1 when the block solve takes the points, else 0",
        ),
        ("face_turn_a", "float4", 3, "block solve: A's angular velocity change per unit of each"),
        ("face_turn_b", "float4", 3, "block solve: B's angular velocity change per unit of each"),
        ("face_q", "float4", 3, "block solve: the face's mobility Q, by rows"),
        ("face_inv_q", "float4", 3, "block solve: Q's inverse, by rows"),
        (
            "held_q",
            "float4",
            3,
            "a shock sweep's block solve (a contact whose tangent1.w holds a body still): "
            "Q with the held body's mass and inertia zero, by rows; [0].w: 1 when the "
            "block solve takes the points so, else 0",
        ),
        ("held_inv_q", "float4", 3, "a shock sweep's block solve: held_q's inverse, by rows"),
        (
            "face_k",
            "float4",
            4,
            "block solve: K = G Q G^T (the points' normal rows' coupling), by rows",
        ),
        (
            "friction_arm_a",
            "float4",
            2,
            "friction rows (tangent1, tangent2): A's lever arm x direction",
        ),
        ("friction_arm_b", "float4", 2, "friction rows: B's lever arm x direction"),
        (
            "friction_turn_a",
            "float4",
            2,
            "friction rows: A's angular velocity change per unit impulse",
        ),
        (
            "friction_turn_b",
            "float4",
            2,
            "friction rows: B's angular velocity change per unit impulse",
        ),
        (
            "twist_turn",
            "float4",
            2,
            "twist row: A's and B's angular velocity change per unit impulse; [0].w: the "
            "points' summed distance from their centre on B",
        ),
    ],
    "What the block solve derives of a contact constraint once a step (its lever "
    "arms, normal and the bodies' inertias hold over the substeps) and reads every sweep "
    "(solvers/contact_rows.cl.mako: FaceBlock, FrictionRows).",
)

# Shock propagation (solvers/pgs.cl.mako, SHOCK_PASS): which body of a contact the shock
# sweep holds still, in ContactConstraint.tangent1.w (a float holding the whole number).
SHOCK_HOLDS_NONE = constant("RB_SHOCK_HOLDS_NONE", 0, "a shock sweep moves both bodies")
SHOCK_HOLDS_A = constant("RB_SHOCK_HOLDS_A", 1, "a shock sweep holds body A (the lower) still")
SHOCK_HOLDS_B = constant("RB_SHOCK_HOLDS_B", 2, "a shock sweep holds body B (the lower) still")

# The constraint-edge list: what batching colours (contacts and, later, joints alike).
# Edge e of a step: joints first, at fixed indices (a joint stage writes edges
# [0, first_contact_edge)), then one edge per contact constraint, written by the
# constraint setup; the count stays on the device. An edge's item names its constraint:
# kind << RB_EDGE_KIND_SHIFT | index into that kind's own array. The contact kind is 0,
# so a contact's item is its constraint index.
EDGE_KIND_SHIFT = constant(
    "RB_EDGE_KIND_SHIFT", 28, "ConstraintEdge.item: kind << shift | index in the kind's array"
)
EDGE_INDEX_MASK = constant(
    "RB_EDGE_INDEX_MASK", (1 << 28) - 1, "ConstraintEdge.item: the index bits"
)
EDGE_CONTACT = constant("RB_EDGE_CONTACT", 0, "constraint kind: a ContactConstraint")
EDGE_JOINT = constant("RB_EDGE_JOINT", 1, "constraint kind: a JointConstraint")

CONSTRAINT_EDGE = declare(
    "ConstraintEdge",
    [
        ("body_a", "uint", "first body"),
        ("body_b", "uint", "second body"),
        ("item", "uint", "the constraint: kind << RB_EDGE_KIND_SHIFT | index in the kind's array"),
        (
            "colour",
            "uint",
            "global batching: the colour the next step's edge of this constraint "
            "starts from (RB_SOLVER_NONE: none)",
        ),
        (
            "point",
            "float4",
            "a world point of the constraint (a contact's first point), whose "
            "cell spatial batching groups it by; w unused",
        ),
    ],
    "One constraint as batching sees it: its two bodies, its kind and index, its colour.",
)

# --------------------------------------------------------------------------
# Narrowphase and hull cooking (owner: narrowphase; rbgen/hull.py,
# rbgen/pipeline/narrowphase/). A cooked hull is Shape.vertex_* vertices,
# Shape.face_* HullFace polygons whose vertex indices (relative to
# vertex_offset) live in the hull face-index uint array, and Shape.edge_*
# unique edge directions (float4, w unused). Boxes are cooked the same way.
HULL_FACE = declare(
    "HullFace",
    [
        ("plane", "float4", "outward unit normal xyz, offset w: n.x = w on the face (shape frame)"),
        ("index_offset", "uint", "first entry of this polygon in the face-index array"),
        ("index_count", "uint", "polygon vertices, counter-clockwise seen from outside"),
    ],
    "One planar polygon of a cooked convex hull.",
)

HULL_EDGE = declare(
    "HullEdge",
    [
        ("v0", "uint", "start vertex (relative to Shape.vertex_offset)"),
        ("v1", "uint", "end vertex; v0 -> v1 runs counter-clockwise around face f0"),
        ("f0", "uint", "face on the left of v0 -> v1 seen from outside (relative to face_offset)"),
        ("f1", "uint", "the other face"),
    ],
    "One edge of a cooked hull with its two faces (Gauss-map arc for the edge-edge SAT).",
)

PAIR_SWAPPED = constant(
    "RB_PAIR_SWAPPED",
    0x80000000,
    "queue entry bit: the pair's bodies are in the kernel's shape order b, a",
)
NO_FEATURE = constant("RB_NO_FEATURE", 0xFFFFFFFF, "separating-axis cache: no axis cached")
SAT_EDGE_PAIR = constant(
    "RB_SAT_EDGE_PAIR",
    0x80000000,
    "separating-axis feature bit: edge i of A x edge j of B in the HullEdge "
    "lists, i * B.adjacency_count + j in the low bits",
)

SAT_CACHE_ENTRY = declare(
    "SatCacheEntry",
    [
        ("a", "uint", "body a of the pair this entry belongs to (key)"),
        ("b", "uint", "body b (key)"),
        ("sub", "uint", "sub-feature of the pair (key, Pair.sub)"),
        ("feature", "uint", "best axis found last step (face/edge code) or RB_NO_FEATURE"),
    ],
    "Previous step's best separating axis, one entry per pair-list index, keyed by (a, b, sub).",
)

SAT_RESULT = declare(
    "SatResult",
    [
        (
            "axis",
            "float4",
            "unit axis from the kernel's first shape to its second (world); "
            "w: separation along it (< 0: penetration)",
        ),
        ("pair", "uint", "pair index, | RB_PAIR_SWAPPED when the kernel's first shape is body b"),
        ("feature", "uint", "face of A (< faces A), face of B (next faces B), else an edge pair"),
    ],
    "A convex-convex pair that passed the separating-axis test, queued for clipping.",
)

# --------------------------------------------------------------------------
# Midphase: triangle meshes and compounds (owner: midphase; rbgen/bvh.py, rbgen/mesh.py,
# rbgen/compound.py, rbgen/pipeline/midphase.py). A mesh is a BVH over its triangles in
# depth-first order (rbgen.bvh): a node's box is quantized to 16 bits per axis inside the
# mesh's quantization box, and an inner node stores minus the size of its subtree, which
# is the offset to the node after it (its "escape"), so a walk needs no stack.
BVH_QUANTA = constant("RB_BVH_QUANTA", 65535, "largest quantized coordinate of a BVH box")

BVH_NODE = declare(
    "BvhNode",
    [
        (
            "bounds",
            "uint",
            3,
            "quantized box: lower.x | lower.y << 16, lower.z | upper.x << 16, "
            "upper.y | upper.z << 16",
        ),
        (
            "index",
            "int",
            "leaf: its triangle (from the mesh's first, >= 0); inner node: minus "
            "the nodes of its subtree (itself included), the offset to its escape",
        ),
    ],
    "One node of a quantized BVH, in depth-first order.",
)

#: `MeshTriangle.edges` bit k: edge k (vertex k to vertex k + 1) is active
ACTIVE_EDGE_BITS = constant("RB_ACTIVE_EDGES", 7, "MeshTriangle.edges: the three active-edge bits")

MESH_TRIANGLE = declare(
    "MeshTriangle",
    [
        (
            "vertices",
            "uint",
            3,
            "indices into the mesh vertex array (float4, mesh frame), "
            "counter-clockwise seen from the front",
        ),
        (
            "edges",
            "uint",
            "bit k: edge from vertex k to vertex k + 1 is active (open, sharp or "
            "non-manifold): a contact on an inactive edge takes the face normal",
        ),
    ],
    "One triangle of a static mesh, in its BVH's leaf order.",
)

COMPOUND_CHILD = declare(
    "CompoundChild",
    [
        ("position", "float4", "origin of the child's frame in the compound's (principal) frame"),
        ("orientation", "float4", "rotation of the child's frame in the compound's (x, y, z, w)"),
        ("shape", "uint", "the child's Shape index"),
    ],
    "One child of a compound shape: a convex shape and where it sits.",
)

#: Pair.sub of a sub-feature pair: 1 + (child << RB_SUB_CHILD_SHIFT | other), where child is
#: a compound child (the first compound's) and other a triangle or the second compound's child
SUB_CHILD_SHIFT = constant(
    "RB_SUB_CHILD_SHIFT", 24, "Pair.sub = 1 + (compound child << shift | triangle or other child)"
)
MAX_COMPOUND_CHILDREN = constant("RB_MAX_COMPOUND_CHILDREN", 256, "children of one compound")
MAX_MESH_TRIANGLES = constant(
    "RB_MAX_MESH_TRIANGLES",
    (1 << 24) - 1,
    "triangles of one mesh (after degenerate ones are dropped)",
)
NO_SUBTREE = constant("RB_NO_SUBTREE", 0xFFFFFFFF, "midphase: no subtree requested")

CHILD_PROXY = declare(
    "ChildProxy",
    [
        ("body", "uint", "the compound body"),
        ("child", "uint", "which of its shape's children"),
    ],
    "A compound child as the narrowphase sees it: a body of its own after the world's "
    "bodies, placed where the child is.",
)

# --------------------------------------------------------------------------
# Broadphase (owner: broadphase; rbgen/pipeline/broadphase/).
#: `BroadphaseStatus.bad_body` when every AABB is valid.
BP_NO_BODY = constant("RB_BP_NO_BODY", 0xFFFFFFFF, "no invalid AABB found")

#: A body's collision word (the broadphase's per-body uint32 input, `rbgen.bodies`):
#: env << 1 | static. Two bodies pair only if not both static and in one environment,
#: or one is shared static geometry (RB_SHARED_STATIC), which meets every environment.
#: A World's bodies are all in environment 0 (the word is its static flag).
GROUP_STATIC = constant("RB_GROUP_STATIC", 1, "collision word: bit of a static body")
SHARED_STATIC = constant(
    "RB_SHARED_STATIC", 0xFFFFFFFF, "collision word of static geometry every environment meets"
)

BROADPHASE_STATUS = declare(
    "BroadphaseStatus",
    [
        ("pair_count", "uint", "pairs stored in the pair buffer: min(pairs_found, capacity)"),
        ("pairs_found", "uint", "pairs the query found; more than the capacity means overflow"),
        ("bad_body", "uint", "lowest body with a NaN or inverted AABB, RB_BP_NO_BODY if none"),
        ("crossings", "uint", "incremental SAP: endpoint crossings scanned this step"),
        ("retry", "uint", "nonzero (RB_BP_RETRY_*) when the query must be redone another way"),
    ],
    "Results of one broadphase query that the host checks without stalling the queue.",
)
#: `BroadphaseStatus.retry`: the grid met more large bodies than its owner rows.
BP_RETRY_LARGE = constant("RB_BP_RETRY_LARGE", 1, "grid: too many large bodies for owner rows")


# --------------------------------------------------------------------------
# Joints (owner: rbgen/joints.py, rbgen/pipeline/joints.py, solvers/joint_rows.cl.mako).
JOINT_BALL = constant("RB_JOINT_BALL", 0, "joint kind: anchors coincide (3 point rows)")
JOINT_FIXED = constant("RB_JOINT_FIXED", 1, "joint kind: point rows and 3 angular rows")
JOINT_HINGE = constant("RB_JOINT_HINGE", 2, "joint kind: point rows, 2 swing rows, limits, motor")
JOINT_SLIDER = constant(
    "RB_JOINT_SLIDER", 3, "joint kind: 3 angular rows, 2 rows across the axis, limits"
)
JOINT_DISTANCE = constant(
    "RB_JOINT_DISTANCE", 4, "joint kind: the anchors' distance kept in [min, max]"
)
JOINT_WORLD = constant("RB_JOINT_WORLD", 1, "JointConstraint.flags: body b is the world")
JOINT_LIMITS = constant("RB_JOINT_LIMITS", 2, "JointConstraint.flags: limit rows")
JOINT_MOTOR = constant(
    "RB_JOINT_MOTOR", 4, "JointConstraint.flags: a motor row (a ball joint: friction)"
)
JOINT_BROKEN = constant("RB_JOINT_BROKEN", 8, "JointConstraint.flags: broken, acts no more")

JOINT_CONSTRAINT = declare(
    "JointConstraint",
    [
        (
            "anchor_a",
            "float4",
            "anchor in A's body frame (m, about its centre of mass); w: distance joint's "
            "min length",
        ),
        (
            "anchor_b",
            "float4",
            "anchor in B's body frame (the world frame when B is the world); w: distance "
            "joint's max length",
        ),
        ("axis_a", "float4", "unit axis in A's body frame; w: lower limit (rad or m)"),
        ("axis_b", "float4", "unit axis in B's body frame; w: upper limit (rad or m)"),
        (
            "reference",
            "float4",
            "B's orientation relative to A's at creation, conj(q_a) q_b (quaternion)",
        ),
        (
            "motor",
            "float4",
            "x: motor target speed (rad/s), y: maximum torque (N m; a ball joint's "
            "friction torque), z: break impulse (N s; FLT_MAX: unbreakable); w unused",
        ),
        (
            "linear_impulse",
            "float4",
            "accumulated impulse on B of the linear rows, world (N s, warm started); w unused",
        ),
        (
            "angular_impulse",
            "float4",
            "accumulated angular impulse on B of the angular rows, world (N m s); w unused",
        ),
        (
            "axial_impulse",
            "float4",
            "accumulated impulses of the lower limit, upper limit and motor rows "
            "(x, y, z; a ball joint's: its friction block's world angular impulse); w unused",
        ),
        ("body_a", "uint", "first body (dynamic)"),
        ("body_b", "uint", "second body (== body_a when B is the world)"),
        ("kind", "uint", "RB_JOINT_*"),
        ("flags", "uint", "RB_JOINT_WORLD | RB_JOINT_LIMITS | RB_JOINT_MOTOR | RB_JOINT_BROKEN"),
    ],
    "One joint between two bodies, as the solver reads it (persistent on the device).",
)


# --------------------------------------------------------------------------
# Sleeping (owner: rbgen/pipeline/sleep.py). A dynamic body asleep is static to every
# other stage: its Body.inv_mass is 0 and its collision word has RB_GROUP_STATIC set;
# its own inverse mass waits in its BodySleep record until its island wakes.
SLEEP_AWAKE = constant("RB_SLEEP_AWAKE", 0, "BodySleep.asleep: the body moves")
SLEEP_ASLEEP = constant("RB_SLEEP_ASLEEP", 1, "BodySleep.asleep: the body's island sleeps")
SLEEP_WAKE = constant(
    "RB_SLEEP_WAKE", 1, "sleep mark of an island label: wake the sleeping island of that label"
)
SLEEP_RESTLESS = constant(
    "RB_SLEEP_RESTLESS",
    2,
    "sleep mark of an island label: a body of that awake island has not rested long enough",
)

BODY_SLEEP = declare(
    "BodySleep",
    [
        ("timer", "float", "seconds the body has moved slower than the sleep threshold"),
        (
            "island",
            "uint",
            "its island's label: the lowest body index of the island (kept while asleep, so "
            "that the island wakes whole)",
        ),
        ("inv_mass", "float", "the body's own inverse mass (0: static; Body.inv_mass is 0 asleep)"),
        ("extent", "float", "largest distance from its centre of mass to its surface (m)"),
        ("asleep", "uint", "RB_SLEEP_AWAKE or RB_SLEEP_ASLEEP"),
    ],
    "A body's sleep state: rest timer, island label, and what waking restores.",
)
