"""No silent edits (issue 30, item 2): the state arrays a World returns are read-only
snapshots whose edit raises naming the setter; `World.set_state` sets any field of some
bodies, checked, all or nothing; setting state forgets the warm start of the bodies set
and only theirs."""

from __future__ import annotations

import numpy as np
import pytest

import rbgen
from rbgen import RbgenError, layouts
from rbgen.world import World

BOX = rbgen.Box((0.5, 0.5, 0.5))
FIELDS = ("positions", "orientations", "linear_velocities", "angular_velocities")
DT = 1 / 60


def two_boxes(runtime):
    """Body 0: the ground (static); bodies 1 and 2: boxes resting on it, 4 m apart (no
    dynamic body touches both, so their contacts are solved independently)."""
    world = World(runtime)
    world.add_static(rbgen.Box((20, 1, 20)), position=(0, -1, 0))
    world.add_bodies(BOX, positions=[[-2.0, 0.5, 0.0], [2.0, 0.5, 0.0]])
    return world


def snapshot(world):
    return [world.body_count] + [getattr(world, f).copy() for f in FIELDS]


def assert_unchanged(world, before):
    after = snapshot(world)
    assert after[0] == before[0]
    for a, b in zip(after[1:], before[1:]):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("field", FIELDS)
def test_state_arrays_are_read_only_and_name_the_setter(runtime, field):
    """`world.positions[i] = x` was silently lost (a copy); now it raises, pointing to
    set_state, and the World is unchanged. A copy is an ordinary writeable array."""
    world = two_boxes(runtime)
    world.step(DT)
    before = snapshot(world)
    array = getattr(world, field)
    with pytest.raises(RbgenError, match=rf"set_state\(ids, {field}=...\).*world.{field} ="):
        array[1] = 0.5
    with pytest.raises(RbgenError, match="read-only"):
        array[1:][0, 0] = 0.5  # views are read-only too
    with pytest.raises(ValueError):
        array += 1  # (numpy's in-place error: a ValueError, as RbgenError is)
    assert_unchanged(world, before)
    copy = array.copy()
    copy[1] = 0.25
    assert np.all(copy[1] == 0.25)
    assert type(array * 2) is np.ndarray
    assert array.dtype == np.float32 and array.shape == (3, 4 if field == "orientations" else 3)


def test_set_state_sets_some_bodies(runtime):
    world = two_boxes(runtime)
    world.set_state([2], positions=[[5.0, 3.0, 1.0]], linear_velocities=[[0, 0, 1.0]])
    world.set_state(
        1, orientations=(0.0, 0.0, np.sin(0.2), np.cos(0.2)), angular_velocities=(0.0, 2.0, 0.0)
    )
    np.testing.assert_allclose(world.positions[2], [5, 3, 1])
    np.testing.assert_allclose(world.positions[1], [-2, 0.5, 0])
    np.testing.assert_allclose(world.linear_velocities[2], [0, 0, 1])
    np.testing.assert_allclose(world.orientations[1], [0, 0, np.sin(0.2), np.cos(0.2)], rtol=1e-6)
    np.testing.assert_allclose(world.angular_velocities[1], [0, 2, 0])
    world.set_state([1, 2], positions=[0.0, 8.0, 0.0])  # one row for every id
    np.testing.assert_allclose(world.positions[1:], [[0, 8, 0], [0, 8, 0]])
    world.set_state(0, positions=(0, -2, 0))  # a static body may be moved
    world.step(DT)
    # free fall over the step's substeps of h: v += g h, then x += v h, each substep
    h, m = DT / world.substeps, world.substeps
    y = 8.0 - 9.81 * h * h * m * (m + 1) / 2
    np.testing.assert_allclose(world.positions[1:, 1], [y, y], rtol=1e-6)
    assert world.positions[0, 1] == -2


@pytest.mark.parametrize(
    "kwargs,needle",
    [
        ({"ids": [1], "positions": [[0, np.nan, 0]]}, "body 1: positions has a NaN"),
        ({"ids": [2, 1], "positions": [[0, 1, 0], [np.inf, 0, 0]]}, "body 1: positions"),
        ({"ids": [1], "positions": [[0, 1]]}, r"positions must have shape \(1, 3\)"),
        ({"ids": [1], "positions": "up"}, "positions must be numbers"),
        ({"ids": [1], "orientations": [[0, 0, 0, 0]]}, "body 1: orientations has a zero"),
        ({"ids": [2], "linear_velocities": [[0, 0, np.nan]]}, "body 2: linear_velocities"),
        ({"ids": [2], "angular_velocities": [[1, 2]]}, "angular_velocities must have shape"),
        ({"ids": [0], "linear_velocities": [[1, 0, 0]]}, "body 0 is static: linear_velocities"),
        ({"ids": [0], "angular_velocities": [[0, 1, 0]]}, "body 0 is static: angular"),
        (
            {"ids": [3], "positions": [[0, 1, 0]]},
            r"ids: body 3 does not exist \(body indices "
            r"run from 0 to 2\)",
        ),
        ({"ids": [-1], "positions": [[0, 1, 0]]}, "ids: body -1 does not exist"),
        ({"ids": [1.0], "positions": [[0, 1, 0]]}, "ids must be a body index"),
        ({"ids": [True], "positions": [[0, 1, 0]]}, "ids must be a body index"),
        ({"ids": [[1]], "positions": [[0, 1, 0]]}, "ids must be a body index"),
        ({"ids": [1, 1], "positions": [[0, 1, 0], [0, 2, 0]]}, "ids: body 1 is listed twice"),
        # all or nothing: the good positions are not written when the orientation is bad
        (
            {"ids": [1], "positions": [[0, 9, 0]], "orientations": [[0, 0, 0, np.nan]]},
            "body 1: orientations",
        ),
    ],
)
def test_set_state_bad_input_names_body_and_field_and_changes_nothing(runtime, kwargs, needle):
    world = two_boxes(runtime)
    world.step(DT)
    before = snapshot(world)
    with pytest.raises(RbgenError, match=needle):
        world.set_state(**kwargs)
    assert_unchanged(world, before)


def test_whole_array_setters_are_checked_and_atomic(runtime):
    world = two_boxes(runtime)
    before = snapshot(world)
    bad = world.positions.copy()
    bad[2, 0] = np.nan
    with pytest.raises(RbgenError, match="body 2: positions"):
        world.positions = bad
    with pytest.raises(RbgenError, match=r"orientations must have shape \(3, 4\)"):
        world.orientations = np.zeros((2, 4))
    assert_unchanged(world, before)


def last_constraints(world):
    constraints = world._pipeline.constraints.constraints
    count = int(world.runtime.read(constraints.count)[0])
    return world.runtime.read(constraints.constraints[:count])


def pairs_of(records):
    return {(int(a), int(b)) for a, b in zip(records["body_a"], records["body_b"])}


def settled(runtime, steps=30):
    world = two_boxes(runtime)
    for _ in range(steps):
        world.step(DT)
    return world


def test_set_state_forgets_the_warm_start_of_the_bodies_set_only(runtime):
    """Setting body 1 (even to its own state) forgets its contact with the ground; body
    2's contact keeps its warm start, so body 2 steps exactly as in a twin World whose
    state was not set (before, every contact was forgotten)."""
    world, twin = settled(runtime), settled(runtime)
    assert pairs_of(last_constraints(world)) == {(0, 1), (0, 2)}
    world.set_state([1], positions=world.positions[[1]])
    assert pairs_of(last_constraints(world)) == {(0, 2), (layouts.SOLVER_NONE,) * 2}
    for _ in range(3):
        world.step(DT)
        twin.step(DT)
    for field in FIELDS:
        assert np.array_equal(getattr(world, field)[2], getattr(twin, field)[2]), field


def test_whole_array_setters_forget_the_rows_that_changed(runtime):
    world, twin = settled(runtime), settled(runtime)
    world.positions = world.positions  # nothing changes: nothing is forgotten
    assert pairs_of(last_constraints(world)) == {(0, 1), (0, 2)}
    velocities = world.linear_velocities.copy()
    velocities[1] += (0.0, 0.0, 0.5)
    world.linear_velocities = velocities
    assert pairs_of(last_constraints(world)) == {(0, 2), (layouts.SOLVER_NONE,) * 2}
    for _ in range(3):
        world.step(DT)
        twin.step(DT)
    assert np.array_equal(world.positions[2], twin.positions[2])
    assert world.positions[1, 2] > twin.positions[1, 2] + 0.01  # body 1 slides on
