"""World AABBs: contain every rotated vertex and are tight (within 1e-5)."""

from __future__ import annotations

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen import layouts
from rbgen.codegen import TemplateParameterError
from rbgen.pipeline.aabbs import WorldAabbs
from rbgen.shapes import Box, Capsule, ConvexHull, Plane, ShapeTable, Sphere
from tests.conftest import SIZES
from tests.reference import quat_to_matrix, random_quaternions


def make_shapes(rng):
    return [
        Box(rng.uniform(0.1, 3, 3)),
        Box((1, 1, 1)),
        Sphere(0.7),
        ConvexHull(rng.normal(size=(12, 3))),
        ConvexHull(rng.uniform(-2, 2, (40, 3))),
        Capsule(0.3, 1.2),
    ]


def run_aabbs(runtime, table, bodies, margin=0.0, work_group_size=None):
    shapes, verts = table.pack()
    n = len(bodies)
    q = runtime.queue
    stage = WorldAabbs(runtime, table.type_names(), work_group_size=work_group_size)
    d_bodies = cla.to_device(q, bodies) if n else cla.empty(q, 1, layouts.BODY.dtype)
    out = cla.empty(q, max(n, 1), layouts.AABB.dtype)
    stage(d_bodies, cla.to_device(q, shapes), cla.to_device(q, verts), out, n, margin)
    return out.get()[:n]


def expected_bounds(shape, position, orientation):
    """float64 bounds from the shape's exact geometry."""
    R = quat_to_matrix(orientation.astype(np.float64))
    if isinstance(shape, Sphere):
        return position - shape.radius, position + shape.radius
    if isinstance(shape, Capsule):
        ends = np.array([[0, shape.half_height, 0], [0, -shape.half_height, 0]]) @ R.T + position
        return ends.min(0) - shape.radius, ends.max(0) + shape.radius
    world = shape.local_vertices() @ R.T + position
    return world.min(0), world.max(0)


@pytest.mark.parametrize("n", SIZES)
def test_contains_and_tight(runtime, rng, n):
    table = ShapeTable()
    shape_list = make_shapes(rng)
    ids = [table.add(s) for s in shape_list]
    bodies = layouts.BODY.zeros(n)
    which = rng.integers(0, len(shape_list), n)
    bodies["shape"] = np.asarray(ids)[which]
    bodies["position"][:, :3] = rng.uniform(-100, 100, (n, 3))
    bodies["orientation"] = random_quaternions(rng, n)
    got = run_aabbs(runtime, table, bodies)
    check = range(n) if n <= 1000 else rng.choice(n, 1000, replace=False)
    for i in check:
        lo, hi = expected_bounds(
            shape_list[which[i]],
            bodies["position"][i, :3].astype(np.float64),
            bodies["orientation"][i],
        )
        np.testing.assert_allclose(got["lower"][i, :3], lo, atol=1e-5 + 1e-6 * np.abs(lo).max())
        np.testing.assert_allclose(got["upper"][i, :3], hi, atol=1e-5 + 1e-6 * np.abs(hi).max())


@pytest.mark.parametrize("work_group_size", [1, 16, 128])
def test_every_rotated_vertex_inside_with_margin(runtime, rng, work_group_size):
    n = 257
    table = ShapeTable()
    box, hull = Box(rng.uniform(0.2, 2, 3)), ConvexHull(rng.normal(size=(30, 3)))
    ids = [table.add(box), table.add(hull)]
    bodies = layouts.BODY.zeros(n)
    which = rng.integers(0, 2, n)
    bodies["shape"] = np.asarray(ids)[which]
    bodies["position"][:, :3] = rng.uniform(-5, 5, (n, 3))
    bodies["orientation"] = random_quaternions(rng, n)
    margin = 0.05
    got = run_aabbs(runtime, table, bodies, margin=margin, work_group_size=work_group_size)
    R = quat_to_matrix(bodies["orientation"].astype(np.float64))
    for i in range(n):
        verts = (box, hull)[which[i]].local_vertices() @ R[i].T + bodies["position"][i, :3]
        assert np.all(verts >= got["lower"][i, :3] + margin - 1e-5)
        assert np.all(verts <= got["upper"][i, :3] - margin + 1e-5)
        # tight: every face of the box touches a vertex
        assert np.allclose(verts.min(0), got["lower"][i, :3] + margin, atol=1e-5)
        assert np.allclose(verts.max(0), got["upper"][i, :3] - margin, atol=1e-5)


def test_ground_plane_is_bounded_on_its_normal_axis(runtime):
    table = ShapeTable()
    ground = table.add(Plane((0, 1, 0), 0.5))
    bodies = layouts.BODY.zeros(1)
    bodies["shape"] = ground
    bodies["orientation"][:, 3] = 1
    got = run_aabbs(runtime, table, bodies)
    assert got["upper"][0, 1] == pytest.approx(0.5)
    assert got["lower"][0, 1] < -1e29 and got["upper"][0, 0] > 1e29 and got["lower"][0, 2] < -1e29


def test_posed_plane_is_bounded_where_the_narrowphase_puts_it(runtime):
    """Plane n.x <= 0.5 (n = +y) on a body at (1, 2, 3): turned -90 deg about z its world
    normal is +x and its offset 0.5 + n.(1, 2, 3) = 1.5 (upper x); turned 180 deg about x
    the normal is -y and the offset 0.5 - 2 = -1.5 (lower y = 1.5); unbounded elsewhere."""
    table = ShapeTable()
    ground = table.add(Plane((0, 1, 0), 0.5))
    bodies = layouts.BODY.zeros(2)
    bodies["shape"] = ground
    bodies["position"][:, :3] = (1, 2, 3)
    bodies["orientation"] = [(0, 0, -np.sin(np.pi / 4), np.cos(np.pi / 4)), (1, 0, 0, 0)]
    got = run_aabbs(runtime, table, bodies)
    assert got["upper"][0, 0] == pytest.approx(1.5, abs=1e-6)
    assert got["lower"][1, 1] == pytest.approx(1.5, abs=1e-6)
    unbounded = np.concatenate(
        [got["lower"][0, :3], got["upper"][0, 1:3], got["lower"][1, [0, 2]], got["upper"][1, :3]]
    )
    assert np.all(np.abs(unbounded) > 1e29)


def test_shape_type_parameter_is_validated(runtime):
    with pytest.raises(TemplateParameterError, match="shape_types"):
        WorldAabbs(runtime, ("box", "torus"))
