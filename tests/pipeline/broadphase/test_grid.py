"""Grid specifics: owner emission, its large-body rows, its launch count and the
fallback to slot emission; the expected pairs come from `brute_force_pairs`."""

from __future__ import annotations

import numpy as np
import pytest

from rbgen.errors import RbgenError
from rbgen.launch import launches_by_kernel
from rbgen.pipeline.broadphase import make_broadphase
from rbgen.pipeline.broadphase.grid import LARGE_ROWS, grid_dim_for
from rbgen.pipeline.broadphase.reference import brute_force_pairs
from rbgen.scenes import boxbox_scene, scene_aabbs

from .conftest import make_aabbs

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


def test_grid_dim_keeps_neighbour_buckets_distinct():
    assert grid_dim_for(0) == grid_dim_for(1) == 3
    for n in (2, 13, 1000, 111_376):
        dim = grid_dim_for(n)
        assert dim >= 3 and dim**3 >= 2 * n
