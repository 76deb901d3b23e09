"""Forces from Python (issue 29, item 1): `World.apply_forces` acts during the next step
only, through the step's preparation kernel, with no blocking read; checked input.

Closed forms (semi-implicit Euler, the World's integrator: v_k = v_{k-1} + a dt, then
x_k = x_{k-1} + v_k dt): a force F pushing a body of mass m for n steps of dt gives
v = F t / m (t = n dt) and x = F dt^2 n (n + 1) / (2 m), which tends to F t^2 / (2 m);
a torque tau about a principal axis gives w = tau t / I.
"""

from __future__ import annotations

import numpy as np
import pytest

import rbgen
from rbgen import RbgenError
from rbgen.world import World

DT = 1 / 60
HALF = np.array([0.5, 0.25, 0.75])
BOX = rbgen.Box(tuple(HALF))


def box_inertia(mass, half):
    """Principal moments of a solid box of half extents ``half``."""
    a, b, c = (2 * np.asarray(half, float)) ** 2
    return mass / 12 * np.array([b + c, a + c, a + b])


def free_box(runtime, mass=2.0, position=(1.0, 2.0, 3.0)):
    world = World(runtime, gravity=(0, 0, 0))
    world.add_body(BOX, mass=mass, position=position)
    return world


def test_push_in_free_flight_matches_the_closed_form(runtime):
    """F on a free box for n steps of S substeps: v = F t / m, x - x0 = F h^2 N (N+1) / (2m)
    with N = n S substeps of h = dt / S (the force acts in every substep, as gravity)."""
    rng = np.random.default_rng(1)
    mass, n = 2.5, 30
    force = rng.uniform(-20, 20, 3)
    world = free_box(runtime, mass)
    for _ in range(n):
        world.apply_forces([0], force[None])
        world.step(DT)
    v = np.asarray(world.linear_velocities[0], float)
    x = np.asarray(world.positions[0], float) - [1.0, 2.0, 3.0]
    np.testing.assert_allclose(v, force * n * DT / mass, rtol=1e-5, atol=1e-6)
    substeps = world.substeps
    h, substeps_run = DT / substeps, n * substeps
    np.testing.assert_allclose(
        x, force * h**2 * substeps_run * (substeps_run + 1) / (2 * mass), rtol=1e-4, atol=1e-5
    )
    assert np.all(np.asarray(world.angular_velocities[0]) == 0)


@pytest.mark.gpu_shape
def test_push_on_frictionless_ground_matches_the_closed_form(runtime):
    """A box resting on a frictionless plane, pushed along x: the contact carries its
    weight and nothing along x, so v_x = F t / m and x - x0 = F h^2 N (N+1) / (2m) over
    N = n S substeps of h = dt / S."""
    mass, force, n = 3.0, 6.0, 40
    world = World(runtime)
    world.add_static(rbgen.Plane((0, 1, 0), 0.0), friction=0.0)
    world.add_body(BOX, mass=mass, position=(0.0, HALF[1], 0.0), friction=0.0)
    for _ in range(n):
        world.apply_forces(1, (force, 0.0, 0.0))
        world.step(DT)
    v, x = world.linear_velocities[1], world.positions[1]
    assert v[0] == pytest.approx(force * n * DT / mass, rel=1e-4)
    h, substeps_run = DT / world.substeps, n * world.substeps
    assert x[0] == pytest.approx(
        force * h**2 * substeps_run * (substeps_run + 1) / (2 * mass), rel=1e-3
    )
    assert abs(x[1] - HALF[1]) < 0.01 and abs(v[1]) < 0.05  # still on the ground


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_torque_about_a_principal_axis(runtime, axis):
    """tau along principal axis `axis` for n steps: w = tau t / I_axis, no other spin
    (no gyroscopic term for a spin about a principal axis)."""
    mass, n, tau = 2.0, 12, 0.7
    world = free_box(runtime, mass)
    torque = np.zeros(3)
    torque[axis] = tau
    for _ in range(n):
        world.apply_forces([0], [0.0, 0.0, 0.0], torques=torque)
        world.step(DT)
    expected = torque * n * DT / box_inertia(mass, HALF)
    np.testing.assert_allclose(world.angular_velocities[0], expected, rtol=1e-4, atol=1e-6)
    assert np.all(world.linear_velocities[0] == 0)


def test_force_at_a_point_adds_its_moment(runtime):
    """F at the point x + r for one step: dv = F dt / m, dw = I^-1 (r x F) dt (the box
    unrotated, so I is its principal diagonal); the host never reads x."""
    mass = 1.5
    position = np.array([4.0, -1.0, 2.0])
    world = free_box(runtime, mass, tuple(position))
    r, force = np.array([0.5, 0.1, -0.3]), np.array([0.0, 3.0, 1.0])
    world.apply_forces(0, force, points=position + r)
    world.step(DT)
    np.testing.assert_allclose(world.linear_velocities[0], force * DT / mass, rtol=1e-5)
    expected = np.cross(r, force) * DT / box_inertia(mass, HALF)
    # the gyroscopic update acts after the spin-up only from the next step
    np.testing.assert_allclose(world.angular_velocities[0], expected, rtol=1e-4, atol=1e-6)


def test_a_force_acts_for_one_step_and_repeats_add_up(runtime):
    """Forces given twice before a step add up (repeated ids too); the step after has
    none: the velocity stays at (F1 + F2 + F3) dt / m."""
    mass = 2.0
    world = free_box(runtime, mass)
    world.apply_forces([0, 0], [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    world.apply_forces(0, (0.0, 0.0, 4.0))
    world.step(DT)
    expected = np.array([1.0, 2.0, 4.0]) * DT / mass
    np.testing.assert_allclose(world.linear_velocities[0], expected, rtol=1e-6)
    for _ in range(3):
        world.step(DT)
    np.testing.assert_allclose(world.linear_velocities[0], expected, rtol=1e-6)


@pytest.mark.gpu_shape
def test_forces_act_during_every_substep(runtime):
    """`step(dt, substeps=k)`: the force acts for the whole dt, so dv = F dt / m."""
    mass = 2.0
    world = free_box(runtime, mass)
    world.apply_forces(0, (3.0, 0.0, 0.0))
    world.step(DT, substeps=4)
    assert world.linear_velocities[0][0] == pytest.approx(3.0 * DT / mass, rel=1e-5)


def test_static_bodies_ignore_forces(runtime):
    world = World(runtime)
    world.add_static(rbgen.Box((5, 1, 5)), position=(0, -1, 0))
    world.add_body(BOX, position=(0, 3, 0))
    world.apply_forces([0, 1], (0.0, 100.0, 0.0), torques=(1.0, 1.0, 1.0))
    world.step(DT)
    assert np.all(world.positions[0] == [0, -1, 0])
    assert np.all(world.linear_velocities[0] == 0)


@pytest.mark.gpu_shape
def test_a_redone_step_sees_the_same_forces(runtime):
    """A pair buffer too small overflows in the pushed step; the redo (grown buffer)
    replays its forces: the end state equals a World that never overflowed."""

    def run(pair_capacity):
        world = World(runtime, gravity=(0, 0, 0), pair_capacity=pair_capacity)
        xs = np.arange(6) * 1.0  # boxes of 1 m side at 1 m spacing: touching
        world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), positions=np.c_[xs, np.zeros(6), np.zeros(6)])
        world.apply_forces(np.arange(6), np.c_[np.zeros(6), np.linspace(1, 6, 6), np.zeros(6)])
        world.step(DT)
        world.step(DT)
        _ = world.positions  # (checks every step in flight)
        return world

    small, large = run(1), run(None)
    assert small.overflows >= 1 and large.overflows == 0
    for field in ("positions", "linear_velocities", "angular_velocities"):
        assert np.array_equal(getattr(small, field), getattr(large, field)), field
    assert np.any(small.linear_velocities[:, 1] > 0)


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda w: w.apply_forces([5], [[1.0, 0.0, 0.0]]), r"ids: body 5 does not exist"),
        (lambda w: w.apply_forces([-1], [[1.0, 0.0, 0.0]]), r"ids: body -1 does not exist"),
        (lambda w: w.apply_forces([0, 1], [[1.0, 0.0]]), r"forces must have shape \(2, 3\)"),
        (lambda w: w.apply_forces([0], [[np.nan, 0.0, 0.0]]), r"forces: body 0 has a NaN"),
        (
            lambda w: w.apply_forces([1], [1.0, 0, 0], torques=[[np.inf, 0.0, 0.0]]),
            r"torques: body 1 has a NaN or infinite",
        ),
        (
            lambda w: w.apply_forces([0, 1], [1.0, 0, 0], points=np.zeros((3, 3))),
            r"points must have shape \(2, 3\)",
        ),
        (lambda w: w.apply_forces([0], "up"), r"forces must be numbers"),
        (lambda w: w.apply_forces([0.5], [1.0, 0, 0]), r"ids must be a body index"),
    ],
)
def test_bad_input_names_the_argument_and_adds_nothing(runtime, call, match):
    world = World(runtime, gravity=(0, 0, 0))
    world.add_bodies(BOX, positions=[[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    world.apply_forces([1], (0.0, 1.0, 0.0))  # pending before the bad call: kept
    with pytest.raises(RbgenError, match=match):
        call(world)
    world.step(DT)
    assert np.all(world.linear_velocities[0] == 0)
    assert world.linear_velocities[1][1] == pytest.approx(DT, rel=1e-6)


def test_no_blocking_read_in_a_pushed_step(runtime):
    """A step with forces costs no blocking read (the upload is a non-blocking copy)."""
    world = free_box(runtime)
    world.step(DT)
    world.apply_forces(0, (1.0, 0.0, 0.0))
    world.step(DT)
    assert world.last_step_counters["blocking_reads"] == 0


def test_removal_keeps_pending_forces_on_their_bodies(runtime):
    world = World(runtime, gravity=(0, 0, 0))
    world.add_bodies(BOX, positions=[[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    world.apply_forces([0, 2], [[1.0, 0.0, 0.0], [0.0, 0.0, 2.0]])
    world.remove_bodies([0])
    world.step(DT)
    assert np.all(world.linear_velocities[0] == 0)
    assert world.linear_velocities[1][2] == pytest.approx(2.0 * DT, rel=1e-6)


def test_a_redo_does_not_take_the_forces_given_for_the_next_step(runtime):
    """A step without forces overflows; forces are then given for the next step, and a
    read checks the step in flight, which is redone: the redo must replay the step as it
    ran (no forces), and the forces must act in the next step. The end state equals a
    World that never overflowed."""

    def run(pair_capacity):
        world = World(runtime, gravity=(0, 0, 0), pair_capacity=pair_capacity)
        xs = np.arange(6) * 1.0  # boxes of 1 m side at 1 m spacing: touching
        world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), positions=np.c_[xs, np.zeros(6), np.zeros(6)])
        world.step(DT)  # (no forces; overflows with the small pair buffer)
        world.apply_forces(np.arange(6), np.c_[np.zeros(6), np.linspace(1, 6, 6), np.zeros(6)])
        after_first = world.linear_velocities.copy()  # (checks, and redoes, the first step)
        world.step(DT)
        _ = world.positions
        return world, after_first

    (small, small_first), (large, large_first) = run(1), run(None)
    assert small.overflows >= 1 and large.overflows == 0
    np.testing.assert_array_equal(small_first, np.zeros((6, 3)))
    np.testing.assert_array_equal(large_first, np.zeros((6, 3)))
    for field in ("positions", "linear_velocities", "angular_velocities"):
        assert np.array_equal(getattr(small, field), getattr(large, field)), field
    assert np.any(small.linear_velocities[:, 1] > 0)


@pytest.mark.gpu_shape
@pytest.mark.parametrize("substeps", [1, 4])
def test_a_force_equal_to_the_weight_balances_gravity_with_substeps(runtime, substeps):
    """Closed form: no net force, so a box at rest stays where it is (x and v constant),
    whatever the solver substeps: a force acts in every substep as gravity does (the
    prepare kernel's per-substep kicks). Applied as one impulse before the first substep,
    the box rose 6.1 cm in 1 s at 4 substeps."""
    mass = 2.0
    world = World(runtime, substeps=substeps)
    world.add_body(BOX, mass=mass, position=(0.0, 5.0, 0.0))
    weight = -mass * np.asarray(world.gravity, float)
    for _ in range(60):
        world.apply_forces(0, weight)
        world.step(DT)
    np.testing.assert_allclose(world.positions[0], [0.0, 5.0, 0.0], atol=1e-4)
    np.testing.assert_allclose(world.linear_velocities[0], 0.0, atol=1e-4)


def _upload_buffers(world) -> list:
    """Every pinned host buffer of the World's force uploads (kept steps and spares)."""
    forces = world._forces
    uploads = [u for step in forces._steps.values() if step for u in step.uploads if u]
    uploads += [u for pool in forces._spare for u in pool]
    return [u.buffer for u in uploads]


def test_pinned_force_buffers_are_unmapped_when_dropped(runtime):
    """The pinned host arrays the forces are uploaded from are mapped while their upload
    lives, and unmapped when it goes, as the World's other pinned buffers (the step
    report's, the pair buffer's status): pyopencl's MemoryMap unmaps on release. Seen
    through CL_MEM_MAP_COUNT of each buffer: 1 while the World holds it; 0 once the
    uploads of an old body count are dropped (an add resizes the forces), and 0 for
    every one once the World itself is collected."""
    import gc

    import pyopencl as cl

    world = World(runtime, gravity=(0, 0, 0))
    world.add_bodies(BOX, positions=[[0, 0, 0], [3, 0, 0]])
    for _ in range(6):  # (more steps than a redo reaches: spares are made and reused)
        world.apply_forces([0, 1], (1.0, 0, 0), torques=(0, 0, 1), points=np.zeros((2, 3)))
        world.step(DT)
    _ = world.positions
    held = _upload_buffers(world)
    assert len(held) == 3 * 4  # (3 fields, the step and the 3 a redo reaches)
    assert all(b.get_info(cl.mem_info.MAP_COUNT) == 1 for b in held)

    world.add_body(BOX, position=(6, 0, 0))  # (uploads of 2 bodies are not reused for 3)
    for _ in range(6):
        world.apply_forces([0], (1.0, 0, 0), torques=(0, 0, 1), points=np.zeros((1, 3)))
        world.step(DT)
    _ = world.positions
    runtime.queue.finish()
    kept = {b.int_ptr for b in _upload_buffers(world)}
    assert len(kept) == 3 * 4 and not kept & {b.int_ptr for b in held}
    assert [b.get_info(cl.mem_info.MAP_COUNT) for b in held] == [0] * len(held)

    everything = _upload_buffers(world)
    del world
    gc.collect()  # (a World is in reference cycles: its store calls back into it)
    runtime.queue.finish()
    assert [b.get_info(cl.mem_info.MAP_COUNT) for b in held + everything] == [0] * (
        len(held) + len(everything)
    )
