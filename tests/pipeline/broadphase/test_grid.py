"""Grid specifics: owner emission, its two grid levels, its large-body rows, its launch
count and the fallback to slot emission; the expected pairs come from `brute_force_pairs`."""

from __future__ import annotations

import numpy as np
import pytest

from rbgen.errors import RbgenError
from rbgen.launch import launches_by_kernel
from rbgen.pipeline.broadphase import make_broadphase
from rbgen.pipeline.broadphase.grid import LARGE_ROWS, grid_dim_for
from rbgen.pipeline.broadphase.reference import COARSE, FINE, brute_force_pairs, grid_levels
from rbgen.scenes import boxbox_scene, scene_aabbs

from .conftest import env_pairs, make_aabbs, make_env_aabbs, pack

#: Launches of one owner-emission query (grid_owner.cl.mako): its whole point.
OWNER_LAUNCHES = 6
#: its kernels, one launch each
OWNER_KERNELS = (
    "measure_grid_bodies",
    "classify_grid_bodies",
    "link_bucket_bodies",
    "count_owned_pairs",
    "place_owner_slices",
    "write_owned_pairs",
)


@pytest.mark.parametrize("work_group_size", [None, 4])
@pytest.mark.parametrize("large", [LARGE_ROWS, LARGE_ROWS + 1])
def test_owner_emission_large_rows_and_fallback(runtime, rng, large, work_group_size):
    """Up to LARGE_ROWS large bodies stay in owner emission; one more makes the
    first query ask for a retry, which runs with slot emission; both are exact.
    The slabs overlap each other, so large owners have large partners too."""
    aabbs, static = make_aabbs(rng, 401, "uniform")
    slabs = rng.choice(401, large, replace=False)
    aabbs["lower"][slabs, :3] = -1e30
    aabbs["upper"][slabs, 0] = 1e30
    aabbs["upper"][slabs, 2] = 1e30
    aabbs["upper"][slabs, 1] = rng.uniform(0, 10, large)
    broadphase = make_broadphase(runtime, "grid", emission="owner", work_group_size=work_group_size)
    broadphase.enqueue(aabbs, static)
    assert broadphase.check() is (large <= LARGE_ROWS)
    broadphase.find_pairs(aabbs, static)
    assert broadphase.emission == ("owner" if large <= LARGE_ROWS else "slot")
    if large <= LARGE_ROWS:
        assert broadphase.fallback is None and broadphase.describe() == "grid, owner emission"
    else:
        assert broadphase.fallback == (
            f"a query met more than {LARGE_ROWS} large bodies (larger than 4 x the bodies' "
            f"geometric mean size)"
        )
        assert broadphase.describe() == (
            f"grid, slot emission ({broadphase.bucketing} bucketing) since {broadphase.fallback}"
        )
    np.testing.assert_array_equal(broadphase.host_pairs(), brute_force_pairs(aabbs, static))


@pytest.mark.parametrize("capacity", [None, 1])
@pytest.mark.parametrize("emission", ["owner", "slot"])
def test_boxbox_scene(runtime, emission, capacity):
    """The BoxBox lattice: resting faces touch exactly; the ground (body 0) is the
    large body. Capacity 1: the first query overflows inside the ground's slice."""
    aabbs, static = scene_aabbs(boxbox_scene(7, 6, 5))
    broadphase = make_broadphase(runtime, "grid", emission=emission, capacity=capacity)
    broadphase.find_pairs(aabbs, static)
    np.testing.assert_array_equal(broadphase.host_pairs(), brute_force_pairs(aabbs, static))


def test_owner_query_launch_count(runtime, rng):
    """An owner-emission query is OWNER_LAUNCHES launches at any size, and exact."""
    broadphase = make_broadphase(runtime, "grid", emission="owner")
    for n in (2, 333, 4099):
        aabbs, static = make_aabbs(rng, n, "clustered")
        broadphase.find_pairs(aabbs, static)  # grows the buffer if needed
        before = runtime.counters["launches"]
        with launches_by_kernel(runtime) as counts:
            broadphase.enqueue(aabbs, static)
        assert runtime.counters["launches"] - before == OWNER_LAUNCHES
        assert counts == dict.fromkeys(OWNER_KERNELS, 1)
        assert broadphase.check()
        np.testing.assert_array_equal(broadphase.host_pairs(), brute_force_pairs(aabbs, static))


def test_emission_and_bucketing_are_checked(runtime):
    with pytest.raises(RbgenError, match="emission must be one of"):
        make_broadphase(runtime, "grid", emission="broadcast")
    with pytest.raises(RbgenError, match="bucketing='count' does not go with emission='owner'"):
        make_broadphase(runtime, "grid", emission="owner", bucketing="count")
    with pytest.raises(RbgenError, match="bucketing='list' does not go with emission='slot'"):
        make_broadphase(runtime, "grid", emission="slot", bucketing="list")
    with pytest.raises(RbgenError, match="fine_factor must be a positive finite number"):
        make_broadphase(runtime, "grid", fine_factor=0.0)


def test_grid_dim_keeps_neighbour_buckets_distinct():
    assert grid_dim_for(0) == grid_dim_for(1) == 3
    for n in (2, 13, 1000, 111_376):
        dim = grid_dim_for(n)
        assert dim >= 3 and dim**3 >= 2 * n


#: owner-emission grids over every value of the fine level's factor: 1 (more coarse
#: bodies), the default 2, and 4 = large_factor (one level, as with equal sizes)
TWO_LEVELS = [
    pytest.param({"fine_factor": f, "work_group_size": wg}, id=f"fine{f:g}-wg{wg}")
    for f in (1.0, 2.0, 4.0)
    for wg in (None, 4)
]


def grid_sizes(broadphase) -> np.ndarray:
    """The largest fine and coarse sizes of the last owner query (0: level empty)."""
    return broadphase.runtime.read(broadphase._views["grid_sizes"]).view(np.float32)


@pytest.mark.parametrize("options", TWO_LEVELS)
@pytest.mark.parametrize("kind", ["bimodal", "log_uniform"])
@pytest.mark.parametrize("n", [0, 1, 2, 3, 63, 64, 65, 127, 301, 1001])
def test_two_levels_match_brute_force(runtime, rng, kind, n, options):
    """Mixed sizes (and two slabs in the large list from 100 bodies on) fill both grid
    levels, with fine-fine, fine-coarse, coarse-fine and coarse-coarse pairs at 1001
    bodies: the pairs are brute force's at counts odd, even, around work-group
    multiples."""
    aabbs, static = make_aabbs(rng, n, kind)
    broadphase = make_broadphase(runtime, "grid", emission="owner", **options)
    broadphase.find_pairs(aabbs, static)
    assert broadphase.emission == "owner"
    expected = brute_force_pairs(aabbs, static)
    np.testing.assert_array_equal(broadphase.host_pairs(), expected)
    if n > 1000:  # (fewer bodies: the slabs' sizes raise the mean, most are fine)
        coarse = grid_levels(aabbs, None, options["fine_factor"]) == COARSE
        assert coarse.any() == (options["fine_factor"] < 4)
        if coarse.any():  # pairs of every kind were there to be found
            assert len({(bool(coarse[a]), bool(coarse[b])) for a, b in expected}) == 4


@pytest.mark.parametrize("options", TWO_LEVELS[::3] + TWO_LEVELS[1::3])
def test_all_bodies_in_one_cell(runtime, rng, options):
    """Bodies of mixed sizes with their lower corners in one fine cell: every pair."""
    n = 201
    lower = rng.uniform(0, 0.01, (n, 3)).astype(np.float32)
    size = np.where(rng.random((n, 1)) < 0.2, 1.1, 0.5) * rng.uniform(0.6, 1.0, (n, 3))
    aabbs, static = pack(lower, lower + size.astype(np.float32)), np.zeros(n, np.uint32)
    broadphase = make_broadphase(runtime, "grid", emission="owner", **options)
    broadphase.find_pairs(aabbs, static)
    pairs = broadphase.host_pairs()
    assert len(pairs) == n * (n - 1) // 2
    np.testing.assert_array_equal(pairs, brute_force_pairs(aabbs, static))


@pytest.mark.parametrize("work_group_size", [None, 4])
@pytest.mark.parametrize("kind", ["bimodal", "log_uniform"])
def test_two_levels_keep_environments_apart(runtime, rng, kind, work_group_size):
    """WorldBatch collision words: 7 environments of mixed sizes in one region and two
    shared slabs: the pairs within an environment or with a slab, never across."""
    aabbs, words = make_env_aabbs(rng, 97, kind, envs=7)
    broadphase = make_broadphase(runtime, "grid", emission="owner", work_group_size=work_group_size)
    broadphase.find_pairs(aabbs, words)
    assert broadphase.emission == "owner" and grid_sizes(broadphase)[1] > 0
    expected = env_pairs(aabbs, words)
    across = len(brute_force_pairs(aabbs, words & 1)) - len(expected)
    assert across > len(expected) > 0  # the environments do overlap
    np.testing.assert_array_equal(broadphase.host_pairs(), expected)


def test_level_sizes(runtime, rng):
    """Equal sizes (the BoxBox lattice): one level, the coarse one empty. Two sizes:
    each level's cell from its largest body, as the numpy rule says."""
    aabbs, static = scene_aabbs(boxbox_scene(7, 6, 5))
    broadphase = make_broadphase(runtime, "grid", emission="owner")
    broadphase.find_pairs(aabbs, static)
    size = np.max(aabbs["upper"][:, :3] - aabbs["lower"][:, :3], axis=1)
    assert grid_sizes(broadphase)[1] == 0 and grid_sizes(broadphase)[0] == size[1:].max()
    aabbs, static = make_aabbs(rng, 1000, "bimodal")
    broadphase.find_pairs(aabbs, static)
    size = np.max(aabbs["upper"][:, :3] - aabbs["lower"][:, :3], axis=1)
    levels = grid_levels(aabbs)
    np.testing.assert_array_equal(
        grid_sizes(broadphase), [size[levels == FINE].max(), size[levels == COARSE].max()]
    )
