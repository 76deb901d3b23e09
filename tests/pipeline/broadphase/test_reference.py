"""The host grid reference equals brute force (it is the benchmarks' sanity count)."""

from __future__ import annotations

import numpy as np
import pytest

from rbgen.pipeline.broadphase.reference import brute_force_pairs, grid_pairs

from .conftest import KINDS, make_aabbs


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("n", [0, 1, 2, 500])
def test_grid_reference_matches_brute_force(rng, kind, n):
    aabbs, static = make_aabbs(rng, n, kind)
    np.testing.assert_array_equal(grid_pairs(aabbs, static), brute_force_pairs(aabbs, static))


def test_brute_force_rules():
    lower = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0.5, 0.5], [3, 3, 3]], float)
    pairs = brute_force_pairs((lower, lower + 1), np.array([1, 1, 0, 0]))
    assert [tuple(p) for p in pairs] == [(0, 2), (1, 2)]  # (0, 1) touch but both are static
