"""Removing bodies (issue 30, item 3): `World.remove_bodies` closes the gaps, keeps the
survivors' order and returns old -> new indices; the survivors' contacts keep their warm
start, renumbered, and nothing of a removed body is carried onto another; buffers keep
their capacity."""

from __future__ import annotations

import numpy as np
import pytest

import rbgen
from rbgen import RbgenError, memory
from rbgen.world import World

DT = 1 / 60
FIELDS = ("positions", "orientations", "linear_velocities", "angular_velocities")


def two_stacks(runtime, heavy=100.0, light=1.0, **options):
    """Body 0: the ground; 1, 2: a stack of two heavy boxes; 3, 4: a stack of two light
    boxes 4 m away. Settled for 40 steps."""
    world = World(runtime, **options)
    world.add_static(rbgen.Box((20, 1, 20)), position=(0, -1, 0))
    box = rbgen.Box((0.5, 0.5, 0.5))
    world.add_bodies(box, mass=heavy, positions=[[-2, 0.5, 0], [-2, 1.5, 0]])
    world.add_bodies(box, mass=light, positions=[[2, 0.5, 0], [2, 1.5, 0]])
    for _ in range(40):
        world.step(DT)
    return world


def test_remove_returns_the_mapping_and_keeps_the_survivors_in_order(runtime):
    world = two_stacks(runtime)
    before = {f: getattr(world, f).copy() for f in FIELDS}
    mapping = world.remove_bodies([3, 1])
    assert mapping.dtype == np.int64
    assert mapping.tolist() == [0, -1, 1, -1, 2]
    assert world.body_count == 3
    for field in FIELDS:
        assert np.array_equal(getattr(world, field), before[field][[0, 2, 4]])
    ids = np.array([2, 4])
    assert mapping[ids].tolist() == [1, 2]  # how a caller updates the indices it keeps


def last_constraints(world):
    constraints = world._pipeline.constraints.constraints
    count = int(world.runtime.read(constraints.count)[0])
    return world.runtime.read(constraints.constraints[:count])


def by_pair(records):
    return {
        (int(r["body_a"]), int(r["body_b"])): r
        for r in records
        if r["body_a"] != rbgen.layouts.SOLVER_NONE
    }


def test_warm_starts_follow_their_bodies(runtime):
    """Removing the heavy stack renumbers the light one (3, 4 -> 1, 2): its constraints
    keep their impulses under the new numbers, in order, and the heavy stack's are gone."""
    world = two_stacks(runtime)
    old = by_pair(last_constraints(world))
    assert set(old) == {(0, 1), (1, 2), (0, 3), (3, 4)}
    world.remove_bodies([1, 2])
    records = last_constraints(world)
    new = by_pair(records)
    assert list(new) == [(0, 1), (1, 2)]  # in order, at the front
    assert [(int(a), int(b)) for a, b in records[["body_a", "body_b"]][:2]] == [(0, 1), (1, 2)]
    for (a, b), (c, d) in (((0, 1), (0, 3)), ((1, 2), (3, 4))):
        assert np.array_equal(new[(a, b)]["normal_impulse"], old[(c, d)]["normal_impulse"])


def test_the_old_pair_table_is_emptied_so_that_the_physics_repeats(runtime):
    """The last generation's table maps old keys to old indices; a lookup through it after
    a renumbering would find a survivor or not depending on the order in which the table
    was filled (device atomics), so two identical runs could differ (a soak of 100,000
    churned steps did). It is emptied: survivors are found at their own index only."""
    world = two_stacks(runtime)
    constraints = world._pipeline.constraints.constraints
    table = constraints._generations[constraints._current].table
    assert np.any(world.runtime.read(table) != rbgen.layouts.SOLVER_NONE)
    world.remove_bodies([1, 2])
    assert np.all(world.runtime.read(table) == rbgen.layouts.SOLVER_NONE)


def test_no_warm_start_is_carried_onto_the_wrong_body(runtime):
    """Without renumbering, the light stack's new pairs (0, 1) and (1, 2) would find the
    heavy stack's old constraints of those numbers, a hundred times its weight, and be
    thrown up. It stays at rest, stepping as in a twin World where nothing was removed."""
    world, twin = two_stacks(runtime), two_stacks(runtime)
    world.remove_bodies([1, 2])
    for _ in range(3):
        world.step(DT)
        twin.step(DT)
    assert np.abs(world.linear_velocities[1:]).max() < 0.01
    np.testing.assert_allclose(world.positions[1:], twin.positions[3:], atol=1e-5)
    np.testing.assert_allclose(world.linear_velocities[1:], twin.linear_velocities[3:], atol=1e-4)


@pytest.mark.parametrize(
    "options", [{"solver": "jacobi"}, {"broadphase": "sap3"}, {"broadphase": "sap"}]
)
def test_removal_with_other_solvers_and_broadphases(runtime, options):
    world = two_stacks(runtime, **options)
    world.remove_bodies([1, 2])
    for _ in range(10):
        world.step(DT)
    assert np.abs(world.linear_velocities[1:]).max() < 0.05
    assert np.all(world.positions[1:, 1] > [0.45, 1.45])


def test_capacities_are_kept_and_reused(runtime):
    """Removing bodies shrinks no buffer; adding as many again allocates nothing more."""
    world = two_stacks(runtime, pair_capacity=4096, manifold_capacity=4096)
    _ = world.positions  # (waits for the steps in flight)
    held = memory.device_bytes(world)
    mapping = world.remove_bodies([3, 4])
    world.step(DT)
    _ = world.positions  # (waits for the steps in flight)
    assert world._pipeline.narrowphase.capacity == 4096
    world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), positions=[[5, 0.5, 0], [5, 1.5, 0]])
    world.step(DT)
    _ = world.positions  # (waits for the steps in flight)
    assert memory.device_bytes(world) <= held  # (grid scratch follows the scene's extent)
    assert mapping.tolist() == [0, 1, 2, -1, -1]


def test_remove_everything_then_add_again(runtime):
    world = two_stacks(runtime)
    world.remove_bodies(np.arange(world.body_count))
    assert world.body_count == 0
    world.step(DT)
    world.add_static(rbgen.Plane((0, 1, 0)))
    world.add_body(rbgen.Sphere(0.5), position=(0, 0.5, 0))
    for _ in range(5):
        world.step(DT)
    assert abs(world.positions[1, 1] - 0.5) < 0.01


def test_repeats_are_allowed_and_empty_is_nothing(runtime):
    world = two_stacks(runtime)
    assert world.remove_bodies([]).tolist() == [0, 1, 2, 3, 4]
    assert world.remove_bodies([4, 4]).tolist() == [0, 1, 2, 3, -1]
    assert world.body_count == 4


@pytest.mark.parametrize(
    "ids,needle",
    [
        ([5], r"ids: body 5 does not exist \(body indices run from 0 to 4\)"),
        ([-1], "ids: body -1 does not exist"),
        ([1.5], "ids must be a body index"),
        ("1", "ids must be a body index"),
        ([[1, 2]], "ids must be a body index"),
        (None, "ids must be a body index"),
    ],
)
def test_remove_bad_ids_names_them_and_changes_nothing(runtime, ids, needle):
    world = two_stacks(runtime)
    before = {f: getattr(world, f).copy() for f in FIELDS}
    with pytest.raises(RbgenError, match=needle):
        world.remove_bodies(ids)
    assert world.body_count == 5
    for field in FIELDS:
        assert np.array_equal(getattr(world, field), before[field])
