"""BoundKernel: arguments reach the driver only when they change, and results stay right."""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

from rbgen.launch import BoundKernel, bound, instance

SOURCE = """
__kernel void axpy(__global const float* x, __global float* y, const float a, const uint n,
                   const float4 shift)
{
    /* one work-item per element; a work group is responsible for a block of them */
    uint i = get_global_id(0);
    if (i < n)
        y[i] = a * x[i] + y[i] + shift.y;
}
"""


class _Built:
    """Stands in for a codegen built program (what `instance` needs)."""

    def __init__(self, program):
        self.program = program


@pytest.fixture
def program(runtime):
    return cl.Program(runtime.context, SOURCE).build()


class _Counting:
    """Counts the driver calls a BoundKernel makes (wraps its setters)."""

    def __init__(self, bk: BoundKernel):
        self.calls = []
        kernel_set, bytes_set = bk.kernel.set_arg, bk._set_bytes
        bk._set_bytes = lambda i, v: (self.calls.append(i), bytes_set(i, v))
        self._kernel_set = kernel_set

        class _Proxy:
            def __init__(s, k):
                s._k = k

            def set_arg(s, i, v):
                self.calls.append(i)
                return kernel_set(i, v)

            def __getattr__(s, name):
                return getattr(s._k, name)

        self.proxy = _Proxy(bk.kernel)


def _axpy_reference(x, y, a, shift):
    return (np.float64(a) * x + y + shift[1]).astype(np.float32)


@pytest.mark.parametrize("n", [0, 1, 7, 64, 1000])
def test_results_match_reference_over_repeated_launches(runtime, program, rng, n):
    queue = runtime.queue
    x_host = rng.standard_normal(max(n, 1)).astype(np.float32)
    y_host = rng.standard_normal(max(n, 1)).astype(np.float32)
    x, y = cla.to_device(queue, x_host), cla.to_device(queue, y_host)
    bk = bound(runtime, program.axpy)
    expected = y_host.copy()
    for step, a in enumerate([0.5, 0.5, -2.0, -2.0]):
        shift = np.array([0, step, 0, 0], np.float32)
        before = runtime.counters["launches"]
        bk.over(n, 16, x, y, np.float32(a), np.uint32(n), shift)
        assert runtime.counters["launches"] == before + 1
        expected[:n] = _axpy_reference(x_host[:n], expected[:n], a, shift)
    np.testing.assert_allclose(y.get()[:n], expected[:n], rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(y.get()[n:], y_host[n:])  # past n untouched


def test_only_changed_arguments_are_set(runtime, program, rng):
    queue = runtime.queue
    bk = BoundKernel(runtime, program.axpy)
    counting = _Counting(bk)
    bk.kernel = counting.proxy
    x, y, z = (cla.zeros(queue, 8, np.float32) for _ in range(3))
    shift = np.zeros(4, np.float32)
    bk.bind(x, y, np.float32(1), np.uint32(8), shift)
    assert sorted(counting.calls) == [0, 1, 2, 3, 4]
    counting.calls.clear()
    bk.bind(x, y, np.float32(1), np.uint32(8), shift.copy())  # same values, new objects
    assert counting.calls == []
    bk.bind(z, y, np.float32(2), np.uint32(8), shift)  # new buffer and a new scalar
    assert sorted(counting.calls) == [0, 2]
    counting.calls.clear()
    bk.bind(z, y, np.float32(2), np.int32(8), shift)  # same value, other type: set again
    assert counting.calls == [3]
    counting.calls.clear()
    shift[1] = 5  # the cache holds a copy: mutating the caller's array is a change
    bk.bind(z, y, np.float32(2), np.int32(8), shift)
    assert counting.calls == [4]
    counting.calls.clear()
    bk.forget()
    bk.bind(z, y, np.float32(2), np.int32(8), shift)
    assert sorted(counting.calls) == [0, 1, 2, 3, 4]
    with pytest.raises(TypeError, match="takes 5 arguments"):
        bk.bind(x, y)


def test_partial_binds_skip_unchanged_arguments_too(runtime, program):
    """bind_first / bind_last reach the driver only for changed arguments, and the
    values they skip are still those the driver holds (a later full bind agrees)."""
    queue = runtime.queue
    bk = BoundKernel(runtime, program.axpy)
    counting = _Counting(bk)
    bk.kernel = counting.proxy
    x, y = (cla.zeros(queue, 8, np.float32) for _ in range(2))
    shift = np.zeros(4, np.float32)
    bk.bind_first(x, y, np.float32(1))
    bk.bind_last(np.uint32(8), shift)
    assert sorted(counting.calls) == [0, 1, 2, 3, 4]
    counting.calls.clear()
    bk.bind_first(x, y, np.float32(1))  # a fresh scalar of the same value
    bk.bind_last(np.uint32(8), shift.copy())
    assert counting.calls == []
    bk.bind_last(np.uint32(7), shift)
    assert counting.calls == [3]
    counting.calls.clear()
    bk.bind_first(x, y, np.int32(1))  # another type (4 bytes all the same): set
    assert counting.calls == [2]
    counting.calls.clear()
    bk.bind(x, y, np.int32(1), np.uint32(7), shift)
    assert counting.calls == []


def test_one_cache_per_kernel_object(runtime, program):
    """Two owners of one kernel object share its cache; an `instance` has its own."""
    kernel = program.axpy
    assert bound(runtime, kernel) is bound(runtime, kernel)
    assert runtime.bound(kernel) is bound(runtime, kernel)
    other = instance(runtime, _Built(program), "axpy")
    assert other is not bound(runtime, kernel) and other.kernel is not kernel


def test_instances_keep_their_own_scalars(runtime, program, rng):
    """Two kernel objects of one function launched alternately keep their arguments."""
    queue = runtime.queue
    n = 37
    x_host = rng.standard_normal(n).astype(np.float32)
    x = cla.to_device(queue, x_host)
    y1, y2 = cla.zeros(queue, n, np.float32), cla.zeros(queue, n, np.float32)
    built = _Built(program)
    first, second = instance(runtime, built, "axpy"), instance(runtime, built, "axpy")
    shift = np.zeros(4, np.float32)
    first.bind(x, y1, np.float32(3), np.uint32(n), shift)
    second.bind(x, y2, np.float32(-1), np.uint32(n), shift)
    for _ in range(3):
        first.launch(64, 16)
        second.launch(64, 16)
    np.testing.assert_allclose(y1.get(), 3 * 3.0 * x_host.astype(np.float64), rtol=1e-5)
    np.testing.assert_allclose(y2.get(), -3.0 * x_host.astype(np.float64), rtol=1e-5)
