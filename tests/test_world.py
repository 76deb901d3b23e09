"""World physics against closed forms (each test states its expectation).

All at dt = 1/60 with the default settings (10 PGS iterations, split impulse,
warm starting) unless a test says otherwise. The contact tests run with both
solvers (Gauss-Seidel and Jacobi with mass splitting); the resting, sliding,
rebound and momentum tests also with each solver built exactly and with
-cl-fast-relaxed-math (``fast_math``, the GPU default), on every device.
"""

from __future__ import annotations

import numpy as np
import pytest

import rbgen
from rbgen.pipeline.solvers import SOLVERS
from rbgen.world import World

DT = 1 / 60
G = 9.81

#: the contact tests run with one solve a step and with substeps (contacts found once a
#: step, the solver run on them each substep)
EFFORTS = {
    "one_step": {"substeps": 1, "iterations": 10, "position_iterations": 4},
    "substeps": {"substeps": 4, "iterations": 3, "position_iterations": 1},
}


@pytest.fixture(params=list(EFFORTS))
def effort(request) -> dict:
    return EFFORTS[request.param]


def ground(world, friction=0.6, restitution=0.0, orientation=(0, 0, 0, 1), position=(0, -1, 0)):
    return world.add_static(
        rbgen.Box(half_extents=(30, 1, 30)),
        position=position,
        orientation=orientation,
        friction=friction,
        restitution=restitution,
    )


@pytest.mark.gpu_shape
@pytest.mark.parametrize("fast_math", [False, True])
@pytest.mark.parametrize("solver", SOLVERS)
def test_box_resting_on_ground_does_not_drift(runtime, solver, fast_math, effort):
    """A unit box placed on the ground stays put: drift < 1 mm over 600 steps."""
    world = World(runtime, solver=solver, fast_math=fast_math, **effort)
    ground(world)
    world.add_body(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, position=(0.3, 0.5, -0.2))
    start = world.positions[1]
    for _ in range(600):
        world.step(DT)
    assert np.linalg.norm(world.positions[1] - start) < 1e-3


def _incline(runtime, mu, steps, solver="pgs", fast_math=False, effort=None):
    theta = np.radians(30)
    q = (0, 0, np.sin(theta / 2), np.cos(theta / 2))  # ramp rising towards -x
    world = World(runtime, solver=solver, fast_math=fast_math, **(effort or {}))
    ground(world, friction=mu, orientation=q, position=(0, 0, 0))
    normal = np.array([-np.sin(theta), np.cos(theta), 0])
    start = 1.0 * normal + 0.5 * normal  # box centre 0.5 above the slab's top face (half 1)
    world.add_body(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, position=start, orientation=q, friction=mu)
    positions = [world.positions[1]]
    for _ in range(steps):
        world.step(DT)
        positions.append(world.positions[1])
    return np.array(positions), theta


@pytest.mark.gpu_shape
@pytest.mark.parametrize("solver", SOLVERS)
def test_box_on_incline_sticks_with_high_friction(runtime, solver, effort):
    """30 degree incline, mu = 0.7 > tan 30 = 0.577: the box moves < 1 mm over 300 steps."""
    positions, _ = _incline(runtime, 0.7, 300, solver, effort=effort)
    assert np.linalg.norm(positions[-1] - positions[0]) < 1e-3


@pytest.mark.parametrize("fast_math", [False, True])
@pytest.mark.parametrize("solver", SOLVERS)
def test_box_slides_down_incline_with_low_friction(runtime, solver, fast_math, effort):
    """mu = 0.3: the box slides with a = g (sin 30 - mu cos 30) (within 5%), fitted from
    the distance travelled, s = a t^2 / 2, between steps 60 and 180."""
    positions, theta = _incline(runtime, 0.3, 180, solver, fast_math, effort)
    down = np.array([-np.cos(theta), -np.sin(theta), 0])
    s = (positions - positions[0]) @ down
    t = np.arange(len(s)) * DT
    sel = slice(60, 181)
    a_fit = np.polyfit(t[sel], s[sel], 2)[0] * 2
    expected = G * (np.sin(theta) - 0.3 * np.cos(theta))
    assert a_fit == pytest.approx(expected, rel=0.05)


def test_projectile(runtime):
    """No contacts: semi-implicit Euler's closed form x_m = x0 + v0 t_m + g h^2 m (m + 1) / 2
    after m substeps of h = dt / substeps (the device's default substeps)."""
    world = World(runtime)
    v0 = np.array([3.0, 10.0, -1.0])
    world.add_body(rbgen.Sphere(0.3), mass=2.0, position=(0, 5, 0), linear_velocity=v0)
    n = 90
    for _ in range(n):
        world.step(DT)
    g = np.array([0, -G, 0])
    h, m = DT / world.substeps, n * world.substeps
    expected = np.array([0, 5, 0]) + v0 * n * DT + g * h * h * m * (m + 1) / 2
    np.testing.assert_allclose(world.positions[0], expected, atol=1e-3)
    np.testing.assert_allclose(world.linear_velocities[0], v0 + g * n * DT, atol=1e-3)
    # The exact parabola differs by g dt t / 2 only.
    exact = np.array([0, 5, 0]) + v0 * n * DT + g * (n * DT) ** 2 / 2
    assert np.linalg.norm(world.positions[0] - exact) < G * DT * n * DT


@pytest.mark.gpu_shape
@pytest.mark.parametrize("fast_math", [False, True])
@pytest.mark.parametrize("solver", SOLVERS)
def test_restitution_rebound_height(runtime, solver, fast_math, effort):
    """A box with e = 0.5 dropped from 1 m (bottom face) rebounds to e^2 * 1 m = 0.25 m (5%)."""
    world = World(runtime, restitution_threshold=0.5, solver=solver, fast_math=fast_math, **effort)
    ground(world, restitution=0.5)
    world.add_body(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, position=(0, 1.5, 0), restitution=0.5)
    heights, bounced = [], False
    for _ in range(150):
        world.step(DT)
        y, vy = world.positions[1][1], world.linear_velocities[1][1]
        bounced |= vy > 0
        if bounced:
            heights.append(y - 0.5)
    assert max(heights) == pytest.approx(0.25, rel=0.05)


@pytest.mark.gpu_shape
@pytest.mark.parametrize("fast_math", [False, True])
@pytest.mark.parametrize("solver", SOLVERS)
def test_two_free_boxes_conserve_momentum(runtime, rng, solver, fast_math, effort):
    """No gravity: two boxes of masses 1 and 3 collide off-centre; linear momentum is
    conserved within 1e-4 relative (before, during and after contact)."""
    world = World(runtime, gravity=(0, 0, 0), solver=solver, fast_math=fast_math, **effort)
    box = rbgen.Box((0.5, 0.5, 0.5))
    world.add_body(
        box,
        mass=1.0,
        position=(-1, 0.2, 0),
        linear_velocity=(3, 0, 0.5),
        angular_velocity=rng.normal(size=3),
    )
    world.add_body(
        box,
        mass=3.0,
        position=(1, -0.2, 0.1),
        linear_velocity=(-1, 0, 0),
        angular_velocity=rng.normal(size=3),
    )
    masses = np.array([1.0, 3.0])[:, None]
    p0 = (masses * world.linear_velocities).sum(0)
    touched = False
    for _ in range(60):
        world.step(DT)
        touched |= world.statistics()["manifolds"] > 0
        p = (masses * world.linear_velocities).sum(0)
        assert np.linalg.norm(p - p0) <= 1e-4 * np.linalg.norm(p0)
    assert touched


@pytest.mark.gpu_shape
def test_spinning_asymmetric_box_conserves_angular_momentum(runtime):
    """A free box with half extents (0.2, 0.5, 1) spinning at 4 rad/s about a tilted axis
    near its middle principal axis: world L = R I R^T w within 1% over 600 steps."""
    world = World(runtime, gravity=(0, 0, 0))
    he = np.array([0.2, 0.5, 1.0])
    world.add_body(rbgen.Box(he), mass=2.0, angular_velocity=(0.2, 4.0, 0.3))
    inertia = (
        2.0
        / 3.0
        * np.array([he[1] ** 2 + he[2] ** 2, he[0] ** 2 + he[2] ** 2, he[0] ** 2 + he[1] ** 2])
    )

    def momentum():
        x, y, z, w = world.orientations[0]
        rot = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
        return rot @ (inertia * (rot.T @ world.angular_velocities[0]))

    l0 = momentum()
    for _ in range(600):
        world.step(DT)
    assert np.linalg.norm(momentum() - l0) < 0.01 * np.linalg.norm(l0)


def test_shape_without_narrowphase_kernels_fails_when_added():
    """An unsupported shape pair is reported when the body is added, not in step()."""

    class Torus(rbgen.Shape):
        type_name = "torus"

    world = rbgen.World()
    with pytest.raises(rbgen.RbgenError, match="Torus has no narrowphase kernels"):
        world.add_body(Torus(), mass=1.0)
    assert world.body_count == 0


def test_one_shape_object_serves_two_worlds_and_cannot_change(runtime):
    """Shapes are values: the same Box in two Worlds gives both the same fall (semi-implicit
    Euler's closed form y = y0 - g h^2 n (n + 1) / 2 after n substeps of h), and setting or
    writing into it afterwards is refused (it would change a World's shape behind its back)."""
    box = rbgen.Box((0.5, 0.5, 0.5))
    worlds = [World(runtime) for _ in range(2)]
    for world in worlds:
        world.add_body(box, mass=1.0, position=(0.0, 10.0, 0.0))
        for _ in range(30):
            world.step(DT)
    for world in worlds:
        h, n = DT / world.substeps, 30 * world.substeps
        assert world.positions[0, 1] == pytest.approx(
            10.0 - 9.81 * h * h * n * (n + 1) / 2, abs=1e-4
        )
    with pytest.raises(rbgen.RbgenError, match="immutable.*'half_extents'"):
        box.half_extents = np.ones(3)
    with pytest.raises(ValueError):
        box.half_extents[0] = 2.0
    assert tuple(box.half_extents) == (0.5, 0.5, 0.5)


def test_shape_index_is_refused_with_a_reason(runtime):
    """A shape index (from some World's table) is not a shape: the error names the index."""
    world = World(runtime)
    world.add_body(rbgen.Sphere(0.5), mass=1.0)
    with pytest.raises(rbgen.RbgenError, match="got the index 0"):
        world.add_body(0, mass=1.0)
