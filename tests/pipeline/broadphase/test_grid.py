"""Grid specifics: owner emission, its large-body rows and the fallback to slot emission."""
from __future__ import annotations

import numpy as np
import pytest

from rbgen.pipeline.broadphase import make_broadphase
from rbgen.pipeline.broadphase.grid import LARGE_ROWS, grid_dim_for
from rbgen.pipeline.broadphase.reference import brute_force_pairs
from rbgen.scenes import boxbox_scene, scene_aabbs

from .conftest import make_aabbs


@pytest.mark.parametrize("large", [LARGE_ROWS, LARGE_ROWS + 1])
def test_owner_emission_large_rows_and_fallback(runtime, rng, large):
    """Up to LARGE_ROWS large bodies stay in owner emission; one more makes the
    first query ask for a retry, which runs with slot emission; both are exact."""
    aabbs, static = make_aabbs(rng, 400, "uniform")
    slabs = rng.choice(400, large, replace=False)
    aabbs["lower"][slabs, :3] = -1e30
    aabbs["upper"][slabs, 0] = 1e30
    aabbs["upper"][slabs, 2] = 1e30
    aabbs["upper"][slabs, 1] = rng.uniform(0, 10, large)
    broadphase = make_broadphase(runtime, "grid", emission="owner")
    broadphase.enqueue(aabbs, static)
    assert broadphase.check() is (large <= LARGE_ROWS)
    broadphase.find_pairs(aabbs, static)
    assert broadphase.emission == ("owner" if large <= LARGE_ROWS else "slot")
    np.testing.assert_array_equal(broadphase.host_pairs(), brute_force_pairs(aabbs, static))


@pytest.mark.parametrize("emission", ["owner", "slot"])
def test_boxbox_scene(runtime, emission):
    """The BoxBox lattice: resting faces touch exactly; the ground is the large body."""
    aabbs, static = scene_aabbs(boxbox_scene(7, 6, 5))
    broadphase = make_broadphase(runtime, "grid", emission=emission)
    broadphase.find_pairs(aabbs, static)
    np.testing.assert_array_equal(broadphase.host_pairs(), brute_force_pairs(aabbs, static))


def test_grid_dim_keeps_neighbour_buckets_distinct():
    assert grid_dim_for(0) == grid_dim_for(1) == 3
    for n in (2, 13, 1000, 111_376):
        dim = grid_dim_for(n)
        assert dim >= 3 and dim ** 3 >= 2 * n
