"""BoundSearch against numpy's searchsorted (lower = side "left", upper = "right").

Keys contain long runs of duplicates; queries fall before, inside, between
and after the keys. Full size list (number of keys) on the default point;
every other search-space point on the reduced list.
"""

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen.primitives import BoundSearch
from rbgen.primitives.bound_search import search_space

from .primitive_spaces import FULL_SIZES, REDUCED_SIZES, all_points, label

NUMPY_SIDE = {"lower": "left", "upper": "right"}


def check(runtime, search, keys, queries, n_keys=None, n_queries=None, what=""):
    q = runtime.queue
    out = cla.to_device(q, np.full(max(queries.size, 1), 0xDEAD, np.uint32))
    search(
        cla.to_device(q, keys), cla.to_device(q, queries), out, n_keys=n_keys, n_queries=n_queries
    )
    nk = (
        keys.size
        if n_keys is None
        else min(keys.size, n_keys if isinstance(n_keys, int) else int(n_keys.get()[0]))
    )
    nq = (
        queries.size
        if n_queries is None
        else min(queries.size, n_queries if isinstance(n_queries, int) else int(n_queries.get()[0]))
    )
    expected = np.searchsorted(keys[:nk], queries[:nq], side=NUMPY_SIDE[search.side])
    got = out.get()
    assert np.array_equal(got[:nq], expected), what
    assert np.all(got[nq : queries.size] == 0xDEAD), what


def random_case(rng, n_keys, n_queries):
    keys = np.sort(rng.integers(10, 10 + max(1, n_keys // 4), n_keys, dtype=np.uint32) * 2)
    queries = rng.integers(0, 30 + n_keys, n_queries, dtype=np.uint32)
    if n_keys:
        queries[: n_queries // 2] = rng.choice(keys, n_queries // 2)  # exact hits on duplicates
    return keys, queries


@pytest.mark.parametrize("side", ["lower", "upper"])
def test_default_point_full_sizes(runtime, rng, side):
    search = BoundSearch(runtime, side)
    for n in FULL_SIZES:
        keys, queries = random_case(rng, n, min(n, 5000) + 3)
        check(runtime, search, keys, queries, what=f"n_keys={n}")
    keys, queries = random_case(rng, 100, 0)
    check(runtime, search, keys, queries, what="no queries")


def test_every_search_space_point(runtime, rng):
    for params in all_points(search_space, runtime.traits):
        for side in ("lower", "upper"):
            search = BoundSearch(runtime, side, params=params)
            for n in REDUCED_SIZES:
                keys, queries = random_case(rng, n, n + 1)
                check(runtime, search, keys, queries, what=f"{label(params)} {side} n={n}")


def test_device_counts(runtime, rng):
    search = BoundSearch(runtime, "upper")
    keys, queries = random_case(rng, 4000, 3000)

    def dev(count):
        return cla.to_device(runtime.queue, np.array([count], np.uint32))

    for n_keys, n_queries in (
        (dev(0), dev(3000)),
        (dev(1234), dev(17)),
        (dev(10**6), dev(10**6)),
        (2000, dev(2999)),
        (dev(3999), 1500),
    ):
        check(runtime, search, keys, queries, n_keys, n_queries, what=f"{n_keys} {n_queries}")
