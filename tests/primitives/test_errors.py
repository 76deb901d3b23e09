"""Bad input to the primitives: each raises RbgenError naming the argument."""

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen.device import Runtime
from rbgen.errors import RbgenError, TemplateParameterError
from rbgen.primitives import (
    BoundSearch,
    Compact,
    Fill,
    RadixSort,
    Reduce,
    Scan,
    float_to_sortable_uint,
)


@pytest.fixture
def arrays(runtime):
    q = runtime.queue
    return {
        "u": cla.to_device(q, np.arange(100, dtype=np.uint32)),
        "f": cla.to_device(q, np.arange(100, dtype=np.float32)),
        "u1": cla.zeros(q, 1, np.uint32),
        "f1": cla.zeros(q, 1, np.float32),
    }


def test_wrong_dtype(runtime, arrays):
    a = arrays
    with pytest.raises(RbgenError, match="src has dtype float32"):
        Scan(runtime, np.uint32)(a["f"], a["u"])
    with pytest.raises(RbgenError, match="keys has dtype float32"):
        RadixSort(runtime)(a["f"], a["u"])
    with pytest.raises(RbgenError, match="flags has dtype float32"):
        Compact(runtime)(a["f"], a["u"], a["u1"])
    with pytest.raises(RbgenError, match="out has dtype uint32"):
        Reduce(runtime, np.float32)(a["f"], a["u1"])
    with pytest.raises(RbgenError, match="queries has dtype float32"):
        BoundSearch(runtime)(a["u"], a["f"], a["u"])
    with pytest.raises(RbgenError, match="Scan dtype"):
        Scan(runtime, np.float64)
    with pytest.raises(RbgenError, match="Fill dtype"):
        Fill(runtime, np.int64)
    with pytest.raises(RbgenError, match="x has dtype uint32"):
        float_to_sortable_uint(np.arange(3, dtype=np.uint32))


def test_not_an_array(runtime, arrays):
    with pytest.raises(RbgenError, match="src must be a pyopencl.array.Array"):
        Scan(runtime)(np.arange(10, dtype=np.uint32), arrays["u"])


def test_non_contiguous(runtime, arrays):
    with pytest.raises(RbgenError, match="keys must be a contiguous 1-D array"):
        RadixSort(runtime)(arrays["u"][::2], arrays["u"])
    with pytest.raises(RbgenError, match="dst must be a contiguous 1-D array"):
        Scan(runtime)(arrays["u"][:50], arrays["u"][::2])


def test_offset_view(runtime, arrays):
    with pytest.raises(RbgenError, match="array must start at the beginning of its buffer"):
        Fill(runtime)(arrays["u"][10:], 1)


def test_other_context(runtime, arrays):
    other = Runtime(runtime.device)
    foreign = cla.zeros(other.queue, 100, np.uint32)
    with pytest.raises(RbgenError, match="values belongs to another OpenCL context"):
        RadixSort(runtime)(arrays["u"], foreign)
    with pytest.raises(RbgenError, match="src belongs to another OpenCL context"):
        Scan(runtime)(foreign, arrays["u"])


def test_values_shorter_than_keys(runtime, arrays):
    with pytest.raises(RbgenError, match="values holds 99 elements, shorter than keys"):
        RadixSort(runtime)(arrays["u"], cla.zeros(runtime.queue, 99, np.uint32))
    with pytest.raises(RbgenError, match="values is required"):
        RadixSort(runtime)(arrays["u"])
    with pytest.raises(RbgenError, match="with_values=False"):
        RadixSort(runtime, with_values=False)(arrays["u"], arrays["u"])


@pytest.mark.parametrize("key_bits", [0, 33, -1, 8.0, True])
def test_key_bits_out_of_range(runtime, key_bits):
    with pytest.raises(RbgenError, match="key_bits must be an int from 1 to 32"):
        RadixSort(runtime, key_bits=key_bits)


def test_bad_counts(runtime, arrays):
    with pytest.raises(RbgenError, match=r"n=101 is outside 0..100"):
        Scan(runtime)(arrays["u"], arrays["u"], n=101)
    with pytest.raises(RbgenError, match="n has dtype float32"):
        Scan(runtime)(arrays["u"], arrays["u"], n=arrays["f1"])
    with pytest.raises(RbgenError, match="n must be None, an int or a device uint32 array"):
        RadixSort(runtime)(arrays["u"], arrays["u"], n=3.0)
    with pytest.raises(RbgenError, match="n_keys holds 0 elements"):
        BoundSearch(runtime)(
            arrays["u"], arrays["u"], arrays["u"], n_keys=cla.zeros(runtime.queue, 0, np.uint32)
        )


def test_short_outputs(runtime, arrays):
    short = cla.zeros(runtime.queue, 10, np.uint32)
    with pytest.raises(RbgenError, match="dst holds 10 elements, shorter than src"):
        Scan(runtime)(arrays["u"], short)
    with pytest.raises(RbgenError, match="out holds 10 elements, needs at least 100"):
        Compact(runtime)(arrays["u"], short, arrays["u1"])
    with pytest.raises(RbgenError, match="out_count holds 0 elements"):
        Compact(runtime)(arrays["u"], arrays["u"], cla.zeros(runtime.queue, 0, np.uint32))
    with pytest.raises(RbgenError, match="out holds 10 elements, needs at least 100"):
        BoundSearch(runtime)(arrays["u"], arrays["u"], short)
    with pytest.raises(RbgenError, match="total has dtype float32"):
        Scan(runtime)(arrays["u"], arrays["u"], total=arrays["f1"])


def test_bad_options(runtime):
    with pytest.raises(RbgenError, match="op must be one of"):
        Reduce(runtime, np.float32, op="mean")
    with pytest.raises(RbgenError, match="side must be one of"):
        BoundSearch(runtime, side="left")
    with pytest.raises(RbgenError, match=r"params\['shape'\]"):
        Scan(runtime, params={"work_items": 4})
    with pytest.raises(TemplateParameterError, match="items_per_thread=3"):
        Scan(
            runtime,
            params={"shape": "gpu", "work_group_size": 64, "items_per_thread": 3, "wavefront": 32},
        )
    with pytest.raises(RbgenError, match="smaller than wavefront"):
        Compact(
            runtime,
            params={"shape": "gpu", "work_group_size": 32, "items_per_thread": 4, "wavefront": 64},
        )
    with pytest.raises(RbgenError, match="runtime must be an rbgen.Runtime"):
        Scan("pocl")
