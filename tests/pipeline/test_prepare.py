"""prepare_bodies: world inverse inertia R diag(I^-1) R^T and, fused in, gravity v += g dt
and world AABBs.

Closed forms checked against a float64 numpy reference, for body counts that
are not multiples of the work-group size (and zero bodies)."""

from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array
import pytest

from rbgen import layouts
from rbgen.errors import RbgenError
from rbgen.pipeline.prepare import BodyPreparation, inertia_records


def _rotation(q):
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _random_bodies(rng, n):
    bodies = layouts.BODY.zeros(n)
    q = rng.standard_normal((n, 4))
    bodies["orientation"] = q / np.linalg.norm(q, axis=1, keepdims=True)
    bodies["linear_velocity"][:, :3] = rng.standard_normal((n, 3))
    bodies["angular_velocity"][:, :3] = rng.standard_normal((n, 3))
    bodies["inv_mass"] = np.where(rng.random(n) < 0.3, 0.0, rng.uniform(0.5, 2.0, n))
    diag = rng.uniform(0.2, 3.0, (n, 3)) * (bodies["inv_mass"] > 0)[:, None]
    return bodies, diag


@pytest.mark.parametrize("n", [0, 1, 67, 200])
def test_gravity_and_world_inertia(runtime, rng, n):
    """Dynamic bodies gain g dt; static ones keep their velocity; angular velocities
    are untouched without the gyroscopic term; every tensor is R diag R^T."""
    bodies, diag = _random_bodies(rng, max(n, 1))
    queue = runtime.queue
    d_bodies = cl_array.to_device(queue, bodies)
    d_inertia = cl_array.to_device(queue, inertia_records(diag))
    gravity, dt = rng.uniform(-10, 10, 3), 1 / 60
    prepare = BodyPreparation(runtime, gyroscopic=False, gravity=True)
    prepare(d_bodies, d_inertia, n, dt, gravity)
    out, inertia = d_bodies.get(), d_inertia.get()
    dynamic = bodies["inv_mass"][:n] > 0
    expected = bodies["linear_velocity"][:n, :3].astype(np.float64)
    expected[dynamic] += np.float32(dt) * gravity.astype(np.float32)
    np.testing.assert_allclose(out["linear_velocity"][:n, :3], expected, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(out["angular_velocity"], bodies["angular_velocity"])
    for i in range(n):
        rot = _rotation(bodies["orientation"][i].astype(np.float64))
        tensor = rot @ np.diag(diag[i]) @ rot.T
        np.testing.assert_allclose(inertia["inv_inertia_world"][i, :, :3], tensor, atol=1e-5)
    if n == 0:
        np.testing.assert_array_equal(out, bodies)  # nothing launched


def test_gravity_argument_must_match_the_build(runtime):
    bodies = cl_array.to_device(runtime.queue, layouts.BODY.zeros(1))
    inertia = cl_array.to_device(runtime.queue, inertia_records(np.ones((1, 3))))
    with pytest.raises(RbgenError, match="gravity"):
        BodyPreparation(runtime, gravity=True)(bodies, inertia, 1, 0.1)
    with pytest.raises(RbgenError, match="gravity"):
        BodyPreparation(runtime, gravity=False)(bodies, inertia, 1, 0.1, (0, -9.81, 0))


@pytest.mark.parametrize("work_group_size", [None, 128])  # the device's default, the GPU one
@pytest.mark.parametrize("n", [0, 1, 67, 1000])
def test_fused_world_aabbs(runtime, rng, n, work_group_size):
    """Built with shape types, prepare_bodies also writes every body's world AABB: each
    holds the float64 bounds of the rotated shape (grown by the margin, within 1e-5), and
    velocities and inertia tensors are those of the pass without AABBs, bit for bit; built
    with backup too (the World's build), it first copies every body as it was."""
    from rbgen.shapes import ShapeTable
    from tests.pipeline.test_aabbs import expected_bounds, make_shapes

    table = ShapeTable()
    shape_list = make_shapes(rng)
    ids = np.asarray([table.add(s) for s in shape_list])
    bodies, diag = _random_bodies(rng, max(n, 1))
    which = rng.integers(0, len(shape_list), len(bodies))
    bodies["shape"] = ids[which]
    bodies["position"][:, :3] = rng.uniform(-50, 50, (len(bodies), 3))
    queue = runtime.queue
    shapes, vertices = table.pack()
    margin, dt, gravity = 0.05, 1 / 60, (0.0, -9.81, 0.0)
    outputs = []
    for shape_types in ((), table.type_names()):
        d_bodies = cl_array.to_device(queue, bodies)
        d_inertia = cl_array.to_device(queue, inertia_records(diag))
        fused = bool(shape_types)  # (the AABBs and the backup fused in, or neither)
        prepare = BodyPreparation(
            runtime,
            gyroscopic=True,
            gravity=True,
            shape_types=shape_types,
            work_group_size=work_group_size,
            backup=fused,
        )
        aabbs = cl_array.empty(queue, max(n, 1), layouts.AABB.dtype)
        backup = cl_array.zeros(queue, max(n, 1), layouts.BODY.dtype)
        inputs = (
            (cl_array.to_device(queue, shapes), cl_array.to_device(queue, vertices), aabbs, margin)
            if shape_types
            else None
        )
        prepare(d_bodies, d_inertia, n, dt, gravity, aabbs=inputs, backup=backup if fused else None)
        outputs.append((d_bodies.get()[:n], d_inertia.get()[:n], aabbs.get()[:n], backup.get()[:n]))
    (plain_bodies, plain_inertia, _, _), (fused_bodies, fused_inertia, boxes, backup) = outputs
    np.testing.assert_array_equal(fused_bodies, plain_bodies)
    np.testing.assert_array_equal(fused_inertia, plain_inertia)
    np.testing.assert_array_equal(backup, bodies[:n])  # the bodies as they were
    for i in range(n):
        lo, hi = expected_bounds(
            shape_list[which[i]],
            bodies["position"][i, :3].astype(np.float64),
            bodies["orientation"][i],
        )
        tol = 1e-5 + 1e-6 * max(np.abs(lo).max(), np.abs(hi).max())
        np.testing.assert_allclose(boxes["lower"][i, :3], lo - margin, atol=tol)
        np.testing.assert_allclose(boxes["upper"][i, :3], hi + margin, atol=tol)


def test_aabb_inputs_must_match_the_build(runtime):
    bodies = cl_array.to_device(runtime.queue, layouts.BODY.zeros(1))
    inertia = cl_array.to_device(runtime.queue, inertia_records(np.ones((1, 3))))
    with pytest.raises(RbgenError, match="aabbs"):
        BodyPreparation(runtime, shape_types=("box",))(bodies, inertia, 1, 0.1)
    with pytest.raises(RbgenError, match="aabbs"):
        BodyPreparation(runtime)(bodies, inertia, 1, 0.1, aabbs=(None, None, None, 0.0))
    with pytest.raises(RbgenError, match="backup"):
        BodyPreparation(runtime, backup=True)(bodies, inertia, 1, 0.1)
    with pytest.raises(RbgenError, match="backup"):
        BodyPreparation(runtime)(bodies, inertia, 1, 0.1, backup=bodies)
    with pytest.raises(Exception, match="shape_types"):
        BodyPreparation(runtime, shape_types=("box", "torus"))
