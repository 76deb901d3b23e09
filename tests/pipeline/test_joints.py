"""The joint stage's kernel (prepare_joints) against a float64 numpy reference.

Random joints (every kind, some to the world, random poses, random impulses and break
impulses) over boundary sizes (0, 1, sizes around the work-group size): edge i is joint
i's (its bodies, its item RB_EDGE_JOINT << shift | i, B's anchor in the world as its
point, the previous edge's colour only when inheriting), and a joint breaks exactly when
its linear reaction over the step (the block's impulse with a slider's or distance
joint's axial impulse, times the substeps) exceeds its break impulse, its impulses then
cleared.
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array
import pytest

from rbgen import layouts
from rbgen.pipeline.joints import JointEdges


def rotate(q, v):
    t = 2.0 * np.cross(q[:, :3], v)
    return v + q[:, 3:] * t + np.cross(q[:, :3], t)


def random_joints(rng, n: int, bodies: int) -> np.ndarray:
    j = layouts.JOINT_CONSTRAINT.zeros(n)
    j["body_a"] = rng.integers(0, bodies, n)
    world = rng.random(n) < 0.3
    j["body_b"] = np.where(world, j["body_a"], rng.integers(0, bodies, n))
    j["kind"] = rng.integers(0, 5, n)
    j["flags"] = np.where(world, layouts.JOINT_WORLD, 0) | np.where(
        rng.random(n) < 0.2, layouts.JOINT_BROKEN, 0
    )
    j["anchor_b"][:, :3] = rng.normal(size=(n, 3))
    j["linear_impulse"][:, :3] = rng.normal(size=(n, 3))
    j["axial_impulse"][:, :2] = rng.normal(size=(n, 2))
    j["motor"][:, 2] = np.where(rng.random(n) < 0.3, np.finfo(np.float32).max, rng.random(n) * 6)
    return j


@pytest.mark.parametrize("n", [0, 1, 15, 16, 17, 33, 101])
@pytest.mark.parametrize("inherit", [False, True])
def test_prepare_joints_matches_reference(runtime, n, inherit):
    rng = np.random.default_rng(n + 7 * inherit)
    body_count = 9
    bodies = layouts.BODY.zeros(body_count)
    bodies["position"][:, :3] = rng.normal(size=(body_count, 3))
    q = rng.normal(size=(body_count, 4))
    bodies["orientation"] = q / np.linalg.norm(q, axis=1, keepdims=True)
    joints = random_joints(rng, n, body_count)
    # the previous step's edges: with ``inherit``, its first joint edges (a random count
    # of them) name the same joints, some with other bodies or items (not inherited)
    previous = layouts.CONSTRAINT_EDGE.zeros(max(1, n))
    previous["colour"] = rng.integers(0, 40, len(previous))
    previous_count = int(rng.integers(n // 2 + 1, n + 1)) if inherit and n else 0
    previous["item"] = (layouts.EDGE_JOINT << layouts.EDGE_KIND_SHIFT) | np.arange(len(previous))
    previous["body_a"][:n], previous["body_b"][:n] = joints["body_a"], joints["body_b"]
    other = rng.random(len(previous)) < 0.3
    previous["body_b"][other] += 1
    contact = rng.random(len(previous)) < 0.2
    previous["item"][contact] = np.arange(len(previous))[contact]  # (contact edges)
    substeps = 3.0
    queue = runtime.queue
    d_joints = cl_array.to_device(queue, joints if n else layouts.JOINT_CONSTRAINT.zeros(1))
    d_edges = cl_array.to_device(queue, layouts.CONSTRAINT_EDGE.zeros(max(1, n)))
    d_backup = cl_array.to_device(queue, layouts.JOINT_CONSTRAINT.zeros(max(1, n)))
    stage = JointEdges(runtime)
    stage(
        d_joints,
        d_backup,
        n,
        cl_array.to_device(queue, bodies),
        d_edges,
        cl_array.to_device(queue, previous),
        previous_count,
        substeps,
    )
    edges = runtime.read(d_edges)[:n]
    after = runtime.read(d_joints)[:n]
    # the backup holds each joint as the launch found it (before the break test)
    np.testing.assert_array_equal(runtime.read(d_backup)[:n], joints)

    on_world = (joints["flags"] & layouts.JOINT_WORLD) != 0
    b = joints["body_b"]
    point = np.where(
        on_world[:, None],
        joints["anchor_b"][:, :3],
        bodies["position"][b, :3]
        + rotate(bodies["orientation"][b].astype(float), joints["anchor_b"][:, :3]),
    )
    np.testing.assert_array_equal(edges["body_a"], joints["body_a"])
    np.testing.assert_array_equal(edges["body_b"], joints["body_b"])
    np.testing.assert_array_equal(
        edges["item"], (layouts.EDGE_JOINT << layouts.EDGE_KIND_SHIFT) | np.arange(n)
    )
    np.testing.assert_allclose(edges["point"][:, :3], point, atol=1e-5)
    same = (np.arange(n) < previous_count) & ~other[:n] & ~contact[:n]
    expected_colour = np.where(same, previous["colour"][:n], layouts.SOLVER_NONE)
    assert not inherit or n < 15 or 0 < same.sum() < n  # (both cases drawn)
    np.testing.assert_array_equal(edges["colour"], expected_colour)

    straight = (joints["kind"] == layouts.JOINT_SLIDER) | (joints["kind"] == layouts.JOINT_DISTANCE)
    axial = np.where(straight, joints["axial_impulse"][:, 0] - joints["axial_impulse"][:, 1], 0)
    reaction = np.sqrt((joints["linear_impulse"][:, :3].astype(float) ** 2).sum(1) + axial**2)
    was_broken = (joints["flags"] & layouts.JOINT_BROKEN) != 0
    breaks = ~was_broken & (reaction * substeps > joints["motor"][:, 2])
    # (well away from the threshold in float32: none of these random draws is within 1e-4)
    assert np.all(np.abs(reaction * substeps - joints["motor"][:, 2]) > 1e-4)
    broken_now = (after["flags"] & layouts.JOINT_BROKEN) != 0
    np.testing.assert_array_equal(broken_now, was_broken | breaks)
    np.testing.assert_array_equal(after["linear_impulse"][breaks], 0.0)
    np.testing.assert_array_equal(
        after["linear_impulse"][~breaks], joints["linear_impulse"][~breaks]
    )
