"""The pair buffer: ordering by (a, b) on both key paths, status, growth."""

from __future__ import annotations

import numpy as np
import pytest

from rbgen import layouts
from rbgen.errors import RbgenError
from rbgen.pipeline.broadphase.pairs import MAX_FOLDED_BODIES, PairBuffer, check_capacity


def random_pairs(rng, body_count, count):
    """Distinct pairs a < b in random order."""
    a = rng.integers(0, body_count - 1, 3 * count)
    b = a + 1 + (rng.integers(0, body_count, 3 * count) % (body_count - 1 - a))
    pairs = np.unique(np.stack([a, b], axis=1), axis=0)[:count]
    return pairs[rng.permutation(len(pairs))].astype(np.uint32)


@pytest.mark.parametrize("body_count", [2, 1000, MAX_FOLDED_BODIES, MAX_FOLDED_BODIES + 1, 200_003])
def test_sort_orders_by_a_then_b(runtime, rng, body_count):
    """Folded keys (n <= 65536) and two stable sorts (larger n) give lexicographic order."""
    pairs = random_pairs(rng, body_count, min(5000, body_count * (body_count - 1) // 2))
    buffer = PairBuffer(runtime, len(pairs) + 17)
    buffer.pairs_a.set(np.concatenate([pairs[:, 0], np.zeros(17, np.uint32)]))
    buffer.pairs_b.set(np.concatenate([pairs[:, 1], np.zeros(17, np.uint32)]))
    status = np.zeros(1, layouts.BROADPHASE_STATUS.dtype)
    status["pair_count"] = status["pairs_found"] = len(pairs)
    buffer.status.set(status.view(np.uint32))
    buffer.sort(body_count)
    buffer.start_status_read()
    assert buffer.read_status()["pair_count"] == len(pairs)
    expected = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    np.testing.assert_array_equal(buffer.host_pairs(len(pairs)), expected)


def test_status_reset_and_growth(runtime):
    buffer = PairBuffer(runtime, 10)
    buffer.reset_status()
    buffer.start_status_read()
    status = buffer.read_status()
    assert status["pair_count"] == status["pairs_found"] == status["retry"] == 0
    assert status["bad_body"] == layouts.BP_NO_BODY
    buffer.grow_for(11)
    assert buffer.capacity >= 20 and buffer.pairs.size == buffer.capacity
    assert int(buffer.count.get()[0]) == 0


def test_capacity_must_be_a_positive_integer():
    assert check_capacity(3) == 3
    for bad in (0, -1, 1.5, True, "8"):
        with pytest.raises(RbgenError, match="pair capacity"):
            check_capacity(bad)
