"""PGS contact solver on synthetic manifolds, against closed forms.

* A body hitting a static plane at normal speed v with restitution e leaves
  at e v (above the threshold), 0 below it.
* Friction: a body with no rotational freedom (zero inverse inertia) sliding
  at u with normal speed v keeps u - mu v of its tangential speed (the
  friction impulse is clamped by mu times the total normal impulse), or stops.
* Two free bodies in contact: total linear and angular momentum conserved,
  and no contact point left approaching.
* Split impulse moves a penetrating body out by beta (d - slop) without
  changing its velocity.
* The implicit gyroscopic term conserves the angular momentum of an
  asymmetric free spinning body.

Every solver variant runs on every device present (tests.pipeline.test_constraints
VARIANTS): the serial form (a work-item per spatial group), the lanes form (a work
group's lanes over level-2 batches), global batching's one group solved by one work
group, and the persistent launch (every compute unit stepping through the batches
together). The kernel signatures are rendered from the Python declarations the solvers
bind by, and a binding that disagrees with them is refused.
"""

from __future__ import annotations

import itertools

import numpy as np
import pyopencl.array as cl_array
import pytest

from rbgen import codegen
from rbgen.codegen import Arg, Signature, kernel_signatures
from rbgen.device import INT64_ATOMICS
from rbgen.errors import RbgenError, TemplateParameterError
from rbgen.launch import instance
from rbgen.pipeline.batching import make_batcher
from rbgen.pipeline.integrate import Integrator
from rbgen.pipeline.prepare import BodyPreparation, inertia_records
from rbgen.pipeline.solvers import jacobi, pgs
from rbgen.pipeline.solvers.pgs import PgsSolver
from tests.pipeline.test_constraints import (
    VARIANTS,
    ContactRig,
    make_batcher_for,
    make_bodies,
    make_manifold,
)

SQUARE = np.array([[0.5, 0, 0.5], [-0.5, 0, 0.5], [0.5, 0, -0.5], [-0.5, 0, -0.5]])


def stacked_columns(columns, height, pitch, separations, side_contacts=False):
    """Body 0 the static ground, then columns of unit boxes ``pitch`` apart along x, each
    box on a 4-point manifold to the one below (separations from ``separations()``) and,
    with ``side_contacts``, on one to its neighbour in the column before: (positions,
    manifolds in build order)."""
    positions, manifolds = [[0, 0, 0]], []
    for col in range(columns):
        for level in range(height):
            positions.append([pitch * col, 0.5 + level, 0])
            i = len(positions) - 1
            below = 0 if level == 0 else i - 1
            manifolds.append(
                make_manifold(
                    below,
                    i,
                    [0, 1, 0],
                    np.array(positions[i]) + SQUARE - [0, 0.5, 0],
                    separations(),
                )
            )
            if side_contacts and col:
                manifolds.append(
                    make_manifold(
                        i - height,
                        i,
                        [1, 0, 0],
                        np.array(positions[i])
                        + SQUARE[:, [1, 0, 2]] * [0, 0.8, 0.8]
                        - [pitch / 2, 0, 0],
                        [-0.002] * 4,
                    )
                )
    return np.array(positions), manifolds


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("restitution,speed", [(0.0, 3.0), (0.5, 3.0), (1.0, 2.0), (0.8, 0.2)])
def test_bounce_off_static_plane(runtime, rng, restitution, speed, variant):
    """Four symmetric points under a box: v_out = e v (v above the 0.5 m/s threshold, else 0)."""
    n_boxes = 33
    positions = np.c_[np.arange(n_boxes) * 2.0, np.full(n_boxes, 0.5), np.zeros(n_boxes)]
    positions = np.r_[[[0, 0, 0]], positions]
    bodies = make_bodies(
        positions,
        np.r_[0.0, rng.uniform(0.2, 2.0, n_boxes)],
        velocities=np.r_[[[0, 0, 0]], np.tile([0, -speed, 0], (n_boxes, 1))],
    )
    inv_inertia = np.r_[[[0, 0, 0]], rng.uniform(0.5, 3.0, (n_boxes, 3))]
    rig = ContactRig(runtime, bodies, inv_inertia, variant=variant, warm_start=False)
    manifolds = np.array(
        [
            make_manifold(
                0,
                i + 1,
                [0, 1, 0],
                positions[i + 1] + SQUARE - [0, 0.5, 0],
                [0.0] * 4,
                restitution=restitution,
            )
            for i in range(n_boxes)
        ]
    )
    out, _ = rig.solve(manifolds, iterations=60)
    expected = restitution * speed if speed > rig.setup.restitution_threshold else 0.0
    np.testing.assert_allclose(out["linear_velocity"][1:, 1], expected, atol=2e-3 * speed)
    np.testing.assert_allclose(out["angular_velocity"][1:, :3], 0.0, atol=2e-3 * speed)
    assert np.all(out["linear_velocity"][0] == 0)  # the static body is never written


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("mu", [0.1, 0.3, 2.0])
def test_friction_clamped_by_normal_impulse(runtime, rng, mu, variant):
    """Translation-only body: tangential speed u becomes max(u - mu v, 0) along its
    direction; the friction pair (slot 0) stays within mu times the total normal impulse."""
    u = rng.uniform(1.0, 2.0)
    direction = rng.normal(size=2)
    direction /= np.linalg.norm(direction)
    v = 2.0
    velocity = [u * direction[0], -v, u * direction[1]]
    bodies = make_bodies([[0, 0, 0], [0, 0.5, 0]], [0.0, 0.7], velocities=[[0, 0, 0], velocity])
    rig = ContactRig(runtime, bodies, np.zeros((2, 3)), variant=variant, warm_start=False)
    m = make_manifold(0, 1, [0, 1, 0], SQUARE, [0.0] * 4, friction=mu)
    out, cons = rig.solve(np.array([m]), iterations=60)
    vel = out["linear_velocity"][1, :3]
    assert vel[1] == pytest.approx(0.0, abs=1e-4)
    expected = max(u - mu * v, 0.0)
    np.testing.assert_allclose(vel[[0, 2]], expected * direction, atol=1e-4)
    friction = np.hypot(cons[0]["tangent1_impulse"][0], cons[0]["tangent2_impulse"][0])
    assert friction <= mu * cons[0]["normal_impulse"].sum() * (1 + 1e-5) + 1e-7


@pytest.mark.parametrize("variant", VARIANTS)
def test_two_free_bodies_conserve_momentum(runtime, rng, variant):
    """Random masses, inertias, normal and 1-4 points: P and L conserved within 1e-4 relative
    (the issue's bound; 1000 float32 iterations of round-off); no point of a 1- or 2-point
    manifold approaching faster than its target allows."""
    n_pairs = 21
    positions, inv_mass, velocities, angular, inv_inertia, manifolds = [], [], [], [], [], []
    for i in range(n_pairs):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        centre = np.array([5.0 * i, 0, 0])
        pa, pb = centre - 0.5 * n, centre + 0.5 * n
        positions += [pa, pb]
        inv_mass += list(rng.uniform(0.2, 2.0, 2))
        velocities += [n * 2 + rng.normal(size=3), -n * 2 + rng.normal(size=3)]
        angular += list(rng.normal(size=(2, 3)))
        inv_inertia += list(rng.uniform(0.3, 3.0, (2, 3)))
        t = np.cross(n, [1, 0, 0] if abs(n[0]) < 0.9 else [0, 1, 0])
        t /= np.linalg.norm(t)
        s = np.cross(n, t)
        k = int(rng.integers(1, 5))
        points = centre + 0.3 * (rng.uniform(-1, 1, (k, 1)) * t + rng.uniform(-1, 1, (k, 1)) * s)
        manifolds.append(
            make_manifold(
                2 * i,
                2 * i + 1,
                n,
                points,
                np.zeros(k),
                friction=rng.uniform(0, 1),
                restitution=rng.uniform(0, 1),
            )
        )
    bodies = make_bodies(
        np.array(positions), np.array(inv_mass), np.array(velocities), np.array(angular)
    )
    rig = ContactRig(runtime, bodies, np.array(inv_inertia), variant=variant, warm_start=False)
    out, cons = rig.solve(np.array(manifolds), iterations=1000)

    def momenta(b):
        mass = 1 / b["inv_mass"]
        x, v, w = b["position"][:, :3], b["linear_velocity"][:, :3], b["angular_velocity"][:, :3]
        # orientation is identity, so the world inertia is the principal diagonal
        spin = w / np.array(inv_inertia)
        return (mass[:, None] * v).reshape(n_pairs, 2, 3).sum(1), (
            spin + np.cross(x, mass[:, None] * v)
        ).reshape(n_pairs, 2, 3).sum(1)

    p0, l0 = momenta(bodies.astype(bodies.dtype))
    p1, l1 = momenta(out)
    scale = np.abs(p0).max() + 1
    np.testing.assert_allclose(p1, p0, atol=1e-4 * scale)
    np.testing.assert_allclose(l1, l0, atol=1e-4 * (np.abs(l0).max() + 1))
    for c in cons:
        a, b = c["body_a"], c["body_b"]
        if c["point_count"] > 2:
            continue  # redundant points (more than the rows' rank) converge slowly
        for k in range(c["point_count"]):
            ra, rb = c["r_a"][k, :3], c["r_b"][k, :3]
            dv = (
                out["linear_velocity"][b, :3]
                + np.cross(out["angular_velocity"][b, :3], rb)
                - out["linear_velocity"][a, :3]
                - np.cross(out["angular_velocity"][a, :3], ra)
            )
            target = c["velocity_target"][k]
            assert dv @ c["normal"][:3] >= target - 1e-2 * max(1.0, abs(target))


@pytest.mark.parametrize("variant", VARIANTS)
def test_penetration_recovery(runtime, variant):
    """Resting box 5 cm deep: the split impulse moves it up beta (d - slop) and leaves its
    velocity at rest."""
    depth, dt = 0.05, 1 / 60
    bodies = make_bodies([[0, 0, 0], [0, 0.45, 0]], [0.0, 1.0])
    rig = ContactRig(
        runtime, bodies, np.array([[0, 0, 0], [1, 1, 1.0]]), variant=variant, warm_start=False
    )
    m = make_manifold(0, 1, [0, 1, 0], SQUARE + [0, -0.05, 0], [-depth] * 4)
    out, _ = rig.solve(np.array([m]), dt=dt, iterations=30, position_iterations=30)
    push = rig.setup.penetration_recovery * (depth - rig.setup.penetration_slop)
    assert out["position"][1, 1] - 0.45 == pytest.approx(push, rel=1e-3)
    assert np.abs(out["linear_velocity"][1, :3]).max() < 1e-5


@pytest.mark.parametrize(
    "variant,work_group_size,batching",
    [
        ("lanes", 1, "cells"),
        ("lanes", 64, "cells"),
        ("lanes", 32, "slabs"),
        ("serial", 1, "cells"),
        ("serial", 2, "cells"),
        ("serial", 1, "slabs"),
        ("one_group", 1, None),
        ("one_group", 32, None),
        ("persistent", 1, None),
        ("persistent", 32, None),
    ],
)
def test_stacked_columns_end_resting(runtime, rng, variant, work_group_size, batching):
    """Columns of 6 boxes falling onto each other (one pile per column, batched): after
    the solve every box's vertical speed is ~0 (inelastic), whatever the batching (in cells
    mode each column spans several cells and colours) and the solver form (serial with 2
    groups per work group: the leftover launch has one idle); PGS converges slowly on the
    lateral drift its point ordering creates, which friction removes (< 10% of v)."""
    speed = 1.0
    positions, manifolds = stacked_columns(17, 6, 3.0, lambda: [0.0] * 4)
    n = len(positions)
    velocities = np.tile([0, -speed, 0], (n, 1))
    velocities[0] = 0
    bodies = make_bodies(positions, np.r_[0.0, np.ones(n - 1)], velocities=velocities)
    rig = ContactRig(
        runtime,
        bodies,
        np.r_[[[0, 0, 0]], np.full((n - 1, 3), 6.0)],
        variant=variant,
        batching=batching,
        warm_start=False,
        group_count=4,
        work_group_size=work_group_size,
    )
    manifolds = np.array(manifolds)[rng.permutation(len(manifolds))]
    out, _ = rig.solve(manifolds, iterations=200)
    assert np.abs(out["linear_velocity"][1:, 1]).max() < 5e-3 * speed
    assert np.abs(out["linear_velocity"][1:, :3]).max() < 0.1 * speed


def test_gyroscopic_term_conserves_angular_momentum(runtime):
    """A free asymmetric box (I = 1, 2, 3) spun at 5 rad/s near its unstable middle axis:
    world L = R I R^T w stays within 1% over 600 steps at dt = 1/60, while w itself
    changes a lot (the box flips; without the gyroscopic term w would stay fixed)."""
    inertia_diag = np.array([1.0, 2.0, 3.0])
    bodies = make_bodies([[0, 0, 0]], [1.0], angular=[[0.3, 5.0, 0.4]])
    queue = runtime.queue
    d_bodies = cl_array.to_device(queue, bodies)
    d_inertia = cl_array.to_device(queue, inertia_records(1 / inertia_diag[None]))
    prepare = BodyPreparation(runtime, gyroscopic=True)
    integrate = Integrator(runtime, gravity=True)

    def momentum(b):
        q = b["orientation"][0]
        x, y, z, w = q
        rot = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
        return rot @ (inertia_diag * (rot.T @ b["angular_velocity"][0, :3]))

    l0 = momentum(bodies)
    w0 = bodies["angular_velocity"][0, :3]
    largest_change = 0.0
    for step in range(600):
        prepare(d_bodies, d_inertia, 1, 1 / 60)
        integrate(d_bodies, 1, 1 / 60, gravity=(0, 0, 0))
        if step % 20 == 0:
            w = d_bodies.get()["angular_velocity"][0, :3]
            largest_change = max(largest_change, np.linalg.norm(w - w0))
    l1 = momentum(d_bodies.get())
    assert np.linalg.norm(l1 - l0) < 0.01 * np.linalg.norm(l0)
    assert largest_change > 0.5 * np.linalg.norm(w0)


@pytest.mark.parametrize("columns, work_group_size", [(7, 32), (48, 32), (7, 256), (160, 256)])
def test_persistent_solve_matches_the_one_group_solve_bit_for_bit(
    runtime, rng, columns, work_group_size
):
    """Over the same batches (global batching's colours depend on the edges alone), the
    persistent launch (every compute unit, a barrier across them after each batch) does
    the one-work-group solve's arithmetic in the same order: equal results, velocities,
    push velocities and impulses alike, for a pile of columns with warm starting. The
    persistent launch hands a small batch's push rows to other lanes than its velocity
    rows (pgs.cl.mako: push_lane), a large one's not: 48 columns at 32 lanes a group and
    160 at 256 make batches larger than that threshold (half a work group's lanes on every
    compute unit) on a device of few compute units. At 256 lanes a group (a GPU's) the
    slots go round the work group's warps (group_slot: a permutation, so every constraint
    is solved once, by one lane). Both are exact
    builds (fast_math=False): -cl-fast-relaxed-math lets the compiler contract and reorder
    each kernel's arithmetic its own way, so only exact builds promise equal bits; both
    warm-start batch by batch (the summed warm start adds in another order:
    test_summed_warm_start_is_the_sum_of_the_impulses)."""
    positions, manifolds = stacked_columns(
        columns, 5, 1.2, lambda: rng.uniform(-0.01, 0.0, 4), side_contacts=True
    )
    n = len(positions)
    velocities = rng.uniform(-1, 1, (n, 3))
    velocities[0] = 0
    bodies = make_bodies(positions, np.r_[0.0, rng.uniform(0.5, 2, n - 1)], velocities=velocities)
    inv_inertia = np.r_[[[0, 0, 0]], rng.uniform(2, 8, (n - 1, 3))]
    manifolds = np.array(manifolds)[rng.permutation(len(manifolds))]
    impulses = rng.uniform(0.0, 0.3, (len(manifolds), 4)).astype(np.float32)
    results = []
    for variant in ("one_group", "persistent"):
        rig = ContactRig(
            runtime,
            bodies,
            inv_inertia,
            variant=variant,
            work_group_size=work_group_size,
            fast_math=False,
            warm_start_mode="batched",
        )
        rig.constraints(manifolds)
        records = rig.setup.constraints.get()
        records["normal_impulse"][: len(manifolds)] = impulses  # something to warm start
        rig.setup.constraints.set(records)
        rig.sweep(iterations=7, position_iterations=3)
        rig.solver.apply_split(rig.bodies, rig.body_count, 1 / 60)
        results.append((rig.bodies.get(), rig.setup.constraints.get()[: len(manifolds)]))
    (bodies_g, cons_g), (bodies_p, cons_p) = results
    for field in ("linear_velocity", "angular_velocity", "position", "orientation"):
        assert np.array_equal(bodies_g[field], bodies_p[field]), field
    for field in ("normal_impulse", "tangent1_impulse", "tangent2_impulse", "push_impulse"):
        assert np.array_equal(cons_g[field], cons_p[field]), field
    assert np.abs(bodies_p["linear_velocity"][1:, :3]).max() > 0  # something was solved


def warm_started_velocities(bodies, inv_inertia, constraints):
    """float64 reference of a warm start: every constraint's accumulated impulses applied
    to its bodies, v_a -= p / m_a, w_a -= I_a^-1 L_a, v_b += p / m_b, w_b += I_b^-1 L_b, with
    p the sum of the points' normal impulses and the friction pair (slot 0 of the tangent
    impulses) and L about each body's centre: the normal impulses at their points, the
    friction pair at the points' centre and the twist (tangent1 slot 1) about the normal:
    (linear, angular) velocities."""
    linear = bodies["linear_velocity"][:, :3].astype(float).copy()
    angular = bodies["angular_velocity"][:, :3].astype(float).copy()
    inv_mass = bodies["inv_mass"].astype(float)
    for c in constraints:
        a, b, count = int(c["body_a"]), int(c["body_b"]), int(c["point_count"])
        n, t1, t2 = (c[f][:3].astype(float) for f in ("normal", "tangent1", "tangent2"))
        ra, rb = c["r_a"][:count, :3].astype(float), c["r_b"][:count, :3].astype(float)
        normal = n * c["normal_impulse"][:count, None].astype(float)
        friction = t1 * float(c["tangent1_impulse"][0]) + t2 * float(c["tangent2_impulse"][0])
        twist = n * float(c["tangent1_impulse"][1])
        p = normal.sum(0) + friction
        moment_a = np.cross(ra, normal).sum(0) + np.cross(ra.mean(0), friction) + twist
        moment_b = np.cross(rb, normal).sum(0) + np.cross(rb.mean(0), friction) + twist
        linear[a] -= p * inv_mass[a]
        angular[a] -= inv_inertia[a] @ moment_a
        linear[b] += p * inv_mass[b]
        angular[b] += inv_inertia[b] @ moment_b
    return linear, angular


def test_summed_warm_start_is_the_sum_of_the_impulses(runtime, rng):
    """The persistent launch's summed warm start (64-bit fixed-point sums per body, then
    every body takes its sum) against the batched one (a batch step per colour) and the
    float64 sum of every constraint's impulses at its lever arms (warm_started_velocities):
    no sweep, only the warm start, over 6 columns of 5 boxes with side contacts (bodies in
    up to 6 manifolds) and random old impulses, odd body and constraint counts. The sums
    are integers, so two runs give the same bits whatever the order of the atomic
    additions."""
    if not runtime.has_extension(INT64_ATOMICS):
        pytest.skip(f"the summed warm start needs {INT64_ATOMICS}")
    positions, manifolds = stacked_columns(
        6, 5, 1.2, lambda: rng.uniform(-0.01, 0.0, 4), side_contacts=True
    )
    n = len(positions)
    velocities = rng.uniform(-1, 1, (n, 3))
    velocities[0] = 0
    bodies = make_bodies(
        positions,
        np.r_[0.0, rng.uniform(0.5, 2, n - 1)],
        velocities=velocities,
        angular=np.r_[[[0, 0, 0]], rng.uniform(-1, 1, (n - 1, 3))],
    )
    inv_inertia = np.r_[[[0, 0, 0]], rng.uniform(2, 8, (n - 1, 3))]
    manifolds = np.array(manifolds)[rng.permutation(len(manifolds))]
    impulses = {
        name: rng.uniform(
            0.0 if name == "normal_impulse" else -0.3, 0.6, (len(manifolds), 4)
        ).astype(np.float32)
        for name in ("normal_impulse", "tangent1_impulse", "tangent2_impulse")
    }
    results = []
    for mode in ("summed", "summed", "batched"):
        rig = ContactRig(runtime, bodies, inv_inertia, variant="persistent", warm_start_mode=mode)
        assert rig.solver.spec.values["warm_start_mode"] == mode
        rig.constraints(manifolds)
        records = rig.setup.constraints.get()
        for name, values in impulses.items():
            records[name][: len(manifolds)] = values
        rig.setup.constraints.set(records)
        rig.sweep(iterations=0, warm_start=True)
        results.append(rig.bodies.get())
        inertia = rig.inertia.get()["inv_inertia_world"][:, :, :3].astype(float)
        constraints = records[: len(manifolds)]
    first, again, batched = results
    assert first.tobytes() == again.tobytes()
    scale = np.abs(batched["linear_velocity"]).max()
    for field in ("linear_velocity", "angular_velocity"):
        np.testing.assert_allclose(first[field], batched[field], atol=2e-6 * scale)
        assert np.abs(first[field] - bodies[field]).max() > 0.1  # the impulses moved them
    linear, angular = warm_started_velocities(bodies, inertia, constraints)
    np.testing.assert_allclose(first["linear_velocity"][:, :3], linear, atol=2e-6 * scale)
    np.testing.assert_allclose(first["angular_velocity"][:, :3], angular, atol=2e-6 * scale)


def test_summed_warm_start_needs_a_persistent_solve_and_int64_atomics(runtime):
    """warm_start_mode='summed' is refused without a persistent launch (naming the rule)
    and is the default of a persistent solve on a device with 64-bit atomics."""
    batcher = make_batcher(runtime, "global")
    with pytest.raises(RbgenError, match="warm_start_mode='summed' needs persistent=True"):
        PgsSolver(runtime, batcher, warm_start_mode="summed")
    expected = "summed" if runtime.has_extension(INT64_ATOMICS) else "batched"
    assert PgsSolver(runtime, batcher, persistent=True).spec.values["warm_start_mode"] == expected
    assert PgsSolver(runtime, batcher).spec.values["warm_start_mode"] == "batched"


@pytest.mark.parametrize("solve_form", ["lanes", "serial"])
def test_persistent_solve_refuses_spatial_groups(runtime, solve_form):
    """A persistent solve needs one group of all constraints (global batching); spatial
    batching is refused, naming it."""
    batcher = make_batcher_for(runtime, "lanes" if solve_form == "lanes" else "serial")
    with pytest.raises(RbgenError, match="needs one group of all constraints .* 'cells'"):
        PgsSolver(runtime, batcher, persistent=True)


@pytest.mark.parametrize("batching", ["global", "cells", "slabs"])
def test_launch_schedule(runtime, batching):
    """global: the warm start and every sweep in ONE launch; cells and slabs: a warm-start
    sweep, then one launch per colour and velocity sweep, the position sweeps riding
    along."""
    batcher = make_batcher_for(runtime, "lanes", batching)
    solver = PgsSolver(runtime, batcher)
    colours = len(batcher.launch_plan)
    one = batching == "global"
    for release_sweeps in (None, 2):  # (the release sweeps change scalars, not launches)
        launches, _ = solver._schedule(batcher.launch_plan, 10, 4, True, release_sweeps)
        assert len(launches) == (1 if one else colours * 11)
        assert len(solver._schedule(batcher.launch_plan, 3, 5, False, release_sweeps)[0]) == (
            1 if one else colours * 5
        )
        assert solver._schedule(batcher.launch_plan, 0, 0, False, release_sweeps)[0] == []


def pgs_specs(
    *,
    forms=("serial", "lanes"),
    persistent_choices=(False, True),
    normal_solves=("block", "sequential"),
    lanes_work_group_size=64,
    fast_math=False,
    support_chains=(False,),
):
    """Every reachable specialisation of the PGS template among the choices given (by
    default every one without the support chains, exact builds), by the rules between
    its parameters."""
    specs = []
    for form, persistent, warm, normal, joints, fold, geometry, chains in itertools.product(
        forms,
        persistent_choices,
        pgs.WARM_START_MODES,
        normal_solves,
        (False, True),
        (False, True),
        (False, True),
        support_chains,
    ):
        try:
            specs.append(
                pgs.TEMPLATE.spec(
                    work_group_size=1 if form == "serial" else lanes_work_group_size,
                    max_batches=128,
                    solve_form=form,
                    normal_solve=normal,
                    persistent=persistent,
                    fast_math=fast_math,
                    warm_start_mode=warm,
                    joints=joints,
                    fold_substeps=fold,
                    contact_geometry=geometry,
                    support_chains=chains,
                )
            )
        except TemplateParameterError:
            continue
    return specs


def test_fold_substeps_changes_only_the_persistent_launches():
    """fold_substeps folds the substeps' passes into the sweeps where the launch runs the
    substeps; every other specialisation renders the same source either way (so that a
    default spec made persistent=False still builds)."""
    by_values = {}
    for spec in pgs_specs():
        values = dict(spec.values)
        by_values.setdefault(values.pop("fold_substeps") and True, {})[
            tuple(sorted(values.items()))
        ] = spec
    assert by_values[True].keys() == by_values[False].keys()
    for key, folded in by_values[True].items():
        values = dict(key)
        changes = values["persistent"]
        assert (folded.source != by_values[False][key].source) == changes, values


def test_kernel_signatures_are_the_declarations():
    """The parameter lists in the generated source of every reachable PGS specialisation
    (and of the Jacobi kernels) are exactly the declared arguments of that
    specialisation, names and types, in order."""
    specs = pgs_specs()
    # (serial; lanes; persistent batched; persistent summed) x 2 normal solves x 2 (joints)
    # x 2 (fold_substeps: it changes the persistent launches alone), and the block solves of
    # the serial form and the persistent launches once more with contact_geometry
    assert len(specs) == 32 + 3 * 4
    # the support chains' phases: a persistent launch's specialisation each
    chained = pgs_specs(support_chains=(True,))
    assert len(chained) == sum(spec.values["persistent"] for spec in specs)
    specs += chained
    cases = [(spec, pgs.TEMPLATE) for spec in specs]
    cases += [
        (
            jacobi.TEMPLATE.spec(
                work_group_size=16, normal_solve="block", persistent=persistent, fast_math=False
            ),
            jacobi.TEMPLATE,
        )
        for persistent in (False, True)
    ]
    for spec, template in cases:
        rendered = kernel_signatures(spec.source)
        assert rendered and set(rendered) <= set(template.signatures)  # every kernel declared
        for name in rendered:
            declared = [
                (a.name, " ".join(a.type_for(spec.values).split()))
                for a in template.signatures[name].args(spec.values)
            ]
            assert [(arg["name"], arg["type"]) for arg in rendered[name]] == declared, (
                f"{name} of {spec}"
            )


def test_bindings_that_disagree_with_the_declaration_are_refused(runtime):
    """A launcher binds by name through the declaration: a name it lacks, or one this
    specialisation does not have, is refused, naming it; so is a set of binders that
    leaves an argument unset, a wrong number of values, and a kernel whose built argument
    list is not the declared one (a template that did not render it)."""
    batcher = make_batcher(runtime, "global")
    solver = PgsSolver(runtime, batcher, warm_start_mode="batched")
    spec = solver.spec
    with pytest.raises(TemplateParameterError, match="'colours' is not declared"):
        pgs.SOLVE_GROUPS.binder(spec, "constraints", "colours")
    with pytest.raises(TemplateParameterError, match="'warm_sums' is not an argument of this"):
        pgs.SOLVE_GROUPS.binder(spec, "warm_sums")
    with pytest.raises(TemplateParameterError, match=r"never sets \['passes'"):
        names = [n for n in pgs.LAUNCH_SCALARS if n not in ("passes", "group_end")]
        pgs.SOLVE_GROUPS.check_bound(
            spec, pgs.SOLVE_GROUPS.binder(spec, *names), solver._bind_buffers
        )
    kernel = instance(runtime, solver._program, "solve_groups")
    with pytest.raises(TypeError, match="6 values expected, got 5"):
        solver._bind_scalars(kernel, *[np.uint32(0)] * 5)
    other = PgsSolver(runtime, make_batcher_for(runtime, "serial"))  # group_end, geometry
    with pytest.raises(
        TemplateParameterError, match="built with 14 arguments, its declaration has 16"
    ):
        other._bind_scalars(kernel, *[np.uint32(0)] * 7)
    with pytest.raises(TemplateParameterError, match="declared twice"):
        Signature("k", [Arg("const uint", "n"), Arg("const float", "n")])
    with pytest.raises(TemplateParameterError, match="declares no signature for kernel 'k'"):
        codegen._signature_renderer(pgs.TEMPLATE.path, spec.values)("k")
