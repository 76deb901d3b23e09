"""Support chains: the launches against a float64 reference of the chains they solve, and
a World's stack with them against the closed form of a stack that does not sink."""

from __future__ import annotations

import numpy as np
import pyopencl.array as cla
import pytest

import rbgen
from rbgen import layouts, scenes
from rbgen.errors import RbgenError
from rbgen.pipeline.solvers.support import FLIP, NO_SUPPORT, ROUNDS, SLACK, SupportChains
from tests.conftest import SIZES

APART = 0x80000000
H, GRAVITY = 1 / 240, 9.81


def random_stack(rng, bodies, contacts):
    """``bodies`` bodies (random velocities, the first of every 7 static) at random heights,
    and ``contacts`` contacts between random pairs: between two dynamic bodies, most hold
    the lower one (by height) up (tangent1.w names it), with a normal within 45 degrees of
    up, 0-4 points with random lever arms, some apart (negative velocity targets); the
    others hold none. Heights make the supports a forest, as gravity does."""
    b = layouts.BODY.zeros(bodies)
    b["inv_mass"] = np.where(np.arange(bodies) % 7 == 0, 0.0, 1.0)
    b["linear_velocity"][:, :3] = rng.normal(0, 0.5, (bodies, 3))
    b["angular_velocity"][:, :3] = rng.normal(0, 0.5, (bodies, 3))
    height = rng.permutation(bodies)
    c = layouts.CONTACT_CONSTRAINT.zeros(contacts)
    if bodies == 0:
        return b, c
    pair = rng.integers(0, bodies, (contacts, 2))
    c["body_a"], c["body_b"] = pair[:, 0], pair[:, 1]
    dynamic = (b["inv_mass"][pair[:, 0]] > 0) & (b["inv_mass"][pair[:, 1]] > 0)
    holds = dynamic & (pair[:, 0] != pair[:, 1]) & (rng.random(contacts) < 0.8)
    a_lower = height[pair[:, 0]] < height[pair[:, 1]]
    c["tangent1"][:, 3] = np.where(
        holds, np.where(a_lower, layouts.SHOCK_HOLDS_A, layouts.SHOCK_HOLDS_B), 0
    )
    tilt = rng.normal(0, 0.3, (contacts, 3))
    up = np.array([0.0, 1.0, 0.0]) + tilt * [1, 0, 1]
    up /= np.linalg.norm(up, axis=1)[:, None]
    # (the normal points from A to B: up into B when A is the lower body)
    c["normal"][:, :3] = np.where(a_lower[:, None], up, -up)
    c["point_count"] = rng.integers(0, 5, contacts)
    c["r_a"][..., :3] = rng.uniform(-1, 1, (contacts, 4, 3))
    c["r_b"][..., :3] = rng.uniform(-1, 1, (contacts, 4, 3))
    c["velocity_target"] = np.where(
        rng.random((contacts, 4)) < 0.6, 0.0, -rng.uniform(0, 2, (contacts, 4))
    )
    return b, c


def reference(b, c, count, slack, flip=0, rounds=ROUNDS):
    """Float64: the velocities after the chains under gravity along -y
    (support_chains.cl.mako's rules: the lowest key of a body's offers, its index
    complemented within 30 bits by ``flip``; a link's approach,
    its centre's unless its fastest point's is slower by more than ``slack``, over up . n;
    gains along up, summed along chains of at most 2^rounds links, the ancestor beyond
    counting as 0)."""
    v = b["linear_velocity"][:, :3].astype(np.float64)
    w = b["angular_velocity"][:, :3].astype(np.float64)
    none = 2**32  # (above every key)
    key = np.full(len(b), none, np.int64)
    for i in range(count):
        holds = c["tangent1"][i, 3]
        if holds == layouts.SHOCK_HOLDS_NONE:
            continue
        upper = int(c["body_b"][i] if holds == layouts.SHOCK_HOLDS_A else c["body_a"][i])
        count_i = int(c["point_count"][i])
        targets = c["velocity_target"][i, :count_i].astype(np.float64)
        apart = count_i > 0 and max(targets) < 0
        key[upper] = min(key[upper], (APART if apart else 0) | (i ^ flip))
    links = {}
    for k in np.flatnonzero(key != none):
        i = int(key[k] & FLIP) ^ flip
        a_low = c["tangent1"][i, 3] == layouts.SHOCK_HOLDS_A
        lower = int(c["body_a"][i] if a_low else c["body_b"][i])
        n = c["normal"][i, :3].astype(np.float64) * (1 if a_low else -1)
        count_i = int(c["point_count"][i])
        targets = c["velocity_target"][i, :count_i].astype(np.float64)
        gap = max(-max(targets), 0.0) if count_i else 0.0
        centre = (v[lower] - v[k]) @ n - gap
        fastest = -np.inf
        for p in range(count_i):
            r_low = c["r_a" if a_low else "r_b"][i, p, :3].astype(np.float64)
            r_up = c["r_b" if a_low else "r_a"][i, p, :3].astype(np.float64)
            point = (v[lower] + np.cross(w[lower], r_low) - v[k] - np.cross(w[k], r_up)) @ n
            fastest = max(fastest, point - max(-targets[p], 0.0))
        e = centre if fastest >= centre - slack else fastest
        links[int(k)] = (lower, e, n)
    up = np.array([0.0, 1.0, 0.0])
    gain = np.zeros(len(b))
    for k in links:
        chain = [k]  # (k, its support's lower body, ...: at most 2^rounds links)
        while len(chain) < 2**rounds and links[chain[-1]][0] in links:
            chain.append(links[chain[-1]][0])
        x = 0.0  # (the gain beyond the chain: none, or beyond the rounds' reach)
        for body in reversed(chain):
            _, e, n = links[body]
            x = max(0.0, e / max(up @ n, 0.5) + x)
        gain[k] = x
    v += gain[:, None] * up
    return v


@pytest.mark.parametrize("substep", [0, 1])
@pytest.mark.parametrize("n", SIZES[:-1])
def test_support_chains_match_float64(runtime, rng, n, substep):
    """Bodies 0, 1, 31-33 and 1,000 (not multiples of the work group), three contacts a
    body; the count on the device is one less than the capacity, so the last contact
    offers nothing. An even substep's supports are a body's lowest contact indices, an
    odd one's the highest. The supports are cleared again after."""
    contacts = 3 * n
    b, c = random_stack(rng, n, max(contacts, 1))
    count = max(0, contacts - 1)
    chains = SupportChains(runtime)
    bodies_d = cla.to_device(runtime.queue, b)
    c_d = cla.to_device(runtime.queue, c)
    count_d = cla.to_device(runtime.queue, np.array([count], np.uint32))
    chains.propagate(c_d, count_d, contacts, bodies_d, n, (0.0, -GRAVITY, 0.0), H, substep)
    got = bodies_d.get()
    want = reference(b, c, count, SLACK * GRAVITY * H, FLIP if substep % 2 else 0)
    assert np.allclose(got["linear_velocity"][:, :3], want, rtol=1e-4, atol=1e-4)
    assert np.array_equal(got["angular_velocity"], b["angular_velocity"])
    assert np.array_equal(got["position"], b["position"])
    if n:
        assert (chains.supports.get()[:n] == NO_SUPPORT).all()


def test_a_chain_deeper_than_the_rounds_is_solved_from_its_lowest_links(runtime):
    """A column of 2^ROUNDS + 5 bodies, body j falling at j m/s: each approaches the one
    below at 1 m/s. Body j >= 2 stands on a chain of j - 1 links and gains 1 m/s a link
    its rounds reach: the closed form min(j - 1, 2^ROUNDS) m/s; body 1 rests on nothing
    dynamic and keeps its velocity."""
    n = 2**ROUNDS + 5
    b = layouts.BODY.zeros(n + 1)
    b["inv_mass"][1:] = 1.0
    b["linear_velocity"][1:, 1] = -np.arange(1, n + 1, dtype=float)  # (body k: -k m/s)
    c = layouts.CONTACT_CONSTRAINT.zeros(n - 1)
    c["body_a"], c["body_b"] = np.arange(1, n), np.arange(2, n + 1)
    c["tangent1"][:, 3] = layouts.SHOCK_HOLDS_A
    c["normal"][:, :3] = (0.0, 1.0, 0.0)
    c["point_count"] = 1
    chains = SupportChains(runtime)
    bodies_d = cla.to_device(runtime.queue, b)
    count_d = cla.to_device(runtime.queue, np.array([n - 1], np.uint32))
    chains.propagate(
        cla.to_device(runtime.queue, c), count_d, n - 1, bodies_d, n + 1, (0, -GRAVITY, 0), H
    )
    got = bodies_d.get()["linear_velocity"][:, 1]
    # body 1 (on nothing dynamic) keeps -1 m/s; body j >= 2 is a link of chain depth
    # j - 1 whose gain reaches j - 1 m/s, or 2^ROUNDS m/s where it reaches that far
    depth = np.arange(2, n + 1) - 1
    want = -np.arange(2, n + 1) + np.minimum(depth, 2**ROUNDS)
    assert got[1] == -1.0
    assert np.allclose(got[2:], want)


@pytest.mark.parametrize("device", [None, "shape:h200"])
def test_a_lattice_with_support_chains_sinks_less_while_its_loads_build(device):
    """A 3 x 30 x 3 BoxBox lattice built touching, at 2 substeps of 2 sweeps: its contacts
    are new, so its weight has not reached the ground when gravity first acts, and without
    the chains its top falls while the loads come down (about g t^2 / 2 over the time
    they take). With them a box's approach to its support is stopped each substep along
    the whole lattice: after 5 steps the top has sunk less than half as far, and by less
    than a free fall of one substep in every substep (g h^2 / 2 each, h = dt / 2). The
    CPU device's own plan (serial launches) and a persistent GPU plan (shape:h200) run the
    same chains."""
    h, substeps = 1 / 120, 10
    drops = {}
    for chains in (False, True):
        scene = scenes.boxbox_scene(3, 30, 3)
        world = rbgen.World(device, substeps=2, iterations=2, support_chains=chains)
        world.add_static(rbgen.Box(scene.ground_half_extents), position=scene.ground_position)
        ids = world.add_bodies(rbgen.Box(scene.half_extents), mass=1.0, positions=scene.positions)
        start = world.positions[ids]
        for _ in range(5):
            world.step(1 / 60)
        top = np.argmax(start[:, 1])
        drops[chains] = start[top, 1] - world.positions[ids][top, 1]
    assert drops[True] < 0.5 * drops[False]
    assert drops[True] < substeps * GRAVITY * h * h / 2


def test_support_chains_true_needs_the_pgs_solver():
    with pytest.raises(RbgenError, match="support_chains=True .* solver 'pgs'"):
        rbgen.World(solver="jacobi", support_chains=True)
    with pytest.raises(RbgenError, match="support_chains"):
        rbgen.World(support_chains="yes")


def test_support_chains_are_a_specialisation_of_their_own():
    """The chains decide kernels (a construction option): a World without them runs a
    solve with no chain phase in it, one with them on a persistent plan runs the
    phases in its persistent launch, and a World with joints plans none (the chains do
    not see joints), saying why."""

    def solve_sources(world):
        world.add_static(rbgen.Plane((0, 1, 0), 0.0))
        world.add_body(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, position=(0, 0.5, 0))
        world.step(1 / 60)
        return [
            spec.source
            for spec, _ in world.kernel_specs()
            if spec.path == "pipeline/solvers/pgs.cl.mako"
        ]

    plain = solve_sources(rbgen.World("shape:h200"))
    chained = solve_sources(rbgen.World("shape:h200", support_chains=True))
    assert plain and chained
    assert not any("propagate_supports" in s for s in plain)
    assert any("propagate_supports" in s for s in chained)
    world = rbgen.World(support_chains=True)
    assert world.plan.support_chains
    a = world.add_body(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, position=(0, 2, 0))
    world.add_joint(rbgen.BallJoint(a, None, (0, 3, 0)))
    world.step(1 / 60)
    assert not world.plan.support_chains
    assert "joints" in world.plan.reasons["support_chains"]
