"""World API: input validation (errors name the body and the field), state
setters, statistics, no blocking read in step(), and capacity overflow
redone rather than dropped (a run with tiny initial buffers gives the same
trajectory as one with ample buffers)."""

from __future__ import annotations

import numpy as np
import pytest

import rbgen
from rbgen import RbgenError
from rbgen.settings import STEP_SETTINGS
from rbgen.world import World

BOX = rbgen.Box((0.5, 0.5, 0.5))


@pytest.fixture
def world(runtime):
    w = World(runtime)
    w.add_static(rbgen.Box((20, 1, 20)), position=(0, -1, 0))
    return w


def grid(n):
    return np.array(
        [[1.2 * (i % 5), 0.5 + 1.0 * (i // 25), 1.2 * ((i // 5) % 5)] for i in range(n)]
    )


@pytest.mark.parametrize(
    "field,kwargs,needle",
    [
        ("positions", {"positions": [[0, 1, 0], [0, np.nan, 0]]}, "body 2: positions"),
        ("mass", {"positions": [[0, 1, 0], [0, 2, 0]], "mass": [1.0, 0.0]}, "body 2: mass"),
        ("mass", {"positions": [[0, 1, 0]], "mass": -1.0}, "body 1: mass"),
        (
            "velocity",
            {"positions": [[0, 1, 0]], "linear_velocities": [[np.inf, 0, 0]]},
            "body 1: linear_velocities",
        ),
        (
            "angular",
            {"positions": [[0, 1, 0]], "angular_velocities": [[0, np.nan, 0]]},
            "body 1: angular_velocities",
        ),
        (
            "orientation",
            {"positions": [[0, 1, 0]], "orientations": [[0, 0, 0, 0]]},
            "body 1: orientations",
        ),
        (
            "friction",
            {"positions": [[0, 1, 0], [0, 2, 0]], "friction": [0.5, -0.1]},
            "body 2: friction",
        ),
        ("restitution", {"positions": [[0, 1, 0]], "restitution": 1.5}, "body 1: restitution"),
    ],
)
def test_bad_body_input_names_body_and_field(world, field, kwargs, needle):
    with pytest.raises(RbgenError, match=needle):
        world.add_bodies(BOX, **kwargs)
    assert world.body_count == 1  # nothing was added


def test_other_bad_input(world):
    with pytest.raises(RbgenError, match="dt"):
        world.step(0.0)
    with pytest.raises(RbgenError, match="dt"):
        world.step(-1 / 60)
    with pytest.raises(RbgenError, match="substeps"):
        world.step(1 / 60, substeps=0)
    with pytest.raises(RbgenError, match="static"):
        world.add_body(rbgen.Plane((0, 1, 0)), mass=1.0)
    with pytest.raises(RbgenError, match="shape"):
        world.add_body("box", mass=1.0)
    with pytest.raises(RbgenError, match="positions"):
        world.positions = np.zeros((5, 3))


def test_non_unit_quaternion_is_normalised_with_a_warning(world):
    with pytest.warns(UserWarning, match="body 1"):
        world.add_body(BOX, position=(0, 3, 0), orientation=(0, 0, 0, 2))
    np.testing.assert_allclose(world.orientations[1], [0, 0, 0, 1])


def test_setters_teleport_and_step_has_no_blocking_read(world, runtime):
    ids = world.add_bodies(BOX, mass=np.array([1.0, 2.0, 3.0]), positions=grid(3) + [0, 2, 0])
    world.step(1 / 60)
    positions = world.positions.copy()  # the property is a read-only snapshot
    positions[ids] += [0, 5, 0]
    world.positions = positions
    world.linear_velocities = np.tile([1.0, 0, 0], (world.body_count, 1))
    np.testing.assert_allclose(world.linear_velocities[0], 0)  # static bodies stay at rest
    reads = runtime.counters["blocking_reads"]
    for _ in range(3):
        world.step(1 / 60)
    assert runtime.counters["blocking_reads"] == reads
    assert world.last_step_counters["blocking_reads"] == 0
    assert world.last_step_counters["launches"] > 10
    # v = 1 m/s along x for 3 steps (no contact yet: the boxes are 5 m up)
    np.testing.assert_allclose(world.positions[ids, 0] - positions[ids, 0], 3 / 60, atol=1e-5)
    stats = world.statistics()
    assert stats["bodies"] == 4 and stats["pairs"] == 0 and stats["contacts"] == 0


def test_overflow_is_redone_not_dropped(runtime):
    """Tiny pair and manifold buffers: the World grows them and redoes steps; the
    trajectory equals the one with ample buffers."""

    def run(**capacities):
        w = World(runtime, **capacities)
        w.add_static(rbgen.Box((20, 1, 20)), position=(0, -1, 0))
        w.add_bodies(BOX, positions=grid(40) + [0, 0.01, 0])
        for _ in range(30):
            w.step(1 / 60)
        return w

    small = run(manifold_capacity=3, pair_capacity=2)
    ample = run()
    assert small.overflows >= 1 and ample.overflows == 0
    # (each redo was asked for by one or both of the stages whose buffers were tiny)
    by_stage = small.overflows_by_stage
    assert set(by_stage) <= {"broadphase", "narrowphase"} and by_stage.get("broadphase")
    assert max(by_stage.values()) <= small.overflows <= sum(by_stage.values())
    assert ample.overflows_by_stage == {}
    assert small.statistics()["manifolds"] == ample.statistics()["manifolds"] >= 40
    np.testing.assert_allclose(small.positions, ample.positions, atol=1e-5)


def test_too_many_large_bodies_move_the_grid_to_slot_emission_visibly(runtime):
    """More large bodies than the grid's owner emission has rows (here static slabs under
    the ground): the first step is redone with slot emission, which the World's statistics
    and `overflows_by_stage` name, and whose launches `launches_by_kernel` shows; the
    trajectory is that of the same boxes on the ground alone (the broadphase is exact)."""
    from rbgen.launch import launches_by_kernel
    from rbgen.pipeline.broadphase.grid import LARGE_ROWS

    def run(slabs):
        w = World(runtime)
        for k in range(slabs):
            w.add_static(rbgen.Box((20, 1, 20)), position=(0, -1 - 3 * k, 0))
        ids = w.add_bodies(BOX, positions=grid(30) + [0, 0.01, 0])
        for _ in range(9):
            w.step(1 / 60)
        with launches_by_kernel(w.runtime) as counts:
            w.step(1 / 60)
        assert sum(counts.values()) == w.last_step_counters["launches"]
        return w, ids, counts

    slot, ids, slot_counts = run(LARGE_ROWS + 1)
    owner, owner_ids, owner_counts = run(1)
    assert owner.statistics()["broadphase"] == "grid, owner emission"
    assert owner.overflows == 0 and owner_counts["write_owned_pairs"] == 1
    assert slot.statistics()["broadphase"].startswith("grid, slot emission")
    assert f"more than {LARGE_ROWS} large bodies" in slot.statistics()["broadphase"]
    assert slot.overflows == 1 and slot.overflows_by_stage == {"broadphase": 1}
    assert owner.fallbacks == [] and slot.fallbacks == ["broadphase"]
    assert slot_counts["write_grid_pairs"] == 1 and "write_owned_pairs" not in slot_counts
    light, full = slot.statistics(contacts=False), slot.statistics()
    assert light["contacts"] is None and full["contacts"] > 0
    assert light == {**full, "contacts": None}
    assert sum(slot_counts.values()) > sum(owner_counts.values())
    np.testing.assert_allclose(slot.positions[ids], owner.positions[owner_ids], atol=1e-5)


def test_empty_world_steps(runtime):
    world = World(runtime)
    world.step(1 / 60)
    assert world.body_count == 0 and world.positions.shape == (0, 3)
    world.add_static(rbgen.Plane((0, 1, 0)))
    world.step(1 / 60)
    assert world.statistics()["contacts"] == 0


def test_the_planned_batching_runs_and_solves(runtime):
    """batching=None: the World runs the batching its plan chose for the device (the plan's
    table is tested in tests/test_plan.py), reports it in statistics(), and a step in it
    solves falling boxes (they land at rest on the ground)."""
    world = World(runtime)
    world.add_static(rbgen.Box((60, 1, 60)), position=(0, -1, 0))
    world.add_bodies(BOX, positions=grid(40) + [0, 0.2, 0])
    for _ in range(60):
        world.step(1 / 60)
    assert world.statistics()["batching"] == world.plan.batching is not None
    assert np.abs(world.linear_velocities).max() < 0.05  # landed and resting


@pytest.mark.parametrize(
    "option,bad",
    [
        ("iterations", -3),
        ("iterations", 2.5),
        ("iterations", True),
        ("position_iterations", -1),
        ("relaxation", 0.0),
        ("relaxation", 2.0),
        ("relaxation", float("nan")),
        ("warm_start", "yes"),
        ("contact_margin", -0.01),
        ("restitution_threshold", -1.0),
        ("penetration_slop", float("inf")),
        ("penetration_recovery", 1.5),
        ("linear_damping", 1.0),
        ("angular_damping", -0.1),
        ("gravity", (0, 1)),
        ("gravity", (0, np.nan, 0)),
        ("solver", "gauss"),
        ("batching", "components"),
        ("normal_solve", "both"),
        ("broadphase", "octree"),
        ("fast_math", "yes"),
        ("gyroscopic", 1),
        ("manifold_capacity", 0),
        ("pair_capacity", -5),
        ("plan", [1]),
        ("plan", {"release_sweeps": -1}),
        ("plan", {"colours": 3}),
    ],
)
def test_every_option_is_checked_when_the_world_is_made(runtime, option, bad):
    """A bad option value is refused at construction, naming the option (and nothing is
    built); the step settings are checked the same way when set later, and a refused set
    leaves the old value."""
    with pytest.raises(RbgenError, match=option if option != "plan" else "plan"):
        World(runtime, **{option: bad})


def test_step_settings_are_checked_when_set(runtime):
    world = World(runtime)
    world.iterations = 20
    assert world.iterations == 20 and world.settings.iterations == 20
    with pytest.raises(RbgenError, match="iterations=-3"):
        world.iterations = -3
    assert world.iterations == 20
    with pytest.raises(RbgenError, match="unknown World option"):
        World(runtime, iteration=3)


def test_step_defaults_follow_the_device_kind(runtime):
    """A World takes its device kind's step defaults (`rbgen.settings`: a CPU's own where
    one is given), and a setting given is kept on either kind."""
    gpu = runtime.traits.is_gpu
    world = World(runtime)
    for option in STEP_SETTINGS:
        expected = option.default_for(gpu)
        assert np.all(np.asarray(getattr(world, option.name)) == np.asarray(expected))
    assert World(runtime, substeps=1, iterations=10).substeps == 1


def test_plan_parameters_reach_the_solve(runtime):
    """World(plan={...}) overrides a tuned plan parameter; the PGS solve the World builds
    takes it (its release sweeps), and the Jacobi solver, which solves the complete block
    every sweep, plans none."""
    world = World(runtime, plan={"release_sweeps": 0}, normal_solve="block")
    assert world.plan.release_sweeps == 0 and world.plan.sources["release_sweeps"] == "option"
    world.add_static(rbgen.Box((5, 0.5, 5)), position=(0, -0.5, 0))
    world.add_body(BOX, position=(0, 0.45, 0))
    world.step(1 / 60)
    assert world._pipeline.solve.solver.release_sweeps == 0
    assert World(runtime, solver="jacobi").plan.release_sweeps is None


def test_fast_math_reaches_the_plan(runtime):
    """World(fast_math=...) takes None (the device's default), True or False; the plan,
    whose choice the solver is built with, says which and why."""
    assert World(runtime, fast_math=True).plan.fast_math is True
    assert World(runtime, fast_math=False).plan.sources["fast_math"] == "option"
    assert World(runtime).plan.sources["fast_math"] == "default"


def test_statistics_report_the_normal_solve_used(runtime):
    """statistics()["normal_solve"] is the plan's normal solve: block under cells batching
    on any device (a column's rows split between colour launches need it)."""
    world = World(runtime, batching="cells")
    world.add_static(rbgen.Box((20, 1, 20)), position=(0, -1, 0))
    world.add_bodies(BOX, positions=grid(8) + [0, 0.01, 0])
    world.step(1 / 60)
    stats = world.statistics()
    assert stats["normal_solve"] == "block" and stats["batching"] == "cells"
    assert stats["contacts"] > 0


@pytest.mark.gpu_shape
def test_a_redone_step_keeps_the_settings_it_ran_with(runtime):
    """Gravity is switched on after a first step without it, which overflowed (a pair
    buffer of 1): the redo of the first step must run without gravity, as it first did.
    Closed form (semi-implicit Euler): after the two steps v_y = g dt, one step of
    gravity, as in a World that never overflowed; the redo with the new gravity gave
    2 g dt."""

    def run(pair_capacity):
        world = World(runtime, gravity=(0, 0, 0), pair_capacity=pair_capacity)
        xs = np.arange(6) * 1.0  # boxes of 1 m side at 1 m spacing: touching
        world.add_bodies(BOX, positions=np.c_[xs, np.zeros(6), np.zeros(6)])
        world.step(1 / 60)
        world.gravity = (0, -9.81, 0)
        world.iterations = 3  # (another setting: the redo keeps the first step's 10)
        world.step(1 / 60)
        _ = world.positions  # (checks, and redoes, the steps in flight)
        return world

    small, large = run(1), run(None)
    assert small.overflows >= 1 and large.overflows == 0
    np.testing.assert_allclose(small.linear_velocities[:, 1], -9.81 / 60, rtol=1e-5)
    for field in ("positions", "linear_velocities", "angular_velocities"):
        assert np.array_equal(getattr(small, field), getattr(large, field)), field
    assert small.gravity[1] == -9.81 and small.iterations == 3
