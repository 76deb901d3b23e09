"""Input generators shared by the broadphase tests.

`make_aabbs(rng, n, kind)` returns (Aabb array, uint32 static flags) for one of
the distributions in `KINDS`; every test compares against the brute-force
reference, so the generators only need to be varied, not precise.
"""

from __future__ import annotations

import numpy as np
import pytest

from rbgen import layouts

KINDS = (
    "uniform",
    "clustered",
    "mixed",
    "identical",
    "huge_static",
    "lattice",
    "bimodal",
    "log_uniform",
)


def pack(lower, upper) -> np.ndarray:
    aabbs = layouts.AABB.zeros(len(lower))
    aabbs["lower"][:, :3] = lower
    aabbs["upper"][:, :3] = upper
    return aabbs


def make_aabbs(rng: np.random.Generator, n: int, kind: str):
    """(aabbs, static) with n bodies; about one in eight static."""
    static = (rng.random(n) < 0.125).astype(np.uint32)
    side = max(1.0, n ** (1 / 3))
    if kind == "uniform":
        lower = rng.uniform(0, 2.5 * side, (n, 3))
        size = rng.uniform(0.5, 2.0, (n, 3))
    elif kind == "clustered":
        centres = rng.uniform(0, 8 * side, (max(1, n // 50), 3))
        lower = centres[rng.integers(0, len(centres), n)] + rng.normal(0, 1.0, (n, 3))
        size = rng.uniform(0.2, 1.5, (n, 3))
    elif kind == "mixed":
        lower = rng.uniform(0, 4 * side, (n, 3))
        size = rng.uniform(0.1, 1.0, (n, 3)) * rng.choice([1.0, 1.0, 1.0, 5.0, 40.0], (n, 1))
    elif kind == "identical":
        lower = np.tile(rng.uniform(-5, 5, (1, 3)), (n, 1))
        size = np.tile(rng.uniform(0.5, 2.0, (1, 3)), (n, 1))
    elif kind == "huge_static":
        lower = rng.uniform(0, 4 * side, (n, 3))
        size = rng.uniform(0.5, 2.0, (n, 3))
    elif kind == "bimodal":
        # ragdoll parts and the unit boxes they fall on: two sizes 2-3x apart (both grid
        # levels of owner emission), about one overlap per body
        lower = rng.uniform(0, (0.6 * n) ** (1 / 3) + 1, (n, 3))
        size = rng.uniform(0.6, 1.0, (n, 3)) * np.where(rng.random((n, 1)) < 0.15, 1.4, 0.5)
    elif kind == "log_uniform":
        # sizes spread evenly in log over a factor 10
        lower = rng.uniform(0, 1.2 * n ** (1 / 3) + 1, (n, 3))
        size = rng.uniform(0.6, 1.0, (n, 3)) * np.exp(
            rng.uniform(np.log(0.25), np.log(2.5), (n, 1))
        )
    elif kind == "lattice":
        # unit cubes on an integer lattice: neighbours share faces, edges, corners exactly
        dim = max(2, int(np.ceil((2 * n) ** (1 / 3))))
        cells = rng.choice(dim**3, n, replace=False)
        lower = np.stack(np.unravel_index(cells, (dim, dim, dim)), axis=1).astype(float)
        size = np.ones((n, 3))
    else:
        raise ValueError(kind)
    lower = lower.astype(np.float32)
    upper = (lower + size.astype(np.float32)).astype(np.float32)
    slabs = {"huge_static": 3, "bimodal": 2, "log_uniform": 2}.get(kind, 0) if n >= 100 else 0
    if kind == "huge_static":
        slabs = min(n, 3)
    if slabs:
        # slabs as planes make them: unbounded sideways, top face inside the scene
        for body in rng.choice(n, slabs, replace=False):
            lower[body] = (-1e30, -1e30, -1e30)
            upper[body] = (1e30, rng.uniform(0, 4 * side), 1e30)
            static[body] = 1
    return pack(lower, upper), static


def make_env_aabbs(rng: np.random.Generator, n: int, kind: str, envs: int, shared: int = 2):
    """(aabbs, collision words) of a WorldBatch: ``shared`` static slabs every environment
    meets (word SHARED_STATIC), then ``envs`` environments of ``n`` bodies of `make_aabbs`
    ``kind`` in the same region of space (word env << 1 | static), each jittered a little."""
    base, static = make_aabbs(rng, n, kind)
    lower = np.concatenate([base["lower"][:, :3]] * envs)
    lower += rng.uniform(-0.1, 0.1, lower.shape).astype(np.float32)
    upper = lower + np.concatenate([base["upper"][:, :3] - base["lower"][:, :3]] * envs)
    words = (np.repeat(np.arange(envs, dtype=np.uint32), n) << 1) | np.tile(static, envs)
    slab_lower = np.full((shared, 3), -1e30, np.float32)
    slab_upper = np.full((shared, 3), 1e30, np.float32)
    slab_upper[:, 1] = rng.uniform(0, 3, shared)
    aabbs = pack(np.concatenate([slab_lower, lower]), np.concatenate([slab_upper, upper]))
    words = np.concatenate([np.full(shared, layouts.SHARED_STATIC, np.uint32), words])
    return aabbs, words.astype(np.uint32)


def env_pairs(aabbs, words) -> np.ndarray:
    """`brute_force_pairs` kept to pairs within one environment or with shared geometry."""
    from rbgen.pipeline.broadphase.reference import brute_force_pairs

    pairs = brute_force_pairs(aabbs, words & 1)
    wa, wb = words[pairs[:, 0]], words[pairs[:, 1]]
    shared = (wa == layouts.SHARED_STATIC) | (wb == layouts.SHARED_STATIC)
    return pairs[((wa >> 1) == (wb >> 1)) | shared]


#: (name, options) of every broadphase configuration the tests cover.
ALGORITHMS = [
    ("grid", {"emission": "slot", "bucketing": "sort"}),
    ("grid", {"emission": "owner"}),
    ("grid", {"emission": "owner", "work_group_size": 4}),
    ("grid", {"emission": "slot", "bucketing": "count"}),
    ("sap", {"shape": "cpu"}),
    ("sap", {"shape": "gpu"}),
    ("sap", {"shape": "gpu", "work_group_size": 4}),
    ("sap3", {}),
]
ALGORITHM_IDS = [
    "grid-slot-sort",
    "grid-owner",
    "grid-owner-wg4",
    "grid-slot-count",
    "sap-cpu",
    "sap-gpu",
    "sap-gpu-wg4",
    "sap3",
]


@pytest.fixture(params=ALGORITHMS, ids=ALGORITHM_IDS)
def broadphase(request, runtime):
    """A fresh broadphase of each configuration on each device."""
    from rbgen.pipeline.broadphase import make_broadphase

    name, options = request.param
    return make_broadphase(runtime, name, **options)
