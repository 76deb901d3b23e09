"""PGS contact solver on synthetic manifolds, against closed forms.

* A body hitting a static plane at normal speed v with restitution e leaves
  at e v (above the threshold), 0 below it.
* Friction: a body with no rotational freedom (zero inverse inertia) sliding
  at u with normal speed v keeps u - mu v of its tangential speed (the
  friction impulse is clamped by mu times the normal impulse), or stops.
* Two free bodies in contact: total linear and angular momentum conserved,
  and no contact point left approaching.
* Split impulse moves a penetrating body out by beta (d - slop) without
  changing its velocity; Baumgarte gives it the velocity beta / dt (d - slop).
* The implicit gyroscopic term conserves the angular momentum of an
  asymmetric free spinning body.

Both kernel shapes (gpu: lanes over level-2 batches; cpu: one work-item per
group), the resident solve (gpu shape, one work group with every body's
velocity in local memory, single-mode batching) and the grid solve (gpu shape,
one work group per compute unit stepping through the batches together,
global-mode batching) run on every device present.
"""
from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array
import pytest

from rbgen.device import INT64_ATOMICS
from rbgen.errors import RbgenError
from rbgen.pipeline.batching import ConstraintBatcher
from rbgen.pipeline.prepare import BodyPreparation, inertia_records
from rbgen.pipeline.integrate import Integrator
from rbgen.pipeline.solver import ContactSolver
from tests.pipeline.test_constraints import ContactRig, make_bodies, make_manifold

#: bodies of the resident solves (fits any device's 32 KiB of local memory)
RESIDENT_BODIES = 1024
SQUARE = np.array([[0.5, 0, 0.5], [-0.5, 0, 0.5], [0.5, 0, -0.5], [-0.5, 0, -0.5]])
SHAPES = ["gpu", "cpu", "resident", "grid"]


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
            manifolds.append(make_manifold(below, i, [0, 1, 0], np.array(positions[i]) + SQUARE
                                           - [0, 0.5, 0], separations()))
            if side_contacts and col:
                manifolds.append(make_manifold(i - height, i, [1, 0, 0], np.array(positions[i])
                                               + SQUARE[:, [1, 0, 2]] * [0, 0.8, 0.8]
                                               - [pitch / 2, 0, 0], [-0.002] * 4))
    return np.array(positions), manifolds


def shaped_rig(runtime, bodies, inv_inertia, shape, *, penetration="split", warm_start=True,
               group_count=3, work_group_size=None, batching="components", friction="point",
               fast_math=None, warm_start_mode=None):
    """A ContactRig whose batcher and solver have the given kernel shape ("resident": the
    gpu shape solving in local memory, over single-mode batches; "grid": the gpu shape
    spread over every compute unit, over global-mode batches with hashed bids only, which
    colour as single mode does); ``fast_math`` and ``warm_start_mode`` as ContactSolver's
    (None: the device's default)."""
    resident = RESIDENT_BODIES if shape == "resident" else 0
    grid = shape == "grid"
    if resident:
        shape, batching = "gpu", "single"
    if grid:
        shape, batching = "gpu", "global"
    rig = ContactRig(runtime, bodies, inv_inertia, penetration=penetration,
                     warm_start=warm_start, group_count=group_count,
                     batching="components" if resident or grid else batching,
                     friction=friction)
    rig.batcher = ConstraintBatcher(runtime, group_count=group_count, mode=batching,
                                    cell_size=2.5, shape=shape,
                                    max_bodies=resident or None,
                                    ordered_rounds=0)  # (read by global mode only)
    rig.solver = ContactSolver(runtime, split_impulse=penetration == "split",
                               work_group_size=work_group_size, friction=friction,
                               normal_solve=rig.solver.spec.values["normal_solve"], shape=shape,
                               resident_bodies=resident, grid=grid, fast_math=fast_math,
                               warm_start_mode=warm_start_mode)
    return rig


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("restitution,speed", [(0.0, 3.0), (0.5, 3.0), (1.0, 2.0), (0.8, 0.2)])
def test_bounce_off_static_plane(runtime, rng, restitution, speed, shape):
    """Four symmetric points under a box: v_out = e v (v above the 0.5 m/s threshold, else 0)."""
    n_boxes = 33
    positions = np.c_[np.arange(n_boxes) * 2.0, np.full(n_boxes, 0.5), np.zeros(n_boxes)]
    positions = np.r_[[[0, 0, 0]], positions]
    bodies = make_bodies(positions, np.r_[0.0, rng.uniform(0.2, 2.0, n_boxes)],
                         velocities=np.r_[[[0, 0, 0]], np.tile([0, -speed, 0], (n_boxes, 1))])
    inv_inertia = np.r_[[[0, 0, 0]], rng.uniform(0.5, 3.0, (n_boxes, 3))]
    rig = shaped_rig(runtime, bodies, inv_inertia, shape, warm_start=False)
    manifolds = np.array([make_manifold(0, i + 1, [0, 1, 0], positions[i + 1] + SQUARE - [0, 0.5, 0],
                                        [0.0] * 4, restitution=restitution)
                          for i in range(n_boxes)])
    out, _ = rig.solve(manifolds, iterations=60)
    expected = restitution * speed if speed > rig.setup.restitution_threshold else 0.0
    np.testing.assert_allclose(out["linear_velocity"][1:, 1], expected, atol=2e-3 * speed)
    np.testing.assert_allclose(out["angular_velocity"][1:, :3], 0.0, atol=2e-3 * speed)
    assert np.all(out["linear_velocity"][0] == 0)  # the static body is never written


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("mu,model", [(0.1, "point"), (0.3, "point"), (2.0, "point"),
                                      (0.3, "manifold"), (2.0, "manifold")])
def test_friction_clamped_by_normal_impulse(runtime, rng, mu, model, shape):
    """Translation-only body: tangential speed u becomes max(u - mu v, 0) along its direction
    (per point or per manifold friction)."""
    u = rng.uniform(1.0, 2.0)
    direction = rng.normal(size=2)
    direction /= np.linalg.norm(direction)
    v = 2.0
    velocity = [u * direction[0], -v, u * direction[1]]
    bodies = make_bodies([[0, 0, 0], [0, 0.5, 0]], [0.0, 0.7], velocities=[[0, 0, 0], velocity])
    rig = shaped_rig(runtime, bodies, np.zeros((2, 3)), shape, warm_start=False, friction=model)
    m = make_manifold(0, 1, [0, 1, 0], SQUARE, [0.0] * 4, friction=mu)
    out, cons = rig.solve(np.array([m]), iterations=60)
    vel = out["linear_velocity"][1, :3]
    assert vel[1] == pytest.approx(0.0, abs=1e-4)
    expected = max(u - mu * v, 0.0)
    np.testing.assert_allclose(vel[[0, 2]], expected * direction, atol=1e-4)
    friction = np.hypot(cons[0]["tangent1_impulse"], cons[0]["tangent2_impulse"])
    if model == "point":
        assert np.all(friction <= mu * cons[0]["normal_impulse"] * (1 + 1e-5) + 1e-7)
    else:  # one pair in slot 0, against the total normal impulse
        assert friction[0] <= mu * cons[0]["normal_impulse"].sum() * (1 + 1e-5) + 1e-7


@pytest.mark.parametrize("shape", SHAPES)
def test_two_free_bodies_conserve_momentum(runtime, rng, shape):
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
        manifolds.append(make_manifold(2 * i, 2 * i + 1, n, points, np.zeros(k),
                                       friction=rng.uniform(0, 1), restitution=rng.uniform(0, 1)))
    bodies = make_bodies(np.array(positions), np.array(inv_mass), np.array(velocities),
                         np.array(angular))
    rig = shaped_rig(runtime, bodies, np.array(inv_inertia), shape, penetration="baumgarte",
                     warm_start=False)
    out, cons = rig.solve(np.array(manifolds), iterations=1000)

    def momenta(b):
        mass = 1 / b["inv_mass"]
        x, v, w = b["position"][:, :3], b["linear_velocity"][:, :3], b["angular_velocity"][:, :3]
        # orientation is identity, so the world inertia is the principal diagonal
        spin = w / np.array(inv_inertia)
        return (mass[:, None] * v).reshape(n_pairs, 2, 3).sum(1), \
            (spin + np.cross(x, mass[:, None] * v)).reshape(n_pairs, 2, 3).sum(1)

    p0, l0 = momenta(bodies.astype(bodies.dtype))
    p1, l1 = momenta(out)
    scale = np.abs(p0).max() + 1
    np.testing.assert_allclose(p1, p0, atol=1e-4 * scale)
    np.testing.assert_allclose(l1, l0, atol=1e-4 * (np.abs(l0).max() + 1))
    for i, c in enumerate(cons):
        a, b = c["body_a"], c["body_b"]
        if c["point_count"] > 2:
            continue  # redundant points (more than the rows' rank) converge slowly
        for k in range(c["point_count"]):
            ra, rb = c["r_a"][k, :3], c["r_b"][k, :3]
            dv = (out["linear_velocity"][b, :3] + np.cross(out["angular_velocity"][b, :3], rb)
                  - out["linear_velocity"][a, :3] - np.cross(out["angular_velocity"][a, :3], ra))
            target = c["velocity_target"][k]
            assert dv @ c["normal"][:3] >= target - 1e-2 * max(1.0, abs(target))


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("penetration", ["split", "baumgarte"])
def test_penetration_recovery(runtime, penetration, shape):
    """Resting box 5 cm deep: split moves it up beta (d - slop), Baumgarte sets v = beta/dt (d - slop)."""
    depth, dt = 0.05, 1 / 60
    bodies = make_bodies([[0, 0, 0], [0, 0.45, 0]], [0.0, 1.0])
    rig = shaped_rig(runtime, bodies, np.array([[0, 0, 0], [1, 1, 1.0]]), shape,
                     penetration=penetration, warm_start=False)
    m = make_manifold(0, 1, [0, 1, 0], SQUARE + [0, -0.05, 0], [-depth] * 4)
    out, _ = rig.solve(np.array([m]), dt=dt, iterations=30,
                       position_iterations=30 if penetration == "split" else 0)
    push = rig.setup.penetration_recovery * (depth - rig.setup.penetration_slop)
    if penetration == "split":
        assert out["position"][1, 1] - 0.45 == pytest.approx(push, rel=1e-3)
        assert np.abs(out["linear_velocity"][1, :3]).max() < 1e-5
    else:
        assert out["linear_velocity"][1, 1] == pytest.approx(push / dt, rel=1e-3)


@pytest.mark.parametrize("shape,work_group_size,batching", [
    ("gpu", 1, "components"), ("gpu", 32, "components"), ("gpu", 64, "cells"), ("gpu", 1, "cells"),
    ("gpu", 32, "slabs"), ("cpu", 1, "components"), ("cpu", 1, "cells"), ("cpu", 2, "cells"),
    ("cpu", 1, "slabs"), ("resident", 1, "single"), ("resident", 64, "single"),
    ("grid", 1, "global"), ("grid", 32, "global")])
def test_stacked_columns_end_resting(runtime, rng, shape, work_group_size, batching):
    """Columns of 6 boxes falling onto each other (one pile per column, batched):
    after the solve every box's vertical speed is ~0 (inelastic), in both batching modes
    (in cells mode each column spans several cells and colours) and both shapes (cpu with
    2 groups per work group: the leftover launch has one idle); PGS converges slowly on
    the lateral drift its point ordering creates, which friction removes (< 10% of v)."""
    speed = 1.0
    positions, manifolds = stacked_columns(17, 6, 3.0, lambda: [0.0] * 4)
    n = len(positions)
    velocities = np.tile([0, -speed, 0], (n, 1))
    velocities[0] = 0
    bodies = make_bodies(positions, np.r_[0.0, np.ones(n - 1)], velocities=velocities)
    rig = shaped_rig(runtime, bodies, np.r_[[[0, 0, 0]], np.full((n - 1, 3), 6.0)], shape,
                     warm_start=False, group_count=4, work_group_size=work_group_size,
                     batching=batching)
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
        rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
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


@pytest.mark.parametrize("variant,columns", [("resident", 7), ("grid", 7), ("grid", 48)])
def test_one_group_solves_match_the_plain_one_bit_for_bit(runtime, rng, variant, columns):
    """Over the same batches (single mode; global mode colours alike), the resident solve
    (velocities in local memory, one work group) and the grid solve (every compute unit,
    a barrier across them after each batch) do the plain one-work-group solve's
    arithmetic in the same order: equal results, velocities, push velocities and
    impulses alike, for a pile of columns with warm starting. The resident solve runs
    its position sweeps after the velocity sweeps, the other two in the same batch steps
    as the first velocity sweeps: equal bits say that neither set of rows sees the
    other's. The grid solve hands a small batch's push rows to other lanes than its
    velocity rows (solver.cl.mako: push_lane), a large one's not: 48 columns make batches
    larger than that threshold on a device of few compute units (PoCL: 32 x 2 lanes).
    Both solvers are exact builds (fast_math=False): -cl-fast-relaxed-math lets the
    compiler contract and reorder each kernel's arithmetic its own way (the H200 gave
    different bits for the resident kernel), so only exact builds promise equal bits;
    the grid solve warm-starts batch by batch as the others do (its summed warm start
    adds in another order: test_summed_warm_start_is_the_sum_of_the_impulses)."""
    positions, manifolds = stacked_columns(columns, 5, 1.2, lambda: rng.uniform(-0.01, 0.0, 4),
                                           side_contacts=True)
    n = len(positions)
    velocities = rng.uniform(-1, 1, (n, 3))
    velocities[0] = 0
    bodies = make_bodies(positions, np.r_[0.0, rng.uniform(0.5, 2, n - 1)],
                         velocities=velocities)
    inv_inertia = np.r_[[[0, 0, 0]], rng.uniform(2, 8, (n - 1, 3))]
    manifolds = np.array(manifolds)[rng.permutation(len(manifolds))]
    results = []
    for plain in (True, False):
        rig = shaped_rig(runtime, bodies, inv_inertia, "resident" if plain else variant,
                         work_group_size=32, fast_math=False,
                         warm_start_mode="batched" if variant == "grid" else None)
        if plain:
            rig.solver = ContactSolver(runtime, split_impulse=True, work_group_size=32,
                                       friction="point", shape="gpu",
                                       normal_solve=rig.solver.spec.values["normal_solve"],
                                       fast_math=False)
        results.append(rig.solve(manifolds, iterations=7, position_iterations=3))
    (bodies_g, cons_g), (bodies_r, cons_r) = results
    for field in ("linear_velocity", "angular_velocity", "position", "orientation"):
        assert np.array_equal(bodies_g[field], bodies_r[field]), field
    for field in ("normal_impulse", "tangent1_impulse", "tangent2_impulse", "push_impulse"):
        assert np.array_equal(cons_g[field], cons_r[field]), field
    assert np.abs(bodies_r["linear_velocity"][1:, :3]).max() > 0  # something was solved


def warm_started_velocities(bodies, inv_inertia, constraints):
    """float64 reference of a warm start with point friction: every constraint's
    accumulated impulses (normal and two tangents per point) applied at its points' lever
    arms, v_a -= p / m_a, w_a -= I_a^-1 (r_a x p), v_b += p / m_b, w_b += I_b^-1 (r_b x p):
    (linear, angular) velocities."""
    linear = bodies["linear_velocity"][:, :3].astype(float).copy()
    angular = bodies["angular_velocity"][:, :3].astype(float).copy()
    inv_mass = bodies["inv_mass"].astype(float)
    for c in constraints:
        a, b = int(c["body_a"]), int(c["body_b"])
        for k in range(int(c["point_count"])):
            p = (c["normal"][:3] * c["normal_impulse"][k] + c["tangent1"][:3]
                 * c["tangent1_impulse"][k] + c["tangent2"][:3] * c["tangent2_impulse"][k])
            p = p.astype(float)
            linear[a] -= p * inv_mass[a]
            angular[a] -= inv_inertia[a] @ np.cross(c["r_a"][k, :3].astype(float), p)
            linear[b] += p * inv_mass[b]
            angular[b] += inv_inertia[b] @ np.cross(c["r_b"][k, :3].astype(float), p)
    return linear, angular


@pytest.mark.parametrize("friction", ["point", "manifold"])
def test_summed_warm_start_is_the_sum_of_the_impulses(runtime, rng, friction):
    """The grid solve's summed warm start (64-bit fixed-point sums per body, then every body
    takes its sum) against the batched one (a batch step per colour) and, with point
    friction, the float64 sum of every constraint's impulses at its lever arms
    (warm_started_velocities): no sweep, only the warm start, over 6 columns of 5 boxes
    with side contacts (bodies in up to 6 manifolds) and random old impulses, odd body and
    constraint counts. The sums are integers, so two runs give the same bits whatever the
    order of the atomic additions."""
    positions, manifolds = stacked_columns(6, 5, 1.2, lambda: rng.uniform(-0.01, 0.0, 4),
                                           side_contacts=True)
    n = len(positions)
    velocities = rng.uniform(-1, 1, (n, 3))
    velocities[0] = 0
    bodies = make_bodies(positions, np.r_[0.0, rng.uniform(0.5, 2, n - 1)],
                         velocities=velocities, angular=np.r_[[[0, 0, 0]],
                                                              rng.uniform(-1, 1, (n - 1, 3))])
    inv_inertia = np.r_[[[0, 0, 0]], rng.uniform(2, 8, (n - 1, 3))]
    manifolds = np.array(manifolds)[rng.permutation(len(manifolds))]
    impulses = {name: rng.uniform(0.0 if name == "normal_impulse" else -0.3, 0.6,
                                  (len(manifolds), 4)).astype(np.float32)
                for name in ("normal_impulse", "tangent1_impulse", "tangent2_impulse")}
    results = []
    for mode in ("summed", "summed", "batched"):
        rig = shaped_rig(runtime, bodies, inv_inertia, "grid", friction=friction,
                         warm_start_mode=mode)
        assert rig.solver.spec.values["warm_start_mode"] == mode
        rig.constraints(manifolds)
        cons = rig.setup.constraints
        records = cons.get()
        for name, values in impulses.items():
            records[name][:len(manifolds)] = values
        cons.set(records)
        rig.batcher(cons, rig.setup.count, rig.bodies, rig.body_count, rig.capacity)
        rig.solver.solve(cons, rig.batcher, rig.bodies, rig.inertia, rig.body_count,
                         iterations=0, warm_start=True)
        results.append(rig.bodies.get())
        inertia = rig.inertia.get()["inv_inertia_world"][:, :, :3].astype(float)
        constraints = records[:len(manifolds)]
    first, again, batched = results
    assert first.tobytes() == again.tobytes()
    scale = np.abs(batched["linear_velocity"]).max()
    for field in ("linear_velocity", "angular_velocity"):
        np.testing.assert_allclose(first[field], batched[field], atol=2e-6 * scale)
        assert np.abs(first[field] - bodies[field]).max() > 0.1  # the impulses moved them
    if friction == "point":
        linear, angular = warm_started_velocities(bodies, inertia, constraints)
        np.testing.assert_allclose(first["linear_velocity"][:, :3], linear, atol=2e-6 * scale)
        np.testing.assert_allclose(first["angular_velocity"][:, :3], angular, atol=2e-6 * scale)


def test_summed_warm_start_needs_a_grid_solve_and_int64_atomics(runtime):
    """warm_start_mode='summed' is refused without grid (naming the rule) and defaults to
    it for a grid solve on a device with 64-bit atomics."""
    with pytest.raises(RbgenError, match="warm_start_mode='summed' needs grid=True"):
        ContactSolver(runtime, shape="gpu", warm_start_mode="summed")
    expected = "summed" if runtime.has_extension(INT64_ATOMICS) else "batched"
    assert ContactSolver(runtime, shape="gpu", grid=True).spec.values["warm_start_mode"] \
        == expected
    assert ContactSolver(runtime, shape="gpu").spec.values["warm_start_mode"] == "batched"


def test_resident_solve_refuses_what_does_not_fit(runtime):
    """A resident solver needs the gpu shape, one group (single batching) and a body
    count within its local memory; each refusal names what is wrong."""
    with pytest.raises(RbgenError, match="resident_bodies needs shape='gpu'"):
        ContactSolver(runtime, shape="cpu", resident_bodies=64)
    with pytest.raises(RbgenError, match="local memory"):
        ContactSolver(runtime, shape="gpu", resident_bodies=1 << 16)
    solver = ContactSolver(runtime, shape="gpu", resident_bodies=64)
    bodies = cl_array.to_device(runtime.queue, make_bodies([[0, 0, 0]], [1.0]))
    with pytest.raises(RbgenError, match="single"):
        solver.solve(None, ConstraintBatcher(runtime, group_count=3, mode="components",
                                             shape="gpu"), bodies, None, 1, iterations=1)
    single = ConstraintBatcher(runtime, mode="single", shape="gpu", max_bodies=128)
    with pytest.raises(RbgenError, match="100 bodies do not fit"):
        solver.solve(None, single, bodies, None, 100, iterations=1)


def test_grid_solve_refuses_what_it_cannot_run(runtime):
    """A grid solver needs the gpu shape, no resident bodies and one group of all
    constraints (single or global batching); each refusal names what is wrong."""
    with pytest.raises(RbgenError, match="grid needs shape='gpu'"):
        ContactSolver(runtime, shape="cpu", grid=True)
    with pytest.raises(RbgenError, match="grid needs shape='gpu' and no resident_bodies"):
        ContactSolver(runtime, shape="gpu", grid=True, resident_bodies=64)
    solver = ContactSolver(runtime, shape="gpu", grid=True)
    bodies = cl_array.to_device(runtime.queue, make_bodies([[0, 0, 0]], [1.0]))
    with pytest.raises(RbgenError, match="grid solve needs one group"):
        solver.solve(None, ConstraintBatcher(runtime, group_count=3, mode="cells",
                                             shape="gpu", cell_size=1.0), bodies, None, 1,
                     iterations=1)


@pytest.mark.parametrize("batching", ["components", "cells", "slabs", "single"])
def test_launch_schedule(runtime, batching):
    """components: the warm start and every sweep in ONE launch; cells: a warm-start sweep,
    then one launch per colour and velocity sweep, the position sweeps riding along."""
    batcher = ConstraintBatcher(runtime, group_count=3, mode=batching, cell_size=2.5,
                                shape="gpu")
    solver = ContactSolver(runtime, split_impulse=True)
    colours = len(batcher.launch_plan)
    one = batching in ("components", "single")
    for release_sweeps in (None, 2):  # (the release sweeps change scalars, not launches)
        launches, _ = solver._schedule(batcher.launch_plan, 10, 4, True, release_sweeps)
        assert len(launches) == (1 if one else colours * 11)
        assert len(solver._schedule(batcher.launch_plan, 3, 5, False, release_sweeps)[0]) == \
            (1 if one else colours * 5)
        assert solver._schedule(batcher.launch_plan, 0, 0, False, release_sweeps)[0] == []


def test_gpu_solver_refuses_unbatched_groups(runtime):
    """The gpu shape needs level-2 batches: a cpu-shaped batcher is refused, naming it."""
    batcher = ConstraintBatcher(runtime, group_count=3, shape="cpu")
    solver = ContactSolver(runtime, shape="gpu")
    bodies = cl_array.to_device(runtime.queue, make_bodies([[0, 0, 0]], [1.0]))
    with pytest.raises(RbgenError, match="shape"):
        solver.solve(None, batcher, bodies, None, 1, iterations=1)
    with pytest.raises(RbgenError, match="shape"):
        ContactSolver(runtime, shape="tpu")
