"""Narrowphase contacts against closed-form answers, on every device.

Conventions checked throughout (rbgen/layouts.py, ContactManifold): the
normal points from body_a to body_b, points lie on body_b with the signed
separation in w (negative: penetration).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from rbgen import layouts
from rbgen.errors import RbgenError
from rbgen.pipeline.narrowphase import Narrowphase, find_contacts, kinds_for
from rbgen.shapes import Box, Capsule, ConvexHull, Plane, ShapeTable, Sphere

from .reference import axis_angle, make_bodies, pair_records, quat_matrix

ATOL = 2e-5  # float32 positions of size ~1


def contacts(runtime, table, bodies, pairs, margin=0.0):
    m = find_contacts(runtime, table, bodies, pairs, margin=margin)
    return {(int(r["body_a"]), int(r["body_b"])): r for r in m}


def points(manifold):
    return manifold["points"][: manifold["point_count"]].astype(np.float64)


def same_point_sets(got, expected, atol=ATOL):
    got, expected = np.asarray(got, np.float64), np.asarray(expected, np.float64)
    if got.shape != expected.shape:
        return False
    d = np.linalg.norm(got[:, None, :] - expected[None, :, :], axis=-1)
    return bool(np.all(d.min(axis=1) < atol) and np.all(d.min(axis=0) < atol))


def test_box_face_on_plane(runtime, rng):
    """Box sunk by d, yawed: 4 points at its bottom corners, separation -d, normal +y."""
    table = ShapeTable()
    ground, box = table.add(Plane((0, 1, 0), 0.0)), table.add(Box((0.5, 0.75, 1.0)))
    d, yaw = 0.0123, rng.uniform(0, 2 * np.pi)
    q = axis_angle((0, 1, 0), yaw)
    bodies = make_bodies([ground, box], [(0, 0, 0), (0.3, 0.75 - d, -0.2)], [(0, 0, 0, 1), q])
    m = contacts(runtime, table, bodies, [(0, 1)])[(0, 1)]
    assert m["point_count"] == 4
    np.testing.assert_allclose(m["normal"][:3], (0, 1, 0), atol=1e-6)
    corners = table.shapes[box].local_vertices() @ quat_matrix(q).T + (0.3, 0.75 - d, -0.2)
    bottom = corners[corners[:, 1] < 0]
    assert same_point_sets(points(m)[:, :3], bottom)
    np.testing.assert_allclose(points(m)[:, 3], -d, atol=ATOL)


def test_box_face_on_box(runtime, rng):
    """A yawed unit box sunk by d into a wide box: its 4 bottom corners, separation -d."""
    table = ShapeTable()
    wide, cube = table.add(Box((3.0, 1.0, 3.0))), table.add(Box((0.5, 0.5, 0.5)))
    d, yaw = 0.02, rng.uniform(0, 2 * np.pi)
    q = axis_angle((0, 1, 0), yaw)
    centre = np.array([0.4, 1.5 - d, -0.3])
    bodies = make_bodies([wide, cube], [(0, 0, 0), centre], [(0, 0, 0, 1), q])
    m = contacts(runtime, table, bodies, [(0, 1)])[(0, 1)]
    assert m["point_count"] == 4
    np.testing.assert_allclose(m["normal"][:3], (0, 1, 0), atol=1e-6)
    corners = table.shapes[cube].local_vertices() @ quat_matrix(q).T + centre
    assert same_point_sets(points(m)[:, :3], corners[corners[:, 1] < centre[1]])
    np.testing.assert_allclose(points(m)[:, 3], -d, atol=ATOL)
    assert len(set(m["features"][:4].tolist())) == 4, "feature ids must tell the points apart"


def test_rotated_box_corner_on_plane(runtime):
    """A cube standing on a corner (diagonal vertical) sunk by d: one point, depth d."""
    table = ShapeTable()
    ground, cube = table.add(Plane((0, 1, 0), 0.0)), table.add(Box((1.0, 1.0, 1.0)))
    diagonal = np.array([1.0, 1.0, 1.0]) / np.sqrt(3)
    axis = np.cross(diagonal, (0, -1, 0))
    q = axis_angle(axis, np.arccos(np.dot(diagonal, (0, -1, 0))))
    d = 0.01
    centre = np.array([0.2, np.sqrt(3) - d, 0.1])
    bodies = make_bodies([ground, cube], [(0, 0, 0), centre], [(0, 0, 0, 1), q])
    m = contacts(runtime, table, bodies, [(0, 1)])[(0, 1)]
    assert m["point_count"] == 1
    np.testing.assert_allclose(points(m)[0], (0.2, -d, 0.1, -d), atol=1e-5)


def test_boxes_crossing_edge_to_edge(runtime):
    """Edge along z (top of A, turned 45 deg about z) on edge along x (bottom of B,
    turned 45 deg about x): one point on B's edge, normal z x x = +y, depth d."""
    table = ShapeTable()
    cube = table.add(Box((1.0, 1.0, 1.0)))
    d = 0.015
    top = np.sqrt(2)
    qa, qb = axis_angle((0, 0, 1), np.pi / 4), axis_angle((1, 0, 0), np.pi / 4)
    bodies = make_bodies([cube, cube], [(0, 0, 0), (0, 2 * top - d, 0)], [qa, qb])
    m = contacts(runtime, table, bodies, [(0, 1)])[(0, 1)]
    assert m["point_count"] == 1
    np.testing.assert_allclose(m["normal"][:3], (0, 1, 0), atol=1e-5)
    np.testing.assert_allclose(points(m)[0], (0, top - d, 0, -d), atol=1e-5)


def test_swapping_bodies_flips_the_normal(runtime, rng):
    """Same geometry with A and B exchanged: normal negated, points moved onto the new B
    (p' = p - s n), separations unchanged."""
    table = ShapeTable()
    cube, ball = table.add(Box((0.6, 0.5, 0.4))), table.add(Sphere(0.5))
    q = axis_angle(rng.normal(size=3), 0.3)
    positions = [(0, 0, 0), (0.2, 0.95, 0.1), (0.1, 0.2, 0.8)]
    shapes = [cube, cube, ball]
    for order in ([0, 1, 2], [2, 1, 0]):
        bodies = make_bodies(
            [shapes[i] for i in order],
            [positions[i] for i in order],
            [q if i == 1 else (0, 0, 0, 1) for i in order],
        )
        found = contacts(runtime, table, bodies, [(0, 1), (1, 2), (0, 2)])
        if order == [0, 1, 2]:
            first = found
            continue
        remap = {0: 2, 1: 1, 2: 0}
        for (a, b), m in first.items():
            other = found[tuple(sorted((remap[a], remap[b])))]
            assert other["point_count"] == m["point_count"]
            n = m["normal"][:3].astype(np.float64)
            np.testing.assert_allclose(other["normal"][:3], -n, atol=1e-5)
            moved = points(m)[:, :3] - n * points(m)[:, 3:]
            assert same_point_sets(points(other)[:, :3], moved, atol=1e-4)
            np.testing.assert_allclose(
                np.sort(points(other)[:, 3]), np.sort(points(m)[:, 3]), atol=1e-5
            )


def test_sphere_cases(runtime, rng):
    """Sphere-sphere, sphere-plane, sphere-box (face, edge, corner regions, centre inside):
    separation = distance to the closest surface point - radius, normal along it."""
    table = ShapeTable()
    ball, ground = table.add(Sphere(0.5)), table.add(Plane(rng.normal(size=3), 0.3))
    cube = table.add(Box((1.0, 0.8, 0.6)))
    plane = table.shapes[ground]
    q = axis_angle(rng.normal(size=3), rng.uniform(0, np.pi))
    r = quat_matrix(q)
    h = table.shapes[cube].half_extents
    local_centres = [(0, 0.8 + 0.45, 0), (1.2, 0.95, 0.1), (1.3, 1.0, 0.75), (0.2, 0.35, -0.1)]
    box_at = np.array([5.0, 5.0, 5.0])
    # sphere-sphere: 0-1; sphere-plane: 2-3; sphere-box: box 4, spheres 5..8
    positions = [
        (0, 0, 0),
        (0.3, 0.85, -0.2),
        tuple(plane.normal * (0.3 + 0.47)),
        (0, 0, 0),
        box_at,
    ]
    positions += [tuple(box_at + r @ c) for c in local_centres]
    shapes = [ball, ball, ball, ground, cube] + [ball] * 4
    orient = [(0, 0, 0, 1)] * 4 + [q] + [(0, 0, 0, 1)] * 4
    bodies = make_bodies(shapes, positions, orient)
    pairs = [(0, 1), (2, 3), (4, 5), (4, 6), (4, 7), (4, 8)]
    found = contacts(runtime, table, bodies, pairs)
    assert set(found) == set(pairs)

    def check(pair, normal, separation, point):
        m = found[pair]
        assert m["point_count"] == 1
        np.testing.assert_allclose(m["normal"][:3], normal, atol=1e-5)
        np.testing.assert_allclose(points(m)[0], (*point, separation), atol=2e-5)

    d = np.array(positions[1]) - positions[0]
    n = d / np.linalg.norm(d)
    check((0, 1), n, np.linalg.norm(d) - 1.0, positions[1] - 0.5 * n)
    # sphere (body 2) against plane (body 3): normal from sphere into the plane
    check((2, 3), -plane.normal, 0.47 - 0.5, np.zeros(3) + plane.normal * 0.3)
    for k, c in enumerate(local_centres):
        c = np.array(c)
        closest = np.clip(c, -h, h)
        if np.all(np.abs(c) <= h):  # inside: out through the nearest face
            axis = int(np.argmin(h - np.abs(c)))
            closest = c.copy()
            closest[axis] = np.sign(c[axis]) * h[axis]
            separation = -np.linalg.norm(closest - c) - 0.5
            normal_local = (closest - c) / np.linalg.norm(closest - c)
        else:
            separation = np.linalg.norm(c - closest) - 0.5
            normal_local = (c - closest) / np.linalg.norm(c - closest)
        # pair (box, sphere): normal from the box to the sphere, point on the sphere
        normal = r @ normal_local
        sphere_centre = box_at + r @ c
        check((4, 5 + k), normal, separation, sphere_centre - 0.5 * normal)


def test_separated_shapes_and_margin(runtime):
    """A gap g gives no contact with margin < g and one with separation +g with margin > g."""
    table = ShapeTable()
    cube, ball, ground = table.add(Box((1, 1, 1))), table.add(Sphere(0.5)), table.add(Plane())
    g = 0.05
    bodies = make_bodies(
        [ground, cube, cube, ball, ball],
        [(0, 0, 0), (0, 1 + g, 0), (0, 3 + 2 * g, 0), (0, 4 + 2 * g + 0.5 + g, 0), (5, 0.5 + g, 0)],
    )
    pairs = [(0, 1), (1, 2), (2, 3), (0, 4)]
    assert contacts(runtime, table, bodies, pairs, margin=0.5 * g) == {}
    found = contacts(runtime, table, bodies, pairs, margin=2 * g)
    assert set(found) == set(pairs)
    for m in found.values():
        np.testing.assert_allclose(points(m)[:, 3], g, atol=2e-5)


@pytest.mark.parametrize("count", [0, 1, 33, 1000])
def test_many_boxes_on_plane(runtime, rng, count):
    """count yawed boxes at random depths in [-0.1, 0.1): those within the margin 0.02 give
    4 points each at separation y - h; manifolds are in pair order."""
    table = ShapeTable()
    ground, box = table.add(Plane()), table.add(Box((0.5, 0.25, 0.5)))
    depth = rng.uniform(-0.1, 0.1, count)
    yaw = rng.uniform(0, 2 * np.pi, count)
    q = np.array([axis_angle((0, 1, 0), a) for a in yaw]).reshape(-1, 4)
    xz = rng.uniform(-50, 50, (count, 2))
    pos = np.column_stack([xz[:, 0], 0.25 + depth, xz[:, 1]])
    bodies = make_bodies(
        [ground] + [box] * count, np.vstack([[0, 0, 0], pos]), np.vstack([[0, 0, 0, 1], q])
    )
    m = find_contacts(runtime, table, bodies, [(0, i + 1) for i in range(count)], margin=0.02)
    expected = np.nonzero(depth <= 0.02)[0] + 1
    np.testing.assert_array_equal(m["body_b"], expected)
    assert np.all(m["point_count"] == 4)
    np.testing.assert_allclose(
        m["points"][:, :, 3], np.repeat(depth[expected - 1], 4).reshape(-1, 4), atol=2e-5
    )
    np.testing.assert_allclose(m["friction"], 0.5, rtol=1e-6)


def test_overflow_grows_and_keeps_everything(runtime):
    """A manifold capacity of 1 for 7 contacts: the step flags 7, find_contacts grows and redoes."""
    table = ShapeTable()
    ground, ball = table.add(Plane()), table.add(Sphere(1.0))
    bodies = make_bodies([ground] + [ball] * 7, [(0, 0, 0)] + [(3 * i, 0.9, 0) for i in range(7)])
    narrowphase = Narrowphase(runtime, table)
    import pyopencl.array as cla

    q = runtime.queue
    pairs = layouts.PAIR.zeros(7)
    pairs["b"] = np.arange(1, 8)
    packed = table.pack_all().to_device(q)
    d_bodies, d_pairs = cla.to_device(q, bodies), cla.to_device(q, pairs)
    manifolds = cla.empty(q, 1, layouts.CONTACT_MANIFOLD.dtype)
    count, overflow = cla.zeros(q, 1, np.uint32), cla.zeros(q, 1, np.uint32)
    narrowphase.enqueue(
        d_bodies,
        packed,
        d_pairs,
        cla.to_device(q, np.array([7], np.uint32)),
        manifolds,
        count,
        overflow,
        0.0,
    )
    assert overflow.get()[0] == 7 and count.get()[0] == 7
    m = narrowphase.find_contacts(d_bodies, packed, d_pairs, 7, capacity=1)
    np.testing.assert_array_equal(m["body_b"], np.arange(1, 8))


def test_icosphere_hull_behaves_like_a_sphere(runtime, rng):
    """trimesh icosphere(subdivisions=3) (1280 triangles, the closest subdivision to ~900):
    against a plane and a sphere its depth and normal match a unit sphere within the
    hull's resolution (faces lie at most 1 - cos(edge angle) inside the sphere)."""
    mesh = trimesh.creation.icosphere(subdivisions=3)
    hull = ConvexHull.from_trimesh(mesh, name="icosphere")
    resolution = 1.0 - np.min(np.abs(hull.cooked().planes[:, 3]))
    assert 0 < resolution < 0.01
    table = ShapeTable()
    ground, rock, ball = table.add(Plane()), table.add(hull), table.add(Sphere(0.5))
    q = axis_angle(rng.normal(size=3), rng.uniform(0, np.pi))
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    d = 0.05
    # plane under a hull sunk by d; a sphere of radius 0.5 sunk by d into a hull along `direction`
    bodies = make_bodies(
        [ground, rock, rock, ball],
        [(0, 0, 0), (0, 1 - d, 0), (0, 0, 0), (1.5 - d) * direction],
        [(0, 0, 0, 1), q, q, (0, 0, 0, 1)],
    )
    found = contacts(runtime, table, bodies, [(0, 1), (2, 3)])
    plane_contact, sphere_contact = found[(0, 1)], found[(2, 3)]
    assert plane_contact["point_count"] >= 1
    assert -d - 1e-5 <= points(plane_contact)[:, 3].min() <= -d + resolution + 1e-5
    m = sphere_contact
    assert m["point_count"] == 1
    angle = np.arccos(np.clip(np.dot(m["normal"][:3], direction), -1, 1))
    assert angle < 2 * np.sqrt(2 * resolution)
    assert -d - 1e-5 <= points(m)[0, 3] <= -d + resolution + 1e-5


def test_unsupported_shapes_fail_at_construction(runtime):
    assert kinds_for(("box", "plane")) == ("convex_plane", "box_box")
    with pytest.raises(RbgenError, match="voxels"):
        Narrowphase(runtime, ("box", "voxels"))


@pytest.mark.parametrize(
    "work_group_size,placement_tile",
    [(1, None), (64, None), (1, 1), (16, 16), (64, 256), (32, 1024)],
)
def test_mixed_world_is_independent_of_work_group_size(
    runtime, rng, work_group_size, placement_tile
):
    """Spheres, capsules, boxes and hulls on a plane (every kind), 301 random pairs: the same
    manifolds, in the same order, as with the default work-group size and placement tile
    (queues are filled by group-aggregated atomics; manifolds are placed per tile of
    pairs, from 1 pair to more than all of them)."""
    table = ShapeTable()
    kinds = [
        table.add(Plane()),
        table.add(Sphere(0.5)),
        table.add(Box((0.5, 0.4, 0.3))),
        table.add(ConvexHull(rng.normal(size=(12, 3)) * 0.5, name="pebble")),
        table.add(Capsule(0.3, 0.4)),
    ]
    n = 120
    shapes = np.concatenate([[kinds[0]], rng.choice(kinds[1:], n)])
    positions = np.vstack([[0, 0, 0], rng.uniform((-3, 0.0, -3), (3, 1.5, 3), (n, 3))])
    quats = np.vstack(
        [[0, 0, 0, 1], [axis_angle(rng.normal(size=3), a) for a in rng.uniform(0, np.pi, n)]]
    )
    bodies = make_bodies(shapes, positions, quats)
    candidates = [(0, i) for i in range(1, n + 1)]
    candidates += sorted(
        {tuple(sorted(p)) for p in rng.integers(1, n + 1, (400, 2)) if p[0] != p[1]}
    )
    pairs = candidates[:301]
    reference = find_contacts(runtime, table, bodies, pairs, margin=0.01)
    other = find_contacts(
        runtime,
        table,
        bodies,
        pairs,
        margin=0.01,
        work_group_size=work_group_size,
        placement_tile=placement_tile,
    )
    assert len(reference) > 20
    np.testing.assert_array_equal(other["body_a"], reference["body_a"])
    np.testing.assert_array_equal(other["body_b"], reference["body_b"])
    np.testing.assert_array_equal(other["point_count"], reference["point_count"])
    np.testing.assert_allclose(other["points"], reference["points"], atol=1e-6)
    np.testing.assert_array_equal(other["friction"], reference["friction"])


def test_no_pairs_give_no_manifolds(runtime):
    """Zero pairs after a call with contacts: count 0, no overflow (the placement counters
    and the contact flags of the earlier call do not leak into this one)."""
    import pyopencl.array as cla

    table = ShapeTable()
    cube = table.add(Box((1, 1, 1)))
    narrowphase = Narrowphase(runtime, table)
    q = runtime.queue
    packed = table.pack_all().to_device(q)
    bodies = cla.to_device(q, make_bodies([cube, cube], [(0, 0, 0), (1.9, 0, 0)]))
    pairs = cla.to_device(q, pair_records([(0, 1)]))
    assert len(narrowphase.find_contacts(bodies, packed, pairs, 1)) == 1
    count = cla.to_device(q, np.array([7], np.uint32))
    overflow = cla.to_device(q, np.array([7], np.uint32))
    manifolds = cla.empty(q, 1, layouts.CONTACT_MANIFOLD.dtype)
    narrowphase.enqueue(
        bodies, packed, pairs, cla.zeros(q, 1, np.uint32), manifolds, count, overflow
    )
    assert count.get()[0] == 0 and overflow.get()[0] == 0


def test_placement_tile_is_checked_and_one_convex_kind_reads_pairs_directly(runtime):
    with pytest.raises(RbgenError, match="placement_tile"):
        Narrowphase(runtime, ("box",), work_group_size=64, placement_tile=32)
    assert Narrowphase(runtime, ("box",)).direct
    assert not Narrowphase(runtime, ("box", "plane")).direct  # two kinds: queues
    assert not Narrowphase(runtime, ("sphere",)).direct  # a primitive kind stores at once


def test_cached_axis_follows_the_bodies(runtime):
    """The per-pair axis cache: a touching pair moved apart loses its contact, and moved
    back regains it, with the same Narrowphase (cache warm)."""
    import pyopencl.array as cla

    table = ShapeTable()
    cube = table.add(Box((1, 1, 1)))
    narrowphase = Narrowphase(runtime, table)
    q = runtime.queue
    packed = table.pack_all().to_device(q)
    pairs = cla.to_device(q, pair_records([(0, 1)]))
    for gap, expected in [(-0.01, 1), (0.5, 0), (0.5, 0), (-0.02, 1), (0.3, 0)]:
        bodies = make_bodies([cube, cube], [(0, 0, 0), (2 + gap, 0.1, 0)])
        m = narrowphase.find_contacts(cla.to_device(q, bodies), packed, pairs, 1)
        assert len(m) == expected
        if expected:
            np.testing.assert_allclose(m[0]["normal"][:3], (1, 0, 0), atol=1e-6)
            np.testing.assert_allclose(m[0]["points"][:4, 3], gap, atol=1e-5)


@pytest.mark.parametrize("with_sphere,expected_launches", [(False, 3), (True, 6)])
def test_enqueue_never_blocks_and_features_persist(runtime, with_sphere, expected_launches):
    """`enqueue` issues a fixed number of launches (box pairs only: separating axis straight
    from the pair list, clip with reduction, scatter with placement; a table that also has
    a sphere, which no body uses, adds classify_pairs and the sphere_sphere and
    sphere_convex kernels: the box pair then comes through its queue) and no blocking
    read; a box resting on a box that moves by 1e-3 keeps its four feature ids
    (warm-starting keys)."""
    import pyopencl.array as cla

    table = ShapeTable()
    wide, cube = table.add(Box((2, 0.5, 2))), table.add(Box((0.5, 0.5, 0.5)))
    if with_sphere:
        table.add(Sphere(0.5))
    narrowphase = Narrowphase(runtime, table)
    assert narrowphase.direct == (not with_sphere)
    q = runtime.queue
    packed = table.pack_all().to_device(q)
    pairs = cla.to_device(q, pair_records([(0, 1)]))
    pair_count = cla.to_device(q, np.array([1], np.uint32))
    manifolds = cla.empty(q, 4, layouts.CONTACT_MANIFOLD.dtype)
    count, overflow = cla.zeros(q, 1, np.uint32), cla.zeros(q, 1, np.uint32)
    features = []
    for shift in (0.0, 1e-3):
        bodies = cla.to_device(
            q,
            make_bodies(
                [wide, cube],
                [(0, 0, 0), (0.2 + shift, 0.99, 0.1)],
                [(0, 0, 0, 1), axis_angle((0, 1, 0), 0.2 + shift)],
            ),
        )
        before = dict(runtime.counters)
        narrowphase.enqueue(bodies, packed, pairs, pair_count, manifolds, count, overflow, 0.0)
        assert runtime.counters["blocking_reads"] == before["blocking_reads"]
        launches = runtime.counters["launches"] - before["launches"]
        m = manifolds.get()[: count.get()[0]]
        assert len(m) == 1 and m[0]["point_count"] == 4
        features.append(sorted(m[0]["features"].tolist()))
    assert launches == expected_launches
    assert features[0] == features[1]


def test_icosphere_hull_rests_on_a_box(runtime):
    """The icosphere hull (box-hull separating-axis path) sunk by d into a box top: deepest
    point within [-d, -d + resolution], normal +y within the resolution."""
    hull = ConvexHull.from_trimesh(trimesh.creation.icosphere(subdivisions=3), name="icosphere")
    resolution = 1.0 - np.min(np.abs(hull.cooked().planes[:, 3]))
    table = ShapeTable()
    slab, rock = table.add(Box((3, 0.5, 3))), table.add(hull)
    d = 0.05
    bodies = make_bodies([slab, rock], [(0, 0, 0), (0.1, 1.5 - d, 0.2)])
    m = contacts(runtime, table, bodies, [(0, 1)])[(0, 1)]
    assert np.arccos(min(1.0, m["normal"][1])) < 2 * np.sqrt(2 * resolution)
    assert -d - 1e-5 <= points(m)[:, 3].min() <= -d + resolution + 1e-5


def test_prism_cap_on_a_box_reduces_to_four_points(runtime, rng):
    """A 12-sided prism lying on its cap, sunk by d into a box: the whole cap is in contact;
    the manifold keeps 4 of its 12 corners (all at separation -d), spanning the cap: the
    deepest/farthest pair is a diameter and the other two lie on both sides of it."""
    angles = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.zeros(12), np.sin(angles)]) * 0.8
    prism = ConvexHull(np.vstack([ring + (0, -0.3, 0), ring + (0, 0.3, 0)]), name="prism")
    table = ShapeTable()
    slab, puck = table.add(Box((3, 0.5, 3))), table.add(prism)
    assert table.max_face_vertices() == 12
    d = 0.02
    q = axis_angle((0, 1, 0), rng.uniform(0, np.pi))
    centre = np.array([0.2, 0.5 + 0.3 - d, -0.1])
    bodies = make_bodies([slab, puck], [(0, 0, 0), centre], [(0, 0, 0, 1), q])
    m = contacts(runtime, table, bodies, [(0, 1)])[(0, 1)]
    assert m["point_count"] == 4
    np.testing.assert_allclose(points(m)[:, 3], -d, atol=2e-5)
    corners = prism.local_vertices() @ quat_matrix(q).T + centre
    bottom = corners[corners[:, 1] < centre[1]]
    p = points(m)[:, :3]
    assert all(np.linalg.norm(bottom - x, axis=1).min() < 1e-4 for x in p)
    assert np.linalg.norm(p[0] - p[1]) > 1.59 * np.cos(np.pi / 12)
    side = np.cross(p[1] - p[0], p[2:] - p[0]) @ (0, 1, 0)
    assert side[0] * side[1] < 0


def prism_points(sides: int, radius: float, half_height: float) -> np.ndarray:
    angles = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.zeros(sides), np.sin(angles)]) * radius
    return np.vstack([ring - (0, half_height, 0), ring + (0, half_height, 0)])


def test_larger_faces_added_later_rebuild_the_clipping(runtime):
    """A Narrowphase built for 8-vertex faces follows its table when a 16-sided prism is
    added later: both prisms, sunk by 0.01 into a box, get 4 points at that depth."""
    import pyopencl.array as cla

    table = ShapeTable()
    slab = table.add(Box((3, 0.5, 3)))
    octagon = table.add(ConvexHull(prism_points(8, 1.0, 0.25), name="octagon"))
    narrowphase = Narrowphase(runtime, table)
    assert narrowphase.max_face_vertices == 8
    sixteen = table.add(ConvexHull(prism_points(16, 1.0, 0.25), name="sixteen"))
    q = runtime.queue
    bodies = make_bodies([slab, octagon, sixteen], [(0, 0, 0), (-1.5, 0.74, 0), (1.5, 0.74, 0)])
    pairs = cla.to_device(q, pair_records([(0, 1), (0, 2)]))
    m = narrowphase.find_contacts(cla.to_device(q, bodies), table.pack_all().to_device(q), pairs, 2)
    assert narrowphase.max_face_vertices == 16
    assert list(m["point_count"]) == [4, 4]
    np.testing.assert_allclose(m["points"][:, :, 3], -0.01, atol=2e-5)


def segment_closest(p, a0, a1):
    d = a1 - a0
    return a0 + d * np.clip(np.dot(p - a0, d) / np.dot(d, d), 0, 1)


def test_capsule_pairs(runtime, rng):
    """Capsules (radius r, segment of half length h along local y): a sphere beside the
    segment and one beyond an end (closest segment point), a capsule lying on a plane
    (2 points at the projected ends, depth d), a tilted one (1 point, the lower end),
    crossed capsules (1 point between the segments) and parallel ones (2 points)."""
    table = ShapeTable()
    ground, ball = table.add(Plane()), table.add(Sphere(0.4))
    rod = table.add(Capsule(0.3, 0.8))
    q = axis_angle(rng.normal(size=3), rng.uniform(0, np.pi))
    axis = quat_matrix(q) @ (0, 1, 0)
    centre = np.array([5.0, 5.0, 5.0])
    side = np.cross(axis, rng.normal(size=3))
    side /= np.linalg.norm(side)
    lying = axis_angle((0, 0, 1), np.pi / 2)
    tilted = axis_angle((0, 0, 1), 0.4)
    d = 0.02
    tilt_low = 0.8 * np.cos(0.4) + 0.3 - d  # centre height: lower end sunk by d
    flat = axis_angle((1, 0, 0), np.pi / 2)  # segment along z
    bodies = make_bodies(
        [ground, rod, ball, ball, rod, rod, rod, rod, rod, rod],
        [
            (0, 0, 0),
            centre,
            centre + 0.3 * axis + 0.65 * side,
            centre + 1.45 * axis,
            (10, 0.3 - d, 0),
            (20, tilt_low, 0),
            (30, 0, 0),
            (30, 0.6 - d, 0.1),
            (40, 0, 0),
            (40.2, 0.6 - d, 0),
        ],
        [(0, 0, 0, 1), q, (0, 0, 0, 1), (0, 0, 0, 1), lying, tilted, lying, flat, lying, lying],
    )
    pairs = [(1, 2), (1, 3), (0, 4), (0, 5), (6, 7), (8, 9)]
    found = contacts(runtime, table, bodies, pairs)
    assert set(found) == set(pairs)
    a0, a1 = centre - 0.8 * axis, centre + 0.8 * axis
    for pair in [(1, 2), (1, 3)]:
        m = found[pair]
        c = bodies["position"][pair[1], :3].astype(np.float64)
        on = segment_closest(c, a0, a1)
        n = (c - on) / np.linalg.norm(c - on)  # from the capsule (a) to the sphere (b)
        np.testing.assert_allclose(m["normal"][:3], n, atol=2e-5)
        np.testing.assert_allclose(
            points(m)[0], (*(c - 0.4 * n), np.linalg.norm(c - on) - 0.7), atol=2e-5
        )
    m = found[(0, 4)]
    assert m["point_count"] == 2
    # points on body b, the capsule: the bottoms of its end caps
    assert same_point_sets(points(m)[:, :3], [(10 - 0.8, -d, 0), (10 + 0.8, -d, 0)], atol=1e-5)
    np.testing.assert_allclose(points(m)[:, 3], -d, atol=2e-5)
    m = found[(0, 5)]
    assert m["point_count"] == 1
    low_end = np.array([20, tilt_low, 0]) - 0.8 * (quat_matrix(tilted) @ (0, 1, 0))
    np.testing.assert_allclose(points(m)[0], (low_end[0], -d, 0, -d), atol=2e-5)
    m = found[(6, 7)]  # crossing: x axis below, z axis above, offset 0.1 along z
    assert m["point_count"] == 1
    np.testing.assert_allclose(m["normal"][:3], (0, 1, 0), atol=1e-5)
    np.testing.assert_allclose(points(m)[0], (30, 0.3 - d, 0, -d), atol=2e-5)
    m = found[(8, 9)]  # parallel along x, shifted by 0.2: overlap [-0.6, 0.8] around x = 40
    assert m["point_count"] == 2
    assert same_point_sets(
        points(m)[:, :3], [(40 - 0.6, 0.3 - d, 0), (40.8, 0.3 - d, 0)], atol=1e-5
    )
    np.testing.assert_allclose(points(m)[:, 3], -d, atol=2e-5)


def test_world_of_planes_reports_no_contacts(runtime):
    """Shapes that cannot touch (only planes): no kernels, manifold count 0, no error."""
    import pyopencl.array as cla

    table = ShapeTable()
    table.add(Plane())
    table.add(Plane((1, 0, 0), 2.0))
    narrowphase = Narrowphase(runtime, table)
    assert narrowphase.kinds == ()
    q = runtime.queue
    count = cla.to_device(q, np.array([5], np.uint32))
    narrowphase.enqueue(
        cla.to_device(q, make_bodies([0, 1], np.zeros((2, 3)))),
        table.pack_all().to_device(q),
        cla.to_device(q, pair_records([(0, 1)])),
        cla.to_device(q, np.array([1], np.uint32)),
        cla.empty(q, 1, layouts.CONTACT_MANIFOLD.dtype),
        count,
        cla.zeros(q, 1, np.uint32),
    )
    assert count.get()[0] == 0


def test_capsule_on_a_box(runtime):
    """Capsule (r 0.3, half length 0.8) against a box top at y = 0.5, all sunk by d:
    lying flat, 2 points under its ends; standing, 1 point under its lower end; lying
    deep inside the top (segment below the face), 2 points at depth r + 0.1; parallel to
    a top edge beyond it, 1 point on the edge, normal along the offset."""
    table = ShapeTable()
    slab, rod = table.add(Box((3, 0.5, 3))), table.add(Capsule(0.3, 0.8))
    d = 0.02
    lying = axis_angle((0, 0, 1), np.pi / 2)  # segment along x
    along_z = axis_angle((1, 0, 0), np.pi / 2)  # segment along z
    offset = np.array([0.12, 0.16])  # beyond the edge x = 3, y = 0.5
    bodies = make_bodies(
        [slab, rod, slab, rod, slab, rod, slab, rod],
        [
            (0, 0, 0),
            (0.5, 0.8 - d, 0.2),
            (10, 0, 0),
            (10.3, 0.5 + 1.1 - d, 0),
            (20, 0, 0),
            (20, 0.5 - 0.1, 0),
            (30, 0, 0),
            (33 + offset[0], 0.5 + offset[1], 0),
        ],
        [
            (0, 0, 0, 1),
            lying,
            (0, 0, 0, 1),
            (0, 0, 0, 1),
            (0, 0, 0, 1),
            lying,
            (0, 0, 0, 1),
            along_z,
        ],
    )
    found = contacts(runtime, table, bodies, [(0, 1), (2, 3), (4, 5), (6, 7)])
    m = found[(0, 1)]
    assert m["point_count"] == 2
    np.testing.assert_allclose(m["normal"][:3], (0, 1, 0), atol=1e-6)
    # points on body b, the capsule: its lowest line, under the segment ends
    assert same_point_sets(points(m)[:, :3], [(-0.3, 0.5 - d, 0.2), (1.3, 0.5 - d, 0.2)], atol=1e-5)
    np.testing.assert_allclose(points(m)[:, 3], -d, atol=2e-5)
    m = found[(2, 3)]
    assert m["point_count"] == 1
    np.testing.assert_allclose(points(m)[0], (10.3, 0.5 - d, 0, -d), atol=2e-5)
    m = found[(4, 5)]
    assert m["point_count"] == 2
    np.testing.assert_allclose(m["normal"][:3], (0, 1, 0), atol=1e-6)
    np.testing.assert_allclose(points(m)[:, 3], -0.4, atol=2e-5)
    m = found[(6, 7)]
    gap = np.linalg.norm(offset)
    assert m["point_count"] >= 1
    np.testing.assert_allclose(m["normal"][:3], (*offset / gap, 0), atol=1e-5)
    np.testing.assert_allclose(points(m)[:, 3], gap - 0.3, atol=2e-5)


def test_capsule_box_distance_matches_brute_force(runtime, rng):
    """300 random capsules around a rotated box with the core segment outside it: contact
    within margin 0.3 exactly when the distance (dense sampling of the segment, closest
    box point by clamping) minus the radius is within it, and then that separation."""
    table = ShapeTable()
    he = np.array([0.7, 0.4, 0.5])
    cube, rod = table.add(Box(he)), table.add(Capsule(0.2, 0.5))
    n = 300
    qb = axis_angle(rng.normal(size=3), 0.7)
    rb = quat_matrix(qb)
    centres = rng.uniform(-1.6, 1.6, (n, 3))
    quats = np.array([axis_angle(rng.normal(size=3), a) for a in rng.uniform(0, np.pi, n)])
    shapes = np.concatenate([[cube], [rod] * n])
    bodies = make_bodies(shapes, np.vstack([[0, 0, 0], centres]), np.vstack([qb, quats]))
    m = find_contacts(runtime, table, bodies, [(0, i + 1) for i in range(n)], margin=0.3)
    found = {int(r["body_b"]) - 1: r for r in m}
    t = np.linspace(-1, 1, 4001)
    checked = 0
    for i in range(n):
        axis = quat_matrix(quats[i]) @ (0, 0.5, 0)
        samples = (centres[i] + t[:, None] * axis) @ rb  # box frame
        outside = samples - np.clip(samples, -he, he)
        distances = np.linalg.norm(outside, axis=1)
        if distances.min() < 1e-3:
            continue  # core segment touches or enters the box: not this test's case
        separation = distances.min() - 0.2
        if abs(separation - 0.3) < 2e-3:
            continue  # at the margin: undecided
        assert (i in found) == (separation <= 0.3), f"capsule {i}: separation {separation}"
        if i in found:
            np.testing.assert_allclose(points(found[i])[:, 3].min(), separation, atol=1e-4)
            checked += 1
    assert checked > 20


def test_capsule_core_across_a_box_edge(runtime):
    """A capsule whose core segment (along (-1, 1, 0)) cuts across the box's +x +y edge,
    its centre d inside along the diagonal: the edge-edge axis wins; one point, normal
    along the diagonal (box to capsule), separation -(d + r), point the capsule's deepest."""
    table = ShapeTable()
    slab, rod = table.add(Box((3, 0.5, 3))), table.add(Capsule(0.3, 0.8))
    d = 0.05
    diagonal = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    centre = np.array([3.0, 0.5, 0.0]) - d * diagonal
    bodies = make_bodies(
        [slab, rod], [(0, 0, 0), centre], [(0, 0, 0, 1), axis_angle((0, 0, 1), np.pi / 4)]
    )
    m = contacts(runtime, table, bodies, [(0, 1)])[(0, 1)]
    assert m["point_count"] == 1
    np.testing.assert_allclose(m["normal"][:3], diagonal, atol=1e-5)
    np.testing.assert_allclose(points(m)[0], (*(centre - 0.3 * diagonal), -(d + 0.3)), atol=2e-5)
