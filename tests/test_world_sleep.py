"""Sleeping islands through the public API (World option ``sleeping``): islands at rest
fall asleep exactly still, and wake whole when touched, pushed or set; a moving body
keeps its island awake; a redone step and a WorldBatch keep the sleep state exact."""

from __future__ import annotations

import numpy as np
import pytest

import rbgen
from rbgen import World

DT = 1.0 / 60.0
BOX = rbgen.Box((0.5, 0.5, 0.5))


def two_stacks(runtime, friction=0.6, **options):
    """Two stacks of three boxes 20 m apart on the ground (bodies 1-3 and 4-6)."""
    world = World(runtime, sleeping=True, **options)
    world.add_static(rbgen.Plane((0, 1, 0), 0.0), friction=friction)
    stack = np.array([[0.0, 0.5 + k, 0.0] for k in range(3)])
    world.add_bodies(BOX, positions=np.vstack([stack, stack + [20.0, 0, 0]]), friction=friction)
    return world


A, B = [1, 2, 3], [4, 5, 6]


def steps(world, count):
    for _ in range(count):
        world.step(DT)


def test_a_dropped_pile_settles_asleep(runtime):
    """50 boxes dropped in 5 layers (the box_pile scene) land, settle and sleep within 300
    steps; asleep, every velocity is exactly 0 and no pose changes by a bit."""
    from rbgen.harness import build_scene

    world, ids = build_scene("box_pile", 50, runtime, sleeping=True)[:2]
    steps(world, 60)
    assert not world.asleep[ids].all()  # (still falling and settling)
    steps(world, 240)
    assert world.asleep[ids].all()
    poses = world.positions.copy(), world.orientations.copy()
    steps(world, 10)
    assert np.array_equal(world.positions, poses[0])
    assert np.array_equal(world.orientations, poses[1])
    assert not world.linear_velocities.any() and not world.angular_velocities.any()
    assert (world.positions[ids, 1] > 0.45).all()  # (on the ground, not through it)


@pytest.mark.parametrize(
    "options",
    [{}, {"broadphase": "sap3"}, {"solver": "jacobi"}, {"batching": "global"}],
    ids=["default", "sap3", "jacobi", "global"],
)
def test_a_settled_pile_sleeps_still_and_a_dropped_box_wakes_only_its_island(runtime, options):
    """Both stacks rest from the start: after sleep_time (0.5 s = 30 steps) and a step of
    margin they are asleep, their velocities exactly 0 and their poses bit for bit
    unchanged step after step. A box dropped on stack A wakes A (its whole island, when
    it touches the top box) and not B, whose poses stay unchanged; then all sleep again.
    With each broadphase and solver (the incremental SAP keeps the pairs of sleeping
    bodies: their contacts, between two bodies of no inverse mass, must do nothing)."""
    world = two_stacks(runtime, **options)
    steps(world, 28)
    assert not world.asleep.any()  # (not before the sleep time)
    steps(world, 4)
    assert world.asleep[1:].all() and not world.asleep[0]  # (the ground is static)
    poses = world.positions.copy(), world.orientations.copy()
    for _ in range(20):
        world.step(DT)
        assert not world.linear_velocities.any() and not world.angular_velocities.any()
        assert np.array_equal(world.positions, poses[0])
        assert np.array_equal(world.orientations, poses[1])
    drop = world.add_body(BOX, position=(0.0, 4.0, 0.0))
    woke = False
    for _ in range(60):
        world.step(DT)
        asleep = world.asleep
        woke = woke or not asleep[A].any()
        assert asleep[B].all()
        assert np.array_equal(world.positions[B], poses[0][B])
    assert woke
    assert world.positions[drop][1] == pytest.approx(3.5, abs=0.01)  # (landed on A)
    steps(world, 40)
    assert world.asleep[1:].all()


def test_apply_forces_wakes_the_island_and_acts_in_that_step(runtime):
    """A push on the top box of a sleeping frictionless stack wakes stack A whole before
    the forces act, so the top box leaves at v = F dt / m; stack B sleeps on."""
    world = two_stacks(runtime, friction=0.0)
    steps(world, 40)
    assert world.asleep[1:].all()
    world.apply_forces([3], (6.0, 0.0, 0.0))
    world.step(DT)
    asleep = world.asleep
    assert not asleep[A].any() and asleep[B].all()
    assert world.linear_velocities[3][0] == pytest.approx(6.0 * DT, rel=1e-4)
    assert world.positions[3][0] > 0


def test_an_island_with_one_moving_body_stays_awake(runtime):
    """A ball rolling at 1 m/s across a heavy slab that rests on the ground: the slab is
    at rest but shares the ball's island, so neither sleeps; a lone box far off sleeps."""
    world = World(runtime, sleeping=True)
    world.add_static(rbgen.Plane((0, 1, 0), 0.0))
    slab = world.add_body(rbgen.Box((4.0, 0.25, 1.0)), mass=50.0, position=(0, 0.25, 0))
    ball = world.add_body(
        rbgen.Sphere(0.2),
        position=(-3.0, 0.7, 0),
        linear_velocity=(1.0, 0, 0),
        angular_velocity=(0, 0, -5.0),
    )
    lone = world.add_body(BOX, position=(20.0, 0.5, 0))
    steps(world, 90)
    asleep = world.asleep
    assert asleep[lone] and not asleep[slab] and not asleep[ball]
    assert world.linear_velocities[ball][0] > 0.5


def test_a_body_above_the_threshold_restarts_its_timer(runtime):
    """A box sliding at v0 = 2 m/s with friction 0.5 slows at mu g; its speed falls below
    the threshold at t1 = (v0 - 0.05) / (mu g) = 0.40 s, and it sleeps sleep_time later
    (0.90 s), not at 0.5 s (its timer restarted every step it was faster)."""
    world = World(runtime, sleeping=True)
    world.add_static(rbgen.Plane((0, 1, 0), 0.0), friction=0.5)
    box = world.add_body(BOX, position=(0, 0.5, 0), linear_velocity=(2.0, 0, 0), friction=0.5)
    t1 = (2.0 - world.sleep_threshold) / (0.5 * 9.81)
    asleep_at = None
    for k in range(1, 80):
        world.step(DT)
        if asleep_at is None and world.asleep[box]:
            asleep_at = k * DT
    assert asleep_at == pytest.approx(t1 + world.sleep_time, abs=3 * DT)


def test_host_changes_wake_the_islands_they_touch(runtime):
    """set_state of one body wakes its island only; removing a body wakes its island and
    keeps the other asleep under its new numbers; `wake` wakes the island named; a new
    gravity wakes every island before the next step (each box then falls at v = g dt)."""
    world = two_stacks(runtime)
    steps(world, 35)
    world.set_state([2], positions=(0.0, 1.6, 0.0))
    asleep = world.asleep
    assert not asleep[A].any() and asleep[B].all()
    steps(world, 45)
    assert world.asleep[1:].all()
    mapping = world.remove_bodies([3])
    asleep = world.asleep
    assert not asleep[mapping[[1, 2]]].any() and asleep[mapping[B]].all()
    before = world.positions[mapping[B]].copy()
    steps(world, 5)
    assert np.array_equal(world.positions[mapping[B]], before)
    steps(world, 40)
    assert world.asleep[1:].all()
    world.wake([mapping[5]])  # (by hand: B's island, not A's)
    asleep = world.asleep
    assert not asleep[mapping[B]].any() and asleep[mapping[[1, 2]]].all()
    world.gravity = (0.0, 9.0, 0.0)  # (upward: nothing resists the fall, v = g dt)
    assert not world.asleep.any()
    world.step(DT)
    np.testing.assert_allclose(world.linear_velocities[1:, 1], 9.0 * DT, rtol=1e-5)


def test_removing_bodies_added_since_the_last_step(runtime):
    """Bodies added and removed between two steps (some without a sleep record yet): the
    survivors keep their records in their new places, stack B sleeps on unmoved."""
    world = two_stacks(runtime)
    steps(world, 35)
    first = world.add_bodies(BOX, positions=[[-10.0, 0.5, 0], [-12.0, 0.5, 0]])
    mapping = world.remove_bodies([3, int(first[0])])
    before = world.positions[mapping[B]].copy()
    steps(world, 5)
    asleep = world.asleep
    assert asleep[mapping[B]].all() and not asleep[mapping[[1, 2, int(first[1])]]].any()
    assert np.array_equal(world.positions[mapping[B]], before)
    steps(world, 40)
    assert world.asleep[1:].all()


def test_sleeping_adds_four_launches_and_no_blocking_read(runtime):
    """The step stays a fixed sequence without a blocking read: sleeping adds its four
    end-of-step launches, from the first step on."""
    counts = {}
    for sleeping in (False, True):
        world = World(runtime, sleeping=sleeping)
        world.add_static(rbgen.Plane((0, 1, 0), 0.0))
        world.add_bodies(BOX, positions=[[0, 0.5, 0], [0, 1.5, 0]])
        world.step(DT)
        first = world.last_step_counters
        world.step(DT)
        counts[sleeping] = (first, world.last_step_counters)
    assert counts[True][1]["launches"] == counts[False][1]["launches"] + 4
    assert counts[True][0]["launches"] == counts[False][0]["launches"] + 4
    assert counts[True][1]["blocking_reads"] == 0 and counts[True][0]["blocking_reads"] == 0


@pytest.mark.parametrize(
    "option, value",
    [
        ("sleeping", "yes"),
        ("sleep_threshold", 0.0),
        ("sleep_threshold", -1.0),
        ("sleep_threshold", float("nan")),
        ("sleep_time", 0.0),
        ("sleep_time", 1e9),
        ("sleep_time", True),
    ],
)
def test_bad_sleep_settings_are_named(runtime, option, value):
    with pytest.raises(rbgen.RbgenError, match=option):
        World(runtime, **{option: value})
    if option != "sleeping":
        world = World(runtime, sleeping=True)
        before = getattr(world, option)
        with pytest.raises(rbgen.RbgenError, match=option):
            setattr(world, option, value)
        assert getattr(world, option) == before


def test_a_redone_step_rewinds_the_sleep_state(runtime):
    """Steps that overflow the manifold buffer (shrunk to one manifold just before the
    islands fall asleep, and again as a dropped box lands) are redone from their backup,
    sleep records included: every pose and sleep flag equals a World that never
    overflowed, bit for bit."""

    def run(shrink):
        world = two_stacks(runtime)
        trace = []
        for k in range(110):
            if k == 60:
                world.add_body(BOX, position=(0.0, 4.0, 0.0))
            if shrink and k in (29, 30, 75):
                world._finish_pending()
                world._steps.narrowphase.set_capacity("manifolds", 1)
            world.step(DT)
            trace.append((world.positions.copy(), world.asleep.copy()))
        return world, trace

    reference, want = run(False)
    shrunk, got = run(True)
    assert shrunk.overflows >= 2 and reference.overflows == 0
    for k, ((p, a), (q, b)) in enumerate(zip(want, got)):
        assert np.array_equal(a, b), k
        assert np.array_equal(p, q), k
    assert any(a[1:].all() for _, a in want) and not all(a[1:].all() for _, a in want)


def batch_run(runtime, envs, **options):
    """``envs`` environments of a small pile, each from its own state; environment 3
    (if any) is pushed at step 70, environment 5 reset at step 80."""

    def build():
        world = World(runtime, sleeping=True, **options)
        world.add_static(rbgen.Plane((0, 1, 0), 0.0))
        world.add_bodies(BOX, positions=[[0, 0.5, 0], [0, 1.5, 0], [1.2, 0.5, 0]])
        return world

    batch = rbgen.WorldBatch(envs, build)
    for k in range(envs):
        rng = np.random.default_rng(100 + k)
        base = np.array([[0, 0.5, 0], [0, 1.6, 0], [1.2, 0.7, 0]])
        batch.reset([k], state={"positions": (base + rng.uniform(-0.05, 0.05, (3, 3)))[None]})
    flags = []
    for s in range(120):
        if s == 70 and envs > 3:
            forces = np.zeros((envs, 3, 3))
            forces[3, 1] = (0.0, 0.0, 30.0)
            batch.apply_forces(forces)
        if s == 80 and envs > 5:
            batch.reset([5])
        batch.step(DT)
        if s in (69, 71, 81, 119):
            flags.append(batch.asleep.copy())
    return batch, flags


@pytest.mark.parametrize("options", [{}, {"pair_capacity": 4, "manifold_capacity": 4}])
def test_batch_environments_sleep_independently_and_bit_for_bit(runtime, options):
    """Environment 0 ends bit for bit the same in a batch of one and of seven (with and
    without overflowing buffers), and sleeps at the same steps; in the batch of seven,
    environment 3's stack wakes when pushed and environment 5 when reset, while the
    others sleep on."""
    one, one_flags = batch_run(runtime, 1, **options)
    seven, seven_flags = batch_run(runtime, 7, **options)
    for field in ("positions", "orientations", "linear_velocities", "angular_velocities"):
        assert np.array_equal(getattr(one, field)[0], getattr(seven, field)[0]), field
    for a, b in zip(one_flags, seven_flags):
        assert np.array_equal(a[0], b[0])
    before, pushed, reset, end = seven_flags
    assert before.all()  # (every environment asleep by step 69)
    # (environment 3's stack wakes; its lone box, an island of its own, sleeps on)
    assert not pushed[3][:2].any() and pushed[3][2] and np.delete(pushed, 3, axis=0).all()
    assert not reset[5].any() and np.delete(reset, [3, 5], axis=0).all()
    assert end.all()
    assert seven.statistics()["asleep"] == 7 * 3


def test_a_jointed_island_sleeps_and_wakes_whole(runtime):
    """Three boxes 10 cm apart on the ground, held by ball joints (jointed bodies do not
    collide: the joints alone make them one island), and a lone box: all sleep; a push on
    one end wakes the three and not the lone box; the joints' impulses stay finite while
    they sleep (their rows see no inverse mass) and after they wake."""
    world = World(runtime, sleeping=True)
    world.add_static(rbgen.Plane((0, 1, 0), 0.0))
    chain = world.add_bodies(BOX, positions=[[0, 0.5, 0], [1.1, 0.5, 0], [2.2, 0.5, 0]])
    lone = world.add_body(BOX, position=(20.0, 0.5, 0))
    for a, b in zip(chain[:-1], chain[1:]):
        anchor = (world.positions[a] + world.positions[b]) / 2
        world.add_joint(rbgen.BallJoint(int(a), int(b), anchor=anchor))
    steps(world, 40)
    assert world.asleep[1:].all()
    assert np.isfinite(world.joint_impulses).all()
    world.apply_forces([int(chain[0])], (0.0, 0.0, 40.0))
    world.step(DT)
    asleep = world.asleep
    assert not asleep[chain].any() and asleep[lone]
    steps(world, 60)
    assert np.isfinite(world.joint_impulses).all() and np.isfinite(world.positions).all()
    gaps = np.linalg.norm(np.diff(world.positions[chain], axis=0), axis=1)
    np.testing.assert_allclose(gaps, 1.1, atol=0.01)  # (the joints held)
