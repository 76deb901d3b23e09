"""Compound shapes (`rbgen.compound`): mass properties, frames, checks.

Mass properties are checked against trimesh's volume integrals of the union of the
children (non-overlapping children as one closed triangle surface: boxes and hulls are
exact polyhedra): mass, centre of mass, and the inertia tensor about it, which must equal
R diag(principal inertia) R^T with R the compound's rotation.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import rbgen
from rbgen.compound import Compound
from rbgen.errors import RbgenError

from .reference import quat_to_matrix


def child_mesh(shape, position, orientation) -> trimesh.Trimesh:
    """A child's closed surface in the compound's given frame."""
    if isinstance(shape, rbgen.Box):
        mesh = trimesh.creation.box(extents=2 * shape.half_extents)
    else:
        mesh = trimesh.convex.convex_hull(shape.local_vertices())
    mesh.apply_transform(
        np.block(
            [
                [
                    quat_to_matrix(np.asarray(orientation, float)),
                    np.asarray(position, float)[:, None],
                ],
                [np.zeros((1, 3)), 1],
            ]
        )
    )
    return mesh


def random_children(rng, count: int):
    """Non-overlapping random boxes and hulls, each in its own cell of a 2 m grid."""
    cells = rng.choice(64, count, replace=False)
    children = []
    for cell in cells:
        centre = 2.0 * np.array([cell % 4, (cell // 4) % 4, cell // 16], float)
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        if rng.random() < 0.5:
            shape = rbgen.Box(rng.uniform(0.1, 0.5, 3))
        else:
            shape = rbgen.ConvexHull(rng.normal(size=(10, 3)) * 0.25)
        children.append((shape, centre + rng.uniform(-0.2, 0.2, 3), q))
    return children


@pytest.mark.parametrize("count", [1, 2, 5, 17])
def test_mass_properties_equal_trimesh_of_the_union(rng, count):
    """Mass at density 3, centre of mass, and inertia tensor about it, against trimesh's
    integrals of the union of the children's surfaces (relative 1e-6)."""
    children = random_children(rng, count)
    compound = Compound(children)
    union = trimesh.util.concatenate([child_mesh(*c) for c in children])
    density = 3.0
    union.density = density
    props = compound.mass_properties(density=density)
    assert props.mass == pytest.approx(union.mass, rel=1e-6)
    np.testing.assert_allclose(props.com, union.center_mass, rtol=1e-6, atol=1e-9)
    rotation = quat_to_matrix(np.asarray(props.rotation))
    tensor = rotation @ np.diag(props.inertia) @ rotation.T
    np.testing.assert_allclose(
        tensor, union.moment_inertia, rtol=1e-6, atol=1e-9 * np.abs(union.moment_inertia).max()
    )
    assert np.linalg.det(rotation) == pytest.approx(1.0)


def test_children_are_stored_in_the_principal_frame(rng):
    """A child point p (given frame) is at R^T (p - com) in the stored frame, and the
    stored orientation is the rotation's inverse times the given one: mapping a child's
    vertices both ways gives the same points."""
    children = random_children(rng, 4)
    compound = Compound(children)
    props = compound.mass_properties(mass=1.0)
    rotation = quat_to_matrix(np.asarray(props.rotation))
    for (shape, position, q), p, stored_q in zip(
        children, compound.positions, compound.orientations
    ):
        given = shape.local_vertices() @ quat_to_matrix(q).T + position
        stored = shape.local_vertices() @ quat_to_matrix(stored_q).T + p
        np.testing.assert_allclose(stored @ rotation.T + props.com, given, atol=1e-9)
    lower, upper = compound.lower, compound.upper
    for shape, p, q in zip(compound.children, compound.positions, compound.orientations):
        points = shape.local_vertices() @ quat_to_matrix(q).T + p
        assert np.all(points >= lower - 1e-9) and np.all(points <= upper + 1e-9)


def test_a_sphere_child_and_a_capsule_child():
    """Spheres and capsules enter by their closed forms: a sphere and a capsule side by
    side have the mass of both and the centre of mass between them by their masses."""
    sphere, capsule = rbgen.Sphere(0.5), rbgen.Capsule(0.2, 0.5)
    compound = Compound([(sphere, (0, 0, 0)), (capsule, (2, 0, 0))])
    vs = sphere.mass_properties(density=1.0).mass
    vc = capsule.mass_properties(density=1.0).mass
    props = compound.mass_properties(density=1.0)
    assert props.mass == pytest.approx(vs + vc)
    np.testing.assert_allclose(props.com, (2 * vc / (vs + vc), 0, 0), atol=1e-12)
    assert compound.bounding_radius() == pytest.approx(
        max(2 * vc / (vs + vc) + 0.5, 2 - 2 * vc / (vs + vc) + 0.7)
    )


def test_bad_compounds_are_refused_naming_the_child():
    box = rbgen.Box((1, 1, 1))
    with pytest.raises(RbgenError, match="at least one child"):
        Compound([])
    mesh = rbgen.TriangleMesh([[0, 0, 0], [1, 0, 0], [0, 0, 1]], [[0, 1, 2]])
    with pytest.raises(RbgenError, match="child 1 is a TriangleMesh"):
        Compound([(box, (0, 0, 0)), (mesh, (0, 0, 0))])
    with pytest.raises(RbgenError, match="child 0 is a Plane"):
        Compound([(rbgen.Plane(), (0, 0, 0))])
    with pytest.raises(RbgenError, match="child 1 is a Compound"):
        Compound([(box, (0, 0, 0)), (Compound([box]), (3, 0, 0))])
    with pytest.raises(RbgenError, match="child 0 position"):
        Compound([(box, (0, np.nan, 0))])
    with pytest.raises(RbgenError, match="child 0 orientation"):
        Compound([(box, (0, 0, 0), (0, 0, 0, 0))])
    with pytest.raises(RbgenError, match="child 2 must be"):
        Compound([box, box, "box"])
    with pytest.raises(RbgenError, match="at most 256"):
        Compound([(box, (3.0 * k, 0, 0)) for k in range(257)])


def test_compound_bodies_in_a_world_keep_their_children_apart(runtime):
    """Two chairs in one world: their manifolds name the children that touch, one
    manifold per (body pair, child pair), with sub-features 1 + (child << 24 | other)."""
    from rbgen import layouts

    legs = [
        (rbgen.Box((0.05, 0.25, 0.05)), (x * 0.4, 0.2, z * 0.4)) for x in (-1, 1) for z in (-1, 1)
    ]
    chair = Compound([(rbgen.Box((0.5, 0.05, 0.5)), (0, 0.5, 0))] + legs)
    world = rbgen.World(runtime)
    world.add_static(rbgen.Plane())
    world.add_bodies(chair, mass=1.0, positions=[(0, 0.6, 0)])
    for _ in range(30):
        world.step(1 / 60)
    world.statistics()
    narrowphase = world._pipeline.narrowphase
    manifolds = narrowphase.manifolds.get()[: int(narrowphase.count.get()[0])]
    assert set(manifolds["body_a"].tolist()) == {0} and set(manifolds["body_b"].tolist()) == {1}
    # the four legs (children 1..4) touch the plane; each its own manifold
    subs = sorted(int(s) for s in manifolds["sub"])
    assert subs == [1 + (k << layouts.SUB_CHILD_SHIFT) for k in (1, 2, 3, 4)]

    # on a mesh: one manifold per (leg, triangle), sub 1 + (leg << 24 | triangle)
    v = np.array([[-2, 0, -2], [-2, 0, 2], [2, 0, -2], [2, 0, 2]], float)
    mesh = rbgen.TriangleMesh(v, np.array([[0, 1, 2], [2, 1, 3]]))
    world = rbgen.World(runtime)
    world.add_static(mesh)
    world.add_bodies(chair, mass=1.0, positions=[(0.1, 0.6, 0.05)])
    for _ in range(30):
        world.step(1 / 60)
    world.statistics()
    narrowphase = world._pipeline.narrowphase
    manifolds = narrowphase.manifolds.get()[: int(narrowphase.count.get()[0])]
    legs = {(int(s) - 1) >> layouts.SUB_CHILD_SHIFT for s in manifolds["sub"]}
    triangles = {(int(s) - 1) & ((1 << layouts.SUB_CHILD_SHIFT) - 1) for s in manifolds["sub"]}
    assert legs == {1, 2, 3, 4} and triangles <= {0, 1}
    assert len(set(manifolds["sub"].tolist())) == len(manifolds)
    assert abs(world.positions[1, 1] - (chair.mass_properties(mass=1.0).com[1] + 0.05)) < 3e-3
