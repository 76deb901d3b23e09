"""Incremental 3-axis SAP over frame sequences equals brute force on every frame.

Each frame is one step of the protocol: ``enqueue`` then ``check``; a False
check (a degenerate step, e.g. after teleports) is redone, which runs a full
query. The tests also check that both paths really ran.
"""

from __future__ import annotations

import numpy as np
import pytest

from rbgen.errors import RbgenError
from rbgen.pipeline.broadphase import make_broadphase
from rbgen.pipeline.broadphase.reference import brute_force_pairs

from .conftest import make_aabbs, pack


def step(broadphase, aabbs, static, modes):
    """One frame; records "incremental" or "full" for the query that completed it."""
    while True:
        broadphase.enqueue(aabbs, static)
        incremental = broadphase.incremental
        if broadphase.check():
            modes.append("incremental" if incremental else "full")
            return broadphase.host_pairs()
        modes.append("redo")


def test_random_walk_with_teleports(runtime, rng):
    """300 bodies of mixed sizes jitter for 100 frames; every 25th frame 10% teleport."""
    n = 300
    aabbs, static = make_aabbs(rng, n, "mixed")
    lower = aabbs["lower"][:, :3].astype(np.float64)
    size = (aabbs["upper"][:, :3] - aabbs["lower"][:, :3]).astype(np.float64)
    broadphase = make_broadphase(runtime, "sap3")
    modes = []
    for frame in range(100):
        lower += rng.normal(0, 0.05, lower.shape) * (static[:, None] == 0)
        if frame % 25 == 24:
            moved = rng.choice(n, n // 10, replace=False)
            lower[moved] = rng.uniform(0, 10, (len(moved), 3))
        frame_aabbs = pack(lower.astype(np.float32), (lower + size).astype(np.float32))
        pairs = step(broadphase, frame_aabbs, static, modes)
        np.testing.assert_array_equal(
            pairs, brute_force_pairs(frame_aabbs, static), err_msg=f"frame {frame}"
        )
    assert modes.count("incremental") >= 90
    assert modes.count("redo") >= 4 and modes.count("full") >= 5  # first + teleports


def test_lattice_hops_touch_exactly(runtime, rng):
    """Unit cubes hop by whole units, so faces start and stop touching exactly."""
    n = 200
    cells = rng.choice(12**3, n, replace=False)
    lower = np.stack(np.unravel_index(cells, (12, 12, 12)), axis=1).astype(np.float32)
    static = (rng.random(n) < 0.1).astype(np.uint32)
    broadphase = make_broadphase(runtime, "sap3", full="sap", max_moves_per_body=64)
    modes = []
    for frame in range(30):
        hop = rng.integers(-1, 2, lower.shape) * (rng.random((n, 1)) < 0.1)
        lower = lower + (hop * (static[:, None] == 0)).astype(np.float32)
        frame_aabbs = pack(lower, lower + 1)
        pairs = step(broadphase, frame_aabbs, static, modes)
        np.testing.assert_array_equal(
            pairs, brute_force_pairs(frame_aabbs, static), err_msg=f"frame {frame}"
        )
    assert modes.count("incremental") >= 25


def test_overflow_during_incremental_step(runtime, rng):
    """A set that outgrows the buffer in an incremental step is regrown and redone."""
    aabbs, static = make_aabbs(rng, 200, "uniform")
    broadphase = make_broadphase(runtime, "sap3", capacity=4000)
    modes = []
    step(broadphase, aabbs, static, modes)
    lower = aabbs["lower"][:, :3].copy()
    # every box grows slowly towards the centre of the scene: many new pairs
    for frame in range(5):
        grown = pack(lower, aabbs["upper"][:, :3] + 0.6 * (frame + 1))
        pairs = step(broadphase, grown, static, modes)
        np.testing.assert_array_equal(pairs, brute_force_pairs(grown, static))
    assert broadphase.capacity >= len(pairs)


def test_reset_and_bad_options(runtime, rng):
    aabbs, static = make_aabbs(rng, 100, "clustered")
    broadphase = make_broadphase(runtime, "sap3")
    modes = []
    step(broadphase, aabbs, static, modes)
    static = 1 - static  # new static flags: history is void
    broadphase.reset()
    np.testing.assert_array_equal(
        step(broadphase, aabbs, static, modes), brute_force_pairs(aabbs, static)
    )
    assert modes == ["full", "full"]
    with pytest.raises(RbgenError, match="full must be"):
        make_broadphase(runtime, "sap3", full="sap3")
    with pytest.raises(RbgenError, match="max_moves_per_body"):
        make_broadphase(runtime, "sap3", max_moves_per_body=-1)


def test_full_query_retry_is_honoured(runtime, rng):
    """A full query by an owner-emission grid with too many large bodies is redone (the
    pair buffer starts large enough for the ~2,450 pairs: a growth redo would come first
    for about 2% of the scenes)."""
    from rbgen.pipeline.broadphase.grid import LARGE_ROWS

    aabbs, static = make_aabbs(rng, 300, "uniform")
    slabs = rng.choice(300, LARGE_ROWS + 2, replace=False)
    aabbs["lower"][slabs, :3] = -1e30
    aabbs["upper"][slabs, 0::2] = 1e30
    broadphase = make_broadphase(runtime, "sap3", capacity=8192, full_options={"emission": "owner"})
    modes = []
    np.testing.assert_array_equal(
        step(broadphase, aabbs, static, modes), brute_force_pairs(aabbs, static)
    )
    assert modes == ["redo", "full"] and broadphase.full.emission == "slot"
