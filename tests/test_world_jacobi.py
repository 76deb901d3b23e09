"""The World with the Jacobi solver (mass splitting), dt = 1/60.

Closed forms and criteria as in the Gauss-Seidel tests (test_world_column,
test_world_stacking); the numbers of sweeps a tall stack needs are the
difference. Measured on PoCL, 20-row pyramid, top box's displacement after 600
steps (during the first 100): 10 iterations 22 cm (29), 20: 11 cm, 40 and 20
position iterations: 2.4 cm (6.4), 80 and 40: 2.0 cm (2.8); Gauss-Seidel at 10
holds it to ~1.6 cm. A Jacobi sweep carries a contact's push one body further
down a stack, a Gauss-Seidel sweep as far as the batch order allows.
"""

from __future__ import annotations

import numpy as np
import pytest

import rbgen
from rbgen.errors import RbgenError
from rbgen.scenes import pile_positions, pyramid_positions

DT = 1 / 60


def test_ten_box_column_stands(runtime):
    """At rest box k's centre is at 0.5 + k; over 600 steps no box drifts sideways or sinks
    more than 2 cm, and the column ends at rest."""
    world = rbgen.World(runtime, solver="jacobi")
    world.add_static(rbgen.Box((50, 1, 50)), position=(0, -1, 0))
    start = np.array([[0.0, 0.5 + k, 0.0] for k in range(10)])
    ids = world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, positions=start)
    for _ in range(600):
        world.step(DT)
    p = world.positions[ids]
    assert np.abs(p[:, [0, 2]]).max() < 0.02
    assert np.abs(p[:, 1] - start[:, 1]).max() < 0.02
    assert np.linalg.norm(world.linear_velocities[ids], axis=1).max() < 0.05


def test_symmetric_column_gets_no_sideways_motion(runtime):
    """Three boxes exactly on each other, no warm start: symmetric under x -> -x and
    z -> -z, so no box may gain lateral or angular velocity (the block solve)."""
    world = rbgen.World(runtime, solver="jacobi", warm_start=False, normal_solve="block")
    world.add_static(rbgen.Box((50, 1, 50)), position=(0, -1, 0))
    ids = world.add_bodies(
        rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, positions=[[0.0, 0.5 + k, 0.0] for k in range(3)]
    )
    for _ in range(10):
        world.step(DT)
        assert np.abs(world.linear_velocities[ids][:, [0, 2]]).max() < 1e-4
        assert np.abs(world.angular_velocities[ids]).max() < 1e-4


def test_dropped_grid_comes_to_rest(runtime):
    """4 x 4 x 4 boxes at 1.5 m pitch (+-5 cm jitter, seed 1) dropped on the ground: max
    speed < 0.05 m/s by step 300 and no box centre below its resting height by more than
    2 cm, at one substep of 10 + 4 sweeps (Jacobi's mass splitting wants sweeps more than
    substeps: at the GPU's default 8 of 2 + 1 this grid still moves at step 300)."""
    world = rbgen.World(runtime, solver="jacobi", substeps=1, iterations=10, position_iterations=4)
    world.add_static(rbgen.Box((50, 1, 50)), position=(0, -1, 0))
    ids = world.add_bodies(
        rbgen.Box((0.5, 0.5, 0.5)),
        mass=1.0,
        positions=pile_positions(64, layers=4, jitter=0.05, seed=1),
    )
    for _ in range(300):
        world.step(DT)
    assert np.linalg.norm(world.linear_velocities[ids], axis=1).max() < 0.05
    assert world.positions[ids][:, 1].min() > 0.5 - 0.02
    stats = world.statistics()
    assert stats["solver"] == "jacobi" and stats["batches"] == 0 and stats["manifolds"] >= 64


def test_pyramid_of_20_rows_holds_with_more_sweeps(runtime):
    """The 20-row pyramid holds (top moves < 5 cm over 600 steps, as Gauss-Seidel does at
    10 iterations) with 80 velocity and 40 position sweeps; at 10 it sinks ~22 cm."""
    world = rbgen.World(runtime, solver="jacobi", iterations=80, position_iterations=40)
    world.add_static(rbgen.Box((50, 1, 50)), position=(0, -1, 0))
    ids = world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, positions=pyramid_positions(20))
    start = world.positions[ids[-1]]
    moved = 0.0
    for _ in range(600):
        world.step(DT)
        moved = max(moved, np.linalg.norm(world.positions[ids[-1]] - start))
    assert moved < 0.05


def test_solver_choice_is_checked(runtime):
    with pytest.raises(RbgenError, match="solver=.conjugate_gradient. is not allowed"):
        rbgen.World(runtime, solver="conjugate_gradient")
    with pytest.raises(RbgenError, match="batching='cells' needs solver='pgs'"):
        rbgen.World(runtime, solver="jacobi", batching="cells")
