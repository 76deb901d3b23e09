"""reset_bodies and forget_contacts (a WorldBatch's reset on the device) against numpy
references, on fresh random inputs, for counts that are not multiples of the work-group
size and for none."""

from __future__ import annotations

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen import layouts
from rbgen.pipeline.reset import EnvironmentReset


class Constraints:
    """What EnvironmentReset reads of a ContactConstraints: records, device count,
    capacity."""

    def __init__(self, queue, records, count):
        self.constraints = cla.to_device(queue, records)
        self.count = cla.to_device(queue, np.array([count], np.uint32))
        self.capacity = len(records)


def random_bodies(rng, n):
    bodies = layouts.BODY.zeros(n)
    for name in ("position", "orientation", "linear_velocity", "angular_velocity"):
        bodies[name] = rng.standard_normal((n, 4))
    bodies["inv_mass"] = rng.uniform(0.5, 2.0, n)
    bodies["shape"] = rng.integers(0, 5, n)
    return bodies


@pytest.mark.parametrize("envs, per_env, reset", [(1, 1, 0), (1, 1, 1), (13, 5, 7), (67, 3, 41)])
def test_reset_bodies_writes_the_reset_environments_only(runtime, rng, envs, per_env, reset):
    shared = 2
    bodies = random_bodies(rng, shared + envs * per_env)
    chosen = rng.permutation(envs)[:reset]
    states = random_bodies(rng, reset * per_env)
    d_bodies = cla.to_device(runtime.queue, bodies)
    words = np.r_[np.full(shared, layouts.SHARED_STATIC), np.repeat(np.arange(envs) << 1, per_env)]
    EnvironmentReset(runtime)(
        d_bodies,
        states,
        chosen,
        per_env,
        shared,
        envs,
        cla.to_device(runtime.queue, words.astype(np.uint32)),
    )
    expected = bodies.copy()
    for k, env in enumerate(chosen):
        first = shared + env * per_env
        expected[first : first + per_env] = states[k * per_env : (k + 1) * per_env]
    assert d_bodies.get().tobytes() == expected.tobytes()


@pytest.mark.parametrize("capacity, count", [(1, 0), (64, 64), (200, 131)])
def test_forget_contacts_of_reset_environments(runtime, rng, capacity, count):
    """A constraint (of the first ``count``) touching a body of a reset environment gets
    both keys RB_SOLVER_NONE; shared static bodies reset nothing; the rest is unchanged."""
    envs, shared, per_env = 9, 3, 4
    n = shared + envs * per_env
    words = np.r_[
        np.full(shared, layouts.SHARED_STATIC), np.repeat(np.arange(envs) << 1, per_env)
    ].astype(np.uint32)
    records = layouts.CONTACT_CONSTRAINT.zeros(capacity)
    records["body_a"] = rng.integers(0, n, capacity)
    records["body_b"] = rng.integers(0, n, capacity)
    records["point_count"] = rng.integers(1, 5, capacity)
    records["body_a"][::7] = layouts.SOLVER_NONE  # forgotten already
    records["body_b"][::7] = layouts.SOLVER_NONE
    chosen = np.array([1, 4, 8])
    flags = np.zeros(envs, bool)
    flags[chosen] = True
    constraints = Constraints(runtime.queue, records, count)
    bodies = cla.to_device(runtime.queue, random_bodies(rng, n))
    states = random_bodies(rng, len(chosen) * per_env)
    d_words = cla.to_device(runtime.queue, words)
    EnvironmentReset(runtime)(bodies, states, chosen, per_env, shared, envs, d_words, constraints)
    expected = records.copy()

    def reset_body(body):
        return (
            body != layouts.SOLVER_NONE
            and words[body] != layouts.SHARED_STATIC
            and bool(flags[words[body] >> 1])
        )

    for i in range(count):
        a, b = int(records["body_a"][i]), int(records["body_b"][i])
        if reset_body(a) or reset_body(b):
            expected["body_a"][i] = expected["body_b"][i] = layouts.SOLVER_NONE
    out = constraints.constraints.get()
    assert out.tobytes() == expected.tobytes()
    assert count == 0 or np.any(out["body_a"][:count] != records["body_a"][:count])
