"""Reduce (sum, min, max) against numpy in float64.

Integer sums wrap modulo 2^32 (compared with numpy's wrapping sum); float
sums are compared with a tolerance of 1e-5 of the sum of magnitudes. The full
size list runs on the heuristic default point for every dtype and op; every
other search-space point runs the reduced list on float32 sum and int32 min.
The reduction of no elements is the identity (0, type max / +inf, type min / -inf).
"""

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen.primitives import Reduce
from rbgen.primitives.reduce import search_space

from .primitive_spaces import FULL_SIZES, REDUCED_SIZES, all_points, label

IDENTITY = {
    ("sum", np.uint32): 0,
    ("sum", np.int32): 0,
    ("sum", np.float32): 0.0,
    ("min", np.uint32): 2**32 - 1,
    ("min", np.int32): 2**31 - 1,
    ("min", np.float32): np.inf,
    ("max", np.uint32): 0,
    ("max", np.int32): -(2**31),
    ("max", np.float32): -np.inf,
}


def values(rng, n, dtype):
    if dtype == np.uint32:
        return rng.integers(0, 2**32, n, dtype=np.uint32)
    if dtype == np.int32:
        return rng.integers(-(2**31), 2**31, n, dtype=np.int64).astype(np.int32)
    return rng.uniform(-100, 100, n).astype(np.float32)


def check(runtime, reducer, x, dtype, op, what="", n=None):
    out = cla.to_device(runtime.queue, np.array([17], dtype))
    reducer(cla.to_device(runtime.queue, x), out, n=n)
    got = out.get()[0]
    if x.size == 0:
        assert got == IDENTITY[(op, dtype)], what
    elif op == "sum" and dtype == np.float32:
        assert abs(got - x.astype(np.float64).sum()) <= 1e-5 * np.abs(x).astype(np.float64).sum(), (
            what
        )
    elif op == "sum":
        assert got == x.sum(dtype=dtype), what  # numpy wraps like C
    else:
        assert got == getattr(x, op)(), what


@pytest.mark.parametrize("dtype", [np.uint32, np.int32, np.float32], ids=lambda d: np.dtype(d).name)
@pytest.mark.parametrize("op", ["sum", "min", "max"])
def test_default_point_full_sizes(runtime, rng, dtype, op):
    reducer = Reduce(runtime, dtype, op)
    for n in FULL_SIZES:
        check(runtime, reducer, values(rng, n, dtype), dtype, op, f"n={n}")


def test_every_search_space_point(runtime, rng):
    for params in all_points(search_space, runtime.traits):
        for dtype, op in ((np.float32, "sum"), (np.int32, "min")):
            reducer = Reduce(runtime, dtype, op, params=params)
            for n in REDUCED_SIZES:
                check(
                    runtime,
                    reducer,
                    values(rng, n, dtype),
                    dtype,
                    op,
                    f"{label(params)} {op} n={n}",
                )


@pytest.mark.parametrize("shape", ["cpu", "gpu"])
def test_device_count(runtime, rng, shape):
    x = values(rng, 5000, np.float32)
    reducer = Reduce(
        runtime, np.float32, "max", params=Reduce.default_params(runtime.traits, shape)
    )
    for count in (0, 1, 999, 5000, 10**6):
        m = min(count, x.size)
        check(
            runtime,
            reducer,
            x,
            np.float32,
            "max",
            f"count={count}",
            n=cla.to_device(runtime.queue, np.array([count], np.uint32)),
        ) if m == x.size else None
        out = cla.zeros(runtime.queue, 1, np.float32)
        reducer(
            cla.to_device(runtime.queue, x),
            out,
            n=cla.to_device(runtime.queue, np.array([count], np.uint32)),
        )
        assert out.get()[0] == (x[:m].max() if m else -np.inf), f"count={count}"
