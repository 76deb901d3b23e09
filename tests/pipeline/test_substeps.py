"""Substeps: the contacts' targets refreshed from the bodies' motion (against a float64
reference), the bodies' motion recorded by the integrator, and a World's substeps against
closed forms."""

from __future__ import annotations

import numpy as np
import pyopencl.array as cla
import pytest

import rbgen
from rbgen import layouts
from rbgen.pipeline.integrate import Integrator
from rbgen.pipeline.solvers.substeps import ContactRefresh
from tests.conftest import SIZES
from tests.pipeline.test_integrate import random_bodies

SLOP, RECOVERY = 0.001, 0.2


def random_contacts(rng, n, bodies):
    """``n`` constraints between random bodies of ``bodies`` (0 static: zero deltas), with
    their setup fields: normal, lever arms with the setup separation (r_a.w) and bounce
    (r_b.w), restitution (tangent2.w), 0-4 points."""
    c = layouts.CONTACT_CONSTRAINT.zeros(n)
    c["body_a"] = rng.integers(0, bodies, n)
    c["body_b"] = rng.integers(0, bodies, n)
    normal = rng.normal(size=(n, 3))
    c["normal"][:, :3] = normal / np.linalg.norm(normal, axis=1)[:, None]
    c["tangent2"][:, 3] = rng.uniform(0, 1, n)
    c["point_count"] = rng.integers(0, 5, n)
    c["r_a"][..., :3] = rng.uniform(-1, 1, (n, 4, 3))
    c["r_b"][..., :3] = rng.uniform(-1, 1, (n, 4, 3))
    c["r_a"][..., 3] = rng.uniform(-0.02, 0.02, (n, 4))
    c["r_b"][..., 3] = np.where(rng.random((n, 4)) < 0.3, rng.uniform(0, 3, (n, 4)), 0.0)
    c["push_impulse"] = 7.0  # (cleared by the refresh)
    return c


def reference_targets(c, deltas, h):
    """Float64: each point's separation from the deltas, then its velocity and push
    targets (the rules of solvers/substeps.cl.mako's header: a point apart lands, one
    touching stops; its bounce, r_b.w, is no target: the restitution pass applies it)."""
    velocity = np.zeros((len(c), 4))
    push = np.zeros((len(c), 4))
    for i, row in enumerate(c):
        a, b = int(row["body_a"]), int(row["body_b"])
        n = row["normal"][:3].astype(np.float64)
        moved = deltas["linear"][b, :3].astype(np.float64) - deltas["linear"][a, :3]
        for k in range(int(row["point_count"])):
            ra, rb = row["r_a"][k, :3].astype(np.float64), row["r_b"][k, :3].astype(np.float64)
            s = (
                row["r_a"][k, 3]
                + n @ moved
                + deltas["angular"][b, :3] @ np.cross(rb, n)
                - deltas["angular"][a, :3] @ np.cross(ra, n)
            )
            velocity[i, k] = -s / h if s > 0 else 0.0
            push[i, k] = -RECOVERY / h * s if s > 0 else RECOVERY / h * max(-s - SLOP, 0.0)
    return velocity, push


@pytest.mark.parametrize("n", SIZES[:-1])
def test_refreshed_targets_match_float64(runtime, rng, n):
    """Sizes 0, 1, 31-33 and 1,000 (not multiples of the work group); the count on the
    device is one less than the capacity, so the last constraint must stay as it was."""
    bodies = 50
    refresh = ContactRefresh(runtime)
    deltas = layouts.BODY_DELTA.zeros(bodies)
    deltas["linear"][1:, :3] = rng.normal(0, 0.01, (bodies - 1, 3))
    deltas["angular"][1:, :3] = rng.normal(0, 0.01, (bodies - 1, 3))
    refresh.body_deltas(bodies).set(deltas)
    c = random_contacts(rng, max(n, 1), bodies)
    count = max(0, n - 1)
    d = cla.to_device(runtime.queue, c)
    h = 1 / 240
    count_d = cla.to_device(runtime.queue, np.array([count], np.uint32))
    refresh(d, count_d, n, bodies, h, SLOP, RECOVERY)
    got = d.get()
    velocity, push = reference_targets(c[:count], deltas, h)
    np.testing.assert_allclose(got["velocity_target"][:count], velocity, rtol=1e-4, atol=2e-3)
    np.testing.assert_allclose(got["position_target"][:count], push, rtol=1e-4, atol=2e-3)
    assert np.all(got["push_impulse"][:count] == 0)
    assert got[count:].tobytes() == c[count:].tobytes()  # past the count: untouched


def test_integrator_records_the_motion_since_the_step_began(runtime, rng):
    """Three substeps of h: the deltas are the sums of v h (and w h, the push included)
    over them, restarted by the first; static bodies keep zero."""
    n, h = 301, 1 / 180
    bodies = random_bodies(rng, n)
    bodies["angular_velocity"][:, :3] *= 0.1  # (below the clamp)
    integrate = Integrator(runtime, gravity=False, damping=True)
    d = cla.to_device(runtime.queue, bodies)
    deltas = cla.to_device(runtime.queue, np.full(n, 5, layouts.BODY_DELTA.dtype))
    split = cla.zeros(runtime.queue, n, layouts.SPLIT_VELOCITY.dtype)
    expected_linear = np.zeros((n, 3))
    expected_angular = np.zeros((n, 3))
    for k in range(3):
        push = layouts.SPLIT_VELOCITY.zeros(n)
        push["linear"][:, :3] = rng.normal(0, 0.1, (n, 3))
        push["angular"][:, :3] = rng.normal(0, 0.1, (n, 3))
        split.set(push)
        before = d.get()
        integrate(d, n, h, split=split, deltas=deltas, first_substep=k == 0)
        expected_linear += (before["linear_velocity"][:, :3] + push["linear"][:, :3]) * h
        expected_angular += (before["angular_velocity"][:, :3] + push["angular"][:, :3]) * h
    got = deltas.get()
    dynamic = bodies["inv_mass"] > 0
    np.testing.assert_allclose(got["linear"][dynamic, :3], expected_linear[dynamic], atol=1e-5)
    np.testing.assert_allclose(got["angular"][dynamic, :3], expected_angular[dynamic], atol=1e-5)
    assert np.all(got["linear"][~dynamic] == np.full(1, 5, layouts.BODY_DELTA.dtype)["linear"])


@pytest.mark.parametrize("substeps", [1, 2, 4])
def test_free_fall_over_substeps(runtime, substeps):
    """A free body over one step of S substeps (semi-implicit Euler each): v = g dt and
    y = y0 + v0 dt + g h^2 S (S + 1) / 2, with h = dt / S."""
    world = rbgen.World(runtime, substeps=substeps)
    world.add_static(rbgen.Box((5, 0.5, 5)), position=(0, -50, 0))
    world.add_body(rbgen.Sphere(0.5), position=(0, 10, 0), linear_velocity=(1, 2, 0))
    dt = 1 / 60
    world.step(dt)
    h = dt / substeps
    y = 10 + 2 * dt - 9.81 * h * h * substeps * (substeps + 1) / 2
    np.testing.assert_allclose(world.positions[1], [dt, y, 0], atol=1e-5)
    np.testing.assert_allclose(world.linear_velocities[1], [1, 2 - 9.81 * dt, 0], atol=1e-5)


def test_substeps_are_checked(runtime):
    for bad in (0, 65, 2.5, True):
        with pytest.raises(rbgen.RbgenError, match="substeps"):
            rbgen.World(runtime, substeps=bad)


def stacked_boxes(world):
    world.add_static(rbgen.Box((10, 1, 10)), position=(0, -1, 0))
    grid = np.array(
        [[1.1 * i, 0.5 + 1.0 * j, 1.1 * k] for i in range(3) for j in range(4) for k in range(2)],
        float,
    )
    return world.add_bodies(
        rbgen.Box((0.5, 0.5, 0.5)),
        mass=1.0,
        positions=grid + np.random.default_rng(3).uniform(-0.02, 0.02, grid.shape),
    )


def test_persistent_launch_runs_the_substeps_as_the_launches_do(runtime, monkeypatch):
    """Global batching's persistent launch runs every substep itself (gravity, the
    targets' refresh, the warm start, the sweeps, the bodies' motion); the same solver made
    to leave the substeps to the launch-per-phase loop (gravity, refresh and integrator
    launches) gives the same trajectory: stacked boxes settling over 40 steps of 4
    substeps, with damping."""
    from rbgen.pipeline.solvers.pgs import PgsSolver

    def run():
        world = rbgen.World(
            runtime,
            batching="global",
            substeps=4,
            iterations=3,
            position_iterations=1,
            linear_damping=0.1,
            angular_damping=0.2,
        )
        ids = stacked_boxes(world)
        for _ in range(40):
            world.step(1 / 60)
        return world.positions[ids], world.linear_velocities[ids], world.orientations[ids]

    fused = run()
    monkeypatch.setattr(PgsSolver, "integrates", property(lambda self: False))
    looped = run()
    for got, want in zip(fused, looped):
        np.testing.assert_allclose(got, want, atol=2e-5)
    assert np.abs(fused[1]).max() < 0.05  # (and they came to rest)


@pytest.mark.parametrize("effort", [{}, {"iterations": 3, "position_iterations": 2}])
def test_folded_substeps_do_the_passes_arithmetic_bit_for_bit(runtime, monkeypatch, effort):
    """A persistent launch without joints folds each substep's refresh of the targets,
    carry of the impulses and summed warm start into its sweeps (pgs.cl.mako:
    solve_copy, template parameter fold_substeps); the same launch built with the
    passes of their own does the same arithmetic in the same order: equal bits, exact
    builds (fast math lets each program reorder its own way), stacked boxes settling over
    40 steps of 8 substeps with damping, at the default effort (with its shock sweep) and at
    another, whose push sweeps outnumber nothing and end after the velocity sweeps."""
    from rbgen.pipeline.solvers import pgs

    def run():
        world = rbgen.World(
            runtime,
            batching="global",
            substeps=8,
            fast_math=False,
            linear_damping=0.1,
            angular_damping=0.2,
            **effort,
        )
        ids = stacked_boxes(world)
        world.add_body(rbgen.Box((0.5, 0.5, 0.5)), mass=2.0, position=(0.3, 6.0, 0.2))
        for _ in range(40):
            world.step(1 / 60)
        folded = world._pipeline.solve.solver.spec.values["fold_substeps"]
        state = (
            world.positions,
            world.orientations,
            world.linear_velocities,
            world.angular_velocities,
        )
        return folded, ids, state

    folded, ids, fused = run()
    monkeypatch.setattr(pgs, "default_fold_substeps", lambda persistent: False)
    unfolded, _, passes = run()
    assert folded and not unfolded
    for got, want in zip(fused, passes):
        np.testing.assert_array_equal(got, want)
    assert np.abs(fused[2][ids]).max() < 0.05  # (the stack came to rest)


def test_folded_substeps_with_joints_do_the_passes_arithmetic_bit_for_bit(runtime, monkeypatch):
    """With joints, a persistent launch folds its contacts' refresh, carry and warm-start
    sums into the sweeps and keeps the joints' warm start as a pass after the bodies move
    (pgs.cl.mako: fold_substeps; the bodies then take every sum behind a barrier); built
    with every pass of its own it does the same arithmetic in the same order: equal bits,
    exact builds, 3 ragdolls (hinges, balls, limits) falling onto a box and the ground over
    50 steps at the ragdoll settings (they land at step 32: bodies with both joints' and
    contacts' warm starts from then on), summed warm start."""
    from rbgen.harness import build_scene
    from rbgen.pipeline.solvers import pgs

    if not runtime.has_extension(pgs.INT64_ATOMICS):
        pytest.skip(f"{runtime.traits.device_name} has no {pgs.INT64_ATOMICS}")

    def run():
        world, ids, _, _ = build_scene("ragdolls", 3, runtime, batching="global", fast_math=False)
        for _ in range(50):
            world.step(1 / 60)
        assert world.statistics(contacts=False)["manifolds"] >= 10  # (they landed)
        solver = world._pipeline.solve.solver
        state = (
            world.positions,
            world.orientations,
            world.linear_velocities,
            world.angular_velocities,
        )
        return solver.spec.values, ids, state

    folded, ids, fused = run()
    monkeypatch.setattr(pgs, "default_fold_substeps", lambda persistent: False)
    unfolded, _, passes = run()
    assert folded["joints"] and folded["fold_substeps"] and not unfolded["fold_substeps"]
    assert folded["warm_start_mode"] == "summed"
    for got, want in zip(fused, passes):
        np.testing.assert_array_equal(got, want)
    assert np.isfinite(fused[0]).all() and (fused[0][ids, 1] > -0.1).all()


@pytest.mark.parametrize(
    "substeps,effort",
    [(1, {}), (4, {}), (8, {"iterations": 2, "position_iterations": 1, "normal_solve": "block"})],
)
def test_bounces_keep_their_restitution(runtime, substeps, effort):
    """A box with e = 0.5 dropped from 1 m on a ground of e = 0.5: each of the first two
    bounces (in at 4.4 and 2.2 m/s) leaves at e times the speed it came in with, within
    10% (in: sqrt(2 g apex); out: the velocity of the first step that rises; slower
    impacts miss up to g dt = 0.16 m/s, the bounce being measured at the step's start).
    The rows stop the points (a gap crossed lands exactly), and the restitution pass after
    the last substep's rows bounces every point that pushed in any substep: a step that
    ended at a landing velocity would have the next step's setup measure the approach
    from it, losing the bounce."""
    world = rbgen.World(runtime, substeps=substeps, restitution_threshold=0.5, **effort)
    world.add_static(rbgen.Box((10, 1, 10)), position=(0, -1, 0), restitution=0.5)
    world.add_body(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, position=(0, 1.5, 0), restitution=0.5)
    g, dt = 9.81, 1 / 60
    bounces, falling, top = [], True, 1.0
    for _ in range(200):
        world.step(dt)
        y, vy = world.positions[1][1] - 0.5, world.linear_velocities[1][1]
        if falling and vy > 0:
            bounces.append((np.sqrt(2 * g * top), vy))
            falling = False
        elif not falling and vy <= 0:
            top, falling = y, True
        if len(bounces) == 2:
            break
    assert len(bounces) == 2, bounces
    for speed_in, speed_out in bounces:
        assert speed_out == pytest.approx(0.5 * speed_in, rel=0.1), bounces


def test_persistent_launch_bounces_as_the_launches_do(runtime, monkeypatch):
    """The persistent launch applies the restitution after its last substep as the loop's
    last solve does: a box (e = 0.5) dropped from 1 m, 4 substeps, through two bounces,
    the same trajectory either way."""
    from rbgen.pipeline.solvers.pgs import PgsSolver

    def run():
        world = rbgen.World(runtime, batching="global", substeps=4, restitution_threshold=0.5)
        world.add_static(rbgen.Box((10, 1, 10)), position=(0, -1, 0), restitution=0.5)
        box = world.add_body(
            rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, position=(0, 1.5, 0), restitution=0.5
        )
        heights = []
        for _ in range(80):
            world.step(1 / 60)
            heights.append(world.positions[box][1])
        return np.array(heights)

    fused = run()
    monkeypatch.setattr(PgsSolver, "integrates", property(lambda self: False))
    looped = run()
    np.testing.assert_allclose(fused, looped, atol=2e-5)
    assert fused[30:].max() > 0.5 + 0.2  # (it bounced)


@pytest.mark.gpu_shape
def test_a_static_body_that_takes_a_moved_bodys_index_stays_still(runtime):
    """A falling sphere (index 0) is removed, so the static ground takes its index: the
    substeps must see the ground at rest (its motion zero), not the sphere's last motion.
    A box resting on the ground then stays at rest, as in the same World without the
    sphere (closed form: y = 0.5, the half extent). The ground kept the sphere's last
    BodyDelta before the fix (never written for a static body) and the box sank 6 mm."""
    world = rbgen.World(runtime, substeps=4)
    sphere = world.add_body(rbgen.Sphere(0.2), position=(10, 30, 0), linear_velocity=(0, -30, 0))
    world.add_static(rbgen.Box((5, 0.5, 5)), position=(0, -0.5, 0))
    world.add_body(rbgen.Box((0.5, 0.5, 0.5)), position=(0, 0.5, 0))
    for _ in range(5):
        world.step(1 / 60)
    world.remove_bodies([sphere])
    for _ in range(30):
        world.step(1 / 60)
        assert abs(world.positions[1, 1] - 0.5) < 2e-4
