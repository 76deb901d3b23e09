"""Jacobi solver with mass splitting, against a float64 numpy reference and Gauss-Seidel.

* Random contact graphs (bodies with up to ~10 contacts, static bodies among
  them, sizes that are not multiples of the work-group size): the warm start,
  velocity sweeps (sequential normal rows, odd sweeps backwards, the manifold's
  friction pair at its points' centre and its twist row) and push sweeps match a
  float64 reference of the same method: each body's share 1/k of its mass per
  contact, every constraint solved on the sweep's starting velocities, each body
  then moved by the mean of its copies' changes. Both launch variants (persistent:
  one launch; phases: one launch per phase) and the row masses rewritten for split
  bodies.
* A body in one contact is not split: where no body has two contacts, Jacobi
  is Gauss-Seidel (block normal solve), to float round-off.
* Total linear and angular momentum of free bodies is conserved.
* No constraints: nothing changes.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from rbgen.errors import RbgenError
from rbgen.pipeline.solvers.jacobi import JacobiSolver
from tests.pipeline.test_constraints import ContactRig, make_bodies, make_manifold

VARIANTS = [(False, 16), (False, 64), (True, 32), (True, 64)]  # (persistent, work-group size)


def sweeps(iterations=1, position_iterations=0, relaxation=1.0, warm_start=True):
    """The sweep settings a solver reads (the World's settings object)."""
    return SimpleNamespace(
        iterations=iterations,
        position_iterations=position_iterations,
        relaxation=relaxation,
        warm_start=warm_start,
    )


def run_jacobi(rig, solver, **settings):
    """Solve the rig's constraints (set up last) with ``solver``."""
    rig.run(solver, sweeps(**settings))


def random_scene(rng, bodies=37, statics=3, manifolds=101):
    """Bodies on a loose lattice (the first ``statics`` static) and manifolds between random
    pairs of them, 1-4 points each, some penetrating, some still apart, half of them with a
    restitution."""
    positions = rng.uniform(-3, 3, (bodies, 3))
    inv_mass = np.r_[np.zeros(statics), rng.uniform(0.3, 2.0, bodies - statics)]
    velocities = rng.uniform(-1, 1, (bodies, 3))
    velocities[:statics] = 0
    angular = rng.uniform(-1, 1, (bodies, 3))
    angular[:statics] = 0
    body_array = make_bodies(positions, inv_mass, velocities=velocities, angular=angular)
    inv_inertia = np.r_[np.zeros((statics, 3)), rng.uniform(0.5, 4.0, (bodies - statics, 3))]
    records = []
    while len(records) < manifolds:
        a, b = rng.integers(0, bodies, 2)
        if a == b or (inv_mass[a] == 0 and inv_mass[b] == 0):
            continue
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        count = int(rng.integers(1, 5))
        centre = 0.5 * (positions[a] + positions[b])
        points = centre + rng.uniform(-0.4, 0.4, (count, 3))
        records.append(
            make_manifold(
                int(a),
                int(b),
                normal,
                points,
                rng.uniform(-0.03, 0.01, count),
                friction=float(rng.uniform(0.2, 0.9)),
                restitution=float(rng.uniform(0.1, 1.0)) if rng.random() < 0.5 else 0.0,
            )
        )
    return body_array, inv_inertia, np.array(records)


def rows_of(c, k):
    """Point k's lever arms and the constraint's frame."""
    return (
        c["r_a"][k, :3].astype(np.float64),
        c["r_b"][k, :3].astype(np.float64),
        c["normal"][:3].astype(np.float64),
        c["tangent1"][:3].astype(np.float64),
        c["tangent2"][:3].astype(np.float64),
    )


def reference_jacobi(
    cons, bodies, world_inv_inertia, *, iterations, position_iterations, relaxation, warm_start
):
    """Float64 Jacobi with mass splitting, sequential normal rows and the manifold's
    friction pair and twist row (the kernels' arithmetic in the template's order), the
    restitution pass in the last sweep (contact_rows.cl.mako: apply_restitution):
    (velocities, angular velocities, push linear, push angular, constraints with their
    impulses)."""
    cons = cons.copy()
    inv_mass = bodies["inv_mass"].astype(np.float64)
    dynamic = inv_mass > 0
    contacts = np.zeros(len(bodies), int)
    for c in cons:
        for body in (c["body_a"], c["body_b"]):
            contacts[body] += dynamic[body]
    share = np.maximum(contacts, 1).astype(np.float64)
    split_mass = inv_mass * share
    split_inertia = world_inv_inertia * share[:, None, None]

    def row_mass(d, ra, rb, a, b):
        ca, cb = np.cross(ra, d), np.cross(rb, d)
        k = split_mass[a] + split_mass[b] + ca @ split_inertia[a] @ ca + cb @ split_inertia[b] @ cb
        return 1.0 / k if k > 0 else 0.0

    def centres(c):
        count = c["point_count"]
        return (
            c["r_a"][:count, :3].astype(np.float64).mean(0),
            c["r_b"][:count, :3].astype(np.float64).mean(0),
        )

    for c in cons:  # the row masses between the split bodies
        a, b = c["body_a"], c["body_b"]
        if max(contacts[a], contacts[b]) <= 1:
            continue
        for k in range(c["point_count"]):
            ra, rb, n, t1, t2 = rows_of(c, k)
            c["normal_mass"][k] = row_mass(n, ra, rb, a, b)
        ra, rb = centres(c)
        _, _, n, t1, t2 = rows_of(c, 0)
        c["tangent1_mass"][0] = row_mass(t1, ra, rb, a, b)
        c["tangent2_mass"][0] = row_mass(t2, ra, rb, a, b)
        twist = n @ split_inertia[a] @ n + n @ split_inertia[b] @ n
        c["tangent1_mass"][1] = 1.0 / twist if twist > 0 else 0.0

    def apply(state, a, b, impulse, ra, rb):
        va, wa, vb, wb = state
        va -= impulse * split_mass[a]
        wa -= split_inertia[a] @ np.cross(ra, impulse)
        vb += impulse * split_mass[b]
        wb += split_inertia[b] @ np.cross(rb, impulse)

    def twist_about(state, a, b, n, impulse):
        state[1] -= split_inertia[a] @ n * impulse
        state[3] += split_inertia[b] @ n * impulse

    def speed(state, d, ra, rb):
        va, wa, vb, wb = state
        return d @ (vb - va) + np.cross(rb, d) @ wb - np.cross(ra, d) @ wa

    def sweep(v, w, action):
        dv, dw = np.zeros_like(v), np.zeros_like(w)
        for c in cons:
            a, b = c["body_a"], c["body_b"]
            state = [v[a].copy(), w[a].copy(), v[b].copy(), w[b].copy()]
            action(c, state, a, b)
            for body, lin, ang in (
                (a, state[0] - v[a], state[1] - w[a]),
                (b, state[2] - v[b], state[3] - w[b]),
            ):
                if dynamic[body]:
                    dv[body] += lin
                    dw[body] += ang
        moved = contacts > 0
        v[moved] += dv[moved] / contacts[moved, None]
        w[moved] += dw[moved] / contacts[moved, None]

    def warm(c, state, a, b):
        for k in range(c["point_count"]):
            ra, rb, n, t1, t2 = rows_of(c, k)
            apply(state, a, b, n * c["normal_impulse"][k], ra, rb)
        ra, rb = centres(c)
        apply(state, a, b, t1 * c["tangent1_impulse"][0] + t2 * c["tangent2_impulse"][0], ra, rb)
        twist_about(state, a, b, n, float(c["tangent1_impulse"][1]))

    def solve(reverse, restitution):
        def action(c, state, a, b):
            count = c["point_count"]
            order = [k for k in (range(3, -1, -1) if reverse else range(4)) if k < count]
            for k in order:
                ra, rb, n, _, _ = rows_of(c, k)
                old = float(c["normal_impulse"][k])
                total = max(
                    0.0,
                    old
                    + relaxation
                    * c["normal_mass"][k]
                    * (c["velocity_target"][k] - speed(state, n, ra, rb)),
                )
                apply(state, a, b, n * (total - old), ra, rb)
                c["normal_impulse"][k] = total
            # the friction pair at the points' centre, within mu times the total impulse
            _, _, n, t1, t2 = rows_of(c, 0)
            ra, rb = centres(c)
            limit = c["normal"][3] * float(c["normal_impulse"][:count].sum())
            old1, old2 = float(c["tangent1_impulse"][0]), float(c["tangent2_impulse"][0])
            f1 = old1 - relaxation * c["tangent1_mass"][0] * speed(state, t1, ra, rb)
            f2 = old2 - relaxation * c["tangent2_mass"][0] * speed(state, t2, ra, rb)
            length = np.hypot(f1, f2)
            if length > limit:
                f1, f2 = f1 * limit / length, f2 * limit / length
            apply(state, a, b, t1 * (f1 - old1) + t2 * (f2 - old2), ra, rb)
            c["tangent1_impulse"][0], c["tangent2_impulse"][0] = f1, f2
            # the twist about the normal, within that limit times the points' mean
            # distance from their centre (on B)
            radius = np.linalg.norm(c["r_b"][:count, :3].astype(np.float64) - rb, axis=1).sum()
            twist_limit = limit * radius / count
            old = float(c["tangent1_impulse"][1])
            turning = n @ state[3] - n @ state[1]
            total = min(
                max(old - relaxation * c["tangent1_mass"][1] * turning, -twist_limit), twist_limit
            )
            twist_about(state, a, b, n, total - old)
            c["tangent1_impulse"][1] = total
            if c["tangent2"][3] > 0:  # the points that pushed (a mask); the restitution pass
                pushed = int(c["tangent2_impulse"][1])
                for k in range(count):
                    pushed |= int(c["normal_impulse"][k] > 0) << k
                c["tangent2_impulse"][1] = pushed
                for _round in range(8 if restitution else 0):
                    for k in range(count):
                        bounce = float(c["r_b"][k, 3])
                        if not (bounce > 0 and pushed >> k & 1):
                            continue
                        ra, rb, n, _, _ = rows_of(c, k)
                        old = float(c["normal_impulse"][k])
                        target = old + c["normal_mass"][k] * (bounce - speed(state, n, ra, rb))
                        apply(state, a, b, n * (max(0.0, target) - old), ra, rb)
                        c["normal_impulse"][k] = max(0.0, target)

        return action

    def push(c, state, a, b):
        for k in range(c["point_count"]):
            ra, rb, n, _, _ = rows_of(c, k)
            old = float(c["push_impulse"][k])
            total = max(
                0.0,
                old
                + relaxation
                * c["normal_mass"][k]
                * (c["position_target"][k] - speed(state, n, ra, rb)),
            )
            apply(state, a, b, n * (total - old), ra, rb)
            c["push_impulse"][k] = total

    v = bodies["linear_velocity"][:, :3].astype(np.float64)
    w = bodies["angular_velocity"][:, :3].astype(np.float64)
    if warm_start:
        sweep(v, w, warm)
    for s in range(iterations):
        sweep(v, w, solve(reverse=s % 2 == 1, restitution=s == iterations - 1))
    pv, pw = np.zeros_like(v), np.zeros_like(w)
    for _ in range(position_iterations):
        sweep(pv, pw, push)
    return v, w, pv, pw, cons


def device_setup(runtime, rng, **scene):
    """A ContactRig with the scene's constraints set up on the device, carrying random
    impulses (to be warm started) and, at half the points of a manifold with a restitution,
    a random bounce (r_b.w: the approaches of the scene are below the threshold)."""
    bodies, inv_inertia, manifolds = random_scene(rng, **scene)
    rig = ContactRig(runtime, bodies, inv_inertia, warm_start=False)
    rig.constraints(manifolds)
    all_constraints = rig.setup.constraints.get()
    n = len(manifolds)
    for field in ("normal_impulse", "tangent1_impulse", "tangent2_impulse"):
        all_constraints[field][:n] = rng.uniform(
            0.0 if field == "normal_impulse" else -0.05, 0.1, (n, 4)
        ).astype(np.float32)
    all_constraints["tangent2_impulse"][:n, 1:] = 0.0  # (slot 1: the pushed points' mask)
    bouncy = (rng.random((n, 4)) < 0.5) & (all_constraints["tangent2"][:n, 3:] > 0)
    all_constraints["r_b"][:n, :, 3] = np.where(bouncy, rng.uniform(0.1, 2.0, (n, 4)), 0.0)
    rig.setup.constraints.set(all_constraints)
    return rig, n


@pytest.mark.parametrize("persistent,work_group_size", VARIANTS)
def test_sweeps_match_the_float64_reference(runtime, rng, persistent, work_group_size):
    rig, n = device_setup(runtime, rng)
    before = rig.setup.constraints.get()[:n]
    bodies = rig.bodies.get()
    world_inv_inertia = rig.inertia.get()["inv_inertia_world"][:, :, :3].astype(np.float64)
    solver = JacobiSolver(
        runtime, normal_solve="sequential", persistent=persistent, work_group_size=work_group_size
    )
    settings = {"iterations": 5, "position_iterations": 3, "relaxation": 0.9, "warm_start": True}
    run_jacobi(rig, solver, **settings)
    v, w, pv, pw, cons = reference_jacobi(before, bodies, world_inv_inertia, **settings)
    got = rig.bodies.get()
    split = solver.split_velocities(rig.body_count).get()
    scale = np.abs(v).max()
    np.testing.assert_allclose(got["linear_velocity"][:, :3], v, atol=2e-5 * scale)
    np.testing.assert_allclose(got["angular_velocity"][:, :3], w, atol=2e-5 * np.abs(w).max())
    np.testing.assert_allclose(split["linear"][:, :3], pv, atol=2e-5 * np.abs(pv).max())
    np.testing.assert_allclose(split["angular"][:, :3], pw, atol=2e-5 * np.abs(pw).max())
    after = rig.setup.constraints.get()[:n]
    for field in (
        "normal_mass",
        "tangent1_mass",
        "tangent2_mass",
        "normal_impulse",
        "tangent1_impulse",
        "tangent2_impulse",
        "push_impulse",
    ):
        np.testing.assert_allclose(
            after[field],
            cons[field],
            rtol=1e-4,
            atol=1e-5 * np.abs(cons[field]).max(),
            err_msg=field,
        )
    assert (np.bincount(np.r_[before["body_a"], before["body_b"]]) > 3).any()  # shared bodies
    pushed = cons["tangent2_impulse"][:, 1].astype(int)[:, None] >> np.arange(4) & 1
    assert ((cons["r_b"][:, :, 3] > 0) & (pushed > 0)).any()  # bounces


@pytest.mark.parametrize("persistent", [False, True])
def test_manifold_friction_masses_rewritten_for_split_bodies(runtime, rng, persistent):
    """The centre friction pair and the twist row get the split bodies' masses too."""
    rig, n = device_setup(runtime, rng)
    before = rig.setup.constraints.get()[:n]
    run_jacobi(rig, JacobiSolver(runtime, persistent=persistent), iterations=1)
    after = rig.setup.constraints.get()[:n]
    inv_mass = rig.bodies.get()["inv_mass"]
    inertia = rig.inertia.get()["inv_inertia_world"][:, :, :3].astype(np.float64)
    contacts = np.bincount(np.r_[before["body_a"], before["body_b"]], minlength=len(inv_mass)) * (
        inv_mass > 0
    )
    share = np.maximum(contacts, 1)
    for c, old in zip(after, before):
        a, b = c["body_a"], c["body_b"]
        count = c["point_count"]
        ra, rb = c["r_a"][:count, :3].mean(0), c["r_b"][:count, :3].mean(0)
        n_ = c["normal"][:3]
        for d, got in (
            (c["tangent1"][:3], c["tangent1_mass"][0]),
            (c["tangent2"][:3], c["tangent2_mass"][0]),
        ):
            ca, cb = np.cross(ra, d), np.cross(rb, d)
            k = share[a] * (inv_mass[a] + ca @ inertia[a] @ ca) + share[b] * (
                inv_mass[b] + cb @ inertia[b] @ cb
            )
            assert got == pytest.approx(1 / k, rel=2e-4)
        twist = share[a] * n_ @ inertia[a] @ n_ + share[b] * n_ @ inertia[b] @ n_
        assert c["tangent1_mass"][1] == pytest.approx(1 / twist, rel=2e-4)
        if max(contacts[a], contacts[b]) <= 1:
            assert np.array_equal(c["normal_mass"], old["normal_mass"])


@pytest.mark.parametrize("persistent", [False, True])
def test_single_contacts_are_gauss_seidel(runtime, rng, persistent):
    """Boxes each resting on the static ground by one 4-point manifold and nothing else:
    no body is split, so Jacobi's sweeps are the Gauss-Seidel solver's (block normal
    solve) to float round-off."""
    boxes = 45  # not a multiple of any work-group size
    positions = np.c_[np.arange(boxes) * 1.5, np.full(boxes, 0.5), np.zeros(boxes)]
    positions = np.r_[[[0, 0, 0]], positions]
    velocities = np.r_[[[0, 0, 0]], rng.uniform(-1, 1, (boxes, 3))]
    bodies = make_bodies(
        positions,
        np.r_[0.0, rng.uniform(0.5, 2, boxes)],
        velocities=velocities,
        angular=np.r_[[[0, 0, 0]], rng.uniform(-1, 1, (boxes, 3))],
    )
    inv_inertia = np.r_[[[0, 0, 0]], rng.uniform(2, 8, (boxes, 3))]
    square = np.array([[0.5, 0, 0.5], [-0.5, 0, 0.5], [0.5, 0, -0.5], [-0.5, 0, -0.5]])
    manifolds = np.array(
        [
            make_manifold(
                0, i, [0, 1, 0], positions[i] - [0, 0.5, 0] + square, rng.uniform(-0.01, 0.0, 4)
            )
            for i in range(1, boxes + 1)
        ]
    )
    results = []
    for use_jacobi in (False, True):
        rig = ContactRig(runtime, bodies, inv_inertia, warm_start=False)
        rig.constraints(manifolds)
        if use_jacobi:
            solver = JacobiSolver(runtime, persistent=persistent)
            run_jacobi(rig, solver, iterations=6, position_iterations=2)
        else:  # the rig's own Gauss-Seidel solver (block normal solve) and batcher
            solver = rig.solver
            rig.sweep(iterations=6, position_iterations=2)
        results.append(
            (
                rig.bodies.get(),
                rig.setup.constraints.get()[:boxes],
                solver.split_velocities(rig.body_count).get(),
            )
        )
    (b_gs, c_gs, s_gs), (b_j, c_j, s_j) = results
    for field in ("linear_velocity", "angular_velocity"):
        np.testing.assert_allclose(b_j[field], b_gs[field], atol=1e-5, err_msg=field)
    for field in ("linear", "angular"):
        np.testing.assert_allclose(s_j[field], s_gs[field], atol=1e-5, err_msg=field)
    for field in ("normal_impulse", "tangent1_impulse", "tangent2_impulse", "push_impulse"):
        np.testing.assert_allclose(c_j[field], c_gs[field], atol=1e-5, rtol=1e-4, err_msg=field)
    assert np.array_equal(c_j["normal_mass"], c_gs["normal_mass"])  # not rewritten
    assert c_j["normal_impulse"].max() > 0  # the boxes were pushed


@pytest.mark.parametrize("persistent", [False, True])
def test_free_bodies_conserve_momentum(runtime, rng, persistent):
    """No static body: every contact's impulses are equal and opposite, so total linear
    momentum and angular momentum about the origin stay as they were."""
    rig, n = device_setup(runtime, rng, statics=0, bodies=24, manifolds=60)
    before = rig.bodies.get()
    inertia = rig.inertia.get()["inv_inertia_world"][:, :, :3].astype(np.float64)

    def momenta(b):
        mass = 1.0 / b["inv_mass"].astype(np.float64)
        x, v = b["position"][:, :3].astype(np.float64), b["linear_velocity"][:, :3]
        w = b["angular_velocity"][:, :3].astype(np.float64)
        spin = np.array([np.linalg.solve(i, wi) for i, wi in zip(inertia, w)])
        return (mass[:, None] * v).sum(0), (np.cross(x, mass[:, None] * v) + spin).sum(0)

    run_jacobi(rig, JacobiSolver(runtime, persistent=persistent), iterations=8)
    after = rig.bodies.get()
    (p0, l0), (p1, l1) = momenta(before), momenta(after)
    assert np.abs(after["linear_velocity"] - before["linear_velocity"]).max() > 0.1
    assert np.linalg.norm(p1 - p0) < 1e-4 * np.linalg.norm(p0)
    assert np.linalg.norm(l1 - l0) < 1e-4 * np.linalg.norm(l0)


@pytest.mark.parametrize("persistent", [False, True])
def test_no_constraints_change_nothing(runtime, rng, persistent):
    bodies, inv_inertia, manifolds = random_scene(rng, manifolds=5)
    rig = ContactRig(runtime, bodies, inv_inertia)
    rig.constraints(manifolds[:0])
    before = rig.bodies.get()
    solver = JacobiSolver(runtime, persistent=persistent)
    run_jacobi(rig, solver, iterations=3, position_iterations=2)
    assert np.array_equal(rig.bodies.get(), before)
    assert not solver.split_velocities(rig.body_count).get()["linear"].any()


def test_bad_settings_are_refused(runtime):
    solver = JacobiSolver(runtime)
    with pytest.raises(RbgenError, match="position_iterations"):
        solver.solve(None, None, 1, None, None, 1, sweeps(position_iterations=-1))
    with pytest.raises(RbgenError, match="relaxation"):
        solver.solve(None, None, 1, None, None, 1, sweeps(relaxation=2.5))
    with pytest.raises(RbgenError, match="normal_solve"):
        JacobiSolver(runtime, normal_solve="cg")
