"""Block solve of a manifold's normal rows (ContactSolver normal_solve="block").

Closed form: a free unit box (mass 1, inverse inertia 6) resting on static
ground on the four corners of its bottom face, falling at speed v while
tumbling slowly (no friction), is stopped by ONE solver iteration without
warm start: every corner's normal velocity becomes 0 with non-negative
impulses, i.e. v_y = 0 and w_x = w_z = 0 (the block is exact), while solving
the corners one after another leaves a residual (checked, so that the test
can fail). With three corners, or two corners separating fast, the result
is the exact contact solution: a point pushes and stops, or has impulse 0
and separates.
"""
from __future__ import annotations

import numpy as np
import pytest

from rbgen.pipeline.solver import ContactSolver
from tests.pipeline.test_constraints import ContactRig, make_bodies, make_manifold

CORNERS = np.array([[0.5, -0.5, 0.5], [-0.5, -0.5, 0.5], [-0.5, -0.5, -0.5], [0.5, -0.5, -0.5]])


def solve_one_iteration(runtime, normal_solve, velocity, angular, count=4):
    bodies = make_bodies([[0, 0, 0], [0, 0.5, 0]], [0.0, 1.0], velocities=[[0, 0, 0], velocity],
                         angular=[[0, 0, 0], angular])
    rig = ContactRig(runtime, bodies, np.array([[0, 0, 0], [6.0, 6.0, 6.0]]), warm_start=False)
    rig.solver = ContactSolver(runtime, split_impulse=True, normal_solve=normal_solve)
    points = CORNERS[:count] + [0, 0.5, 0]
    m = make_manifold(0, 1, [0, 1, 0], points, [0.0] * count, friction=0.0)
    out, cons = rig.solve(np.array([m]), iterations=1)
    v, w = out["linear_velocity"][1, :3], out["angular_velocity"][1, :3]
    normal_speed = v[1] + np.cross(w, CORNERS[:count])[:, 1]
    return normal_speed, cons[0]["normal_impulse"][:count], v, w


def test_block_stops_every_point_in_one_iteration(runtime, rng):
    velocity = [rng.uniform(-0.2, 0.2), -rng.uniform(1.0, 3.0), rng.uniform(-0.2, 0.2)]
    angular = rng.uniform(-0.3, 0.3, 3)  # slow: the stopping impulse's centre stays inside
    normal_speed, impulses, v, w = solve_one_iteration(runtime, "block", velocity, angular)
    assert np.abs(normal_speed).max() < 1e-4
    assert impulses.min() > 0.0
    assert abs(v[1]) < 1e-4 and abs(w[0]) < 1e-4 and abs(w[2]) < 1e-4
    # tangential motion and spin about the normal are untouched without friction
    assert v[[0, 2]] == pytest.approx(np.array(velocity)[[0, 2]], abs=1e-5)
    assert w[1] == pytest.approx(angular[1], abs=1e-5)
    sequential, _, _, _ = solve_one_iteration(runtime, "sequential", velocity, angular)
    assert np.abs(sequential).max() > 1e-3


def test_block_three_points_complementary(runtime, rng):
    """Three corners whose triangle has the centre of mass on its edge: one iteration
    gives the exact contact solution (every point pushes and stops, or has impulse 0
    and separates) whatever the tumbling."""
    velocity = [0.0, -rng.uniform(1.0, 3.0), 0.0]
    normal_speed, impulses, _, _ = solve_one_iteration(runtime, "block", velocity,
                                                       rng.uniform(-0.3, 0.3, 3), count=3)
    assert impulses.min() >= 0.0
    pushing = impulses > 0
    assert pushing.any()
    assert np.abs(normal_speed[pushing]).max() < 1e-4
    assert np.all(normal_speed[~pushing] > -1e-4)


def test_block_releases_separating_points(runtime):
    """Falling at 1 m/s while rolling about z at 4 rad/s: the +x corners move up at
    -1 + 4 * 0.5 = 1 m/s and keep impulse 0 (they still separate afterwards); the -x
    corners (approaching at 3 m/s) stop: normal speed 0, positive impulses."""
    normal_speed, impulses, _, _ = solve_one_iteration(runtime, "block", [0, -1.0, 0], [0, 0, 4.0])
    pushing = CORNERS[:, 0] < 0
    assert np.abs(normal_speed[pushing]).max() < 1e-4
    assert np.all(normal_speed[~pushing] > 0)
    assert np.all(impulses[~pushing] == 0) and np.all(impulses[pushing] > 0)


def test_block_leaves_a_corner_that_is_apart(runtime, rng):
    """Closed form: a box falling at speed v onto static ground with three corners touching
    and the fourth still 1-3 mm apart (target: approach at most gap/dt) is stopped flat by
    one iteration: the three touching corners fix the plane of the bottom face, so v_y = 0
    and w = 0, and the corner apart keeps impulse 0 (it does not close its gap). The four
    targets fit no rigid motion; a least-squares compromise tips the box towards the gap
    (|w| ~ gap/dt)."""
    bodies = make_bodies([[0, 0, 0], [0, 0.5, 0]], [0.0, 1.0],
                         velocities=[[0, 0, 0], [0, -rng.uniform(0.5, 2.0), 0]])
    rig = ContactRig(runtime, bodies, np.array([[0, 0, 0], [6.0, 6.0, 6.0]]), warm_start=False)
    rig.solver = ContactSolver(runtime, split_impulse=True, normal_solve="block")
    apart = int(rng.integers(4))
    separations = [0.0] * 4
    separations[apart] = rng.uniform(0.001, 0.003)
    m = make_manifold(0, 1, [0, 1, 0], CORNERS + [0, 0.5, 0], separations, friction=0.0)
    out, cons = rig.solve(np.array([m]), iterations=1)
    v, w = out["linear_velocity"][1, :3], out["angular_velocity"][1, :3]
    assert abs(v[1]) < 1e-4 and np.abs(w).max() < 1e-4
    impulses = cons[0]["normal_impulse"][:4]
    assert impulses[apart] == 0.0 and impulses.min() >= 0.0
