"""The shape-type and pair-kernel registries: every list of types is derived from them, and
a new shape type is its registry entry plus its kernels.

The new type of these tests, "ball" (a sphere under another name), is written the way a
real one would be: a Shape subclass (its entry), its world-AABB function in
``templates/shapes/ball.cl.mako`` and a template of pair kernels declared with
`register_pair_kernel`. Nothing else changes, and the stages then handle it: world AABBs
(centre +- r), routing beside built-in kinds, and contacts with the closed forms of
spheres (separation = distance - radii, normal along the centres, points on body b).
The registries, the constants and the template directory are copies restored after.
"""

from __future__ import annotations

import re
import shutil

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen import codegen, layouts
from rbgen import mass as mass_props
from rbgen import shapes as shapes_module
from rbgen.bodies import bounding_radius, check_supported, supported_shapes
from rbgen.codegen import KernelTemplate
from rbgen.errors import RbgenError
from rbgen.pipeline.aabbs import TEMPLATE as WORLD_AABBS
from rbgen.pipeline.aabbs import WorldAabbs
from rbgen.pipeline.narrowphase import Narrowphase, find_contacts, kinds
from rbgen.pipeline.narrowphase.kinds import (
    PairKernel,
    kernel_for,
    kinds_for,
    missing_pairs,
    pair_kernels,
    register_pair_kernel,
)
from rbgen.pipeline.narrowphase.templates import DISPATCH, PAIR_ROLES, pair_kernel_params
from rbgen.shapes import (
    Box,
    Plane,
    Shape,
    ShapeTable,
    Sphere,
    shape_type,
    shape_type_names,
    shape_types,
)

from .reference import make_bodies

BALL_AABB = """/* ---- Ball (a test's shape type): world AABB ---- */

inline void ball_world_aabb(Shape shape, float3 centre, float3 r0, float3 r1, float3 r2,
                            __global const float4* hull_vertices, float3* lower, float3* upper)
{
    *lower = centre - shape.extents.x;
    *upper = centre + shape.extents.x;
}
"""

BALL_PAIRS = """/* Ball pairs (a test's shape type): ${", ".join(kinds)}. One work-item per
 * queued pair; a work group is responsible for ${work_group_size} entries of the queue. */
${cl_constants()}

${cl_structs("Body", "Shape", "Pair", "ContactManifold")}

<%include file="/common/quaternion.cl.mako"/>
<%include file="/pipeline/narrowphase/common.cl.mako"/>
<%include file="/pipeline/narrowphase/store_manifold.cl.mako"/>
<%def name="arguments()">__global const Pair* pairs, __global const Body* bodies,
        __global const Shape* shapes, __global const uint* queues,
        __global const uint* queue_counts, const uint pair_capacity, const uint kind,
        __global ContactManifold* slots, __global uint* contact_flags,
        __global uint* tile_counts, const float margin</%def>
% if "ball_round" in kinds:

/* A ball (first) against a ball or a sphere (second): both keep their radius in extents.x. */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void ball_round(${arguments()})
{
    uint slot = get_global_id(0);
    if (slot >= queue_counts[kind])
        return;
    QueuedPair q = decode_queue_entry(queues[kind * pair_capacity + slot], pairs);
    Body a = bodies[q.first], b = bodies[q.second];
    float ra = shapes[a.shape].extents.x, rb = shapes[b.shape].extents.x;
    float3 d = b.position.xyz - a.position.xyz;
    float distance = length3(d);
    if (distance - ra - rb > margin)
        return;
    float3 normal = d / distance;
    float4 point = (float4)(b.position.xyz - normal * rb, distance - ra - rb);
    uint feature = 0u;
    store_manifold(slots, contact_flags, tile_counts, q, normal, &point, &feature, 1u);
}
% endif
% if "ball_plane" in kinds:

/* A ball (first) against a plane (second). */
__kernel __attribute__((reqd_work_group_size(${work_group_size}, 1, 1)))
void ball_plane(${arguments()})
{
    uint slot = get_global_id(0);
    if (slot >= queue_counts[kind])
        return;
    QueuedPair q = decode_queue_entry(queues[kind * pair_capacity + slot], pairs);
    Body a = bodies[q.first], b = bodies[q.second];
    float radius = shapes[a.shape].extents.x;
    Placement plane_body = placement_of(b);
    float4 plane = plane_to_world(&plane_body, shapes[b.shape].extents);
    float height = dot3(plane.xyz, a.position.xyz) - plane.w;
    if (height - radius > margin)
        return;
    float4 point = (float4)(a.position.xyz - plane.xyz * height, height - radius);
    uint feature = 0u;
    store_manifold(slots, contact_flags, tile_counts, q, -plane.xyz, &point, &feature, 1u);
}
% endif
"""


@pytest.fixture
def registries(monkeypatch, tmp_path):
    """Copies of both registries, of the constants and of the template directory, so that a
    test can add a shape type and its kernels; everything is restored afterwards."""
    monkeypatch.setattr(shapes_module, "_SHAPE_TYPES", dict(shapes_module._SHAPE_TYPES))
    monkeypatch.setattr(kinds, "_KINDS", dict(kinds._KINDS))
    monkeypatch.setattr(layouts, "_CONSTANTS", dict(layouts._CONSTANTS))
    monkeypatch.setattr(codegen, "TEMPLATES", dict(codegen.TEMPLATES))
    templates = tmp_path / "templates"
    shutil.copytree(codegen.TEMPLATE_DIR, templates)
    monkeypatch.setattr(codegen, "TEMPLATE_DIR", templates)
    codegen._lookup.cache_clear()
    codegen.render.cache_clear()
    yield templates
    codegen._lookup.cache_clear()  # (monkeypatch restores the directory after this)
    codegen.render.cache_clear()


def define_ball(templates, *, with_kernels: bool = True):
    """The test's new shape type: its entry (a class), its AABB file and its pair kernels."""
    (templates / "shapes" / "ball.cl.mako").write_text(BALL_AABB)

    class Ball(Shape):
        type_name = "ball"
        type_code = 7
        extents_doc = "extents.x = radius"
        aabb_template = "shapes/ball.cl.mako"

        def __init__(self, radius):
            self.radius = float(radius)

        def pack(self, record, hull_vertices):
            record["extents"] = (self.radius, 0, 0, 0)

        def key(self):
            return ("ball", self.radius)

        def mass_properties(self, density=None, mass=None):
            return self._solid(
                4.0 / 3.0 * np.pi * self.radius**3,
                mass_props.sphere_unit_inertia(self.radius),
                density,
                mass,
            )

        def bounding_radius(self):
            return self.radius

    if with_kernels:
        path = "pipeline/narrowphase/ball_pairs.cl.mako"
        (templates / path).write_text(BALL_PAIRS)
        template = KernelTemplate(
            path, pair_kernel_params(path), doc="Ball pairs.", roles=PAIR_ROLES
        )
        register_pair_kernel(
            PairKernel("ball_round", [("ball", "ball"), ("ball", "sphere")], template)
        )
        register_pair_kernel(PairKernel("ball_plane", [("ball", "plane")], template))
    return Ball


def test_every_type_list_is_derived_from_the_registry():
    """The AABB kernel has one case per registered type, calling <type>_world_aabb; the
    dispatch kernel one test per declared type pair (both orders); every pair of
    registered types (but two static-only ones, and pairs with a composite type, which the
    midphase turns into its children's) has exactly one kernel; a World accepts
    every registered type; ShapeTable.type_names are registry names."""
    names = shape_type_names()
    assert set(names) == {"sphere", "box", "capsule", "hull", "plane", "mesh", "compound"}
    aabbs = WORLD_AABBS.spec(work_group_size=64, shape_types=tuple(sorted(names))).source
    assert re.findall(r"case (RB_SHAPE_\w+):", aabbs) == [
        shape_type(n).type_constant for n in sorted(names)
    ]
    for name in names:
        assert f"{name}_world_aabb(shape, centre" in aabbs
    every_kind = tuple(k.name for k in pair_kernels())
    assert kinds_for(names) == every_kind
    dispatch = DISPATCH.spec(work_group_size=16, kinds=every_kind, placement_tile=1024).source
    tests = re.findall(r"if \(ta == (RB_SHAPE_\w+) && tb == (RB_SHAPE_\w+)\)", dispatch)
    declared = [
        (shape_type(f).type_constant, shape_type(s).type_constant)
        for k in pair_kernels()
        for f, s in k.pairs
    ]
    assert sorted(tests) == sorted(set(declared + [(s, f) for f, s in declared]))
    assert missing_pairs(names) == []
    for a in names:
        for b in names:
            if (
                shape_type(a).static_only
                and shape_type(b).static_only
                or shape_type(a).composite
                or shape_type(b).composite
            ):
                assert kernel_for(a, b) is None  # (a compound's pairs are its children's)
            else:
                kind, swapped = kernel_for(a, b)
                assert ((b, a) if swapped else (a, b)) in kind.pairs
    assert supported_shapes() == shape_types()
    table = ShapeTable()
    for shape in (Box((1, 1, 1)), Plane(), Sphere(0.5)):
        table.add(shape)
    assert table.type_names() == ("box", "plane", "sphere")


def test_a_new_shape_type_is_its_entry_and_its_kernels(runtime, rng, registries):
    """A ball type added by its entry and kernels only: world AABBs centre +- r, a World
    accepts balls beside planes and spheres (not beside boxes: no kernel), and the
    narrowphase routes plane-ball (swapped), sphere-ball (swapped) and ball-ball pairs to
    the new kernels beside the built-in sphere_plane, with the spheres' closed forms."""
    Ball = define_ball(registries)
    assert layouts.constants()["RB_SHAPE_BALL"] == 7 and Ball.type_constant == "RB_SHAPE_BALL"
    ball = Ball(0.4)
    assert bounding_radius(ball) == 0.4
    assert ball.mass_properties(density=2.0).mass == pytest.approx(2.0 * 4 / 3 * np.pi * 0.4**3)
    check_supported(ball, ("plane", "sphere"))
    with pytest.raises(RbgenError, match=r"\('ball', 'box'\)"):
        check_supported(ball, ("box", "plane"))

    table = ShapeTable()
    ground, sphere, rounded = table.add(Plane()), table.add(Sphere(0.5)), table.add(ball)
    assert table.type_names() == ("ball", "plane", "sphere")
    d = 0.03
    centres = np.array([(0, 0, 0), (0.0, 0.5 - d, 0.0), (0.3, 0.4 - d, 0.6), (1.0, 0.38, 0.7)])
    bodies = make_bodies([ground, sphere, rounded, rounded], centres)
    q = runtime.queue

    aabbs = cla.empty(q, 4, layouts.AABB.dtype)
    packed = table.pack_all()
    WorldAabbs(runtime, table.type_names())(
        cla.to_device(q, bodies),
        cla.to_device(q, packed.shapes),
        cla.to_device(q, packed.vertices),
        aabbs,
        4,
    )
    boxes = aabbs.get()
    for body in (2, 3):
        np.testing.assert_allclose(boxes["lower"][body, :3], centres[body] - 0.4, atol=1e-6)
        np.testing.assert_allclose(boxes["upper"][body, :3], centres[body] + 0.4, atol=1e-6)

    narrowphase = Narrowphase(runtime, table)
    assert narrowphase.kinds == ("sphere_sphere", "sphere_plane", "ball_round", "ball_plane")
    pairs = [(0, 1), (0, 2), (1, 2), (2, 3)]
    found = {
        (int(m["body_a"]), int(m["body_b"])): m
        for m in find_contacts(runtime, table, bodies, pairs)
    }
    assert set(found) == set(pairs)
    radius = {1: 0.5, 2: 0.4, 3: 0.4}
    for a, b in pairs:
        m = found[(a, b)]
        assert m["point_count"] == 1
        if a == 0:  # the plane y = 0: normal +y, the point under b's centre on its surface
            normal, separation = np.array([0.0, 1.0, 0.0]), centres[b][1] - radius[b]
        else:
            offset = centres[b] - centres[a]
            normal = offset / np.linalg.norm(offset)
            separation = np.linalg.norm(offset) - radius[a] - radius[b]
        np.testing.assert_allclose(m["normal"][:3], normal, atol=2e-6)
        np.testing.assert_allclose(m["points"][0, :3], centres[b] - radius[b] * normal, atol=2e-6)
        assert m["points"][0, 3] == pytest.approx(separation, abs=2e-6)


def test_missing_kernels_and_clashes_are_refused(registries):
    """A registered type without kernels: its pairs are named as missing (a World refuses
    it, kinds_for raises); a second kernel for a handled pair, a duplicate type name, a
    taken type code and a name that cannot be part of a kind name are refused."""
    Ball = define_ball(registries, with_kernels=False)
    assert ("ball", "box") in missing_pairs(shape_type_names())
    assert Ball not in supported_shapes()
    with pytest.raises(RbgenError, match=r"no pair kernel handles \[\('ball', 'ball'\)"):
        kinds_for(("ball",))
    with pytest.raises(RbgenError, match="Ball has no narrowphase kernel"):
        check_supported(Ball(1.0), ())
    with pytest.raises(RbgenError, match="already handled by 'sphere_plane'"):
        register_pair_kernel(
            PairKernel(
                "plane_sphere", [("plane", "sphere")], kinds.pair_kernel("sphere_plane").template
            )
        )

    def declare(name, code):
        return type(
            "Other",
            (Shape,),
            {"type_name": name, "type_code": code, "aabb_template": "shapes/ball.cl.mako"},
        )

    with pytest.raises(RbgenError, match="already Ball's"):
        declare("ball", 8)
    with pytest.raises(RbgenError, match="no other type uses"):
        declare("pebble", Box.type_code)
    with pytest.raises(RbgenError, match="lower-case"):
        declare("round_ball", 9)
