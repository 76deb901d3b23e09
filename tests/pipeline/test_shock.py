"""Shock propagation (the step setting shock_propagation): the last velocity sweep of each
substep holds the lower body of every contact that carries a load against gravity still.

The constraint setup names that body (ContactConstraint.tangent1.w, RB_SHOCK_HOLDS_*):
of two dynamic bodies whose normal is within 45 degrees of the vertical gravity defines,
the lower; none without gravity or with a static body. The shock sweep, exactly:

* never moves the held body: its velocities equal those after k ordinary sweeps;
* keeps what it adds to the normal impulse in the free body's share (its inverse mass
  over both bodies'): the impulse that would stop the same approach with both bodies
  free. In float64, from the free body's velocity change dv over the sweep: the kept
  total normal impulse grows by (dv . n) / (inverse mass of A + of B), and the
  friction pair's impulses, solved with both bodies' masses, are kept whole:
  (dv . t) / (the free body's inverse mass);
* is an ordinary sweep for a contact that holds nothing (a normal far from the vertical):
  the velocities equal those after k + 1 ordinary sweeps;
* leaves a manifold that bounces this step alone (the restitution came in the sweep
  before);
* and a one-point frictionless contact's upper body leaves it with no approach to the held
  body's translation (its row, with its mass of the held bodies, is exact; friction after
  it would turn the body): the held body's spin is not passed on, so the upper body is
  not matched to a turning surface (in an in-place walk up a column each layer passed a
  larger turn to the next).

The rigs use the sequential normal solve, whose one sweep does not finish a manifold of
several points, so the shock sweep has work left to do.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from rbgen import BallJoint, Box, Sphere, World, layouts
from rbgen.errors import RbgenError

from .test_constraints import ContactRig, make_bodies, make_manifold

GRAVITY = (0.0, -9.81, 0.0)
#: the solver variants, every one of which runs a shock sweep
SHOCK_VARIANTS = ["serial", "lanes", "one_group", "persistent"]


def holds_reference(normal, gravity, inv_mass_a, inv_mass_b) -> int:
    """The body a shock sweep holds still (layouts.SHOCK_HOLDS_*), in float64."""
    g = np.asarray(gravity, float)
    if not (g @ g > 0 and inv_mass_a > 0 and inv_mass_b > 0):
        return layouts.SHOCK_HOLDS_NONE
    up = -np.asarray(normal, float) @ g / np.linalg.norm(g)
    if up >= np.sqrt(0.5):
        return layouts.SHOCK_HOLDS_A
    return layouts.SHOCK_HOLDS_B if up <= -np.sqrt(0.5) else layouts.SHOCK_HOLDS_NONE


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


@pytest.mark.parametrize(
    "normal, gravity, static_a, expected",
    [
        ((0, 1, 0), GRAVITY, False, layouts.SHOCK_HOLDS_A),  # B on A
        ((0, -1, 0), GRAVITY, False, layouts.SHOCK_HOLDS_B),  # A on B
        (unit((0.5, 0.866, 0)), GRAVITY, False, layouts.SHOCK_HOLDS_A),  # 30 degrees
        (unit((0.766, 0.643, 0)), GRAVITY, False, layouts.SHOCK_HOLDS_NONE),  # 50 degrees
        ((1, 0, 0), GRAVITY, False, layouts.SHOCK_HOLDS_NONE),  # side by side
        ((0, 1, 0), GRAVITY, True, layouts.SHOCK_HOLDS_NONE),  # on a static body
        ((0, 1, 0), (0.0, 0.0, 0.0), False, layouts.SHOCK_HOLDS_NONE),  # no gravity
        ((-1, 0, 0), (9.81, 0.0, 0.0), False, layouts.SHOCK_HOLDS_A),  # gravity along +x
    ],
)
def test_setup_names_the_held_body(runtime, normal, gravity, static_a, expected):
    normal = unit(normal)
    bodies = make_bodies([[0, 0, 0], normal], [0.0 if static_a else 1.0, 0.5])
    rig = ContactRig(runtime, bodies, np.ones((2, 3)), warm_start=False)
    rig.setup.gravity = gravity
    point = 0.5 * normal
    c = rig.constraints(np.array([make_manifold(0, 1, normal, [point], [0.0])]))[0]
    assert c["tangent1"][3] == expected


def test_held_body_matches_float64_reference_on_random_contacts(runtime, rng):
    """Random normals (every direction), random gravity, some static bodies: tangent1.w
    against `holds_reference` (normals within 1e-4 of the 45-degree cone left out)."""
    from .test_constraints import random_scene

    bodies, inv_inertia_diag, manifolds = random_scene(rng, 301)
    rig = ContactRig(runtime, bodies, inv_inertia_diag, warm_start=False)
    gravity = rng.normal(size=3) * 9.81
    rig.setup.gravity = tuple(gravity)
    got = rig.constraints(manifolds)
    seen = set()
    for m, c in zip(manifolds, got):
        n = m["normal"][:3].astype(float)
        if abs(abs(n @ gravity) / np.linalg.norm(gravity) - np.sqrt(0.5)) < 1e-4:
            continue
        a, b = int(m["body_a"]), int(m["body_b"])
        expected = holds_reference(n, gravity, bodies["inv_mass"][a], bodies["inv_mass"][b])
        assert c["tangent1"][3] == expected, (a, b, n)
        seen.add(expected)
    assert seen == {layouts.SHOCK_HOLDS_NONE, layouts.SHOCK_HOLDS_A, layouts.SHOCK_HOLDS_B}


def random_pairs(rng, count, vertical, restitution=0.0, points=None, friction=0.6):
    """``count`` independent pairs of dynamic bodies in contact (5 m apart), B approaching
    A: normals within 30 degrees of +y (``vertical``) or within 20 degrees of the
    horizontal; 1-4 points (or ``points``) on a face; random masses and inertias."""
    positions, inv_mass, velocities, angular, inv_inertia, manifolds = [], [], [], [], [], []
    for i in range(count):
        if vertical:
            n = unit([rng.uniform(-0.5, 0.5), 1.0, rng.uniform(-0.5, 0.5)])
        else:
            n = unit([1.0, rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)])
        centre = np.array([5.0 * i, 0, 0])
        positions += [centre - 0.5 * n, centre + 0.5 * n]
        inv_mass += list(rng.uniform(0.2, 2.0, 2))
        velocities += [rng.normal(size=3), -n * 2 + rng.normal(size=3) * 0.3]
        angular += list(rng.normal(size=(2, 3)))
        inv_inertia += list(rng.uniform(0.3, 3.0, (2, 3)))
        t = unit(np.cross(n, [0, 0, 1]))
        s = np.cross(n, t)
        k = int(rng.integers(1, 5)) if points is None else points
        offsets = rng.uniform(-1, 1, (k, 2)) * 0.3
        face = centre + offsets[:, :1] * t + offsets[:, 1:] * s
        manifolds.append(
            make_manifold(
                2 * i, 2 * i + 1, n, face, np.zeros(k), friction=friction, restitution=restitution
            )
        )
    bodies = make_bodies(
        np.array(positions), np.array(inv_mass), np.array(velocities), np.array(angular)
    )
    return bodies, np.array(inv_inertia), np.array(manifolds)


def solve(runtime, variant, scene, iterations, shock, threshold=None, normal_solve="sequential"):
    """One call of the rig's solver over ``scene`` (no warm start, sequential normal rows
    unless ``normal_solve`` says otherwise, gravity set up for the held bodies): (bodies,
    constraints) after it."""
    bodies, inv_inertia, manifolds = scene
    rig = ContactRig(
        runtime,
        bodies,
        inv_inertia,
        warm_start=False,
        variant=variant,
        normal_solve=normal_solve,
    )
    rig.setup.gravity = GRAVITY
    if threshold is not None:
        rig.setup.restitution_threshold = threshold
    rig.constraints(manifolds)
    rig.batch()
    sweeps = SimpleNamespace(
        iterations=iterations,
        position_iterations=0,
        relaxation=1.0,
        warm_start=False,
        shock_propagation=shock,
    )
    rig.run(rig.solver, sweeps)
    return rig.bodies.get(), rig.setup.constraints.get()[: len(manifolds)]


IMPULSES = ("normal_impulse", "tangent1_impulse", "tangent2_impulse")


@pytest.mark.parametrize("variant", SHOCK_VARIANTS)
def test_shock_sweep_holds_the_lower_body_and_keeps_the_free_share(runtime, rng, variant):
    scene = random_pairs(rng, 37, vertical=True)
    before, c_before = solve(runtime, variant, scene, 1, shock=False)
    after, c_after = solve(runtime, variant, scene, 2, shock=True)
    assert (c_after["tangent1"][:, 3] == layouts.SHOCK_HOLDS_A).all()
    lower = np.arange(0, len(before), 2)
    for field in ("linear_velocity", "angular_velocity"):
        np.testing.assert_array_equal(after[field][lower], before[field][lower], err_msg=field)
    # the free (upper) body's change is the rows' impulses over its mass alone
    upper = lower + 1
    dv = (after["linear_velocity"][upper, :3] - before["linear_velocity"][upper, :3]).astype(float)
    assert np.abs(dv).max() > 1e-3  # (the shock sweep had work)
    inv_a = before["inv_mass"][lower].astype(float)
    inv_b = before["inv_mass"][upper].astype(float)
    n = c_after["normal"][:, :3].astype(float)
    t1 = c_after["tangent1"][:, :3].astype(float)
    t2 = c_after["tangent2"][:, :3].astype(float)

    def grew(field, slot=None):
        d = c_after[field].astype(float) - c_before[field].astype(float)
        return d.sum(axis=1) if slot is None else d[:, slot]

    scale = 1.0 + np.abs(c_after["normal_impulse"]).sum(axis=1)
    np.testing.assert_allclose(
        grew("normal_impulse") / scale,
        np.einsum("ij,ij->i", dv, n) / (inv_a + inv_b) / scale,
        atol=2e-5,
    )
    for field, t in (("tangent1_impulse", t1), ("tangent2_impulse", t2)):
        np.testing.assert_allclose(
            grew(field, 0) / scale, np.einsum("ij,ij->i", dv, t) / inv_b / scale, atol=2e-5
        )


@pytest.mark.parametrize("variant", SHOCK_VARIANTS)
def test_one_point_contact_leaves_no_approach(runtime, rng, variant):
    scene = random_pairs(rng, 23, vertical=True, points=1, friction=0.0)
    after, cons = solve(runtime, variant, scene, 2, shock=True)
    v, w = after["linear_velocity"][:, :3], after["angular_velocity"][:, :3]
    assert np.abs(w[0::2]).min() > 0  # (the held bodies turn)
    for c in cons:
        a, b = int(c["body_a"]), int(c["body_b"])
        rb, n = c["r_b"][0, :3], c["normal"][:3]
        approach = (v[b] + np.cross(w[b], rb) - v[a]) @ n
        assert approach >= -1e-4 * (1 + np.abs(v[b]).max())


def resting_faces(rng, count):
    """``count`` pairs: B resting face down on A across a square of 4 points centred under
    it, B falling onto it at 2 m/s with a little spin, A turning at up to 0.3 rad/s;
    frictionless, random masses and inertias."""
    positions, inv_mass, velocities, angular, inv_inertia, manifolds = [], [], [], [], [], []
    n = np.array([0.0, 1.0, 0.0])
    for i in range(count):
        centre = np.array([5.0 * i, 0, 0])
        positions += [centre - 0.5 * n, centre + 0.5 * n]
        inv_mass += list(rng.uniform(0.2, 2.0, 2))
        velocities += [rng.normal(size=3) * 0.1, [0.0, -2.0, 0.0] + rng.normal(size=3) * 0.05]
        angular += [rng.uniform(-0.3, 0.3, 3), rng.normal(size=3) * 0.05]
        inv_inertia += list(rng.uniform(0.3, 3.0, (2, 3)))
        half = rng.uniform(0.2, 0.5)
        face = centre + half * np.array([[1, 0, 1], [1, 0, -1], [-1, 0, -1], [-1, 0, 1]])
        manifolds.append(make_manifold(2 * i, 2 * i + 1, n, face, np.zeros(4), friction=0.0))
    bodies = make_bodies(
        np.array(positions), np.array(inv_mass), np.array(velocities), np.array(angular)
    )
    return bodies, np.array(inv_inertia), np.array(manifolds)


@pytest.mark.parametrize("variant", SHOCK_VARIANTS)
def test_face_block_leaves_no_approach_at_any_point(runtime, rng, variant):
    """With the block normal solve (on a CPU's serial form, the face block of the held
    bodies derived in the sweep instead of the cached one of both), a shock sweep leaves no
    point of a resting 4-point face approaching the held body's translation (a point it
    releases may separate): the block is exact where one pass of the rows is not (checked:
    the sequential solve leaves points approaching)."""
    scene = resting_faces(rng, 17)

    def closest_approach(normal_solve):
        after, cons = solve(runtime, variant, scene, 2, shock=True, normal_solve=normal_solve)
        v, w = after["linear_velocity"][:, :3], after["angular_velocity"][:, :3]
        speeds = [
            float((v[b] + np.cross(w[b], rb) - v[a]) @ c["normal"][:3])
            for c in cons
            for a, b in [(int(c["body_a"]), int(c["body_b"]))]
            for rb in c["r_b"][: c["point_count"], :3]
        ]
        return min(speeds)

    assert closest_approach("block") > -1e-4
    assert closest_approach("sequential") < -1e-3


@pytest.mark.parametrize("variant", SHOCK_VARIANTS)
def test_contact_that_holds_nothing_gets_an_ordinary_sweep(runtime, rng, variant):
    scene = random_pairs(rng, 29, vertical=False)
    shocked, cons = solve(runtime, variant, scene, 2, shock=True)
    assert (cons["tangent1"][:, 3] == layouts.SHOCK_HOLDS_NONE).all()
    ordinary, _ = solve(runtime, variant, scene, 2, shock=False)
    for field in ("linear_velocity", "angular_velocity"):
        np.testing.assert_array_equal(shocked[field], ordinary[field], err_msg=field)


@pytest.mark.parametrize("variant", SHOCK_VARIANTS)
def test_bouncing_manifold_is_left_to_the_sweep_before(runtime, rng, variant):
    """Restitution 0.8, approach above the threshold: the restitution goes with the sweep
    before the shock sweep, which leaves the bouncing manifolds alone."""
    scene = random_pairs(rng, 19, vertical=True, restitution=0.8)
    shocked, cons = solve(runtime, variant, scene, 2, shock=True, threshold=0.1)
    one_sweep, _ = solve(runtime, variant, scene, 1, shock=False, threshold=0.1)
    bouncing = [c for c in cons if (c["r_b"][: c["point_count"], 3] > 0).any()]
    assert len(bouncing) > len(cons) // 2  # (most approach faster than the threshold)
    pair_bodies = [int(i) for c in bouncing for i in (c["body_a"], c["body_b"])]
    for field in ("linear_velocity", "angular_velocity"):
        np.testing.assert_array_equal(
            shocked[field][pair_bodies], one_sweep[field][pair_bodies], err_msg=field
        )


# ------------------------------------------------------------------ the World


def lattice_world(runtime, nx, ny, nz, **options):
    from rbgen.scenes import boxbox_scene

    scene = boxbox_scene(nx, ny, nz)
    world = World(runtime, **options)
    world.add_static(Box(scene.ground_half_extents), position=scene.ground_position)
    ids = world.add_bodies(Box(scene.half_extents), mass=scene.mass, positions=scene.positions)
    return world, ids


def test_tall_lattice_comes_to_rest(runtime):
    """A 4 x 24 x 4 BoxBox lattice (24 layers) at 8 substeps of 3 + 1 sweeps, from its
    start: with the shock sweep its boxes' median vertical speed stays below 5 mm/s (at
    rest: a tenth of Box2D's sleep speed) from step 30 to step 90 and its top layer's
    median drop changes by less than 2 mm over those steps. Without it the same lattice at
    the same effort breathes: its median speed passes 1 cm/s (the scene exercises what
    the shock sweep stops)."""
    effort = {"substeps": 8, "iterations": 3, "position_iterations": 1}
    window = {}
    for shock in (True, False):
        world, ids = lattice_world(runtime, 4, 24, 4, shock_propagation=shock, **effort)
        start = world.positions[ids]
        top = start[:, 1] > start[:, 1].max() - 0.5
        drops, speeds = [], []
        for step in range(1, 91):
            world.step(1 / 60)
            if step >= 30:
                drops.append(float(np.median(start[top, 1] - world.positions[ids][top, 1])))
                speeds.append(float(np.median(np.abs(world.linear_velocities[ids][:, 1]))))
        assert np.isfinite(drops).all()
        window[shock] = (max(drops) - min(drops), max(speeds))
    swing, speed = window[True]
    assert speed < 0.005, window
    assert swing < 0.002, window
    assert window[False][1] > 0.01, window


def test_refused_where_no_shock_sweep_runs(runtime):
    """iterations 1 and the Jacobi solver refuse the setting at step(), naming it, and the
    World is as it was."""
    cases = [
        ({"iterations": 1}, "iterations >= 2"),
        ({"solver": "jacobi"}, "solver 'pgs'"),
    ]
    for options, words in cases:
        world = World(runtime, **options)
        world.add_static(Box((5, 1, 5)), position=(0, -1, 0))
        world.add_body(Box((0.5, 0.5, 0.5)), position=(0, 0.5, 0))
        world.shock_propagation = True
        with pytest.raises(RbgenError, match="shock_propagation") as error:
            world.step(1 / 60)
        assert words in str(error.value)
        assert world.steps == 0
        np.testing.assert_array_equal(world.positions[1], [0, 0.5, 0])
        world.shock_propagation = False
        world.step(1 / 60)  # (and steps again once the setting is undone)
        assert world.steps == 1


def test_default_runs_it_wherever_it_can(runtime):
    """The default (None) is the shock sweep wherever it can run: a PGS World at
    iterations >= 2 steps exactly as with shock_propagation=True, and one at iterations 1
    or with solver 'jacobi' steps exactly as with False (no refusal), and so does a World
    with joints (`shock_sweep`: jointed bodies are not held as a unit). The scene (a box on
    a box on the ground) has a held body, so the two settings differ on it."""

    def run(shock, joint=False, **options):
        world = World(runtime, shock_propagation=shock, **options)
        world.add_static(Box((5, 1, 5)), position=(0, -1, 0))
        world.add_body(Box((0.5, 0.5, 0.5)), position=(0, 0.49, 0))
        world.add_body(
            Box((0.5, 0.5, 0.5)),
            position=(0.1, 1.48, 0),
            orientation=(0, np.sin(0.05), 0, np.cos(0.05)),
        )
        if joint:  # (a pendulum beside the stack)
            ball = world.add_body(Sphere(0.1), position=(3, 1, 0))
            world.add_joint(BallJoint(ball, None, anchor=(3, 2, 0)))
        for _ in range(20):
            world.step(1 / 60)
        return world.positions.copy(), world.linear_velocities.copy()

    assert World(runtime).shock_propagation is None
    on, off = run(True, iterations=3), run(False, iterations=3)
    assert not np.array_equal(on[1], off[1])  # (the scene sees the sweep)
    for got, want in zip(run(None, iterations=3), on):
        np.testing.assert_array_equal(got, want)
    for options in (
        {"iterations": 1},
        {"solver": "jacobi", "iterations": 3},
        {"joint": True, "iterations": 3},
    ):
        for got, want in zip(run(None, **options), run(False, **options)):
            np.testing.assert_array_equal(got, want)
    on, off = run(True, joint=True, iterations=3), run(False, joint=True, iterations=3)
    assert not np.array_equal(on[1], off[1])  # (asked for, it runs with joints too)
