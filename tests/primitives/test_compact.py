"""Compact against numpy's flatnonzero.

Flags are arbitrary nonzero values (not just 1). The full size list runs on
the heuristic default point (indices and values); every other search-space
point runs the reduced list with indices. The count stays on the device.
"""

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen.primitives import Compact
from rbgen.primitives.compact import search_space

from .primitive_spaces import FULL_SIZES, REDUCED_SIZES, all_points, label


def random_flags(rng, n, density):
    return ((rng.random(n) < density) * rng.integers(1, 2**32, n, dtype=np.uint64)).astype(
        np.uint32
    )


def check(runtime, compact, flags, values=None, n=None, what=""):
    q = runtime.queue
    size = flags.size
    out = cla.to_device(q, np.full(max(size, 1), 0xDEAD, np.uint32))
    count = cla.zeros(q, 1, np.uint32)
    d_values = None if values is None else cla.to_device(q, values)
    compact(cla.to_device(q, flags), out, count, n=n, values=d_values)
    m = size if n is None else min(size, n if isinstance(n, int) else int(n.get()[0]))
    kept = np.flatnonzero(flags[:m]).astype(np.uint32)
    expected = kept if values is None else values[kept]
    c = int(count.get()[0])
    assert c == kept.size, what
    result = out.get()
    assert np.array_equal(result[:c], expected), what
    assert np.all(result[c:] == 0xDEAD), what


@pytest.mark.parametrize("gather", [False, True], ids=["indices", "values"])
def test_default_point_full_sizes(runtime, rng, gather):
    compact = Compact(runtime)
    for n in FULL_SIZES:
        for density in (0.0, 0.3, 1.0) if n == 1000 else (0.5,):
            values = rng.integers(0, 2**32, n, dtype=np.uint32) if gather else None
            check(
                runtime,
                compact,
                random_flags(rng, n, density),
                values,
                what=f"n={n} density={density}",
            )


def test_every_search_space_point(runtime, rng):
    for params in all_points(search_space, runtime.traits):
        compact = Compact(runtime, params=params)
        for n in REDUCED_SIZES:
            check(runtime, compact, random_flags(rng, n, 0.4), what=f"{label(params)} n={n}")


@pytest.mark.parametrize("shape", ["cpu", "gpu"])
def test_device_count(runtime, rng, shape):
    compact = Compact(runtime, params=Compact.default_params(runtime.traits, shape))
    flags = random_flags(rng, 7000, 0.5)
    for count in (0, 1, 3333, 7000, 10**6):
        check(
            runtime,
            compact,
            flags,
            n=cla.to_device(runtime.queue, np.array([count], np.uint32)),
            what=f"count={count}",
        )
    check(runtime, compact, flags, n=4444, what="host count")
