"""Fill: the first n elements get the value, the rest is untouched.

Full size list on the default point for every dtype; every other
search-space point on the reduced list.
"""

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen.primitives import Fill
from rbgen.primitives.fill import search_space

from .primitive_spaces import FULL_SIZES, REDUCED_SIZES, all_points, label


def check(runtime, fill, size, value, dtype, n=None, what=""):
    before = np.arange(size).astype(dtype)
    array = cla.to_device(runtime.queue, before)
    fill(array, value, n=n)
    m = size if n is None else min(size, n if isinstance(n, int) else int(n.get()[0]))
    after = array.get()
    assert np.all(after[:m] == dtype(value)), what
    assert np.array_equal(after[m:], before[m:]), what


@pytest.mark.parametrize("dtype", [np.uint32, np.int32, np.float32], ids=lambda d: np.dtype(d).name)
def test_default_point_full_sizes(runtime, rng, dtype):
    fill = Fill(runtime, dtype)
    value = {np.uint32: 4000000000, np.int32: -123456, np.float32: -2.5}[dtype]
    for n in FULL_SIZES:
        check(runtime, fill, n, value, dtype, what=f"n={n}")


def test_every_search_space_point(runtime, rng):
    for params in all_points(search_space, runtime.traits):
        fill = Fill(runtime, np.uint32, params=params)
        for n in REDUCED_SIZES:
            check(
                runtime,
                fill,
                n,
                int(rng.integers(0, 2**32)),
                np.uint32,
                what=f"{label(params)} n={n}",
            )


def test_counts(runtime, rng):
    fill = Fill(runtime, np.float32)
    for count in (0, 1, 777, 3000, 10**6):
        check(
            runtime,
            fill,
            3000,
            1.5,
            np.float32,
            n=cla.to_device(runtime.queue, np.array([count], np.uint32)),
            what=f"count={count}",
        )
    check(runtime, fill, 3000, 1.5, np.float32, n=1001, what="host count")
