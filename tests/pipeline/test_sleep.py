"""The sleeping kernels (rbgen.pipeline.sleep) against numpy references, on fresh random
inputs, for body and edge counts that are not multiples of the work-group size, and for
none: rest timers, islands (connected components by brute force, labelled by their
lowest body), waking on touch and by force, falling asleep, the record backup, and the
host's record edits (`wake_islands`, `renumber`)."""

from __future__ import annotations

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen import layouts
from rbgen.pipeline import sleep
from rbgen.pipeline.sleep import Sleeping

THRESHOLD, TIME_TO_SLEEP, DT = 0.05, 0.5, 1.0 / 60.0


class Settings:
    sleep_threshold = THRESHOLD
    sleep_time = TIME_TO_SLEEP


def random_world(rng, n):
    """Bodies (a tenth static), sleep records (sleeping islands of a few bodies each,
    labelled by their lowest body), collision words and velocities well off the
    threshold (either side)."""
    static = rng.random(n) < 0.1
    records = sleep.fresh_records(
        np.where(static, 0.0, rng.uniform(0.5, 2.0, n)).astype(np.float32),
        rng.uniform(0.1, 1.0, n).astype(np.float32),
    )
    records["timer"] = rng.choice([0.0, 0.2, TIME_TO_SLEEP - DT / 2, 0.49, 0.6, 3.0], n)
    sleepers = np.flatnonzero(~static & (rng.random(n) < 0.4))
    rng.shuffle(sleepers)
    for group in np.array_split(sleepers, max(1, len(sleepers) // 3)):
        if len(group):
            records["asleep"][group] = layouts.SLEEP_ASLEEP
            records["island"][group] = group.min()
    bodies = layouts.BODY.zeros(n)
    bodies["position"] = rng.standard_normal((n, 4))
    bodies["inv_mass"] = np.where(records["asleep"] == layouts.SLEEP_ASLEEP, 0, records["inv_mass"])
    fast = rng.random(n) < 0.3
    scale = np.where(fast, 2.0 * THRESHOLD, 0.2 * THRESHOLD) / np.sqrt(3)
    bodies["linear_velocity"][:, :3] = rng.choice([-1, 1], (n, 3)) * scale[:, None]
    bodies["angular_velocity"][:, :3] = (
        rng.choice([-1, 1], (n, 3)) * (0.2 * THRESHOLD / np.sqrt(3)) / records["extent"][:, None]
    )
    asleep = records["asleep"] == layouts.SLEEP_ASLEEP
    bodies["linear_velocity"][asleep] = 0
    bodies["angular_velocity"][asleep] = 0
    words = ((rng.integers(0, 3, n) << 1) | (static | asleep)).astype(np.uint32)
    return records, bodies, words


def components(n, edges, member):
    """Lowest body of each body's component over ``edges`` among ``member`` bodies."""
    label = np.arange(n)
    changed = True
    while changed:  # (brute force: relax every edge until nothing changes)
        changed = False
        for a, b in edges:
            if member[a] and member[b] and label[a] != label[b]:
                label[a] = label[b] = min(label[a], label[b])
                changed = True
    return label


def reference_end(records, bodies, words, edges):
    """What the end of a step makes of them (see sleep.cl.mako), in numpy."""
    n = len(records)
    edges = list(zip(edges["body_a"].astype(int), edges["body_b"].astype(int)))
    records, bodies, words = records.copy(), bodies.copy(), words.copy()
    dynamic = records["inv_mass"] > 0
    awake = dynamic & (records["asleep"] == layouts.SLEEP_AWAKE)
    v = np.linalg.norm(bodies["linear_velocity"][:, :3], axis=1)
    w = np.linalg.norm(bodies["angular_velocity"][:, :3], axis=1)
    slow = v + w * records["extent"] <= THRESHOLD
    records["timer"] = np.where(
        awake, np.where(slow, records["timer"] + np.float32(DT), 0.0), records["timer"]
    )
    label = components(n, edges, awake)
    records["island"] = np.where(awake, label, records["island"])
    wake = set()
    for a, b in edges:
        if dynamic[a] and dynamic[b] and awake[a] != awake[b]:
            wake.add(records["island"][b if awake[a] else a])
    restless = set(label[awake & (records["timer"] < TIME_TO_SLEEP)])
    falls = awake & ~np.isin(label, list(restless))
    woken = dynamic & ~awake & np.isin(records["island"], list(wake))
    records["asleep"][falls] = layouts.SLEEP_ASLEEP
    records["asleep"][woken] = layouts.SLEEP_AWAKE
    records["timer"][woken] = 0
    asleep = dynamic & (records["asleep"] == layouts.SLEEP_ASLEEP)
    bodies["inv_mass"] = np.where(
        dynamic, np.where(asleep, 0, records["inv_mass"]), bodies["inv_mass"]
    )
    bodies["linear_velocity"][asleep] = 0
    bodies["angular_velocity"][asleep] = 0
    words = np.where(dynamic, np.where(asleep, words | 1, words & ~np.uint32(1)), words)
    return records, bodies, words.astype(np.uint32)


def random_edges(rng, n, m):
    edges = layouts.CONSTRAINT_EDGE.zeros(m)
    if n:
        edges["body_a"] = rng.integers(0, n, m)
        edges["body_b"] = rng.integers(0, n, m)
    return edges


@pytest.mark.parametrize("n, m", [(0, 0), (1, 1), (63, 40), (64, 64), (65, 97), (301, 250)])
def test_end_of_step_matches_the_reference(runtime, rng, n, m):
    """Timers, island labels (lowest body of each component of awake dynamic bodies),
    touch wakes, islands falling asleep, bodies and collision words: as the numpy
    reference; the records before the step are in the backup slot."""
    records, bodies, words = random_world(rng, n)
    edges = random_edges(rng, n, m)
    queue = runtime.queue
    s = Sleeping(runtime, backups=2)
    s.adopt(records)
    d_bodies = cla.to_device(queue, bodies if n else layouts.BODY.zeros(1))
    d_words = cla.to_device(queue, words if n else np.zeros(1, np.uint32))
    d_edges = cla.to_device(queue, edges if m else layouts.CONSTRAINT_EDGE.zeros(1))
    count = cla.to_device(queue, np.array([m], np.uint32))
    s.end(d_bodies, d_words, d_edges, count, m + 37, 1, Settings, DT)
    want_records, want_bodies, want_words = reference_end(records, bodies, words, edges)
    got = s.read()
    for field in ("asleep", "island", "inv_mass", "extent"):
        np.testing.assert_array_equal(got[field], want_records[field], err_msg=field)
    np.testing.assert_array_equal(got["timer"], want_records["timer"].astype(np.float32))
    if n:
        assert d_bodies.get().tobytes() == want_bodies.tobytes()
        np.testing.assert_array_equal(d_words.get(), want_words)
        assert s.backups[1].get()[:n].tobytes() == records.tobytes()


@pytest.mark.parametrize("n", [0, 1, 64, 129])
def test_start_of_step_forces_wake_islands_and_bodies_agree(runtime, rng, n):
    """A sleeping body with a force (or torque, or force at a point) wakes its whole
    island before the forces act; every other body, its inverse mass and collision word
    are made to agree with its record (as after the host rewrote them)."""
    records, bodies, words = random_world(rng, n)
    queue = runtime.queue
    s = Sleeping(runtime, backups=2)
    s.adopt(records)
    host_bodies = bodies.copy()
    host_bodies["inv_mass"] = records["inv_mass"]  # (an upload writes the true ones)
    d_bodies = cla.to_device(queue, host_bodies if n else layouts.BODY.zeros(1))
    uploaded = np.where(records["inv_mass"] > 0, words & ~np.uint32(1), words).astype(np.uint32)
    d_words = cla.to_device(queue, uploaded if n else np.zeros(1, np.uint32))
    pushed = rng.random(n) < 0.1
    arrays = [np.zeros((max(n, 1), 4), np.float32) for _ in range(3)]
    for k in range(n):
        if pushed[k]:
            arrays[rng.integers(0, 3)][k, rng.integers(0, 3)] = rng.choice([-1.0, 1.0])

    class Forces:
        def arrays(self):
            return [cla.to_device(queue, a) for a in arrays]

    s.begin(d_bodies, d_words, Forces(), 0)
    dynamic = records["inv_mass"] > 0
    asleep = records["asleep"] == layouts.SLEEP_ASLEEP
    woken = dynamic & asleep & np.isin(records["island"], records["island"][pushed & asleep])
    want = records.copy()
    want["asleep"][woken] = layouts.SLEEP_AWAKE
    want["timer"][woken] = 0
    assert s.read().tobytes() == want.tobytes()
    if n:
        still = dynamic & (want["asleep"] == layouts.SLEEP_ASLEEP)
        got = d_bodies.get()
        np.testing.assert_array_equal(
            got["inv_mass"], np.where(still, 0, np.where(dynamic, records["inv_mass"], 0))
        )
        assert not np.any(got["linear_velocity"][still]) and not np.any(
            got["angular_velocity"][still]
        )
        np.testing.assert_array_equal(
            d_words.get() & 1, np.where(dynamic, still, words & 1).astype(np.uint32)
        )


@pytest.mark.parametrize("envs, per_env", [(1, 1), (7, 5), (70, 3)])
def test_wake_environments_wakes_the_reset_ones_only(runtime, rng, envs, per_env):
    n = 2 + envs * per_env
    records, _, _ = random_world(rng, n)
    words = np.r_[
        np.full(2, layouts.SHARED_STATIC), (np.repeat(np.arange(envs), per_env) << 1) | 1
    ].astype(np.uint32)
    flags = (rng.random(envs) < 0.5).astype(np.uint32)
    s = Sleeping(runtime, backups=2)
    s.adopt(records)
    s.wake_environments(cla.to_device(runtime.queue, words), flags)
    reset = np.r_[False, False, np.repeat(flags > 0, per_env)]
    want = records.copy()
    want["asleep"][reset] = layouts.SLEEP_AWAKE
    want["timer"][reset] = 0
    want["island"][reset] = np.flatnonzero(reset)
    assert s.read().tobytes() == want.tobytes()


def test_host_wake_and_renumber(rng):
    """`wake_islands` wakes whole islands of the bodies named and nothing else;
    `renumber` wakes the islands of removed bodies and renumbers the survivors' labels."""
    records = sleep.fresh_records(np.ones(8, np.float32), np.ones(8, np.float32))
    records["asleep"][[1, 2, 3, 5, 6]] = layouts.SLEEP_ASLEEP
    records["island"][[1, 2, 3]] = 1
    records["island"][[5, 6]] = 5
    records["timer"] = 1.0
    woken = records.copy()
    assert sleep.wake_islands(woken, [3, 0]) == 3
    assert list(woken["asleep"]) == [0, 0, 0, 0, 0, 1, 1, 0]
    assert list(woken["timer"]) == [1, 0, 0, 0, 1, 1, 1, 1]
    assert sleep.wake_islands(woken, np.zeros(8, bool)) == 0
    mapping = np.array([0, 1, -1, 2, 3, 4, 5, 6])  # body 2 removed: island 1 wakes
    kept = sleep.renumber(records, mapping)
    assert list(kept["asleep"]) == [0, 0, 0, 0, 1, 1, 0]
    assert list(kept["island"]) == [0, 1, 2, 3, 4, 4, 6]
    mapping = np.array([-1, 0, 1, 2, 3, 4, 5, 6])  # body 0 removed: the labels move down
    kept = sleep.renumber(records, mapping)
    assert list(kept["asleep"]) == [1, 1, 1, 0, 1, 1, 0]
    assert list(kept["island"]) == [0, 0, 0, 3, 4, 4, 6]
