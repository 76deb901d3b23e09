"""World API: input validation (errors name the body and the field), state
setters, statistics, no blocking read in step(), and capacity overflow
redone rather than dropped (a run with tiny initial buffers gives the same
trajectory as one with ample buffers)."""
from __future__ import annotations

import numpy as np
import pytest

import rbgen
from rbgen import RbgenError
from rbgen.world import World

BOX = rbgen.Box((0.5, 0.5, 0.5))


@pytest.fixture
def world(runtime):
    w = World(runtime)
    w.add_static(rbgen.Box((20, 1, 20)), position=(0, -1, 0))
    return w


def grid(n):
    return np.array([[1.2 * (i % 5), 0.5 + 1.0 * (i // 25), 1.2 * ((i // 5) % 5)] for i in range(n)])


@pytest.mark.parametrize("field,kwargs,needle", [
    ("positions", {"positions": [[0, 1, 0], [0, np.nan, 0]]}, "body 2: positions"),
    ("mass", {"positions": [[0, 1, 0], [0, 2, 0]], "mass": [1.0, 0.0]}, "body 2: mass"),
    ("mass", {"positions": [[0, 1, 0]], "mass": -1.0}, "body 1: mass"),
    ("velocity", {"positions": [[0, 1, 0]], "linear_velocities": [[np.inf, 0, 0]]},
     "body 1: linear_velocities"),
    ("angular", {"positions": [[0, 1, 0]], "angular_velocities": [[0, np.nan, 0]]},
     "body 1: angular_velocities"),
    ("orientation", {"positions": [[0, 1, 0]], "orientations": [[0, 0, 0, 0]]},
     "body 1: orientations"),
    ("friction", {"positions": [[0, 1, 0], [0, 2, 0]], "friction": [0.5, -0.1]}, "body 2: friction"),
    ("restitution", {"positions": [[0, 1, 0]], "restitution": 1.5}, "body 1: restitution"),
])
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
    positions = world.positions
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
    assert small.statistics()["manifolds"] == ample.statistics()["manifolds"] >= 40
    np.testing.assert_allclose(small.positions, ample.positions, atol=1e-5)


def test_empty_world_steps(runtime):
    world = World(runtime)
    world.step(1 / 60)
    assert world.body_count == 0 and world.positions.shape == (0, 3)
    world.add_static(rbgen.Plane((0, 1, 0)))
    world.step(1 / 60)
    assert world.statistics()["contacts"] == 0


def test_automatic_batching_follows_the_body_count(runtime):
    """batching=None: on an NVIDIA GPU "global" whatever the body count; on another GPU
    "single" (a resident solve, two solver-side launches a step) while every body fits
    the local memory, "cells" once bodies are added past it; on a CPU "slabs". The mode
    used is reported by statistics(), and a step in it solves falling boxes (they land at
    rest on the ground)."""
    from rbgen.pipeline.device_barrier import persistent_launch_validated
    from rbgen.pipeline.solver import resident_capacity
    world = World(runtime)
    world.add_static(rbgen.Box((60, 1, 60)), position=(0, -1, 0))
    world.add_bodies(BOX, positions=grid(40) + [0, 0.2, 0])
    for _ in range(60):
        world.step(1 / 60)
    gpu, grid_mode = runtime.traits.is_gpu, persistent_launch_validated(runtime.traits)
    small = "global" if grid_mode else "single" if gpu else "slabs"
    assert world.statistics()["batching"] == small
    assert np.abs(world.linear_velocities).max() < 0.05  # landed and resting
    if not gpu:
        return
    capacity = resident_capacity(runtime.traits)
    side = int(np.ceil(np.sqrt(capacity))) + 1
    spread = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2) * 3.0
    world.add_bodies(BOX, positions=np.c_[spread[:, 0] - 90, np.full(len(spread), 5.0),
                                          spread[:, 1] - 90])
    assert world.body_count > capacity
    world.step(1 / 60)
    assert world.statistics()["batching"] == ("global" if grid_mode else "cells")


def test_fast_math_must_be_a_bool_or_none(runtime):
    """World(fast_math=...) takes None (the device's default), True or False; anything else
    is refused when the World is made, naming the parameter."""
    with pytest.raises(RbgenError, match="fast_math"):
        World(runtime, fast_math="yes")
    assert World(runtime, fast_math=True)._solver_options["fast_math"] is True


def test_release_sweeps_is_checked_and_reaches_the_solve(runtime):
    """World(release_sweeps=...): None is the PGS default (DEFAULT_RELEASE_SWEEPS), an integer
    >= 0 is kept; a negative, fractional or boolean value is refused when the World is
    made, naming the parameter, and so is any value with the Jacobi solver (which solves
    the block on every sweep). The World's value is the one its steps pass to the solve
    (a one-box step with release_sweeps left at an illegal value after construction fails
    naming it)."""
    from rbgen.world import DEFAULT_RELEASE_SWEEPS
    assert World(runtime).release_sweeps == DEFAULT_RELEASE_SWEEPS
    assert World(runtime, release_sweeps=0).release_sweeps == 0
    assert World(runtime, solver="jacobi").release_sweeps is None
    for bad in (-1, 1.5, True, "2"):
        with pytest.raises(RbgenError, match="release_sweeps"):
            World(runtime, release_sweeps=bad)
    with pytest.raises(RbgenError, match="release_sweeps"):
        World(runtime, solver="jacobi", release_sweeps=2)
    world = World(runtime, batching="components")
    world.add_body(rbgen.Box((0.5, 0.5, 0.5)), position=(0, 0.45, 0))
    world.add_static(rbgen.Box((5, 0.5, 5)), position=(0, -0.5, 0))
    world.step(1 / 60)
    world.release_sweeps = -3
    with pytest.raises(RbgenError, match="release_sweeps"):
        world.step(1 / 60)


def test_statistics_report_the_normal_solve_used(runtime):
    """statistics()["normal_solve"] is the normal solve the step ran: block under cells
    batching on any device, and with the automatic batching sequential for the cpu shape's
    slabs but block for the gpu shape (see rbgen.world._default_normal_solve); None before
    any step."""
    def used(**options):
        world = World(runtime, **options)
        world.add_static(rbgen.Box((20, 1, 20)), position=(0, -1, 0))
        world.add_bodies(BOX, positions=grid(8) + [0, 0.01, 0])
        before = world.statistics()["normal_solve"]
        world.step(1 / 60)
        return before, world.statistics()["normal_solve"]
    assert used(batching="cells") == (None, "block")
    assert used()[1] == ("sequential" if runtime.traits.kind == "cpu" else "block")
