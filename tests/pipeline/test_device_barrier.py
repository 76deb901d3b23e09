"""Persistent launches whose work groups cannot all run at once give up instead of hanging.

A launch of many more work groups than the device runs side by side (64 per
compute unit, where a persistent launch has one) can never pass a barrier across all
of them: the groups that run wait, give up after the spin limit (made small
here), set the abandoned flag and leave; the groups started later see the flag
and leave at once. Checked: every such launch returns, the flag is set, the
barrier's counters are back to zero, a later kernel on the same buffer does
nothing, and a World redoes the step without persistent launches, with a warning,
ending exactly where a World that never tried them ends.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import rbgen
import rbgen.plan
from rbgen import layouts
from rbgen.pipeline import device_barrier
from rbgen.pipeline.batching import global_colouring
from rbgen.pipeline.solvers import jacobi, pgs
from tests.pipeline.test_constraints import ContactRig, make_bodies
from tests.pipeline.test_solver import stacked_columns

#: work groups per compute unit of the oversubscribed launches
OVERSUBSCRIBED = 64


@pytest.fixture
def oversubscribed(monkeypatch):
    """Persistent launches of OVERSUBSCRIBED groups per compute unit, giving up after 4,096
    polls."""

    def too_many(traits):
        return OVERSUBSCRIBED * max(1, int(traits.compute_units))

    for module in (global_colouring, pgs, jacobi):
        monkeypatch.setattr(module, "persistent_groups", too_many)
    monkeypatch.setattr(device_barrier, "spin_limit", lambda traits: 1 << 12)


def column_rig(runtime, rng):
    positions, manifolds = stacked_columns(
        5, 4, 1.2, lambda: rng.uniform(-0.01, 0.0, 4), side_contacts=True
    )
    n = len(positions)
    bodies = make_bodies(
        positions,
        np.r_[0.0, rng.uniform(0.5, 2, n - 1)],
        velocities=np.r_[[[0, 0, 0]], rng.uniform(-1, 1, (n - 1, 3))],
    )
    inv_inertia = np.r_[[[0, 0, 0]], rng.uniform(2, 8, (n - 1, 3))]
    return ContactRig(
        runtime, bodies, inv_inertia, variant="persistent", work_group_size=32
    ), np.array(manifolds)


def test_oversubscribed_colouring_and_solve_give_up(runtime, rng, oversubscribed):
    rig, manifolds = column_rig(runtime, rng)
    rig.constraints(manifolds)
    before = rig.bodies.get()
    rig.batch()
    state = rig.batcher.state.get()
    assert state[layouts.BARRIER_ABANDONED] == 1
    assert state[layouts.BARRIER_ARRIVALS] == state[layouts.BARRIER_DEPARTURES] == 0
    assert rig.solver.barrier_state() is rig.batcher.state  # the solve shares its words
    rig.sweep(iterations=4, position_iterations=2)
    assert np.array_equal(rig.bodies.get(), before)  # the solve saw the flag: no work
    device_barrier.clear_abandoned(runtime, rig.batcher.state)
    assert rig.batcher.state.get()[layouts.BARRIER_ABANDONED] == 0


def test_oversubscribed_jacobi_gives_up(runtime, rng, oversubscribed):
    rig, manifolds = column_rig(runtime, rng)
    rig.constraints(manifolds)
    before = rig.bodies.get()
    jacobi_solver = jacobi.JacobiSolver(runtime, persistent=True, work_group_size=32)
    rig.run(
        jacobi_solver,
        SimpleNamespace(iterations=4, position_iterations=0, relaxation=1.0, warm_start=True),
    )
    sync = jacobi_solver.sync.get()
    assert sync[layouts.BARRIER_ABANDONED] == 1
    assert sync[layouts.BARRIER_ARRIVALS] == sync[layouts.BARRIER_DEPARTURES] == 0
    assert np.array_equal(rig.bodies.get()["linear_velocity"], before["linear_velocity"])


def small_pile(world):
    world.add_static(rbgen.Box((20, 1, 20)), position=(0, -1, 0))
    i, j = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    positions = np.stack([1.1 * i.ravel(), 0.5 + 1.0 * j.ravel(), np.zeros(9)], -1)
    return world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, positions=positions)


@pytest.mark.parametrize("solver_name", ["pgs", "jacobi"])
def test_world_redoes_an_abandoned_step_without_persistent_launches(
    runtime, solver_name, oversubscribed, monkeypatch
):
    """The World's persistent launches give up on the first step; it warns, redoes the
    step with a plan without them (PGS: spatial batching; Jacobi: one launch per phase)
    and then matches, bit for bit, a World that used that plan from the start."""
    monkeypatch.setattr(rbgen.plan, "persistent_launch_validated", lambda traits: True)
    options = {"batching": "global"} if solver_name == "pgs" else {"solver": "jacobi"}
    world = rbgen.World(runtime, **options)
    ids = small_pile(world)
    with pytest.warns(RuntimeWarning, match="gave up waiting at a device-wide barrier"):
        for _ in range(20):
            world.step(1 / 60)
        positions = world.positions[ids]
    monkeypatch.setattr(rbgen.plan, "persistent_launch_validated", lambda traits: False)
    stats = world.statistics()
    assert not world.plan.persistent
    if solver_name == "pgs":
        assert stats["batching"] != "global"
        reference = rbgen.World(runtime, batching=stats["batching"])
    else:
        reference = rbgen.World(runtime, solver="jacobi")
    small_pile(reference)
    for _ in range(20):
        reference.step(1 / 60)
    assert np.array_equal(positions, reference.positions[ids])
    assert world.overflows == 0  # nothing overflowed: only the persistent launches were redone
    assert positions[:, 1].min() > 0.45  # the pile stands


def test_snapshots_across_an_abandoned_step_are_the_redone_state(
    runtime, oversubscribed, monkeypatch
):
    """Snapshots (`World.snapshot_frame`) taken after steps whose persistent launches gave
    up, resolved late: each equals, bit for bit, the blocking read of a World that used
    the plan without them from the start (the redo copies them again)."""
    monkeypatch.setattr(rbgen.plan, "persistent_launch_validated", lambda traits: True)
    world = rbgen.World(runtime, solver="jacobi")
    small_pile(world)
    with pytest.warns(RuntimeWarning, match="gave up waiting at a device-wide barrier"):
        snapshots = []
        for _ in range(6):
            world.step(1 / 60)
            snapshots.append(world.snapshot_frame())
        frames = [pending.result() for pending in snapshots]
    assert snapshots[0]._copies == 2  # (copied again after the first step's redo)
    monkeypatch.setattr(rbgen.plan, "persistent_launch_validated", lambda traits: False)
    assert not world.plan.persistent
    reference = rbgen.World(runtime, solver="jacobi")
    small_pile(reference)
    for frame in frames:
        reference.step(1 / 60)
        assert np.array_equal(frame.positions, reference.positions)
        assert np.array_equal(frame.orientations, reference.orientations)


def test_benchmark_records_a_plan_fallback(runtime, oversubscribed, monkeypatch):
    """A scene whose persistent launch gave up records it (`run_scene`'s plan_fallbacks, the
    bench result's, and its printed line), so a benchmark's launch count is not read as
    the persistent plan's."""
    from rbgen import bench
    from rbgen.harness import run_scene

    monkeypatch.setattr(rbgen.plan, "persistent_launch_validated", lambda traits: True)
    with pytest.warns(RuntimeWarning, match="gave up waiting at a device-wide barrier"):
        summary = run_scene("boxbox", 8, 3, device=runtime, progress=False, batching="global")
    assert summary["plan_fallbacks"] == ["batching"]
    result = bench.scene_result(summary, 1)
    assert result["plan_fallbacks"] == ["batching"]
    assert "fell back from the plan's batching" in bench.format_result(result)
    assert "persistent" not in result["plan"]  # (the plan the World ended with)
