"""Integrate kernel against a float64 reference and closed forms."""

from __future__ import annotations

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen import layouts
from rbgen.errors import RbgenError
from rbgen.pipeline.integrate import DEFAULT_MAX_ANGULAR_STEP, Integrator
from tests.conftest import SIZES
from tests.reference import quat_mul, random_quaternions, rotation_angle_between


def reference_step(
    bodies,
    dt,
    gravity,
    linear_damping=0.0,
    angular_damping=0.0,
    max_angular_step=DEFAULT_MAX_ANGULAR_STEP,
):
    """One step in float64: v += g dt, damping, x += v dt, exact axis-angle rotation."""
    out = bodies.copy()
    dynamic = bodies["inv_mass"] != 0
    pos = bodies["position"][:, :3].astype(np.float64)
    v = bodies["linear_velocity"][:, :3].astype(np.float64) + np.asarray(gravity) * dt
    w = bodies["angular_velocity"][:, :3].astype(np.float64)
    v *= (1 - linear_damping) ** dt
    w *= (1 - angular_damping) ** dt
    speed = np.linalg.norm(w, axis=1)
    angle = np.minimum(speed * dt, max_angular_step)
    axis = np.divide(w, speed[:, None], out=np.zeros_like(w), where=speed[:, None] > 0)
    dq = np.concatenate([axis * np.sin(angle / 2)[:, None], np.cos(angle / 2)[:, None]], axis=1)
    q = quat_mul(dq, bodies["orientation"].astype(np.float64))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    for name, value in (
        ("linear_velocity", v),
        ("angular_velocity", w),
        ("position", pos + v * dt),
    ):
        out[name][dynamic, :3] = value[dynamic]
    out["orientation"][dynamic] = q[dynamic]
    return out


def random_bodies(rng, n, static_fraction=0.1):
    bodies = layouts.BODY.zeros(n)
    bodies["position"][:, :3] = rng.uniform(-50, 50, (n, 3))
    bodies["orientation"] = random_quaternions(rng, n)
    bodies["linear_velocity"][:, :3] = rng.normal(0, 5, (n, 3))
    bodies["angular_velocity"][:, :3] = rng.normal(0, 4, (n, 3))
    bodies["inv_mass"] = np.where(rng.random(n) < static_fraction, 0.0, rng.uniform(0.1, 2, n))
    return bodies


@pytest.mark.parametrize("n", SIZES)
def test_matches_float64_reference(runtime, rng, n):
    bodies = random_bodies(rng, n)
    dt, g = 1 / 60, (0.5, -9.81, 0.25)
    integrate = Integrator(runtime)
    d = (
        cla.to_device(runtime.queue, bodies)
        if n
        else cla.empty(runtime.queue, 1, layouts.BODY.dtype)
    )
    integrate(d, n, dt, gravity=g)
    got = d.get()[:n]
    want = reference_step(bodies, dt, g)
    for name in ("position", "linear_velocity", "angular_velocity"):
        np.testing.assert_allclose(got[name], want[name], rtol=1e-5, atol=1e-4, err_msg=name)
    if n:
        angle = rotation_angle_between(got["orientation"].astype(np.float64), want["orientation"])
        assert angle.max() < 1e-5
    static = bodies["inv_mass"] == 0
    assert np.array_equal(got[static], bodies[static]), "static bodies must be untouched"


@pytest.mark.parametrize("work_group_size", [1, 32, 256])
def test_damping_and_work_group_sizes(runtime, rng, work_group_size):
    n = 333
    bodies = random_bodies(rng, n)
    integrate = Integrator(runtime, damping=True, work_group_size=work_group_size)
    d = cla.to_device(runtime.queue, bodies)
    integrate(d, n, 0.01, gravity=(0, -9.81, 0), linear_damping=0.2, angular_damping=0.5)
    want = reference_step(bodies, 0.01, (0, -9.81, 0), 0.2, 0.5)
    got = d.get()
    np.testing.assert_allclose(
        got["linear_velocity"], want["linear_velocity"], rtol=1e-5, atol=1e-5
    )
    np.testing.assert_allclose(got["position"], want["position"], rtol=1e-5, atol=1e-4)


def test_projectile_closed_form(runtime):
    """Semi-implicit Euler: x_N = x0 + v0 N dt + g dt^2 N (N + 1) / 2, v_N = v0 + g N dt."""
    bodies = layouts.BODY.zeros(1)
    bodies["orientation"][:, 3] = 1
    bodies["inv_mass"] = 1
    x0, v0, g, dt, steps = (
        np.array([1.0, 2.0, -3.0]),
        np.array([3.0, 12.0, -1.0]),
        np.array([0, -9.81, 0]),
        1 / 120,
        240,
    )
    bodies["position"][0, :3], bodies["linear_velocity"][0, :3] = x0, v0
    d = cla.to_device(runtime.queue, bodies)
    integrate = Integrator(runtime)
    for _ in range(steps):
        integrate(d, 1, dt, gravity=tuple(g))
    got = d.get()[0]
    expect_x = x0 + v0 * steps * dt + g * dt * dt * steps * (steps + 1) / 2
    np.testing.assert_allclose(got["position"][:3], expect_x, atol=2e-4)
    np.testing.assert_allclose(got["linear_velocity"][:3], v0 + g * steps * dt, atol=2e-4)


@pytest.mark.parametrize("speed", [0.01, 0.5, 7.0])
def test_constant_spin_exact_rotation(runtime, rng, speed):
    """Constant w for N steps is a rotation by |w| N dt about w (mod 2 pi): within 1e-4 rad."""
    n, steps, dt = 64, 600, 1 / 60
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    bodies = layouts.BODY.zeros(n)
    q0 = random_quaternions(rng, n)
    bodies["orientation"] = q0
    bodies["angular_velocity"][:, :3] = axes * speed
    bodies["inv_mass"] = 1
    d = cla.to_device(runtime.queue, bodies)
    integrate = Integrator(runtime)
    for _ in range(steps):
        integrate(d, n, dt, gravity=(0, 0, 0))
    got = d.get()
    angle = speed * steps * dt
    dq = np.concatenate([axes * np.sin(angle / 2), np.full((n, 1), np.cos(angle / 2))], axis=1)
    want = quat_mul(dq, q0)
    err = rotation_angle_between(got["orientation"].astype(np.float64), want)
    assert err.max() < 1e-4, err.max()
    assert np.abs(np.linalg.norm(got["orientation"], axis=1) - 1).max() < 1e-6


def test_angular_step_clamp(runtime):
    """A spin faster than max_angular_step/dt rotates exactly max_angular_step per step."""
    bodies = layouts.BODY.zeros(1)
    bodies["orientation"][0] = (0, 0, 0, 1)
    bodies["angular_velocity"][0, :3] = (0, 100.0, 0)
    bodies["inv_mass"] = 1
    d = cla.to_device(runtime.queue, bodies)
    Integrator(runtime)(d, 1, 0.1, gravity=(0, 0, 0), max_angular_step=0.25)
    got = d.get()[0]
    np.testing.assert_allclose(
        rotation_angle_between(got["orientation"], np.array([0, 0, 0, 1.0])), 0.25, atol=1e-5
    )
    assert got["angular_velocity"][1] == pytest.approx(100.0), "the stored w is not clamped"


def test_separate_gravity_kernel(runtime):
    bodies = layouts.BODY.zeros(3)
    bodies["orientation"][:, 3] = 1
    bodies["inv_mass"] = (1, 0, 2)
    d = cla.to_device(runtime.queue, bodies)
    integrate = Integrator(runtime, gravity=False)
    integrate.apply_gravity(d, 3, 0.5, gravity=(0, -10, 0))
    np.testing.assert_allclose(d.get()["linear_velocity"][:, 1], [-5, 0, -5])
    integrate(d, 3, 0.5)
    np.testing.assert_allclose(d.get()["position"][:, 1], [-2.5, 0, -2.5])


def test_bad_input(runtime):
    integrate = Integrator(runtime)
    d = cla.empty(runtime.queue, 1, layouts.BODY.dtype)
    for dt in (0.0, -1.0, float("nan")):
        with pytest.raises(RbgenError, match="dt"):
            integrate(d, 1, dt)
    with pytest.raises(RbgenError, match="damping"):
        integrate(d, 1, 0.1, linear_damping=0.1)
    with pytest.raises(RbgenError, match="gravity"):
        integrate.apply_gravity(d, 1, 0.1)


@pytest.mark.parametrize("work_group_size", [None, 128])  # the device's default, the GPU one
@pytest.mark.parametrize("n", [0, 1, 67, 1000])
def test_split_push_fused(runtime, rng, n, work_group_size):
    """With the solver's push velocities, integrate_bodies first integrates (as without),
    then moves each dynamic body by the push over dt (x += v_push dt; q += (w_push dt/2, 0) q,
    renormalised: the solver's first-order update, in float64 here) and clears the pushes."""
    bodies = random_bodies(rng, max(n, 1))
    split = layouts.SPLIT_VELOCITY.zeros(max(n, 1))
    split["linear"][:, :3] = rng.normal(0, 0.5, (len(split), 3))
    split["angular"][:, :3] = rng.normal(0, 0.5, (len(split), 3))
    dt = 1 / 60
    q = runtime.queue
    d_bodies, d_split = cla.to_device(q, bodies), cla.to_device(q, split)
    Integrator(runtime, gravity=False, work_group_size=work_group_size)(
        d_bodies, n, dt, split=d_split
    )
    got, pushes = d_bodies.get()[:n], d_split.get()[:n]
    expected = reference_step(bodies[:n], dt, (0.0, 0.0, 0.0))
    dynamic = bodies["inv_mass"][:n] != 0
    v, w = split["linear"][:n, :3].astype(np.float64), split["angular"][:n, :3].astype(np.float64)
    position = expected["position"][:, :3].astype(np.float64) + v * dt
    orientation = expected["orientation"].astype(np.float64)
    half = 0.5 * dt * w
    turned = orientation + quat_mul(np.concatenate([half, np.zeros((n, 1))], axis=1), orientation)
    turned /= np.linalg.norm(turned, axis=1, keepdims=True)
    np.testing.assert_allclose(
        got["position"][dynamic, :3], position[dynamic], rtol=1e-5, atol=1e-4
    )
    np.testing.assert_array_equal(got["position"][~dynamic], bodies["position"][:n][~dynamic])
    assert np.all(rotation_angle_between(got["orientation"][dynamic], turned[dynamic]) < 1e-5)
    np.testing.assert_array_equal(
        got["linear_velocity"][dynamic, :3],
        expected["linear_velocity"][dynamic, :3].astype(np.float32),
    )
    assert not np.any(pushes["linear"][dynamic]) and not np.any(pushes["angular"][dynamic])
    with pytest.raises(RbgenError, match="split"):
        Integrator(runtime)(d_bodies, n + 5, dt, split=d_split[:n] if n else d_split[:0])
