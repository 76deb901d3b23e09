"""Many environments in one pipeline (issue 29, item 2): `rbgen.WorldBatch`.

No pair across environments (brute force over the step's AABBs, environments that
overlap in space, every broadphase); environment k's end state is bit for bit the same
with 1, 7 and 64 environments, whatever the others do (other initial states, forces,
resets); `reset` restores an environment exactly; bad input names the argument.
"""

from __future__ import annotations

import numpy as np
import pytest

import rbgen
from rbgen import RbgenError, layouts
from rbgen.world import World

DT = 1 / 60
BOX = rbgen.Box((0.5, 0.5, 0.5))
FIELDS = ("positions", "orientations", "linear_velocities", "angular_velocities")


def stack_scene(runtime, obstacle=False, **options):
    """One environment: a ground plane (shared), a stack of 3 boxes and 2 boxes
    dropped beside it, all within 3 m of the origin (environments overlap); with
    ``obstacle``, a small static box (shared too) where the dropped boxes land."""

    def build():
        world = World(runtime, **options)
        world.add_static(rbgen.Plane((0, 1, 0), 0.0))
        if obstacle:
            world.add_static(rbgen.Box((0.3, 0.3, 0.3)), position=(1.2, 0.0, 0.3))
        world.add_bodies(BOX, positions=[[0, 0.5, 0], [0, 1.5, 0], [0.1, 2.5, 0]])
        world.add_bodies(BOX, positions=[[1.2, 0.6, 0.3], [-1.0, 2.0, 0.5]], mass=2.0)
        return world

    return build


def env_state(k, bodies=5):
    """Environment k's own initial state (depends on k alone)."""
    rng = np.random.default_rng(1000 + k)
    base = np.array([[0, 0.5, 0], [0, 1.5, 0], [0.1, 2.5, 0], [1.2, 0.6, 0.3], [-1.0, 2.0, 0.5]])
    positions = base + rng.uniform(-0.05, 0.05, (bodies, 3)) + [0, 0.02, 0]
    return {
        "positions": positions,
        "linear_velocities": rng.uniform(-0.5, 0.5, (bodies, 3)),
    }


def env_forces(k, step, bodies=5):
    rng = np.random.default_rng(k * 7919 + step)
    return rng.uniform(-8, 8, (bodies, 3))


def run_batch(runtime, envs, steps=40, reset_others_at=None, obstacle=False, **options):
    """``envs`` environments, each from its own state, pushed by its own forces; with
    ``reset_others_at``, environments 7 and up are reset to their initial state then."""
    batch = rbgen.WorldBatch(envs, stack_scene(runtime, obstacle, **options))
    for k in range(envs):
        batch.reset([k], state={f: v[None] for f, v in env_state(k).items()})
    for s in range(steps):
        forces = np.stack([env_forces(k, s) for k in range(envs)])
        batch.apply_forces(forces)
        if s == reset_others_at and envs > 7:
            batch.reset(np.arange(7, envs))
        batch.step(DT)
    return batch


@pytest.mark.gpu_shape
@pytest.mark.parametrize("broadphase", ["grid", "sap", "sap3"])
def test_no_pair_across_environments(runtime, broadphase):
    """Brute force over the step's world AABBs: the broadphase's pairs are exactly the
    overlapping pairs within one environment or with the shared ground, though every
    environment occupies the same space (so most overlapping pairs are across). A small
    static box shared by all (kept out of the grid's displaced cells) meets them all."""
    batch = run_batch(runtime, 9, steps=3, obstacle=True, broadphase=broadphase)
    world = batch.world
    world.statistics()  # (checks the steps in flight)
    steps = world._steps
    bp = steps.broadphase.broadphase
    count = int(world.runtime.read(bp.count)[0])
    found = {tuple(p) for p in bp.buffer.host_pairs(count).tolist()}
    aabbs = world.runtime.read(steps.prepare.aabbs)[: world.body_count]
    lower, upper = aabbs["lower"][:, :3], aabbs["upper"][:, :3]
    env = world._bodies.envs
    static = world._bodies.host["inv_mass"] == 0
    expected, across = set(), 0
    n = world.body_count
    for a in range(n):
        for b in range(a + 1, n):
            if static[a] and static[b]:
                continue
            if not (np.all(lower[a] <= upper[b]) and np.all(lower[b] <= upper[a])):
                continue
            shared = env[a] == layouts.SHARED_STATIC or env[b] == layouts.SHARED_STATIC
            if env[a] == env[b] or shared:
                expected.add((a, b))
            else:
                across += 1
    assert across > len(expected) > 0  # the environments do overlap
    assert found == expected
    obstacle_pairs = {b for a, b in expected if a == 1}  # (body 1: the shared box)
    assert len({int(env[b]) for b in obstacle_pairs}) >= 5  # met by several environments
    manifolds = steps.constraints.constraints
    m = int(world.runtime.read(manifolds.count)[0])
    records = world.runtime.read(manifolds.constraints)[:m]
    ea, eb = env[records["body_a"]], env[records["body_b"]]
    assert m > 0 and np.all((ea == eb) | (ea == layouts.SHARED_STATIC))


def end_states(batch, envs):
    return {f: getattr(batch, f)[envs].copy() for f in FIELDS}


SOLVES = {
    "default": {},
    "global": {"batching": "global"},  # a GPU's default: persistent colouring and solve
    "global-fast": {"batching": "global", "fast_math": True},
    "cells": {"batching": "cells"},
    "jacobi": {"solver": "jacobi"},
    # buffers far too small: steps overflow, grow and are redone (forces replayed)
    "overflow": {"pair_capacity": 4, "manifold_capacity": 4},
}


@pytest.mark.parametrize("solve", sorted(SOLVES))
def test_an_environment_does_not_depend_on_the_others(runtime, solve, request):
    """Environments 0..6 end bit for bit the same with 1, 7 and 64 environments (each
    with its own initial state and forces; with 64, environments 7..63 are reset half
    way), and environment 0 the same as in a batch of one; for each solver and
    batching a device may run."""
    from rbgen.pipeline.batching import default_solve_form

    if solve == "cells" and default_solve_form(runtime.traits) == "lanes":
        request.applymarker(
            pytest.mark.xfail(
                strict=False,
                reason="spatial batching's lanes form (GPUs) colours a group's edges by "
                "Luby rounds on hashed edge indices, which shift with the environments "
                "before, and places edges by atomic counters: an environment's colours, "
                "so its solve order, may depend on N. Predicted, not yet seen: the "
                "H200's shape on PoCL ends bit for bit equal at N = 1, 7 and 64 (with "
                "1 and 132 compute units); strict once the H200 shows which",
            )
        )
    steps = 40
    options = SOLVES[solve]
    one = end_states(run_batch(runtime, 1, steps, **options), [0])
    seven = end_states(run_batch(runtime, 7, steps, **options), np.arange(7))
    many_batch = run_batch(runtime, 64, steps, reset_others_at=steps // 2, **options)
    many = end_states(many_batch, np.arange(7))
    for f in FIELDS:
        assert np.array_equal(one[f][0], seven[f][0]), f
        assert np.array_equal(seven[f], many[f]), f
    if solve == "overflow":
        assert many_batch.overflows >= 1
    # the environments did differ and did touch (a stack and falls)
    assert not np.array_equal(seven["positions"][0], seven["positions"][1])
    assert many_batch.statistics()["contacts"] > 64 * 3


@pytest.mark.gpu_shape
def test_reset_restores_exactly(runtime):
    """An environment reset to a state then run n steps ends bit for bit where it ended
    the first time from that state (no warm start kept), while the others go on."""
    batch = rbgen.WorldBatch(5, stack_scene(runtime))
    state = {f: v[None] for f, v in env_state(2).items()}

    def run(n):
        for s in range(n):
            batch.apply_forces(np.stack([env_forces(k, s) for k in range(5)]))
            batch.step(DT)

    batch.reset([2], state=state)
    run(25)
    first = end_states(batch, [2])
    others = batch.positions[[0, 1, 3, 4]].copy()
    run(10)
    batch.reset([2], state=state)
    run(25)
    again = end_states(batch, [2])
    for f in FIELDS:
        assert np.array_equal(first[f], again[f]), f
    assert not np.array_equal(batch.positions[[0, 1, 3, 4]], others)  # the others moved on
    batch.reset()  # every environment, to the initial state
    initial = stack_scene(runtime)().positions[1:]
    assert np.array_equal(batch.positions, np.broadcast_to(initial, (5, 5, 3)))


def test_observations_have_the_batch_shape(runtime):
    batch = rbgen.WorldBatch(3, stack_scene(runtime, gravity=(0, 0, 0)))
    assert batch.positions.shape == (3, 5, 3) and batch.orientations.shape == (3, 5, 4)
    assert batch.body_ids([2]).tolist() == [[11, 12, 13, 14, 15]]
    forces = np.zeros((3, 5, 3))
    forces[1, 4] = (0.0, 0.0, 6.0)
    batch.apply_forces(forces)
    batch.step(DT)
    v = batch.linear_velocities
    assert v[1, 4, 2] == pytest.approx(6.0 * DT / 2.0, rel=1e-6)  # mass 2
    v_others = np.delete(v.reshape(-1, 3), 1 * 5 + 4, axis=0)
    assert np.all(v_others == 0)
    with pytest.raises(RbgenError, match="read-only"):
        batch.positions[0, 0, 0] = 1.0


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda b: b.reset([3]), r"env_ids: environment 3 does not exist"),
        (lambda b: b.reset([-1]), r"env_ids: environment -1 does not exist"),
        (lambda b: b.reset([0.5]), r"env_ids must be an environment index"),
        (lambda b: b.reset([0], state={"positions": np.zeros((2, 5, 3))}), r"positions must"),
        (lambda b: b.reset([0], state={"speed": 1}), r"state: unknown field"),
        (
            lambda b: b.reset([1], state={"positions": np.full((5, 3), np.nan)}),
            r"positions: environment 1, body 0 has a NaN",
        ),
        (lambda b: b.reset([0], state=[np.zeros((5, 3))]), r"state must be a dict of fields"),
        (lambda b: b.apply_forces(np.zeros((3, 4, 3))), r"forces must have shape \(3, 5, 3\)"),
        (lambda b: b.apply_forces(np.zeros((1, 5, 3)), env_ids=[7]), r"environment 7"),
        (
            lambda b: b.apply_forces(np.zeros((3, 5, 3)), torques=np.full((3, 5, 3), np.inf)),
            r"torques: environment 0, body 0 has a NaN or infinite",
        ),
    ],
)
def test_bad_input_names_it_and_changes_nothing(runtime, call, match):
    batch = rbgen.WorldBatch(3, stack_scene(runtime))
    batch.step(DT)
    before = batch.positions.copy()
    with pytest.raises(RbgenError, match=match):
        call(batch)
    assert np.array_equal(batch.positions, before)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"envs": 0}, r"envs must be from 1"),
        ({"envs": 2.0}, r"envs must be a positive integer"),
        ({"envs": 2, "build": lambda: "a world"}, r"build must return an rbgen.World, got str"),
        ({"envs": 2, "build": None}, r"exactly one of build"),
    ],
)
def test_bad_construction(runtime, kwargs, match):
    kwargs = {"build": stack_scene(runtime), **kwargs}
    with pytest.raises(RbgenError, match=match):
        rbgen.WorldBatch(**kwargs)


def test_one_launch_sequence_whatever_the_batch_size(runtime):
    """A step of 1 and of 64 environments enqueues the same launches, no blocking read."""
    counters = []
    for envs in (1, 64):
        batch = rbgen.WorldBatch(envs, stack_scene(runtime))
        for _ in range(3):
            batch.step(DT)
        counters.append(dict(batch.last_step_counters))
    assert counters[0] == counters[1]
    assert counters[0]["blocking_reads"] == 0 and counters[0]["launches"] > 10


def test_hashed_colouring_priorities_would_break_independence(runtime):
    """Why a batch runs enough index-order colouring rounds (`ordered_rounds_for`): with
    none, global batching colours by hashed edge indices, which shift with the
    environments before, and the end states differ between 7 and 64 environments (the
    comparison above detects a change of solve order)."""
    options = {"batching": "global", "plan": {"ordered_rounds": 0}}
    seven = end_states(run_batch(runtime, 7, 40, **options), np.arange(7))
    many = end_states(run_batch(runtime, 64, 40, **options), np.arange(7))
    assert not all(np.array_equal(seven[f], many[f]) for f in FIELDS)


def test_batch_export_is_exactly_what_it_compiled(runtime, tmp_path):
    """`rbgen export` of a batch (a file whose build(device) returns a WorldBatch) writes
    every source the batch handed the compiler, with its build options, nothing more; the
    prepare kernel among them applies external forces."""
    import json

    from rbgen.cli import main
    from rbgen.codegen import SpecLog
    from rbgen.export import export_world

    compiled = SpecLog(runtime)
    with compiled:
        batch = rbgen.WorldBatch(3, stack_scene(runtime))
        batch.apply_forces(np.ones((3, 5, 3)))
        batch.step(DT)
        batch.reset([1])  # (on the device: the reset kernels)
        batch.step(DT)
        batch.statistics()
    manifest = export_world(batch, tmp_path / "direct")
    exported = {
        (e["template"], (tmp_path / "direct" / e["file"]).read_text()) for e in manifest["files"]
    }
    assert exported == {(spec.path, spec.source) for spec, _ in compiled.specs()}
    prepare = [e for e in manifest["files"] if e["template"] == "pipeline/prepare.cl.mako"]
    assert prepare and prepare[0]["params"]["external_forces"] is True
    assert any(e["template"] == "pipeline/reset.cl.mako" for e in manifest["files"])
    scene = tmp_path / "batch_scene.py"
    scene.write_text(
        "import rbgen\n"
        "def build(device):\n"
        "    def env():\n"
        "        w = rbgen.World(device)\n"
        "        w.add_static(rbgen.Plane((0, 1, 0), 0.0))\n"
        "        w.add_body(rbgen.Box((0.5, 0.5, 0.5)), position=(0, 0.5, 0))\n"
        "        return w\n"
        "    return rbgen.WorldBatch(4, env)\n"
    )
    device = runtime.device.name.strip()
    out = tmp_path / "cli"
    assert main(["export", "--out", str(out), "--world", str(scene), "--device", device]) == 0
    assert json.loads((out / "plan.json").read_text())["choices"]["solver"] == batch.plan.solver
    # a C++ schedule of a batch is refused by name (was an AttributeError)
    with pytest.raises(RbgenError, match="WorldBatch"):
        export_world(batch, tmp_path / "schedule", build=lambda: batch)


def test_a_reset_after_a_step_reads_nothing_back(runtime):
    """A reset between steps writes the environments on the device: no blocking read,
    in the reset or in the step after it; the other environments' bodies are untouched
    (bit for bit the same as a batch with no reset)."""
    runs = []
    for reset in (False, True):
        batch = rbgen.WorldBatch(4, stack_scene(runtime))
        for _ in range(10):
            batch.step(DT)
        before = batch.runtime.counters["blocking_reads"]
        if reset:
            batch.reset([1, 3])
        batch.step(DT)
        assert batch.runtime.counters["blocking_reads"] == before
        for _ in range(10):
            batch.step(DT)
        runs.append(batch.positions.copy())
    assert np.array_equal(runs[0][[0, 2]], runs[1][[0, 2]])
    assert not np.array_equal(runs[0][[1, 3]], runs[1][[1, 3]])
    with pytest.raises(RbgenError, match="listed twice"):
        batch.reset([2, 2])


def varied_scene(runtime, gravity=(0, -9.81, 0), extra=None):
    """Environment k's own World: the stack scene with masses 1 + k/4, friction
    0.3 + k/20 and a sideways shift of k cm (``extra``: environment given one more box)."""

    def build(k):
        world = World(runtime, gravity=gravity)
        world.add_static(rbgen.Plane((0, 1, 0), 0.0))
        base = np.array([[0, 0.5, 0], [0, 1.5, 0], [0.1, 2.5, 0], [1.2, 0.6, 0.3]])
        count = 5 if k == extra else 4
        positions = np.r_[base, [[-1.0, 2.0, 0.5]]][:count] + [0.01 * k, 0, 0]
        world.add_bodies(BOX, positions=positions, mass=1 + k / 4, friction=0.3 + k / 20)
        return world

    return build


def test_per_environment_bodies(runtime):
    """per_env=True: environment k is build(k)'s World (its masses and materials: a push
    F gives v = F dt / m_k), bit for bit the same with 7 and 13 environments; a build
    whose bodies do not match environment 0's is refused, naming it."""
    free = rbgen.WorldBatch(5, varied_scene(runtime, gravity=(0, 0, 0)), per_env=True)
    free.apply_forces(np.broadcast_to([0.0, 0.0, 3.0], (5, 4, 3)))
    free.step(DT)
    masses = 1 + np.arange(5) / 4
    np.testing.assert_allclose(free.linear_velocities[:, 0, 2], 3.0 * DT / masses, rtol=1e-6)
    ends = []
    for envs in (7, 13):
        batch = rbgen.WorldBatch(envs, varied_scene(runtime), per_env=True)
        for s in range(30):
            batch.apply_forces(np.stack([env_forces(k, s, 4) for k in range(envs)]))
            batch.step(DT)
        ends.append(end_states(batch, np.arange(7)))
    for f in FIELDS:
        assert np.array_equal(ends[0][f], ends[1][f]), f
    batch.reset([3])
    assert np.array_equal(batch.positions[3], varied_scene(runtime)(3).positions[1:])
    with pytest.raises(RbgenError, match=r"build\(2\): every environment needs 4 dynamic"):
        rbgen.WorldBatch(4, varied_scene(runtime, extra=2), per_env=True)
    with pytest.raises(RbgenError, match=r"per_env=True needs build"):
        rbgen.WorldBatch(4, template=varied_scene(runtime)(0), per_env=True)


def chain_scene(runtime, **options):
    """One jointed environment: a ground plane (shared), a static post (shared), a
    6-link capsule chain hung from the post by a hinge, its links on ball joints (the
    last with a break impulse), falling onto a box below it."""

    def build():
        world = World(runtime, substeps=2, **options)
        world.add_static(rbgen.Plane((0, 1, 0), 0.0))
        post = world.add_static(rbgen.Box((0.1, 0.1, 0.1)), position=(0.0, 1.6, 0.0))
        box = world.add_body(BOX, position=(0.4, 0.5, 0.0))
        centres = np.array([[0.15 + 0.1 * i, 1.6, 0.0] for i in range(6)])
        links = world.add_bodies(rbgen.Capsule(0.02, 0.02), mass=0.5, positions=centres)
        world.add_joint(rbgen.HingeJoint(int(links[0]), post, anchor=(0.1, 1.6, 0), axis=(0, 0, 1)))
        world.add_joints(
            rbgen.BallJoint,
            a=links[1:],
            b=links[:-1],
            anchor=centres[1:] - (0.05, 0, 0),
            break_impulse=[None] * 4 + [0.05],
        )
        assert box == 2
        return world

    return build


def run_chains(runtime, envs, steps=40, **options):
    batch = rbgen.WorldBatch(envs, chain_scene(runtime, **options))
    for k in range(envs):
        rng = np.random.default_rng(500 + k)
        batch.reset([k], state={"linear_velocities": rng.uniform(-1, 1, (1, 7, 3))})
    for s in range(steps):
        if s == steps // 2 and envs > 1:
            batch.reset(np.arange(1, envs, 2))  # the odd environments start again
        batch.step(DT)
    return batch


@pytest.mark.gpu_shape
@pytest.mark.parametrize("solve", ["default", "overflow"])
def test_jointed_environments_do_not_depend_on_the_others(runtime, solve):
    """The template's joints are copied into every environment (bodies renumbered, the
    hinge to the shared post kept on it): environment 0 ends bit for bit the same alone
    and among 7 (each with its own initial velocities, the odd ones reset half way), its
    joints' impulses and broken flags too; environment 1 (reset) ends as it does
    when run from the reset."""
    options = SOLVES["overflow"] if solve == "overflow" else {}
    one = run_chains(runtime, 1, **options)
    seven = run_chains(runtime, 7, **options)
    assert seven.world.joint_count == 7 * 6 and seven.joints == 6
    for f in FIELDS:
        assert np.array_equal(getattr(one, f)[0], getattr(seven, f)[0]), f
    assert np.array_equal(one.joint_impulses[0], seven.joint_impulses[0])
    assert np.array_equal(one.joints_broken[0], seven.joints_broken[0])
    # the joints hold the chain to the post: the first link's anchor stays at the post
    first = seven.world._joints.host[seven.joint_ids([3])[0, 0]]
    assert first["body_b"] == 1 and first["body_a"] == 2 + 3 * 7 + 1
    assert np.all(np.abs(seven.positions[:, 1, 0] - 0.15) < 0.2)
    assert np.all(np.abs(seven.joint_impulses[:, :5]).sum(axis=2) > 0)
    # environments differ (their velocities) and touched the box
    assert not np.array_equal(seven.positions[0], seven.positions[2])
    assert seven.statistics()["contacts"] > 7
    if solve == "overflow":
        assert seven.overflows >= 1
    # a reset environment ends as a batch of one run from its reset (at step 20, 20 more)
    again = rbgen.WorldBatch(1, chain_scene(runtime, **options))
    for _ in range(20):
        again.step(DT)
    for f in FIELDS:
        assert np.array_equal(getattr(again, f)[0], getattr(seven, f)[1]), f
    assert np.array_equal(again.joint_impulses[0], seven.joint_impulses[1])


def test_per_env_builds_with_joints_are_refused(runtime):
    build = chain_scene(runtime)
    with pytest.raises(RbgenError, match=r"build\(1\) has 6 joints"):
        rbgen.WorldBatch(2, lambda k: build(), per_env=True)


def test_a_world_whose_bodies_changed_is_refused_and_left_as_it_was(runtime):
    """Bodies removed from (or added to) batch.world break the layout ``shared + k *
    bodies + j``: reset, apply_forces and the observations raise RbgenError naming the
    body counts, and the world's bodies are as they were (a reset used to write the
    environments' records over the wrong bodies, then fail with an IndexError)."""
    batch = rbgen.WorldBatch(3, stack_scene(runtime))
    batch.step(DT)
    batch.world.remove_bodies([1])
    before = [batch.world.positions.copy(), batch.world.linear_velocities.copy()]
    match = r"has 15 bodies, not the 16 it laid out"
    with pytest.raises(RbgenError, match=match):
        batch.reset([2])
    with pytest.raises(RbgenError, match=match):
        batch.apply_forces(np.zeros((3, 5, 3)))
    with pytest.raises(RbgenError, match=match):
        _ = batch.positions
    assert np.array_equal(batch.world.positions, before[0])
    assert np.array_equal(batch.world.linear_velocities, before[1])


def test_a_reset_after_joints_changed_is_refused_before_any_change(runtime):
    """Joints removed from batch.world: reset raises RbgenError naming the joint counts
    before it touches a body (it used to reset the bodies first, then raise)."""
    batch = rbgen.WorldBatch(3, chain_scene(runtime))
    for _ in range(3):
        batch.step(DT)
    batch.world.remove_joints([0])
    before = [batch.positions.copy(), batch.linear_velocities.copy()]
    with pytest.raises(RbgenError, match=r"has 17 joints, not 6 a environment \(18\)"):
        batch.reset([1])
    assert np.array_equal(batch.positions, before[0])
    assert np.array_equal(batch.linear_velocities, before[1])


def _reset_joints_one_env_at_a_time(batch, envs):
    """The reset of the joints as it was: one device write per environment (the
    reference the run-coalesced writes must equal bit for bit)."""
    import pyopencl as cl

    from rbgen.device import buffer_of

    store = batch.world._joints
    queue, size = batch.world.runtime.queue, store.device.dtype.itemsize
    for k in envs:
        records = np.ascontiguousarray(batch._joint_records[k])
        cl.enqueue_copy(
            queue, buffer_of(store.device), records, dst_offset=int(k) * batch.joints * size
        )
    store.device_newer = True


def test_env_runs():
    from rbgen.batch import env_runs

    assert env_runs([3, 0, 1, 5, 4]) == [(0, 2), (3, 6)]
    assert env_runs(np.arange(4096)) == [(0, 4096)]
    assert env_runs([7]) == [(7, 8)]
    assert env_runs(np.arange(0, 10, 2)) == [(0, 1), (2, 3), (4, 5), (6, 7), (8, 9)]
    assert env_runs([]) == []


@pytest.mark.parametrize("envs", [None, [5, 1, 2, 3, 7], [6]])
def test_a_joint_reset_writes_each_run_of_environments_once(runtime, monkeypatch, envs):
    """After steps (the device's joint records hold impulses, broken flags), a reset of
    ``envs`` writes their joints in one device write per run of consecutive environments
    (all 8: one write; [1, 2, 3, 5, 7]: three), and the device records, and the state
    after more steps, are bit for bit those of the old write per environment."""
    import pyopencl as cl

    copies = []
    enqueue_copy = cl.enqueue_copy

    def counted(queue, dst, src, **kwargs):
        if dst.int_ptr == joints.int_ptr:  # (only the writes into the joint records)
            copies.append(kwargs.get("dst_offset"))
        return enqueue_copy(queue, dst, src, **kwargs)

    results = []
    for coalesced in (True, False):
        batch = run_chains(runtime, 8, steps=12)
        _ = batch.positions  # (the steps are checked)
        store = batch.world._joints
        assert not store.dirty and store.device is not None  # (the device write path)
        if coalesced:
            joints = store.device.base_data
            monkeypatch.setattr(cl, "enqueue_copy", counted)
            batch.reset(envs)
            monkeypatch.setattr(cl, "enqueue_copy", enqueue_copy)
        else:
            monkeypatch.setattr(
                batch, "_reset_joints", lambda e, b=batch: _reset_joints_one_env_at_a_time(b, e)
            )
            batch.reset(envs)
        batch.world.runtime.queue.finish()
        device = store.device.get()
        for _ in range(5):
            batch.step(DT)
        results.append((device, batch.positions.copy(), batch.joint_impulses.copy()))
    size = layouts.JOINT_CONSTRAINT.itemsize * 6
    expected = {None: [0], (5, 1, 2, 3, 7): [1 * size, 5 * size, 7 * size], (6,): [6 * size]}
    assert copies == expected[None if envs is None else tuple(envs)]
    (device, positions, impulses), (device0, positions0, impulses0) = results
    assert device.tobytes() == device0.tobytes()
    assert np.array_equal(positions, positions0) and np.array_equal(impulses, impulses0)
    # the reset environments' joints are the template's again, the others are not
    reset = np.arange(8) if envs is None else np.array(envs)
    records = device.reshape(8, 6)
    assert records[reset].tobytes() == batch._joint_records[reset].tobytes()
    if envs is not None:
        kept = np.setdiff1d(np.arange(8), reset)
        assert records[kept].tobytes() != batch._joint_records[kept].tobytes()
