"""Property-based tests of the World (issue 30, item 5), with hypothesis.

Valid worlds: every shape kind (sphere, box, capsule, convex hull dynamic; plane and box
static), sizes 0.01-100 m, masses 1e-3-1e3 kg, positions up to +-1e4 m, speeds up to
100 m/s. Properties:

* a step never makes a NaN or an infinity, whatever the overlaps;
* nothing tunnels through static ground: a body that starts above a ground (a plane or
  a static box 10 cm to 10 m thick) at up to 100 m/s ends above its surface (continuous
  collision: speculative contacts for fast bodies, tests/test_world_continuous.py);
* energy does not grow without input: bodies with restitution up to 0.5 that start
  apart end a second later with at most their starting energy (kinetic, rotational and
  potential above the ground) plus, for each body, m g (v dt + margin), v its top speed
  (the split impulse may lift a body out of the penetration of one step's travel), plus
  1e-4 of it (float32 rounding); spin is kept below 100 m/s at the body's surface. An
  elastic bounce (restitution 1) holds it too, except a spinning body's off-centre impact
  with friction (the xfail below names it);
* invalid input to every public function raises `RbgenError` naming the argument, and
  leaves the World as it was.

CI runs a small fixed budget (derandomized: the same examples every run, no deadline);
``RBGEN_FUZZ=long`` runs fifty times as many random examples by hand.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import rbgen
from rbgen import RbgenError
from rbgen.errors import MemoryLimitError
from rbgen.settings import CONSTRUCTION_OPTIONS, STEP_SETTINGS
from rbgen.world import World

LONG = os.environ.get("RBGEN_FUZZ") == "long"
DT = 1 / 60
G = 9.81


def budget(examples: int, **more):
    """CI: ``examples``, the same ones every run; RBGEN_FUZZ=long: fifty times as many,
    random (hypothesis prints how to reproduce a failure)."""
    return settings(
        max_examples=examples * (50 if LONG else 1),
        deadline=None,
        derandomize=not LONG,
        database=None,
        print_blob=True,
        **more,
        suppress_health_check=[
            HealthCheck.too_slow,
            HealthCheck.data_too_large,
            HealthCheck.filter_too_much,
        ],
    )


# ----------------------------------------------------------------- valid worlds

sizes = st.floats(-2, 2).map(lambda e: 10.0**e)  # 0.01 .. 100 m
masses = st.floats(-3, 3).map(lambda e: 10.0**e)  # 1e-3 .. 1e3 kg
coordinates = st.floats(-1e4, 1e4, allow_nan=False)
#: hull point clouds: a few fixed ones (each hull size is a new scale of one), so that
#: the kernels compiled for them stay few
HULL_CLOUDS = [np.random.default_rng(seed).normal(size=(10, 3)) for seed in range(3)]


@st.composite
def unit_vectors(draw):
    v = np.array(draw(st.tuples(*[st.floats(-1, 1)] * 3)))
    assume(np.linalg.norm(v) > 1e-3)
    return v / np.linalg.norm(v)


@st.composite
def quaternions(draw):
    q = np.array(draw(st.tuples(*[st.floats(-1, 1)] * 4)))
    assume(np.linalg.norm(q) > 1e-3)
    return q / np.linalg.norm(q)


@st.composite
def velocities(draw, top):
    return draw(unit_vectors()) * draw(st.floats(0, top))


@st.composite
def shapes(draw, kind):
    """(shape, r): r is the smallest distance from the body's centre to its surface."""
    size = draw(sizes)
    if kind == "sphere":
        return rbgen.Sphere(size), size
    if kind == "box":
        half = size * np.array(draw(st.tuples(*[st.floats(0.2, 1)] * 3)))
        return rbgen.Box(tuple(half)), float(half.min())
    if kind == "capsule":
        radius = size * draw(st.floats(0.2, 1))
        return rbgen.Capsule(radius, size * draw(st.floats(0, 1))), radius
    cloud = HULL_CLOUDS[draw(st.integers(0, len(HULL_CLOUDS) - 1))]
    hull = rbgen.ConvexHull(cloud * size)
    return hull, inradius(hull)


def inradius(hull) -> float:
    """The distance from a hull's centre (its principal frame's origin) to its nearest
    face plane."""
    return float(np.min(hull.cooked().planes[:, 3]))


KINDS = ("sphere", "box", "capsule", "hull")


@st.composite
def bodies(draw, top_speed=100.0, spin=20.0, restitution=1.0):
    kind = draw(st.sampled_from(KINDS))
    shape, r = draw(shapes(kind))
    # (no point of the body faster than top_speed + 100 m/s from its spin)
    spin = min(spin, 100.0 / radius_of(shape))
    return {
        "kind": kind,
        "shape": shape,
        "r": r,
        "mass": draw(masses),
        "orientation": draw(quaternions()),
        "velocity": draw(velocities(top_speed)),
        "spin": draw(velocities(spin)),
        "friction": draw(st.floats(0, 1.5)),
        "restitution": draw(st.floats(0, restitution)),
    }


def add(world, body, position):
    return world.add_body(
        body["shape"],
        mass=body["mass"],
        position=position,
        orientation=body["orientation"],
        linear_velocity=body["velocity"],
        angular_velocity=body["spin"],
        friction=body["friction"],
        restitution=body["restitution"],
    )


def assert_finite(world):
    for field in ("positions", "orientations", "linear_velocities", "angular_velocities"):
        assert np.all(np.isfinite(getattr(world, field))), field
    np.testing.assert_allclose(np.linalg.norm(world.orientations, axis=1), 1, atol=1e-3)


@budget(6)
@given(data=st.data())
def test_random_worlds_stay_finite(runtime, data):
    """Every shape kind at once (so one set of kernels serves every example), anywhere up
    to 1e4 m, overlapping or not, at up to 100 m/s: every state stays finite."""
    world = World(runtime)
    world.add_static(rbgen.Plane(tuple(data.draw(unit_vectors())), data.draw(st.floats(-100, 100))))
    world.add_static(
        rbgen.Box((data.draw(sizes),) * 3),
        position=data.draw(st.tuples(coordinates, coordinates, coordinates)),
    )
    drawn = [data.draw(bodies()) for _ in range(data.draw(st.integers(4, 8)))]
    for kind, body in zip(KINDS, drawn):  # every kind at least once
        body["shape"], body["r"] = data.draw(shapes(kind))
    cluster = np.array(data.draw(st.tuples(coordinates, coordinates, coordinates)))
    for body in drawn:
        spread = data.draw(st.sampled_from([1.0, 10.0, 1e4]))
        offset = np.array(data.draw(st.tuples(*[st.floats(-1, 1)] * 3))) * spread
        add(world, body, np.clip(cluster + offset, -1e4, 1e4))
    for _ in range(30):
        world.step(DT)
    assert_finite(world)


# ----------------------------------------------------------------- tunnelling


@st.composite
def drops(draw, ground):
    """One body above a ground, falling at up to 100 m/s, anywhere within 1e4 m
    horizontally."""
    body = draw(bodies(top_speed=0.0, spin=5.0))
    x, z = draw(coordinates), draw(coordinates)
    gap = draw(st.floats(0, 2))
    half = draw(st.floats(-1.3, 0.7).map(lambda e: 10.0**e))  # ground box: 5 cm .. 5 m
    speed = draw(st.floats(0, 100.0))
    lateral = draw(st.tuples(st.floats(-5, 5), st.floats(-5, 5)))
    body["velocity"] = np.array([lateral[0], -speed, lateral[1]])
    return body, (x, z), gap, half


def landing_world(runtime, ground, body, where, gap, half):
    world = World(runtime)
    x, z = where
    extent = 20.0 * body["shape"].mass_properties(mass=1.0).inertia[0] ** 0.5 + 20.0
    if ground == "plane":
        world.add_static(rbgen.Plane((0, 1, 0), 0.0))
    else:
        world.add_static(rbgen.Box((extent, half, extent)), position=(x, -half, z))
    reach = radius_of(body["shape"])
    add(world, body, (x, reach + gap, z))
    return world


def radius_of(shape) -> float:
    from rbgen.bodies import bounding_radius

    return bounding_radius(shape)


@pytest.mark.parametrize("ground", ["plane", "box"])
@budget(8)
@given(data=st.data())
def test_nothing_tunnels_through_static_ground(runtime, ground, data):
    body, where, gap, half = data.draw(drops(ground))
    world = landing_world(runtime, ground, body, where, gap, half)
    for _ in range(60):
        world.step(DT)
    assert_finite(world)
    assert world.positions[1, 1] > 0.0, "the body's centre ended below the ground's surface"


@pytest.mark.parametrize(
    "shape",
    [rbgen.ConvexHull(HULL_CLOUDS[0] * 0.01), rbgen.Box((0.005, 0.003, 0.007))],
    ids=["hull", "box"],
)
def test_small_hull_rests_on_a_plane(runtime, shape):
    """A box or hull smaller than the contact margin (inradius 3.9 mm and 3 mm), dropped
    tilted onto a Plane, comes to rest on a face: its centre ends no lower than its
    inradius (the distance to its nearest face plane, so to any face it rests on) less
    the penetration slop the split impulse leaves, and at rest."""
    world = World(runtime)
    world.add_static(rbgen.Plane((0, 1, 0), 0.0))
    world.add_body(
        shape,
        mass=1.0,
        position=(0, radius_of(shape) + 0.01, 0),
        orientation=np.array([0.2, 0.1, 0.3, 0.9]) / np.linalg.norm([0.2, 0.1, 0.3, 0.9]),
        friction=0.5,
    )
    for _ in range(120):
        world.step(DT)
    assert world.positions[1, 1] >= shape.inner_radius() - world.settings.penetration_slop - 1e-5
    assert np.abs(world.linear_velocities[1]).max() < 1e-3


def test_fast_sphere_stops_at_a_thin_wall(runtime):
    """A 5 cm sphere at 100 m/s (1.7 m a step) shot at a 10 cm static wall from 1 m away
    ends before it (continuous collision; tests/test_world_continuous.py measures more)."""
    world = World(runtime, gravity=(0, 0, 0))
    world.add_static(rbgen.Box((5, 5, 0.05)), position=(0, 0, 0))
    world.add_body(rbgen.Sphere(0.05), position=(0, 0, -1.0), linear_velocity=(0, 0, 100))
    for _ in range(10):
        world.step(DT)
    assert world.positions[1, 2] < 0.0


# ----------------------------------------------------------------- energy


def energy(world, drawn, ground_y=0.0) -> float:
    """Kinetic (linear and rotational, in the body frame's principal inertia) and
    potential energy above the ground of the dynamic bodies (1..N)."""
    v, w = world.linear_velocities[1:].astype(float), world.angular_velocities[1:].astype(float)
    q, y = world.orientations[1:].astype(float), world.positions[1:, 1].astype(float)
    total = 0.0
    for k, body in enumerate(drawn):
        inertia = body["mass"] * np.asarray(body["shape"].mass_properties(mass=1.0).inertia)
        local = rotate(conjugate(q[k]), w[k])
        total += 0.5 * body["mass"] * v[k] @ v[k] + 0.5 * local @ (inertia * local)
        total += body["mass"] * G * (y[k] - ground_y)
    return total


def conjugate(q):
    return np.array([-q[0], -q[1], -q[2], q[3]])


def rotate(q, v):
    u, s = q[:3], q[3]
    return 2 * (u @ v) * u + (s * s - u @ u) * v + 2 * s * np.cross(u, v)


ENERGY_RESTITUTION = float(os.environ.get("RBGEN_FUZZ_RESTITUTION", 0.5))
#: float32 state over a second of steps: a relative rounding of the energy
FLOAT32_DRIFT = 1e-4


@budget(8)
@given(data=st.data())
def test_energy_does_not_grow_without_input(runtime, data):
    """Bodies start apart (bounding spheres separated by a gap), above a plane, and
    fall, collide and bounce for a second; see the module docstring for the bound."""
    world = World(runtime)
    world.add_static(rbgen.Plane((0, 1, 0), 0.0))
    drawn = [
        data.draw(
            bodies(
                top_speed=data.draw(st.sampled_from([2.0, 20.0, 100.0])),
                restitution=ENERGY_RESTITUTION,
            )
        )
        for _ in range(data.draw(st.integers(1, 5)))
    ]
    x = 0.0
    for body in drawn:
        reach = radius_of(body["shape"])
        x += reach
        add(world, body, (x, reach + data.draw(st.floats(0.05, 3)), 0.0))
        x += reach + data.draw(st.floats(0.05, 2))
    start = energy(world, drawn)
    top = max(np.linalg.norm(b["velocity"]) for b in drawn) + G * 1.0
    allowance = sum(b["mass"] * G * (top * DT + world.contact_margin) for b in drawn)
    for _ in range(60):
        world.step(DT)
    assert_finite(world)
    end = energy(world, drawn)
    assert end <= start * (1 + FLOAT32_DRIFT) + allowance, (start, end, allowance)


def elastic_drop(runtime, shape, mass, spin, friction, substeps=1):
    """(start energy, the highest energy over a second, the allowance): ``shape`` dropped
    from 1 m above a plane with restitution 1, spinning at ``spin`` rad/s about z: one
    bounce."""
    drawn = [{"shape": shape, "mass": mass}]
    world = World(runtime, substeps=substeps)
    world.add_static(rbgen.Plane((0, 1, 0), 0.0))
    world.add_body(
        shape,
        mass=mass,
        position=(0, radius_of(shape) + 1.0, 0),
        angular_velocity=(0, 0, spin),
        friction=friction,
        restitution=1.0,
    )
    start = energy(world, drawn)
    highest = start
    for _ in range(60):
        world.step(DT)
        highest = max(highest, energy(world, drawn))
    # a contact found late lets the body sink at most one step's travel at its impact
    # speed (the centre's fall, gravity's step, the spin at the surface) before the
    # bounce, and the split impulse lifts it back: m g v dt
    speed = np.sqrt(2 * G * (1.0 + radius_of(shape))) + G * DT + spin * radius_of(shape)
    return start, highest, mass * G * speed * DT


@pytest.mark.parametrize(
    "case",
    [
        ("sphere", rbgen.Sphere(0.5), 1.0, 0.0, 0.5),
        ("box", rbgen.Box((0.3, 0.3, 0.3)), 1.0, 0.0, 0.5),
        ("hull", rbgen.ConvexHull(HULL_CLOUDS[0]), 100.0, 0.0, 1.0),
    ],
    ids=lambda case: case[0],
)
@pytest.mark.parametrize("substeps", [1, 4, 8])
def test_elastic_bounce_keeps_the_energy_bound(runtime, case, substeps, request):
    """Restitution 1: a bounce returns the normal speed the body came in with, measured
    before the step's gravity (which prepare_bodies adds before the contacts are set
    up), so over the second of the drop and the bounce the energy never exceeds the start
    plus what lifting the body out of one step's travel adds (a target of e times the
    approach after gravity gained about twice that)."""
    name, shape, mass, spin, friction = case
    # (on GPU plans, at their default 2 + 1 sweeps with the shock sweep last, the bound
    # holds: on the H200 and in its shape; the mechanism was not isolated)
    if name == "hull" and substeps == 8 and not runtime.traits.is_gpu:
        request.applymarker(
            pytest.mark.xfail(
                strict=True,
                reason=(
                    "solver owner (restitution pass, contact_rows.cl.mako): the bounce is "
                    "each point's approach before the step (Box2D v3's relativeVelocity). "
                    "At 8 substeps the hull's two points both push in the first substep; "
                    "the rows turn it about the first, which lifts off, and the "
                    "restitution drives the second to the step's 7.19 m/s though the "
                    "turn already carries the body up: +482 J over 3,452 J against a "
                    "139 J allowance (the bounce in the row target gained +2,197 J here; "
                    "CPU plans, 3 + 1 sweeps a substep)"
                ),
            )
        )
    start, highest, allowance = elastic_drop(runtime, shape, mass, spin, friction, substeps)
    assert highest <= start * (1 + FLOAT32_DRIFT) + allowance, (start, highest, allowance)


@pytest.mark.parametrize("substeps", [1, 4, 8])
def test_elastic_bounce_of_a_spinning_hull_keeps_the_energy_bound(runtime, substeps):
    """A 100 kg hull (HULL_CLOUDS[0]) dropped 1 m onto a plane, spinning at 1 rad/s,
    restitution 1, friction 1, hits on one vertex. The rows stop the point's approach and
    its slip (the impact's compression), and only then does the restitution pass drive
    the normal row alone to the bounce (Box2D v3's order): a bounce in the rows' own
    target, solved with sticking friction, added about 267 J over the start of 3,487 J
    and left the bound (its allowance: lifting the hull out of one step's travel); with
    substeps, the restitution comes once, after the last substep's rows."""
    hull = rbgen.ConvexHull(HULL_CLOUDS[0])
    drawn = [{"shape": hull, "mass": 100.0}]
    world = World(runtime, substeps=substeps)
    world.add_static(rbgen.Plane((0, 1, 0), 0.0))
    world.add_body(
        hull,
        mass=100.0,
        position=(0, radius_of(hull) + 1.0, 0),
        angular_velocity=(0, 0, 1),
        friction=1.0,
        restitution=1.0,
    )
    start = energy(world, drawn)
    allowance = 100.0 * G * (G * 1.0 * DT + world.contact_margin)
    for _ in range(60):
        world.step(DT)
    assert energy(world, drawn) <= start * (1 + FLOAT32_DRIFT) + allowance


# ----------------------------------------------------------------- invalid input

FIELDS = ("positions", "orientations", "linear_velocities", "angular_velocities")


def snapshot(world):
    return [world.body_count, world.steps, repr(world.settings.as_dict())] + [
        getattr(world, f).copy() for f in FIELDS
    ]


def assert_unchanged(world, before):
    after = snapshot(world)
    assert after[:3] == before[:3]
    for a, b in zip(after[3:], before[3:]):
        assert np.array_equal(a, b)


junk = st.one_of(
    st.text(max_size=3),
    st.just(object()),
    st.just({"a": 1}),
    st.lists(st.text(max_size=2), min_size=1, max_size=3),
)
bad_float = st.sampled_from([np.nan, np.inf, -np.inf])


@st.composite
def bad_rows(draw, n, lanes, none_ok=True, zero_row_bad=False, any_rows=False, broadcast=False):
    """An (n, lanes) argument that is wrong: the wrong shape, a NaN or infinity, a
    ragged or non-numeric sequence (None only when ``none_ok`` is False). ``any_rows``:
    any row count is right (positions decide it); ``broadcast``: one row of ``lanes`` is
    right too (set_state)."""
    choice = draw(st.integers(0, 4 if zero_row_bad else 3))
    good = np.ones((n, lanes))
    if choice == 0:
        shapes = [(n, lanes - 1), (), (n, lanes, 1), (lanes + 1,)]
        shapes += [] if any_rows else [(n + 1, lanes)]
        shapes += [] if broadcast else [(lanes,)]
        return np.ones(draw(st.sampled_from(shapes)))
    if choice == 1:
        good[draw(st.integers(0, n - 1)), draw(st.integers(0, lanes - 1))] = draw(bad_float)
        return good
    if choice == 2:
        return draw(junk) if none_ok else draw(st.one_of(junk, st.none()))
    if choice == 3:
        return [list(range(lanes)), list(range(lanes - 1))] if n == 2 else [[1.0] * (lanes + 1)]
    good[draw(st.integers(0, n - 1))] = 0.0  # a zero quaternion
    return good


@st.composite
def bad_per_body(draw, n, lo, hi, lo_open):
    """A scalar-or-per-body argument out of its range, the wrong length, or not numbers."""
    choice = draw(st.integers(0, 3))
    if choice == 0:
        value = draw(
            st.one_of(
                bad_float,
                st.floats(max_value=lo, exclude_max=not lo_open).filter(
                    lambda v: v < lo or (lo_open and v == lo)
                ),
                *([st.floats(min_value=hi, exclude_min=True)] if hi else []),
            )
        )
        return value
    if choice == 1:
        values = np.full(n, (lo + (hi or lo + 2)) / 2 + 0.01)
        values[draw(st.integers(0, n - 1))] = draw(bad_float)
        return values
    if choice == 2:
        return np.ones(draw(st.sampled_from([n + 1, max(0, n - 1) or 3])))
    return draw(junk)


def base_world(runtime):
    world = World(runtime)
    world.add_static(rbgen.Box((20, 1, 20)), position=(0, -1, 0))
    world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), positions=[[0, 0.5, 0], [2, 0.5, 0]])
    world.step(DT)
    return world


BOX = rbgen.Box((0.5, 0.5, 0.5))


@st.composite
def bad_adds(draw):
    """(argument name, add_bodies keyword arguments with that one wrong)."""
    n = draw(st.integers(1, 3))
    kwargs = {"shape": BOX, "positions": np.ones((n, 3))}
    name = draw(
        st.sampled_from(
            [
                "shape",
                "positions",
                "orientations",
                "linear_velocities",
                "angular_velocities",
                "mass",
                "friction",
                "restitution",
            ]
        )
    )
    if name == "shape":
        kwargs["shape"] = draw(
            st.one_of(junk, st.integers(), st.none(), st.just(rbgen.Plane((0, 1, 0))))
        )
    elif name in ("positions", "linear_velocities", "angular_velocities"):
        kwargs[name] = draw(
            bad_rows(n, 3, none_ok=name != "positions", any_rows=name == "positions")
        )
    elif name == "orientations":
        kwargs[name] = draw(bad_rows(n, 4, zero_row_bad=True))
    elif name == "mass":
        kwargs[name] = draw(bad_per_body(n, 0.0, None, True))
    elif name == "friction":
        kwargs[name] = draw(bad_per_body(n, 0.0, None, False))
    else:
        kwargs[name] = draw(bad_per_body(n, 0.0, 1.0, False))
    return name, kwargs


@budget(60)
@given(case=bad_adds())
def test_bad_add_bodies_raises_naming_the_argument(runtime, case):
    name, kwargs = case
    world = base_world(runtime)
    before = snapshot(world)
    with pytest.raises(RbgenError, match=name):
        world.add_bodies(**kwargs)
    assert_unchanged(world, before)


@st.composite
def bad_singles(draw):
    """(function, argument name, keyword arguments) of add_static / add_body."""
    function = draw(st.sampled_from(["add_static", "add_body"]))
    names = ["position", "orientation", "friction", "restitution"] + (
        ["mass", "linear_velocity", "angular_velocity"] if function == "add_body" else []
    )
    name = draw(st.sampled_from(names))
    kwargs = {}
    if name in ("position", "linear_velocity", "angular_velocity", "orientation"):
        lanes = 4 if name == "orientation" else 3
        value = draw(bad_rows(1, lanes, zero_row_bad=name == "orientation", broadcast=True))
        kwargs[name] = (
            value[0]
            if isinstance(value, np.ndarray) and value.ndim == 2 and value.shape[0] == 1
            else value
        )
    elif name == "mass":
        kwargs[name] = draw(st.one_of(bad_float, st.floats(max_value=0.0), junk))
    elif name == "friction":
        kwargs[name] = draw(st.one_of(bad_float, st.floats(max_value=0.0, exclude_max=True), junk))
    else:
        kwargs[name] = draw(
            st.one_of(
                bad_float,
                st.floats(max_value=0.0, exclude_max=True),
                st.floats(min_value=1.0, exclude_min=True),
                junk,
            )
        )
    return function, name, kwargs


@budget(60)
@given(case=bad_singles())
def test_bad_add_static_and_add_body_raise_naming_the_argument(runtime, case):
    function, name, kwargs = case
    world = base_world(runtime)
    before = snapshot(world)
    with pytest.raises(RbgenError, match=name):
        getattr(world, function)(BOX, **kwargs)
    assert_unchanged(world, before)


bad_ids = st.one_of(
    st.integers(3, 10**9),
    st.integers(max_value=-1),
    st.floats(),
    st.just([0.5]),
    st.just([[1]]),
    st.just([True]),
    st.none(),
    junk,
    st.lists(st.integers(3, 100), min_size=1, max_size=3),
)


@st.composite
def bad_sets(draw):
    """(argument name, set_state keyword arguments with that one wrong)."""
    name = draw(st.sampled_from(["ids", *FIELDS]))
    kwargs = {"ids": [1, 2], "positions": np.ones((2, 3))}
    if name == "ids":
        kwargs["ids"] = draw(st.one_of(bad_ids, st.just([1, 1])))
        if kwargs["ids"] == [1, 1]:
            kwargs["positions"] = np.ones(3)
    elif name == "orientations":
        kwargs[name] = draw(bad_rows(2, 4, zero_row_bad=True, broadcast=True))
    else:
        kwargs[name] = draw(bad_rows(2, 3, broadcast=True))
    return name, kwargs


@budget(40)
@given(case=bad_sets())
def test_bad_set_state_raises_naming_the_argument(runtime, case):
    name, kwargs = case
    world = base_world(runtime)
    before = snapshot(world)
    with pytest.raises(RbgenError, match=name):
        world.set_state(**kwargs)
    assert_unchanged(world, before)


@budget(30)
@given(ids=bad_ids)
def test_bad_remove_bodies_raises_naming_ids(runtime, ids):
    world = base_world(runtime)
    before = snapshot(world)
    with pytest.raises(RbgenError, match="ids"):
        world.remove_bodies(ids)
    assert_unchanged(world, before)


@budget(30)
@given(
    case=st.one_of(
        st.tuples(
            st.just("dt"),
            st.one_of(bad_float, st.floats(max_value=0.0), junk, st.none(), st.booleans()),
        ),
        st.tuples(
            st.just("substeps"),
            st.one_of(st.integers(max_value=0), st.floats(), junk, st.none(), st.booleans()),
        ),
    )
)
def test_bad_step_raises_naming_the_argument(runtime, case):
    name, value = case
    world = base_world(runtime)
    before = snapshot(world)
    with pytest.raises(RbgenError, match=name):
        world.step(**{"dt": DT, name: value})
    assert_unchanged(world, before)


anything = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**12), 10**12),
    st.floats(),
    st.text(max_size=4),
    st.lists(st.floats(), max_size=4),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
    st.just(object()),
)


@budget(60)
@given(name=st.sampled_from([o.name for o in STEP_SETTINGS + CONSTRUCTION_OPTIONS]), value=anything)
def test_world_options_are_checked_naming_them(runtime, name, value):
    """Any value of any option: the World is built (the value is allowed), or the error
    names the option; a step setting set later is checked the same way and a refused one
    leaves the old value."""
    option = {o.name: o for o in STEP_SETTINGS + CONSTRUCTION_OPTIONS}[name]
    try:
        option.check(value)
        allowed = True
    except (ValueError, TypeError):
        allowed = False
    try:
        World(runtime, **{name: value})
        built = True
    except MemoryLimitError as error:
        assert name in str(error)
        return
    except RbgenError as error:
        assert name in str(error) or (name == "plan" and "plan parameter" in str(error))
        built = False
    assert built == allowed or name == "plan"
    if option in STEP_SETTINGS:
        world = base_world(runtime)
        before = snapshot(world)
        if allowed:
            setattr(world, name, value)
        else:
            with pytest.raises(RbgenError, match=name):
                setattr(world, name, value)
            assert_unchanged(world, before)


# ----------------------------------------------------------------- shapes

BAD_SHAPE_NUMBERS = [
    ("radius", lambda v: rbgen.Sphere(v), [np.nan, np.inf, 0.0, -1.0]),
    (
        "half_extents",
        lambda v: rbgen.Box(v),
        [(1, 1), (1, np.nan, 1), (1, -1, 1), (0, 1, 1), (np.inf, 1, 1), 1.0, None],
    ),
    ("radius", lambda v: rbgen.Capsule(v, 1.0), [np.nan, 0.0, -1.0, np.inf]),
    ("half_height", lambda v: rbgen.Capsule(1.0, v), [np.nan, -1.0, np.inf]),
    ("offset", lambda v: rbgen.Plane((0, 1, 0), v), [np.nan, np.inf]),
    ("normal", lambda v: rbgen.Plane(v), [(0, 0, 0), (np.nan, 1, 0), (1, 0)]),
    (
        "points",
        lambda v: rbgen.ConvexHull(v),
        [np.zeros((5, 3)), np.ones((2, 3)), np.full((5, 3), np.nan), np.eye(3), None],
    ),
]


@budget(30)
@given(
    case=st.sampled_from(BAD_SHAPE_NUMBERS).flatmap(
        lambda c: st.tuples(st.just(c[0]), st.just(c[1]), st.sampled_from(c[2]))
    )
)
def test_bad_shape_numbers_raise(case):
    """Shape constructors refuse out-of-range numbers and wrong shapes with RbgenError."""
    name, make, value = case
    with pytest.raises(RbgenError):
        make(value)


@budget(20)
@given(
    case=st.sampled_from(
        [
            ("radius", lambda v: rbgen.Sphere(v)),
            ("half_extents", lambda v: rbgen.Box(v)),
            ("radius", lambda v: rbgen.Capsule(v, 1.0)),
            ("half_height", lambda v: rbgen.Capsule(1.0, v)),
            ("normal", lambda v: rbgen.Plane(v)),
            ("offset", lambda v: rbgen.Plane((0, 1, 0), v)),
            ("points", lambda v: rbgen.ConvexHull(v)),
        ]
    ),
    value=st.one_of(st.text(min_size=1, max_size=3), st.none(), st.just([[1, "a"]])),
)
def test_non_numeric_shape_arguments_raise_rbgen_error(case, value):
    """A string, None or a ragged mixed sequence for any shape argument raises
    RbgenError naming that argument (not numpy's TypeError or ValueError)."""
    name, make = case
    with pytest.raises(RbgenError, match=name):
        make(value)
