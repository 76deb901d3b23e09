"""Block solve of a manifold's normal rows (PgsSolver normal_solve="block").

Closed form: a free unit box (mass 1, inverse inertia 6) resting on static
ground on the four corners of its bottom face, falling at speed v while
tumbling slowly (no friction), is stopped by ONE solver iteration without
warm start: every corner's normal velocity becomes 0 with non-negative
impulses, i.e. v_y = 0 and w_x = w_z = 0 (the block is exact), while solving
the corners one after another leaves a residual (checked, so that the test
can fail). With three corners, or two corners separating fast, the result
is the exact contact solution: a point pushes and stops, or has impulse 0
and separates. Three or four pushing points of random tilted faces between two free
bodies with full inertia tensors get the smallest impulses that stop every
point, K total = target - v (float64 pseudo-inverse reference); when one of
four corners would pull, it is released and the other three stop the face.
In general (points released because they separate, would pull, or are still
apart) the block is the exact contact solution: on random manifolds with
spinning bodies and corners apart, the velocities after one iteration equal
those of a float64 brute-force solve of the linear complementarity problem
(every active set tried), and the impulses are complementary to them. The
sequential solve (rows one after another) is float64 Gauss-Seidel over the rows.
"""

from __future__ import annotations

import itertools
from types import SimpleNamespace

import numpy as np
import pytest

from rbgen import layouts
from tests.pipeline.test_constraints import ContactRig, make_bodies, make_manifold

CORNERS = np.array([[0.5, -0.5, 0.5], [-0.5, -0.5, 0.5], [-0.5, -0.5, -0.5], [0.5, -0.5, -0.5]])


def solve_one_iteration(runtime, normal_solve, velocity, angular, count=4):
    bodies = make_bodies(
        [[0, 0, 0], [0, 0.5, 0]],
        [0.0, 1.0],
        velocities=[[0, 0, 0], velocity],
        angular=[[0, 0, 0], angular],
    )
    rig = ContactRig(
        runtime,
        bodies,
        np.array([[0, 0, 0], [6.0, 6.0, 6.0]]),
        warm_start=False,
        normal_solve=normal_solve,
    )
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
    normal_speed, impulses, _, _ = solve_one_iteration(
        runtime, "block", velocity, rng.uniform(-0.3, 0.3, 3), count=3
    )
    assert impulses.min() >= 0.0
    pushing = impulses > 0
    assert pushing.any()
    assert np.abs(normal_speed[pushing]).max() < 1e-4
    assert np.all(normal_speed[~pushing] > -1e-4)


@pytest.mark.parametrize("count", [2, 4])
def test_block_releases_separating_points(runtime, count):
    """Falling at 1 m/s while rolling about z at 4 rad/s: the +x corners move up at
    -1 + 4 * 0.5 = 1 m/s and keep impulse 0 (they still separate afterwards); the -x
    corners (approaching at 3 m/s) stop: normal speed 0, positive impulses. With two
    corners (an edge, one of each) the same, by the two-point active sets."""
    normal_speed, impulses, _, _ = solve_one_iteration(
        runtime, "block", [0, -1.0, 0], [0, 0, 4.0], count=count
    )
    pushing = CORNERS[:count, 0] < 0
    assert np.abs(normal_speed[pushing]).max() < 1e-4
    assert np.all(normal_speed[~pushing] > 0)
    assert np.all(impulses[~pushing] == 0) and np.all(impulses[pushing] > 0)


def test_block_releases_the_one_pulling_corner(runtime, rng):
    """Falling at 1 m/s while turning at w (1.7-2.3 rad/s) about (1, 0, 1): the corners'
    normal speeds are -1, -1 - w, -1, -1 + w, so the smallest impulses that stop all four
    would pull at the last corner. The contact solution releases it (impulse 0) and stops
    the other three, which stops the whole face: p0 + p1 + p2 = 1 (mass 1) and the moments
    that cancel w with inverse inertia 6, sum r_z p = w / 6 and sum r_x p = -w / 6."""
    spin = rng.uniform(1.7, 2.3)
    normal_speed, impulses, v, w = solve_one_iteration(
        runtime, "block", [0, -1.0, 0], [spin, 0, spin]
    )
    rows = np.array([np.ones(3), CORNERS[:3, 2], CORNERS[:3, 0]])
    expected = np.linalg.solve(rows, [1.0, spin / 6, -spin / 6])
    assert expected.min() > 0
    np.testing.assert_allclose(impulses[:3], expected, rtol=1e-4)
    assert abs(impulses[3]) < 1e-6
    assert np.abs(normal_speed).max() < 1e-4 and np.abs(w).max() < 1e-4


def test_block_leaves_a_corner_that_is_apart(runtime, rng):
    """Closed form: a box falling at speed v onto static ground with three corners touching
    and the fourth still 1-3 mm apart (target: approach at most gap/dt) is stopped flat by
    one iteration: the three touching corners fix the plane of the bottom face, so v_y = 0
    and w = 0, and the corner apart keeps impulse 0 (it does not close its gap). The four
    targets fit no rigid motion; a least-squares compromise tips the box towards the gap
    (|w| ~ gap/dt), and the rows one after another converge slowly (measured on PoCL,
    |w| 0.03-0.15 rad/s after 10 iterations)."""
    bodies = make_bodies(
        [[0, 0, 0], [0, 0.5, 0]], [0.0, 1.0], velocities=[[0, 0, 0], [0, -rng.uniform(0.5, 2.0), 0]]
    )
    rig = ContactRig(runtime, bodies, np.array([[0, 0, 0], [6.0, 6.0, 6.0]]), warm_start=False)
    apart = int(rng.integers(4))
    separations = [0.0] * 4
    separations[apart] = rng.uniform(0.001, 0.003)
    m = make_manifold(0, 1, [0, 1, 0], CORNERS + [0, 0.5, 0], separations, friction=0.0)
    out, cons = rig.solve(np.array([m]), iterations=1)
    v, w = out["linear_velocity"][1, :3], out["angular_velocity"][1, :3]
    assert abs(v[1]) < 1e-4 and np.abs(w).max() < 1e-4
    impulses = cons[0]["normal_impulse"][:4]
    assert impulses[apart] == 0.0 and impulses.min() >= 0.0


def random_face_pairs(
    runtime,
    rng,
    count,
    variant,
    pairs=7,
    spin=0.2,
    separations=(0.0, 0.0),
    batching=None,
    normal_solve="block",
    restitution=True,
):
    """``pairs`` pairs of free bodies with full inertia tensors, each in contact through
    ``count`` points of a random tilted face (a rectangle, an edge or a triangle about the
    line of centres, points off the contact plane by a few mm), approaching at 1-2 m/s and
    turning at up to ``spin`` rad/s, separations uniform in ``separations`` (a (low, high)
    range, or a list of ranges taken by the pairs in turn) and random restitution (none for
    a pair whose points may be apart, or without ``restitution``: a bounce is applied after
    the rows, see `bounce_targets`), friction 0, solved by a ContactRig of
    ``variant`` (``batching``: its algorithm, if not the variant's): (rig, manifolds,
    constraints before solving, bodies before)."""
    ranges = separations if isinstance(separations, list) else [separations]
    positions, manifolds = [], []
    for i in range(pairs):
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        t1 = np.cross(normal, rng.normal(size=3))
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(normal, t1)
        centre = np.array([5.0 * i, 0.0, 0.0])
        a, b = centre - 0.5 * normal, centre + 0.5 * normal
        if count == 4:  # a rectangle about the line of centres
            corners = rng.uniform(0.3, 0.6, 2) * np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]])
        elif count == 2:  # an edge across it
            corners = rng.uniform(0.3, 0.6) * np.array([[1.0, 0.1], [-1.0, -0.1]])
        else:  # a triangle around it
            angles = np.radians([90, 210, 330]) + rng.uniform(0, 2 * np.pi)
            corners = rng.uniform(0.4, 0.6, (3, 1)) * np.c_[np.cos(angles), np.sin(angles)]
        corners = corners + rng.uniform(-0.05, 0.05, (count, 2))
        points = (
            centre
            + corners[:, :1] * t1
            + corners[:, 1:] * t2
            + rng.uniform(-0.003, 0.003, (count, 1)) * normal
        )
        positions += [a, b]
        low, high = ranges[i % len(ranges)]
        manifolds.append(
            make_manifold(
                2 * i,
                2 * i + 1,
                normal,
                points,
                rng.uniform(low, high, count),
                friction=0.0,
                restitution=rng.uniform(0.0, 0.8) if high <= 0 and restitution else 0.0,
            )
        )
    n_bodies = 2 * pairs
    normals = np.array([m["normal"][:3] for m in manifolds])
    velocities = np.repeat(normals, 2, axis=0) * np.tile([1.0, -1.0], pairs)[:, None] * rng.uniform(
        1.0, 2.0, (n_bodies, 1)
    ) + rng.uniform(-0.2, 0.2, (n_bodies, 3))
    bodies = make_bodies(
        positions,
        rng.uniform(0.5, 2.0, n_bodies),
        velocities=velocities,
        angular=rng.uniform(-spin, spin, (n_bodies, 3)),
    )
    quaternions = rng.normal(size=(n_bodies, 4))
    bodies["orientation"] = quaternions / np.linalg.norm(quaternions, axis=1)[:, None]
    rig = ContactRig(
        runtime,
        bodies,
        rng.uniform(1.0, 6.0, (n_bodies, 3)),
        variant=variant,
        batching=batching,
        warm_start=False,
        normal_solve=normal_solve,
    )
    assert rig.solver.spec.values["normal_solve"] == normal_solve
    manifolds = np.array(manifolds)
    cons = rig.constraints(manifolds)
    return rig, manifolds, cons, rig.bodies.get()


def bounce_targets(constraint, count):
    """The normal speeds a solve ends at for points that all push: each point's bounce
    (r_b.w, e times its approach), which the restitution pass drives it to after the rows
    (exactly, as a block, when every point of the face bounces), else its velocity
    target."""
    bounce = constraint["r_b"][:count, 3].astype(float)
    return np.where(bounce > 0, bounce, constraint["velocity_target"][:count].astype(float))


def normal_rows(manifold, constraint, before, inertia):
    """float64 normal rows of one manifold: (a, b, n, lever arms x n on A and B, K, the
    normal speeds at the points)."""
    a, b = int(manifold["body_a"]), int(manifold["body_b"])
    count = int(manifold["point_count"])
    n = manifold["normal"][:3].astype(float)
    ra = constraint["r_a"][:count, :3].astype(float)
    rb = constraint["r_b"][:count, :3].astype(float)
    arm_a, arm_b = np.cross(ra, n), np.cross(rb, n)
    inv_mass = before["inv_mass"].astype(float)
    k_matrix = (
        inv_mass[a] + inv_mass[b] + arm_a @ inertia[a] @ arm_a.T + arm_b @ inertia[b] @ arm_b.T
    )
    v, w = (before[f][:, :3].astype(float) for f in ("linear_velocity", "angular_velocity"))
    normal_speed = (v[b] - v[a]) @ n + arm_b @ w[b] - arm_a @ w[a]
    return a, b, n, arm_a, arm_b, k_matrix, normal_speed


def apply_totals(before, inertia, a, b, n, arm_a, arm_b, total):
    """{body: (linear, angular velocity)} after the normal impulses ``total`` (float64)."""
    inv_mass = before["inv_mass"].astype(float)
    v, w = (before[f][:, :3].astype(float) for f in ("linear_velocity", "angular_velocity"))
    impulse = total.sum() * n
    return {
        a: (v[a] - inv_mass[a] * impulse, w[a] - inertia[a] @ (arm_a.T @ total)),
        b: (v[b] + inv_mass[b] * impulse, w[b] + inertia[b] @ (arm_b.T @ total)),
    }


def assert_velocities_after(out, before, inertia, a, b, n, arm_a, arm_b, total, atol=None):
    """The solved velocities of bodies a and b are those after the normal impulses
    ``total`` (apply_totals), within ``atol`` (default: 1e-4 of each body's speed before)."""
    expected = apply_totals(before, inertia, a, b, n, arm_a, arm_b, total)
    for body, (linear, angular) in expected.items():
        tolerance = 1e-4 * np.abs(before["linear_velocity"][body]).max() if atol is None else atol
        np.testing.assert_allclose(out["linear_velocity"][body, :3], linear, atol=tolerance)
        np.testing.assert_allclose(out["angular_velocity"][body, :3], angular, atol=tolerance)


def brute_force_lcp(k_matrix, rhs):
    """float64 reference: impulses x >= 0 with K x - rhs >= 0 and x . (K x - rhs) = 0, found
    by trying every active set (least squares on each, as K is singular for four points of
    one face); the velocities K x are the same for every solution (K is positive
    semidefinite)."""
    count = len(rhs)
    scale = max(np.abs(rhs).max(), 1e-12)
    for size in range(count, -1, -1):
        for active in itertools.combinations(range(count), size):
            x = np.zeros(count)
            if active:
                idx = list(active)
                x[idx] = np.linalg.lstsq(k_matrix[np.ix_(idx, idx)], rhs[idx], rcond=1e-9)[0]
            slack = k_matrix @ x - rhs
            if (
                x.min() >= -1e-9 * scale
                and slack.min() >= -1e-7 * scale
                and np.abs(slack[list(active)]).max(initial=0) <= 1e-7 * scale
            ):
                return np.maximum(x, 0.0)
    raise AssertionError("no active set solves the reference problem")


@pytest.mark.parametrize("variant", ["lanes", "serial"])
@pytest.mark.parametrize("count", [2, 3, 4])
def test_pushing_points_get_the_smallest_exact_impulses(runtime, rng, variant, count):
    """Reference (float64): K[j][k] = m_a + m_b + (r_aj x n).I_a (r_ak x n) + (r_bj x n).I_b
    (r_bk x n) (singular for four points: three independent motions); the block's totals are
    pinv(K) (target - v_n), the smallest ones, all positive here (the bodies approach fast
    and turn slowly), and the velocities change by them. Random normals, points off the
    contact plane by a few mm (the lever arms' part along n does not matter), random
    orientations (full world inertias) and restitution (the rows stop the points, then the
    restitution pass drives them to -e v_n, one rigid motion: the smallest totals of both
    together are pinv(K) (-e v_n - v_n)). Two points (an edge): K is regular, the totals
    are K^-1 (target - v_n)."""
    rig, manifolds, cons, before = random_face_pairs(runtime, rng, count, variant)
    inertia = rig.inertia.get()["inv_inertia_world"][:, :, :3].astype(float)
    out, solved = rig.solve(manifolds, iterations=1)
    for m, c, s in zip(manifolds, cons, solved):
        a, b, n, arm_a, arm_b, k_matrix, normal_speed = normal_rows(m, c, before, inertia)
        total = np.linalg.pinv(k_matrix, rcond=1e-6) @ (bounce_targets(c, count) - normal_speed)
        assert total.min() > 0.05 * total.max()
        np.testing.assert_allclose(
            s["normal_impulse"][:count], total, rtol=2e-3, atol=1e-4 * total.max()
        )
        assert_velocities_after(out, before, inertia, a, b, n, arm_a, arm_b, total)


def assert_exact_solution(out, before, inertia, solved, count, reference):
    """The velocities ``out`` are those of the float64 solution ``total`` of ``reference`` =
    (a, b, n, arm_a, arm_b, k_matrix, normal_speed, target, total) and the impulses the
    solve kept in ``solved`` are complementary: non-negative, pushing points at their
    targets, the others not approaching past them (tolerance 2e-4 of the scene's speeds)."""
    a, b, n, arm_a, arm_b, k_matrix, normal_speed, target, total = reference
    scale = max(
        np.abs(before["linear_velocity"][[a, b]]).max(), 1.0, np.abs(target - normal_speed).max()
    )
    assert_velocities_after(out, before, inertia, a, b, n, arm_a, arm_b, total, atol=2e-4 * scale)
    impulses = solved["normal_impulse"][:count].astype(float)
    reached = normal_speed + k_matrix @ impulses
    assert impulses.min() >= 0.0
    pushing = impulses > 1e-4 * max(impulses.max(), 1e-9)
    np.testing.assert_allclose(reached[pushing], target[pushing], atol=2e-4 * scale)
    assert np.all(reached[~pushing] >= target[~pushing] - 2e-4 * scale)


@pytest.mark.parametrize("variant", ["lanes", "serial"])
@pytest.mark.parametrize("count", [2, 3, 4])
def test_block_is_the_exact_contact_solution(runtime, rng, variant, count):
    """The general case: bodies spinning at up to 4 rad/s (so that some points separate
    or the smallest all-pushing impulses would pull) and points up to 4 mm apart (targets
    that fit no rigid motion). One iteration leaves the velocities of the float64
    brute-force solution of the contact problem (brute_force_lcp; unique for a positive
    semidefinite K), and the impulses are complementary to the speeds reached: a point
    with an impulse moves at its target, one without moves no slower. The scenes are
    checked to contain released points, so the test cannot pass on the all-pushing case
    alone. Tolerances scale with the largest right-hand side too: the block accepts four
    pushing points whose targets fit one rigid motion to within 1e-4 of it
    (OVERSHOOT_TOLERANCE), so the velocities agree to that order of it (scaled by the
    bodies' speeds alone, 3 of 150 seeds failed with four points, at fac43a9 as well;
    the rows one by one instead of the block fail every seed)."""
    released = 0
    for _attempt in range(3):
        rig, manifolds, cons, before = random_face_pairs(
            runtime, rng, count, variant, pairs=9, spin=4.0, separations=(-0.002, 0.004)
        )
        inertia = rig.inertia.get()["inv_inertia_world"][:, :, :3].astype(float)
        out, solved = rig.solve(manifolds, iterations=1)
        for m, c, s in zip(manifolds, cons, solved):
            a, b, n, arm_a, arm_b, k_matrix, normal_speed = normal_rows(m, c, before, inertia)
            target = c["velocity_target"][:count].astype(float)
            total = brute_force_lcp(k_matrix, target - normal_speed)
            released += int((total == 0).sum())
            reference = (a, b, n, arm_a, arm_b, k_matrix, normal_speed, target, total)
            assert_exact_solution(out, before, inertia, s, count, reference)
    assert released > 0


@pytest.mark.parametrize("variant", ["lanes", "serial"])
@pytest.mark.parametrize("count", [3, 4])
def test_block_from_warm_started_impulses_is_the_exact_contact_solution(
    runtime, rng, variant, count
):
    """As test_block_is_the_exact_contact_solution, from accumulated impulses already
    applied (the warm start): half the faces start from impulses on the reference
    solution's active set, scaled at random, the others from a random set of pushing
    points. Either way one iteration leaves the velocities of the float64 brute-force
    solution for the velocities before the warm start, with complementary impulses (a
    block search that starts from a face's current active set must keep this: one that
    did was tried on the serial form and reverted); the scenes are checked to hold faces
    that start from the reference's set of one to count - 1 pushing points."""
    hinted = 0
    for _attempt in range(3):
        rig, manifolds, cons, before = random_face_pairs(
            runtime, rng, count, variant, pairs=9, spin=4.0, separations=(-0.002, 0.004)
        )
        inertia = rig.inertia.get()["inv_inertia_world"][:, :, :3].astype(float)
        records = rig.setup.constraints.get()
        references = []
        for i, (m, c) in enumerate(zip(manifolds, cons)):
            a, b, n, arm_a, arm_b, k_matrix, normal_speed = normal_rows(m, c, before, inertia)
            target = c["velocity_target"][:count].astype(float)
            total = brute_force_lcp(k_matrix, target - normal_speed)
            references.append((a, b, n, arm_a, arm_b, k_matrix, normal_speed, target, total))
            if i % 2 == 0:
                pushing = total > 0
                start = np.where(pushing, total * rng.uniform(0.5, 1.5, count), 0.0)
                hinted += int(0 < pushing.sum() < count)
            else:
                start = np.where(rng.random(count) < 0.5, rng.uniform(0.0, 2.0, count), 0.0)
            records["normal_impulse"][i, :count] = start
        rig.setup.constraints.set(records)
        rig.sweep(iterations=1, warm_start=True)
        out, solved = rig.bodies.get(), rig.setup.constraints.get()[: len(manifolds)]
        for s, reference in zip(solved, references):
            assert_exact_solution(out, before, inertia, s, count, reference)
    assert hinted > 0


@pytest.mark.parametrize("variant", ["lanes", "serial"])
@pytest.mark.parametrize("count", [2, 3, 4])
def test_sequential_rows_are_gauss_seidel(runtime, rng, variant, count):
    """normal_solve="sequential" (the rows one after another, whose kernel carries the
    rows' speeds forward through K instead of re-reading the velocities): two sweeps, the
    points in order, then backwards, equal the float64 Gauss-Seidel of the normal rows,
    lambda_k = max(0, lambda_k + (target_k - speed_k) / K_kk) with the speeds updated after
    every row, and the velocities change by the impulses found; then the restitution pass
    (contact_rows.cl.mako: apply_restitution), RESTITUTION_ROUNDS = 8 sweeps of the rows of
    the points that pushed in a sweep and have a bounce, to that bounce. Friction 0."""
    rig, manifolds, cons, before = random_face_pairs(
        runtime, rng, count, variant, spin=2.0, normal_solve="sequential"
    )
    inertia = rig.inertia.get()["inv_inertia_world"][:, :, :3].astype(float)
    out, solved = rig.solve(manifolds, iterations=2)
    for m, c, s in zip(manifolds, cons, solved):
        a, b, n, arm_a, arm_b, k_matrix, normal_speed = normal_rows(m, c, before, inertia)
        target = c["velocity_target"][:count].astype(float)
        total = np.zeros(count)
        pushed = np.zeros(count)
        for order in (range(count), reversed(range(count))):
            for k in order:
                speed = normal_speed + k_matrix @ total
                total[k] = max(0.0, total[k] + (target[k] - speed[k]) / k_matrix[k, k])
            pushed = np.maximum(pushed, total)
        bounce = c["r_b"][:count, 3].astype(float)
        for _round in range(8):
            for k in range(count):
                if bounce[k] > 0 and pushed[k] > 0:
                    speed = normal_speed + k_matrix @ total
                    total[k] = max(0.0, total[k] + (bounce[k] - speed[k]) / k_matrix[k, k])
        assert total.max() > 0.0
        np.testing.assert_allclose(
            s["normal_impulse"][:count], total, rtol=1e-3, atol=1e-4 * total.max()
        )
        assert_velocities_after(out, before, inertia, a, b, n, arm_a, arm_b, total)


def gauss_seidel_rows(k_matrix, rhs, sweeps, alternate=True):
    """float64 Gauss-Seidel of the normal rows from zero impulses, lambda_k = max(0,
    lambda_k + (rhs_k - (K lambda)_k) / K_kk): forwards, then (``alternate``: the velocity
    rows) backwards on odd sweeps."""
    count = len(rhs)
    total = np.zeros(count)
    for sweep in range(sweeps):
        for k in reversed(range(count)) if alternate and sweep % 2 else range(count):
            total[k] = max(0.0, total[k] + (rhs[k] - k_matrix[k] @ total) / k_matrix[k, k])
    return total


def all_pushing(k_matrix, rhs):
    """float64 reference of the block's first case: the smallest totals with K total = rhs
    and whether they hold (True: the targets fit one rigid motion and no total is negative,
    by a margin that float32 cannot blur; False: clearly not; None: too close to call)."""
    total = np.linalg.pinv(k_matrix, rcond=1e-6) @ rhs
    scale = max(np.abs(rhs).max(), 1e-12)
    misfit = np.abs(k_matrix @ total - rhs).max() / scale
    lowest = total.min() / max(np.abs(total).max(), 1e-12)
    if misfit < 1e-6 and lowest > 1e-3:
        return total, True
    if misfit > 1e-2 or lowest < -1e-2:
        return total, False
    return total, None


@pytest.mark.parametrize(
    "variant, batching",
    [
        ("lanes", "cells"),
        ("lanes", "slabs"),
        ("serial", "cells"),
        ("serial", "slabs"),
        ("one_group", "global"),
        ("persistent", "global"),
    ],
)
def test_release_sweeps_leave_the_releasing_faces_to_the_rows_until_the_last(
    runtime, rng, variant, batching
):
    """release_sweeps=1 of 3 velocity and 3 position sweeps: whatever the first two did,
    the last solves the complete block, whose result is the exact contact solution: the
    velocities are those of the float64 brute-force solution (brute_force_lcp), and the
    push impulses (push velocities start at zero) the complementary solution for the
    position targets. release_sweeps=0: every sweep takes the block's all-pushing
    solution where it holds (float64 pinv(K) rhs, as in
    test_pushing_points_get_the_smallest_exact_impulses: a face resting on a face keeps
    its exact, order-free impulses) and else solves the rows one after another (the
    float64 Gauss-Seidel of three sweeps, the push rows always forwards), which misses the
    exact solution (checked, so that the first half can fail). Random faces, every other
    one touching at every point (targets -e v_n: one rigid motion) and the others with
    points 1-4 mm apart or 2 mm deep, and bodies spinning at up to 3 rad/s give both kinds,
    and the test needs both. Global batching runs all sweeps in one launch (one work group,
    or the persistent launch over every compute unit, whose sweep loop is its own),
    spatial batching one launch per colour and sweep (the pairs sit in different cells
    and slabs)."""
    kinds, missed = {True: 0, False: 0}, 0
    for _attempt in range(3):
        seed = int(rng.integers(1 << 31))
        for release_sweeps in (1, 0):
            rig, manifolds, cons, before = random_face_pairs(
                runtime,
                np.random.default_rng(seed),
                4,
                variant,
                pairs=9,
                spin=3.0,
                separations=[(-0.002, 0.0), (-0.002, 0.004)],
                batching=batching,
                restitution=False,  # (the rows' solution alone)
            )
            assert (len(rig.batcher.launch_plan) > 1) == (batching != "global")
            inertia = rig.inertia.get()["inv_inertia_world"][:, :, :3].astype(float)
            out, solved = rig.solve(
                manifolds, iterations=3, position_iterations=3, release_sweeps=release_sweeps
            )
            for m, c, s in zip(manifolds, cons, solved):
                a, b, n, arm_a, arm_b, k_matrix, normal_speed = normal_rows(m, c, before, inertia)
                rhs = c["velocity_target"][:4].astype(float) - normal_speed
                push_target = c["position_target"][:4].astype(float)
                scale = max(np.abs(before["linear_velocity"][[a, b]]).max(), 1.0, np.abs(rhs).max())
                push = s["push_impulse"][:4].astype(float)
                push_scale = max(np.abs(push_target).max(), 1e-3)
                exact = brute_force_lcp(k_matrix, rhs)
                if release_sweeps:
                    assert_velocities_after(
                        out, before, inertia, a, b, n, arm_a, arm_b, exact, atol=2e-4 * scale
                    )
                    reached = k_matrix @ push
                    pushing = push > 1e-4 * max(push.max(), 1e-9)
                    assert push.min() >= 0.0
                    np.testing.assert_allclose(
                        reached[pushing], push_target[pushing], atol=2e-4 * push_scale
                    )
                    assert np.all(reached[~pushing] >= push_target[~pushing] - 2e-4 * push_scale)
                    continue
                block, holds = all_pushing(k_matrix, rhs)
                if holds is None:
                    continue
                kinds[holds] += 1
                total = block if holds else gauss_seidel_rows(k_matrix, rhs, 3)
                np.testing.assert_allclose(
                    s["normal_impulse"][:4],
                    total,
                    rtol=2e-3,
                    atol=2e-4 * max(np.abs(total).max(), 1e-9),
                )
                missed += int(not holds and np.abs(k_matrix @ (total - exact)).max() > 1e-2 * scale)
                push_block, push_holds = all_pushing(k_matrix, push_target)
                if push_holds is not None:
                    expected = (
                        push_block
                        if push_holds
                        else gauss_seidel_rows(k_matrix, push_target, 3, alternate=False)
                    )
                    np.testing.assert_allclose(
                        push, expected, rtol=2e-3, atol=2e-4 * max(np.abs(expected).max(), 1e-9)
                    )
    assert kinds[True] > 0 and kinds[False] > 0 and missed > 0


def _second_solve(rig, same_geometry, inertia_scale=1.0, restitution=False):
    """Solve the rig's constraints again (one velocity and one push sweep, warm started
    from the first solve's impulses), as a later substep would (``restitution``: the
    step's last), after scaling every body's world inverse inertia by ``inertia_scale``:
    (linear, angular velocities)."""
    if inertia_scale != 1.0:
        inertia = rig.inertia.get()
        inertia["inv_inertia_world"] *= inertia_scale
        rig.inertia.set(inertia)
    sweeps = SimpleNamespace(iterations=1, position_iterations=1, relaxation=1.0, warm_start=True)
    rig.run(rig.solver, sweeps, restitution=restitution, same_geometry=same_geometry)
    out = rig.bodies.get()
    return np.concatenate([out["linear_velocity"], out["angular_velocity"]])


@pytest.mark.parametrize("count", [2, 3, 4])
def test_serial_block_solve_keeps_its_geometry_over_a_step(runtime, count):
    """The serial block solve derives each constraint's geometry (ContactGeometry: the
    face's Q, Q^-1 and K, the friction and twist rows) in a solve's first launches and,
    told ``same_geometry`` (a later substep of the step, same lever arms and inertias),
    reads it back instead: the second solve is then bit for bit the one that derives it
    again. With the inertias changed in between, a solve told the geometry is the same
    differs from one that derives it (for faces of three or four points, whose normal rows
    come from the record; two points' normal rows use the live inertias, and friction is 0
    here), so the record is what the sweeps read. The same holds when the second solve is
    a step's last substep, whose restitution pass (a face of bouncing points solved as a
    block) reads the record too; that pass changes the result."""
    results = {}
    for bounce, same, scale in itertools.product([False, True], [False, True], [1.0, 0.5]):
        rig, manifolds, _, _ = random_face_pairs(
            runtime, np.random.default_rng(7), count, "serial", spin=2.0
        )
        rig.sweep(iterations=2, position_iterations=1, release_sweeps=1)
        results[bounce, same, scale] = _second_solve(rig, same, scale, bounce)
    for bounce in (False, True):
        np.testing.assert_array_equal(results[bounce, True, 1.0], results[bounce, False, 1.0])
        # (inertia matters)
        assert not np.array_equal(results[bounce, True, 0.5], results[bounce, False, 1.0])
        if count >= 3:
            assert not np.array_equal(results[bounce, True, 0.5], results[bounce, False, 0.5])
        else:
            np.testing.assert_array_equal(results[bounce, True, 0.5], results[bounce, False, 0.5])
    assert not np.array_equal(results[True, False, 1.0], results[False, False, 1.0])


@pytest.mark.parametrize("shock", [False, True])
@pytest.mark.parametrize("variant", ["serial", "persistent"])
def test_contact_geometry_is_what_every_sweep_would_derive(runtime, rng, variant, shock):
    """A block solve that keeps its contacts' geometry for the step (the template
    parameter contact_geometry: ContactGeometry records derived by the launch, read by
    every sweep) does the arithmetic of one that derives it again in each sweep: with
    friction, a warm start, restitution and, with ``shock``, shock sweeps (whose face
    block of the held bodies comes from the record too, and whose held bodies take no turn
    from the friction rows read from it, as from rows derived with their zero inertia), the
    velocities, push velocities and impulses are equal bit for bit (exact builds), in the
    serial form and in the persistent launch."""
    from tests.pipeline.test_shock import GRAVITY, random_pairs

    bodies, inv_inertia, manifolds = random_pairs(rng, 29, vertical=True, restitution=0.4)
    manifolds["points"][:, :, 3] = rng.uniform(-0.01, 0.0, (len(manifolds), 4))  # to push
    manifolds["restitution"][::2] = 0.0  # (a shock sweep leaves a bouncing manifold alone)
    impulses = rng.uniform(0.0, 0.3, (len(manifolds), 4)).astype(np.float32)
    results = []
    for geometry in (False, True):
        rig = ContactRig(
            runtime,
            bodies,
            inv_inertia,
            variant=variant,
            fast_math=False,
            contact_geometry=geometry,
        )
        assert rig.solver.spec.values["contact_geometry"] == geometry
        rig.setup.gravity = GRAVITY
        rig.setup.restitution_threshold = 0.5
        rig.constraints(manifolds)
        records = rig.setup.constraints.get()
        records["normal_impulse"][: len(manifolds)] = impulses  # something to warm start
        rig.setup.constraints.set(records)
        rig.batch()
        sweeps = SimpleNamespace(
            iterations=3,
            position_iterations=2,
            relaxation=1.0,
            warm_start=True,
            shock_propagation=shock,
        )
        rig.run(rig.solver, sweeps)
        split = rig.solver.split_velocities(rig.body_count).get()
        results.append((rig.bodies.get(), split, rig.setup.constraints.get()[: len(manifolds)]))
    (bodies_d, split_d, cons_d), (bodies_c, split_c, cons_c) = results
    for field in ("linear_velocity", "angular_velocity"):
        np.testing.assert_array_equal(bodies_c[field], bodies_d[field], err_msg=field)
    for field in split_d.dtype.names:
        np.testing.assert_array_equal(split_c[field], split_d[field], err_msg=field)
    for field in ("normal_impulse", "tangent1_impulse", "tangent2_impulse", "push_impulse"):
        np.testing.assert_array_equal(cons_c[field], cons_d[field], err_msg=field)
    # (what the sweeps solved: friction, pushes, and with shock, contacts held)
    assert np.abs(cons_d["tangent1_impulse"][:, 0]).max() > 1e-3
    assert np.abs(cons_d["push_impulse"]).max() > 0.0
    assert (cons_d["tangent1"][:, 3] != layouts.SHOCK_HOLDS_NONE).any()


def test_a_world_keeps_contact_geometry_as_its_plan_says(runtime):
    """The plan parameter contact_geometry reaches the World's solver: a persistent launch
    told to keep its contacts' geometry steps a dropped stack of boxes exactly as one that
    derives it in every sweep (exact builds), and the serial form keeps it by default on a
    CPU."""
    from rbgen import Box, World

    ends = []
    for keep in (False, True):
        world = World(runtime, batching="global", fast_math=False, plan={"contact_geometry": keep})
        world.add_static(Box((5.0, 0.5, 5.0)), position=(0.0, -0.5, 0.0))
        positions = [(0.03 * k, 0.52 + 1.02 * k, -0.02 * k) for k in range(5)]
        world.add_bodies(Box((0.5, 0.5, 0.5)), mass=1.0, positions=positions)
        for _ in range(20):
            world.step(1 / 60)
        solver = world._pipeline.solve.solver
        assert solver.persistent and solver.spec.values["contact_geometry"] == keep
        ends.append(world.positions.copy())
    np.testing.assert_array_equal(ends[0], ends[1])
    # (the stack came down onto the ground and stands: each box a metre above the last)
    np.testing.assert_allclose(ends[0][-5:, 1], 0.5 + np.arange(5), atol=0.03)
    if not runtime.traits.is_gpu:
        cpu = World(runtime)
        cpu.add_bodies(Box((0.5, 0.5, 0.5)), mass=1.0, positions=[(0.0, 1.0, 0.0)])
        cpu.step(1 / 60)
        assert cpu.plan.contact_geometry
        assert cpu._pipeline.solve.solver.spec.values["contact_geometry"]
