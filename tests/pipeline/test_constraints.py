"""Contact constraint setup: effective masses, velocity targets, warm starting, edges.

Closed forms: for a point contact on a body with inverse mass m and inverse
world inertia I at lever arm r, the normal row's effective mass is
1 / (m + (r x n) . I (r x n)); an approaching body (normal speed v above the
threshold) gets the target -e v; a penetration d gets the split-impulse push
target beta / dt * (d - slop). Warm starting copies the impulses of the previous
step's point with the same body pair and feature id, in the share `carried_share`
allows (an impact's impulse is not carried). Every field of the setup
is also checked against a float64 numpy reference on random manifolds (random
normals, 1-4 points, full inertia tensors) over boundary sizes including 0. Each
constraint gets one constraint edge (its bodies, its item: the contact kind and its
index, its first point, the colour inherited from the previous step's edge).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pyopencl.array as cl_array
import pytest

from rbgen import layouts
from rbgen.pipeline.batching import make_batcher
from rbgen.pipeline.constraints import ContactConstraints
from rbgen.pipeline.prepare import BodyPreparation, inertia_records
from rbgen.pipeline.solvers.pgs import PgsSolver

#: the solver variants a ContactRig can run: (batching, solve form, persistent launch).
#: serial: a work-item walks each spatial group in order (the CPU form); lanes: a work
#: group's lanes solve a batch together (the GPU form); one_group: global batching's one
#: group of everything, solved by one work group's lanes; persistent: global batching
#: solved by the persistent launch over every compute unit.
VARIANTS = {
    "serial": ("cells", "serial", False),
    "lanes": ("cells", "lanes", False),
    "one_group": ("global", "lanes", False),
    "persistent": ("global", "lanes", True),
}


def make_bodies(positions, inv_mass, velocities=None, angular=None):
    n = len(positions)
    bodies = layouts.BODY.zeros(n)
    bodies["position"][:, :3] = positions
    bodies["orientation"][:, 3] = 1.0
    bodies["inv_mass"] = inv_mass
    if velocities is not None:
        bodies["linear_velocity"][:, :3] = velocities
    if angular is not None:
        bodies["angular_velocity"][:, :3] = angular
    return bodies


def make_manifold(a, b, normal, points, separations, features=None, friction=0.5, restitution=0.0):
    m = layouts.CONTACT_MANIFOLD.zeros(1)[0]
    m["body_a"], m["body_b"] = a, b
    m["normal"][:3] = normal
    k = len(points)
    m["points"][:k, :3] = points
    m["points"][:k, 3] = separations
    m["features"][:k] = np.arange(k) if features is None else features
    m["point_count"] = k
    m["friction"], m["restitution"] = friction, restitution
    return m


def make_batcher_for(runtime, variant="serial", batching=None, group_count=3, **options):
    """The batcher of a rig variant (VARIANTS), ``batching`` overriding its algorithm;
    spatial ones with cells of 2.5 m and slabs across x."""
    mode, solve_form, _ = VARIANTS[variant]
    mode = batching or mode
    if mode == "global":
        return make_batcher(runtime, "global", **options)
    batcher = make_batcher(runtime, mode, group_count=group_count, solve_form=solve_form, **options)
    batcher.configure(cell_size=2.5, slab_axis=(1.0, 0.0, 0.0))
    return batcher


class ContactRig:
    """Bodies + manifolds on the device, through setup, batching and the PGS solver of one
    of the VARIANTS (no integration); the block normal solve unless ``normal_solve`` says
    otherwise, the device's fast_math and warm-start mode unless given."""

    def __init__(
        self,
        runtime,
        bodies,
        inv_inertia,
        *,
        warm_start=True,
        variant="serial",
        batching=None,
        group_count=3,
        work_group_size=None,
        normal_solve="block",
        fast_math=None,
        warm_start_mode=None,
        batcher_options=None,
        contact_geometry=None,
    ):
        self.runtime = runtime
        queue = runtime.queue
        self.body_count = len(bodies)
        self.bodies = cl_array.to_device(queue, bodies)
        self.inertia = cl_array.to_device(queue, inertia_records(inv_inertia))
        self.prepare = BodyPreparation(runtime, gyroscopic=False)
        self.setup = ContactConstraints(runtime, warm_start=warm_start)
        self.batcher = make_batcher_for(
            runtime, variant, batching, group_count, **(batcher_options or {})
        )
        self.solver = PgsSolver(
            runtime,
            self.batcher,
            persistent=VARIANTS[variant][2],
            normal_solve=normal_solve,
            fast_math=fast_math,
            warm_start_mode=warm_start_mode,
            work_group_size=work_group_size,
            contact_geometry=contact_geometry,
        )
        self.warm_start = warm_start

    def constraints(self, manifolds, dt=1 / 60, capacity_slack=3):
        queue = self.runtime.queue
        n = len(manifolds)
        capacity = n + capacity_slack
        padded = layouts.CONTACT_MANIFOLD.zeros(capacity)
        padded[:n] = manifolds
        self.manifolds = cl_array.to_device(queue, padded)
        self.count = cl_array.to_device(queue, np.array([n], np.uint32))
        self.capacity = capacity
        self.prepare(self.bodies, self.inertia, self.body_count, dt)
        self.setup(
            self.manifolds,
            self.count,
            self.bodies,
            self.inertia,
            capacity,
            dt,
        )
        return self.setup.constraints.get()[:n]

    def batch(self):
        """Batch the constraints' edges (after `constraints`)."""
        setup = self.setup
        self.batcher(
            setup.edges,
            setup.edge_count,
            self.bodies,
            self.body_count,
            setup.first_contact_edge + self.capacity,
        )

    def sweep(
        self,
        iterations=20,
        position_iterations=0,
        relaxation=1.0,
        warm_start=None,
        release_sweeps=None,
    ):
        """Batch and solve the constraints set up last (warm start: the rig's setting)."""
        self.batch()
        self.solver.release_sweeps = release_sweeps
        sweeps = SimpleNamespace(
            iterations=iterations,
            position_iterations=position_iterations,
            relaxation=relaxation,
            warm_start=self.warm_start if warm_start is None else warm_start,
        )
        self.run(self.solver, sweeps)

    def run(self, solver, sweeps, **options):
        """``solver`` (this rig's or another) over the constraints set up last, with the rig's
        bodies and inertias; ``options``: the solver's own keyword arguments."""
        setup = self.setup
        solver.solve(
            setup.constraints,
            setup.count,
            self.capacity,
            self.bodies,
            self.inertia,
            self.body_count,
            sweeps,
            **options,
        )

    def solve(
        self,
        manifolds,
        dt=1 / 60,
        iterations=20,
        position_iterations=0,
        relaxation=1.0,
        release_sweeps=None,
    ):
        """Set up, batch and solve the manifolds; apply the push velocities over dt: (the
        bodies, the constraints after the solve)."""
        self.constraints(manifolds, dt)
        self.sweep(iterations, position_iterations, relaxation, release_sweeps=release_sweeps)
        if position_iterations:
            self.solver.apply_split(self.bodies, self.body_count, dt)
        return self.bodies.get(), self.setup.constraints.get()[: len(manifolds)]


def test_effective_masses_and_targets(runtime, rng):
    """Normal/tangent masses match 1/(m + (r x d).I(r x d)); velocity and push targets,
    and the bounce kept for the restitution pass (none in the velocity targets)."""
    inv_inertia = np.array([[0, 0, 0], rng.uniform(0.5, 2.0, 3)])
    speed, e, dt = 3.0, 0.4, 1 / 60
    bodies = make_bodies([[0, 0, 0], [0, 1, 0]], [0.0, 0.5], velocities=[[0, 0, 0], [0, -speed, 0]])
    points = np.array([[0.3, 0.0, 0.2], [-0.4, 0.0, 0.1], [0.1, 0.0, -0.3]])
    depth = np.array([-0.05, 0.0, 0.02])
    rig = ContactRig(runtime, bodies, inv_inertia, warm_start=False)
    m = make_manifold(0, 1, [0, 1, 0], points, depth, restitution=e)
    c = rig.constraints(np.array([m]), dt)[0]
    n = np.array([0, 1.0, 0])
    slop, beta = rig.setup.penetration_slop, rig.setup.penetration_recovery
    centre = points.mean(0) - [0, 1, 0]
    for direction, field in (
        (c["tangent1"][:3], "tangent1_mass"),
        (c["tangent2"][:3], "tangent2_mass"),
    ):
        rc = np.cross(centre, direction)  # the friction pair acts at the points' centre
        assert c[field][0] == pytest.approx(1 / (0.5 + rc @ (inv_inertia[1] * rc)), rel=1e-4)
    for k in range(3):
        rc = np.cross(points[k] - [0, 1, 0], n)
        assert c["normal_mass"][k] == pytest.approx(
            1 / (0.5 + rc @ (inv_inertia[1] * rc)), rel=1e-4
        )
        # touching: stop the approach; apart: land (close the gap, no further); the
        # bounce comes after the rows (the restitution pass)
        target = 0.0 if depth[k] <= 0 else -depth[k] / dt
        assert c["velocity_target"][k] == pytest.approx(target, rel=1e-4, abs=1e-7)
        # what later substeps and the restitution need: the separation, the bounce
        assert c["r_a"][k][3] == pytest.approx(depth[k], abs=1e-7)
        assert c["r_b"][k][3] == pytest.approx(e * speed, rel=1e-5)
    assert c["tangent2"][3] == pytest.approx(e)
    for k in range(3):
        push = beta / dt * (-depth[k] if depth[k] > 0 else max(-depth[k] - slop, 0.0))
        assert c["position_target"][k] == pytest.approx(push, rel=1e-4, abs=1e-6)
    t1, t2 = c["tangent1"][:3], c["tangent2"][:3]
    assert abs(t1 @ n) < 1e-6 and abs(t2 @ n) < 1e-6 and abs(t1 @ t2) < 1e-6
    assert np.linalg.norm(t1) == pytest.approx(1, abs=1e-6)


def tangent_basis_reference(n):
    """The kernel's friction frame: chosen from n alone (see constraints.cl.mako)."""
    t1 = [n[1], -n[0], 0.0] if abs(n[0]) > 0.57735 else [0.0, n[2], -n[1]]
    t1 = np.array(t1) / np.linalg.norm(t1)
    return t1, np.cross(n, t1)


#: contact_targets.cl.mako's CARRY_GROWTH and CARRY_ACCELERATION
CARRY_GROWTH, CARRY_ACCELERATION = 1.5, 9.81


def carried_share(old):
    """The share of constraint record ``old``'s impulses that a warm start carries: all,
    unless their total normal impulse exceeds CARRY_GROWTH times what ``old`` carried
    itself (tangent2_impulse slot 2) plus its allowance (slot 3); then the cap over the
    total."""
    total = float(old["normal_impulse"].astype(float).sum())
    cap = CARRY_GROWTH * float(old["tangent2_impulse"][2]) + float(old["tangent2_impulse"][3])
    return cap / total if total > cap else 1.0


def carry_allowance(normal_mass, gravity, dt):
    """A constraint's allowance (tangent2_impulse slot 3): one step of gravity, at least
    CARRY_ACCELERATION, on the sum of its normal rows' masses."""
    return max(float(np.linalg.norm(gravity)), CARRY_ACCELERATION) * dt * float(np.sum(normal_mass))


def setup_reference(manifold, bodies, inv_inertia, dt, setup):
    """float64 constraint of one manifold: masses, targets (see the module docstring)."""
    a, b = int(manifold["body_a"]), int(manifold["body_b"])
    count = min(int(manifold["point_count"]), 4)
    x = bodies["position"][:, :3].astype(float)
    v, w = (bodies[f][:, :3].astype(float) for f in ("linear_velocity", "angular_velocity"))
    inv_mass = bodies["inv_mass"].astype(float)
    n = manifold["normal"][:3].astype(float)
    t1, t2 = tangent_basis_reference(n)

    def row_mass(d, ra, rb):
        ca, cb = np.cross(ra, d), np.cross(rb, d)
        k = inv_mass[a] + inv_mass[b] + ca @ inv_inertia[a] @ ca + cb @ inv_inertia[b] @ cb
        return 1 / k if k > 0 else 0.0

    out = {
        f: np.zeros(4)
        for f in (
            "normal_mass",
            "tangent1_mass",
            "tangent2_mass",
            "velocity_target",
            "position_target",
            "separation",
            "bounce",
        )
    }
    out["tangent1"], out["tangent2"] = t1, t2
    ras, rbs = [], []
    beta, slop = setup.penetration_recovery, setup.penetration_slop
    for k in range(count):
        p, separation = manifold["points"][k, :3].astype(float), float(manifold["points"][k, 3])
        ra, rb = p - x[a], p - x[b]
        ras.append(ra), rbs.append(rb)
        out["normal_mass"][k] = row_mass(n, ra, rb)
        approach = (v[b] + np.cross(w[b], rb) - v[a] - np.cross(w[a], ra)) @ n
        # the bounce restores the approach before the step's gravity (dynamic bodies only)
        fall = [np.asarray(setup.gravity, float) * dt * (inv_mass[i] > 0) for i in (a, b)]
        incoming = approach - (fall[1] - fall[0]) @ n
        bounce = (
            -manifold["restitution"] * incoming if incoming < -setup.restitution_threshold else 0.0
        )
        # (the bounce is not a target: the restitution pass applies it after the rows)
        out["velocity_target"][k] = -separation / dt if separation > 0 else 0.0
        out["separation"][k], out["bounce"][k] = separation, bounce
        out["position_target"][k] = (
            -beta / dt * separation if separation > 0 else beta / dt * max(-separation - slop, 0.0)
        )
    if count:  # the friction pair at the points' centre, the twist about the normal
        centre_a, centre_b = np.mean(ras, axis=0), np.mean(rbs, axis=0)
        out["tangent1_mass"][0] = row_mass(t1, centre_a, centre_b)
        out["tangent2_mass"][0] = row_mass(t2, centre_a, centre_b)
        twist = n @ inv_inertia[a] @ n + n @ inv_inertia[b] @ n
        out["tangent1_mass"][1] = 1 / twist if twist > 0 else 0.0
    out["r_a"], out["r_b"] = np.zeros((4, 3)), np.zeros((4, 3))
    out["r_a"][:count], out["r_b"][:count] = ras, rbs
    return out


def random_manifolds(rng, n_manifolds, n_bodies, static):
    """Random pairs (B dynamic), unit normals of every direction, 1-4 points near B."""
    manifolds = layouts.CONTACT_MANIFOLD.zeros(n_manifolds)
    dynamic = np.flatnonzero(~static)
    for i in range(n_manifolds):
        b = int(rng.choice(dynamic))
        a = int(rng.choice(np.delete(np.arange(n_bodies), b)))
        normal = rng.normal(size=3)
        count = int(rng.integers(1, 5))
        manifolds[i] = make_manifold(
            a,
            b,
            normal / np.linalg.norm(normal),
            rng.uniform(-1, 1, (count, 3)),
            rng.uniform(-0.05, 0.03, count),
            features=rng.integers(0, 100, count),
            friction=rng.uniform(0, 1),
            restitution=rng.uniform(0, 1),
        )
    return manifolds


def random_scene(rng, n_manifolds, n_bodies=23, statics=3):
    """Random bodies (the first ``statics`` static, random orientations so that the world
    inverse inertia is a full matrix) and random manifolds between them: (bodies, inverse
    inertia diagonals, manifolds)."""
    static = np.arange(n_bodies) < statics
    quaternions = rng.normal(size=(n_bodies, 4))
    bodies = make_bodies(
        rng.uniform(-3, 3, (n_bodies, 3)),
        np.where(static, 0.0, rng.uniform(0.2, 2.0, n_bodies)),
        velocities=rng.uniform(-3, 3, (n_bodies, 3)),
        angular=rng.uniform(-3, 3, (n_bodies, 3)),
    )
    bodies["orientation"] = quaternions / np.linalg.norm(quaternions, axis=1)[:, None]
    inv_inertia_diag = np.where(static[:, None], 0.0, rng.uniform(0.5, 3.0, (n_bodies, 3)))
    return bodies, inv_inertia_diag, random_manifolds(rng, n_manifolds, n_bodies, static)


@pytest.mark.parametrize("n_manifolds", [0, 1, 17, 130])
def test_setup_matches_float64_reference(runtime, rng, n_manifolds):
    """Every field of every constraint against `setup_reference` (random bodies, some static,
    random orientations so that the world inverse inertia is a full matrix, a random
    gravity whose step the bounce targets leave out)."""
    bodies, inv_inertia_diag, manifolds = random_scene(rng, n_manifolds)
    rig = ContactRig(runtime, bodies, inv_inertia_diag, warm_start=False)
    rig.setup.gravity = tuple(rng.uniform(-20, 20, 3))  # (what the step added before)
    dt = 1 / 60
    got = rig.constraints(manifolds, dt)
    assert int(rig.setup.count.get()[0]) == n_manifolds
    prepared = rig.bodies.get()  # the velocities and inertias the setup read
    inv_inertia = rig.inertia.get()["inv_inertia_world"][:, :, :3].astype(float)
    for m, c in zip(manifolds, got):
        expected = setup_reference(m, prepared, inv_inertia, dt, rig.setup)
        count = int(m["point_count"])
        assert (c["body_a"], c["body_b"], c["point_count"]) == (m["body_a"], m["body_b"], count)
        assert list(c["features"][:count]) == list(m["features"][:count])
        np.testing.assert_allclose(c["normal"], [*m["normal"][:3], m["friction"]], rtol=1e-6)
        for field in ("tangent1", "tangent2"):
            np.testing.assert_allclose(c[field][:3], expected[field], atol=1e-6)
        for field in ("r_a", "r_b"):
            np.testing.assert_allclose(c[field][:, :3], expected[field], atol=1e-5)
        # (what later substeps need: each point's separation and bounce, the restitution)
        np.testing.assert_allclose(c["r_a"][:count, 3], expected["separation"][:count], atol=1e-7)
        np.testing.assert_allclose(
            c["r_b"][:count, 3], expected["bounce"][:count], rtol=1e-4, atol=1e-5
        )
        assert c["tangent2"][3] == pytest.approx(m["restitution"])
        for field in (
            "normal_mass",
            "tangent1_mass",
            "tangent2_mass",
            "velocity_target",
            "position_target",
        ):
            np.testing.assert_allclose(
                c[field], expected[field], rtol=1e-4, atol=1e-5, err_msg=field
            )
        for field in ("normal_impulse", "tangent1_impulse", "push_impulse"):
            assert not c[field].any(), field
        # (tangent2_impulse[1]: no point pushed yet; [2]: nothing carried; [3]: the allowance)
        assert not c["tangent2_impulse"][:3].any()
        assert c["tangent2_impulse"][3] == pytest.approx(
            carry_allowance(expected["normal_mass"], rig.setup.gravity, dt), rel=1e-4
        )


@pytest.mark.parametrize("first_contact_edge", [0, 5])
@pytest.mark.parametrize("n_manifolds", [0, 1, 17, 130])
def test_edges_describe_the_constraints(runtime, rng, n_manifolds, first_contact_edge):
    """Contact i's edge is edge first_contact_edge + i (the edges before it are the joints',
    left alone): its bodies, its item (the contact kind, index i), its first point (the
    manifold's, in the world), no inherited colour without warm starting; the edge count
    first_contact_edge + n is on the device."""
    bodies, inv_inertia, manifolds = random_scene(rng, n_manifolds)
    rig = ContactRig(runtime, bodies, inv_inertia, warm_start=False)
    rig.setup.first_contact_edge = first_contact_edge
    rig.constraints(manifolds)
    assert int(rig.setup.edge_count.get()[0]) == first_contact_edge + n_manifolds
    assert rig.setup.edge_capacity == first_contact_edge + rig.capacity
    edges = rig.setup.edges.get()
    assert not edges[:first_contact_edge].view(np.uint8).any()  # the joints' edges untouched
    edges = edges[first_contact_edge : first_contact_edge + n_manifolds]
    assert np.array_equal(edges["body_a"], manifolds["body_a"])
    assert np.array_equal(edges["body_b"], manifolds["body_b"])
    assert np.array_equal(
        edges["item"], layouts.EDGE_CONTACT << layouts.EDGE_KIND_SHIFT | np.arange(n_manifolds)
    )
    assert np.all(edges["colour"] == layouts.SOLVER_NONE)
    np.testing.assert_allclose(edges["point"][:, :3], manifolds["points"][:, 0, :3], atol=1e-5)


def test_slow_speculative_contact_only_closes_the_gap(runtime):
    """A point 0.1 m apart approaching at 1 m/s (no crossing in 1/60 s) may approach at gap/dt."""
    bodies = make_bodies([[0, 0, 0], [0, 1, 0]], [0.0, 1.0], velocities=[[0, 0, 0], [0, -1, 0]])
    rig = ContactRig(runtime, bodies, np.array([[0, 0, 0], [1, 1, 1.0]]), warm_start=False)
    c = rig.constraints(
        np.array([make_manifold(0, 1, [0, 1, 0], [[0, 0, 0]], [0.1], restitution=1.0)])
    )[0]
    assert c["velocity_target"][0] == pytest.approx(-0.1 * 60, rel=1e-5)


def boxes_on_ground(n_pairs, features=None):
    """A static ground (body 0) and n_pairs unit-mass boxes in a row, 3 m apart, falling at
    2 m/s, each touching the ground at its four lower corners (1 cm deep): the bodies,
    the inverse inertias and one manifold a box (features: the four ids of each, else
    0..3)."""
    positions = np.zeros((n_pairs + 1, 3))
    positions[1:, 0] = np.arange(n_pairs) * 3.0
    positions[1:, 1] = 0.5
    bodies = make_bodies(
        positions,
        np.r_[0.0, np.ones(n_pairs)],
        velocities=np.r_[[[0, 0, 0]], np.tile([0, -2.0, 0], (n_pairs, 1))],
    )
    inv_inertia = np.r_[[[0, 0, 0]], np.ones((n_pairs, 3))]
    corners = np.array([[0.3, 0.5, 0.3], [-0.3, 0.5, 0.3], [0.3, 0.5, -0.3], [-0.3, 0.5, -0.3]])
    manifolds = layouts.CONTACT_MANIFOLD.zeros(n_pairs)
    for i in range(n_pairs):
        manifolds[i] = make_manifold(
            0,
            i + 1,
            [0, 1, 0],
            positions[i + 1] - corners,
            [-0.01] * 4,
            features=None if features is None else features[i],
        )
    return bodies, inv_inertia, manifolds


@pytest.mark.parametrize("warm_start", [True, False])
@pytest.mark.parametrize("reorder", [True, False])
def test_warm_start_matches_pair_and_feature(runtime, rng, warm_start, reorder):
    """Impulses carry over for the same body pair, per point: from the old point with the
    same feature id, else from an old point within match_distance (relative to B), else 0;
    whether the pairs come in the same order (found at their own index) or another (found
    through the table). The old edge's colour (global batching's, set by hand here to a
    value per pair) comes along too, as the next colouring's inherited colour; none
    without warm starting or after a reset."""
    n_pairs = 37
    features = [rng.permutation(50)[:4] for _ in range(n_pairs)]
    bodies, inv_inertia, manifolds = boxes_on_ground(n_pairs, features)
    rig = ContactRig(runtime, bodies, inv_inertia, warm_start=warm_start)
    order = rng.permutation(n_pairs)
    _, first = rig.solve(manifolds[order], iterations=5)
    first_by_body = {int(c["body_b"]): c for c in first}
    edges = rig.setup.edges.get()
    edges["colour"][:n_pairs] = 1000 + edges["body_b"][:n_pairs]  # a colour per pair
    rig.setup.edges.set(edges)
    # Next step, pairs in another order: point 0 keeps its feature and moves 5 cm,
    # point 1 gets a new feature id at the same place, point 2 a new id and moves 5 cm.
    changed = manifolds.copy()
    for i in range(n_pairs):
        changed[i]["features"][1:3] = [100 + i, 200 + i]
        changed[i]["points"][0, 0] += 0.05
        changed[i]["points"][2, 0] += 0.05
    second = rig.constraints(changed[rng.permutation(n_pairs) if reorder else order])
    second_edges = rig.setup.edges.get()[:n_pairs]
    assert rig.setup.match_distance < 0.05
    for c, edge in zip(second, second_edges):
        old = first_by_body[int(c["body_b"])]
        share = carried_share(old)
        for k in range(4):
            if not warm_start or k == 2:
                expected = 0.0
            else:
                j = k if k == 1 else list(old["features"]).index(c["features"][k])
                expected = share * old["normal_impulse"][j]
            np.testing.assert_allclose(c["normal_impulse"][k], expected, rtol=1e-5, atol=1e-7)
        # the friction pair (slot 0, the frame unchanged) and the twist, in the same share
        expected = share * np.r_[old["tangent1_impulse"][:2], old["tangent2_impulse"][:1]]
        if not warm_start:
            expected = np.zeros(3)
        got = np.r_[c["tangent1_impulse"][:2], c["tangent2_impulse"][:1]]
        np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-7)
        assert c["tangent2_impulse"][2] == pytest.approx(c["normal_impulse"].sum(), rel=1e-5)
        assert edge["body_b"] == c["body_b"]
        assert edge["colour"] == (1000 + c["body_b"] if warm_start else layouts.SOLVER_NONE)
    assert not warm_start or np.all(second["normal_impulse"][:, [0, 1, 3]] > 0)
    rig.setup.reset()  # forgets the previous step, found at its index or through the table
    fresh = rig.constraints(changed[order])
    assert not fresh["normal_impulse"].any()
    assert np.all(rig.setup.edges.get()[:n_pairs]["colour"] == layouts.SOLVER_NONE)


def test_warm_start_off_for_one_call(runtime, rng):
    """A call with warm_start=False (a World whose warm_start setting is off) finds no
    previous constraint: zero impulses and no inherited colour, as a setup built without
    warm starting gives; the next call warm-starts again, from that call."""
    n_pairs = 9
    bodies, inv_inertia, manifolds = boxes_on_ground(n_pairs)
    rig = ContactRig(runtime, bodies, inv_inertia)
    reference = ContactRig(runtime, bodies, inv_inertia, warm_start=False)
    rig.solve(manifolds, iterations=5)
    edges = rig.setup.edges.get()
    edges["colour"][:n_pairs] = 7
    rig.setup.edges.set(edges)
    rig.bodies.set(bodies)  # falling again, so that every call has impulses to carry
    rig.prepare(rig.bodies, rig.inertia, rig.body_count, 1 / 60)
    rig.setup(
        rig.manifolds, rig.count, rig.bodies, rig.inertia, rig.capacity, 1 / 60, warm_start=False
    )
    off = rig.setup.constraints.get()[:n_pairs]
    assert np.array_equal(off, reference.constraints(manifolds))
    assert np.all(rig.setup.edges.get()[:n_pairs]["colour"] == layouts.SOLVER_NONE)
    rig.sweep(iterations=5)
    solved = rig.setup.constraints.get()[:n_pairs]
    rig.bodies.set(bodies)
    again = rig.constraints(manifolds)
    shares = np.array([[carried_share(c)] for c in solved])
    assert np.all(shares < 1)  # (the falling boxes' first impulses: an impact's, capped)
    np.testing.assert_allclose(
        again["normal_impulse"], shares * solved["normal_impulse"], rtol=1e-5
    )
    assert again["normal_impulse"].min() > 0


def test_overflowing_manifold_count_is_clamped_to_capacity(runtime):
    """The narrowphase reports its true count (9) past our capacity (5): 5 constraints are built."""
    bodies = make_bodies(np.c_[np.arange(6.0), np.zeros(6), np.zeros(6)], np.r_[0.0, np.ones(5)])
    rig = ContactRig(runtime, bodies, np.r_[[[0, 0, 0]], np.ones((5, 3))], warm_start=False)
    manifolds = layouts.CONTACT_MANIFOLD.zeros(5)  # (np.array of records drops the padding)
    for i in range(1, 6):
        manifolds[i - 1] = make_manifold(0, i, [0, 1, 0], [[i, -0.5, 0]], [0.0])
    queue = runtime.queue
    d_manifolds = cl_array.to_device(queue, manifolds)
    count = cl_array.to_device(queue, np.array([9], np.uint32))
    rig.prepare(rig.bodies, rig.inertia, 6, 1 / 60)
    rig.setup(d_manifolds, count, rig.bodies, rig.inertia, 5, 1 / 60)
    assert int(rig.setup.count.get()[0]) == 5 == int(rig.setup.edge_count.get()[0])
    assert sorted(rig.setup.constraints.get()["body_b"][:5]) == [1, 2, 3, 4, 5]
    assert sorted(rig.setup.edges.get()["body_b"][:5]) == [1, 2, 3, 4, 5]


def test_warm_start_follows_the_ring_through_shrinking_pair_sets_and_undo(runtime, rng):
    """Every call warm-starts from the call before it (after ``undo(k)``: the call before
    the k undone ones), pair by pair, and finds nothing for a pair that call lacked, even
    when an older call that reused the same buffers had it (its table entry must be gone,
    not found past the newer count). Calls with shrinking, reordered pair sets and undos
    of one and two calls go round the ring of generations several times; each call's
    warm-started impulses are compared with the final impulses of the call it follows."""
    n_pairs = 24
    bodies, inv_inertia, manifolds = boxes_on_ground(n_pairs)
    rig = ContactRig(runtime, bodies, inv_inertia)

    def call(pairs, speed):
        """Set up and solve the manifolds of ``pairs`` (in that order), the boxes falling
        at ``speed`` (a new one each call, so that each call's impulses differ): the
        warm-started and the final impulses by body_b."""
        bodies["linear_velocity"][1:, 1] = -speed
        bodies["angular_velocity"] = 0.0
        rig.bodies.set(bodies)
        started = rig.constraints(manifolds[pairs])
        rig.sweep(iterations=3)
        final = rig.setup.constraints.get()[: len(pairs)]

        def impulses(cs, carried=False):
            """By body_b: the normal impulses, the friction pair and the twist, as a warm
            start carries them (``carried``) or as they are."""
            return {
                int(c["body_b"]): (carried_share(c) if carried else 1.0)
                * np.r_[c["normal_impulse"], c["tangent1_impulse"][:2], c["tangent2_impulse"][:1]]
                for c in cs
            }

        return impulses(started), impulses(final, carried=True)

    history = []  # final impulses of the calls in effect, oldest first
    everything = np.arange(n_pairs)
    # (a redo with fewer pairs than the undone call it replaces, then all pairs again: an
    # undone call's table entries must not survive into the redo's generation)
    schedule = [
        everything,
        everything,
        everything,
        everything,
        everything[: n_pairs // 3],
        rng.permutation(n_pairs),
        rng.permutation(n_pairs),
        "undo 2",
        rng.permutation(n_pairs)[: n_pairs // 2],
        everything,
        "undo 1",
        rng.permutation(n_pairs),
        everything[::2],
        rng.permutation(n_pairs),
        everything,
    ]
    found = missing = 0
    for number, entry in enumerate(schedule):
        if isinstance(entry, str):
            undone = int(entry.split()[1])
            rig.setup.undo(undone)
            del history[-undone:]
            continue
        started, final = call(entry, 1.0 + 0.25 * number)
        before = history[-1] if history else {}
        for body, impulses in started.items():
            expected = before.get(body, np.zeros(7))
            np.testing.assert_allclose(
                impulses,
                expected,
                rtol=1e-5,
                atol=1e-7,
                err_msg=f"warm start of the pair (0, {body})",
            )
            found, missing = found + (body in before), missing + (body not in before)
        history.append(final)
        assert all(np.all(v[:4] > 0) for v in final.values())  # every call carries impulses
    assert found > 100 and missing > 20  # both cases were exercised
