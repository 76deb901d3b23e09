"""Continuous collision (issue 30, item 4): fast bodies get speculative contacts.

A body whose travel in one step, |v| dt, exceeds FAST_FRACTION of its inner radius r
(`rbgen.pipeline.prepare`) has its AABB swept along that travel and its pairs keep
points up to the contact margin plus that travel apart; the solver lets a gap close
in the step and no more. So a body cannot pass a surface between two steps. What is
checked, at dt = 1/60 s and speeds up to 200 m/s (3.3 m a step, 67 times the bodies'
5 cm radius), on every device:

* a sphere or a box (r = 5 cm) shot at a static wall (a Plane; static Boxes 1 cm,
  5 cm and 10 cm thick) never reaches into it deeper than FAST_FRACTION r (the travel
  of a body just below the fast threshold, which no speculative contact catches before
  the margin does) and ends on its own side;
* the same bodies shot at a resting dynamic box (0.5 m, on a plane, under gravity, at
  projectile masses 0.1 to 10 times the box's) never reach into it deeper than that
  either, and never pass its centre.
"""

from __future__ import annotations

import numpy as np
import pytest

import rbgen
from rbgen.pipeline.prepare import FAST_FRACTION

DT = 1 / 60
R = 0.05  # the projectiles' inner radius (sphere radius, box half extent)
SPEEDS = [10.0, 50.0, 100.0, 200.0]
#: half thicknesses of the static box walls (1 cm, 5 cm and 10 cm thick)
WALLS = ["plane", 0.005, 0.025, 0.05]


def projectile(kind):
    return rbgen.Sphere(R) if kind == "sphere" else rbgen.Box((R, R, R))


def deepest_point(world, body, kind, axis, sign):
    """The projectile's farthest reach along ``sign`` * axis ``axis`` (its surface: a
    sphere's radius, a box's corners in its current orientation)."""
    centre = world.positions[body].astype(np.float64)
    if kind == "sphere":
        return sign * centre[axis] + R
    x, y, z, w = world.orientations[body].astype(np.float64)
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    corners = np.array([[i, j, k] for i in (-R, R) for j in (-R, R) for k in (-R, R)])
    return float(np.max(sign * (centre[axis] + corners @ rotation[axis])))


@pytest.mark.gpu_shape
@pytest.mark.parametrize("wall", WALLS)
@pytest.mark.parametrize("kind", ["sphere", "box"])
@pytest.mark.parametrize("speed", SPEEDS)
def test_fast_body_does_not_tunnel_through_a_static_wall(runtime, wall, kind, speed):
    """Shot along +z from 1 m before the wall's face (z = 0), without gravity, for 20
    steps (up to 66 m of travel): the projectile's surface never passes z = FAST_FRACTION
    r, and its centre ends before the face."""
    world = rbgen.World(runtime, gravity=(0, 0, 0))
    if wall == "plane":
        world.add_static(rbgen.Plane((0, 0, -1), 0.0))  # solid beyond z = 0
    else:
        world.add_static(rbgen.Box((5, 5, wall)), position=(0, 0, wall))
    body = world.add_body(
        projectile(kind), mass=1.0, position=(0, 0, -1.0 - R), linear_velocity=(0, 0, speed)
    )
    deepest = -np.inf
    for _ in range(20):
        world.step(DT)
        deepest = max(deepest, deepest_point(world, body, kind, axis=2, sign=1.0))
    assert deepest <= FAST_FRACTION * R, f"reached {deepest:.4f} m into the wall"
    assert world.positions[body, 2] < 0.0


@pytest.mark.parametrize("normal_solve", [None, "block"])
@pytest.mark.parametrize("mass", [0.1, 10.0])
@pytest.mark.parametrize("kind", ["sphere", "box"])
@pytest.mark.parametrize("speed", [50.0, 200.0])
def test_fast_body_does_not_pass_a_resting_box(runtime, request, mass, kind, speed, normal_solve):
    """A 1 kg box (half extent 0.25 m) rests on a plane; a projectile of ``mass`` flies
    at it along +x at its centre's height from 2 m away. Over 30 steps the projectile
    never reaches deeper than FAST_FRACTION r past the face it hits (measured in the
    box's frame, the box being knocked away and tipped) and never passes its centre.
    ``normal_solve``: the device's default, and the block solve on every device."""
    half = 0.25
    world = rbgen.World(runtime, normal_solve=normal_solve)
    if (kind, mass, speed) == ("box", 10.0, 200.0) and world.plan.normal_solve == "sequential":
        request.applymarker(
            pytest.mark.xfail(
                strict=True,
                reason="solver owner (contact_rows.cl.mako, solve_normal_rows): a 10 kg box "
                "stopped from 200 m/s on a 1 kg box's face by four point rows solved one "
                "after another keeps a residual torque (14 rad/s after the impact step), so "
                "its corners turn 3-4 cm into the target over the next steps; the block "
                "normal solve (GPUs' default) leaves 0.2 mm. It does not pass the box.",
            )
        )
    world.add_static(rbgen.Plane((0, 1, 0), 0.0))
    target = world.add_body(rbgen.Box((half, half, half)), mass=1.0, position=(0, half, 0))
    body = world.add_body(
        projectile(kind), mass=mass, position=(-2.0, half, 0), linear_velocity=(speed, 0, 0)
    )
    for _ in range(30):
        world.step(DT)
        assert world.positions[body, 0] < world.positions[target, 0], "passed the box"
        assert overlap(world, target, body, kind, half) <= FAST_FRACTION * R


def overlap(world, target, body, kind, half) -> float:
    """How deep the projectile reaches into the target box: the largest depth of its
    surface points (sphere: centre's signed distance to the box minus r; box: its
    corners' signed distances), 0 when apart."""
    q = world.orientations[target].astype(np.float64)
    u, s = -q[:3], q[3]

    def to_box(p):
        v = p - world.positions[target].astype(np.float64)
        return 2 * (u @ v) * u + (s * s - u @ u) * v + 2 * s * np.cross(u, v)

    def distance(local):
        d = np.abs(local) - half
        return np.linalg.norm(np.maximum(d, 0.0)) + min(d.max(), 0.0)

    centre = world.positions[body].astype(np.float64)
    if kind == "sphere":
        return max(0.0, R - distance(to_box(centre)))
    qb = world.orientations[body].astype(np.float64)
    ub, sb = qb[:3], qb[3]
    corners = [np.array([i, j, k]) for i in (-R, R) for j in (-R, R) for k in (-R, R)]
    depths = []
    for c in corners:
        world_c = centre + 2 * (ub @ c) * ub + (sb * sb - ub @ ub) * c + 2 * sb * np.cross(ub, c)
        depths.append(-distance(to_box(world_c)))
    return max(0.0, max(depths))


def wall_mesh():
    """A static triangle-mesh wall: two triangles in the plane z = 0, 10 m square."""
    vertices = np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], float)
    return rbgen.TriangleMesh(vertices, np.array([[0, 1, 2], [0, 2, 3]]))


OTHER_SHAPES = {
    "capsule": lambda: rbgen.Capsule(R, 2 * R),
    "hull": lambda: rbgen.ConvexHull(np.random.default_rng(0).normal(size=(10, 3)) * R),
    "compound": lambda: rbgen.Compound(
        [(rbgen.Sphere(R), (0, 0, 0), None), (rbgen.Box((R, R, R)), (2 * R, 0, 0), None)]
    ),
}


@pytest.mark.gpu_shape
@pytest.mark.parametrize("wall", ["plane", "box", "mesh"])
@pytest.mark.parametrize("kind", sorted(OTHER_SHAPES))
def test_other_fast_shapes_stop_at_a_wall(runtime, wall, kind):
    """A capsule, a hull (inradius 2 cm) and a compound (a sphere and a box: its children's
    boxes sweep with it) at 200 m/s against a Plane, a 5 cm static Box and a triangle-mesh
    wall, with the block normal solve: the centre never passes the face (z = 0). (The
    sequential rows stop a hull too, but their residual torque from so large an impulse
    spins it so that its corners turn into the wall.)"""
    world = rbgen.World(runtime, gravity=(0, 0, 0), normal_solve="block")
    if wall == "plane":
        world.add_static(rbgen.Plane((0, 0, -1), 0.0))
    elif wall == "box":
        world.add_static(rbgen.Box((5, 5, 0.025)), position=(0, 0, 0.025))
    else:
        world.add_static(wall_mesh())
    body = world.add_body(
        OTHER_SHAPES[kind](), mass=1.0, position=(0, 0, -1.2), linear_velocity=(0, 0, 200.0)
    )
    for _ in range(20):
        world.step(DT)
        assert world.positions[body, 2] < 0.0
