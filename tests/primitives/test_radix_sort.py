"""RadixSort against numpy's stable argsort.

Keys are drawn from a small range at most sizes so that duplicates are
common: values (the original positions) must come out in numpy's stable
order. The full boundary size list runs on the heuristic default point
(key-value and keys only, 32 bits) and on the reference GPU's defaults of the
8-bit shapes (split, onesweep); every other search-space point (the device's own
space and the reference GPUs' -- see primitive_spaces) runs the reduced size
list, key-value with 32 and with 13 key bits. The GPU shapes are also run
with key_bits whose last digit is shorter than the others, and on all-equal
and extreme keys.
"""

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen.errors import RbgenError
from rbgen.primitives import RadixSort, float_to_sortable_uint, sortable_uint_to_float
from rbgen.primitives.radix_sort import search_space

from .primitive_spaces import FULL_SIZES, NVIDIA, REDUCED_SIZES, all_points, label

#: the reference GPU's defaults of each GPU shape (rendered for, and run on, this device)
GPU_SHAPES = {
    shape: RadixSort.default_params(NVIDIA, shape) for shape in ("split", "onesweep", "gpu")
}


def random_keys(rng, n, key_bits=32, duplicates=True):
    high = min(2**key_bits, max(2, n // 3)) if duplicates else 2**key_bits
    keys = rng.integers(0, high, n, dtype=np.uint64)
    # spread the small range over all key bits so every pass matters
    spread = (keys * np.uint64(2654435761)) % np.uint64(2**key_bits)
    return spread.astype(np.uint32)


def check_sort(runtime, sorter, keys, key_bits=32, what=""):
    n = keys.size
    d_keys = cla.to_device(runtime.queue, keys)
    d_values = (
        cla.to_device(runtime.queue, np.arange(n, dtype=np.uint32)) if sorter.with_values else None
    )
    sorter(d_keys, d_values)
    sort_keys = keys & np.uint32((1 << key_bits) - 1) if key_bits < 32 else keys
    order = np.argsort(sort_keys, kind="stable")
    assert np.array_equal(d_keys.get(), keys[order]), f"keys: {what} n={n}"
    if d_values is not None:
        assert np.array_equal(d_values.get(), order.astype(np.uint32)), f"values: {what} n={n}"


@pytest.mark.parametrize("with_values", [True, False], ids=["kv", "keys"])
def test_default_point_full_sizes(runtime, rng, with_values):
    sorter = RadixSort(runtime, 32, with_values)
    for n in FULL_SIZES:
        check_sort(runtime, sorter, random_keys(rng, n, duplicates=n % 2 == 1))


@pytest.mark.parametrize("shape", ["split", "onesweep"])
@pytest.mark.parametrize("with_values", [True, False], ids=["kv", "keys"])
def test_8_bit_shapes_full_sizes(runtime, rng, with_values, shape):
    sorter = RadixSort(runtime, 32, with_values, params=GPU_SHAPES[shape])
    assert sorter.program(1000)[0]["shape"] == shape  # onesweep passed its guard
    for n in FULL_SIZES:
        check_sort(runtime, sorter, random_keys(rng, n, duplicates=n % 2 == 1))


def test_every_search_space_point(runtime, rng):
    def extra(p):
        """On CPU devices, besides the reference GPUs' defaults: the 4-bit tiled
        default, a tiled 8-bit point, a 4-bit split point and a smaller onesweep
        tile (wavefront 32)."""
        point = (p["shape"], p["radix_bits"], p["work_group_size"], p["items_per_thread"])
        return p.get("wavefront") == 32 and point in {
            ("gpu", 4, 256, 8),
            ("gpu", 8, 64, 16),
            ("split", 4, 256, 16),
            ("onesweep", 8, 256, 8),
        }

    for params in all_points(search_space, runtime.traits, extra=extra):
        for key_bits in (32, 13):
            sorter = RadixSort(runtime, key_bits, with_values=True, params=params)
            for n in REDUCED_SIZES:
                check_sort(
                    runtime,
                    sorter,
                    random_keys(rng, n, key_bits),
                    key_bits,
                    f"{label(params)} key_bits={key_bits}",
                )


def test_bits_above_key_bits_are_ignored(runtime, rng):
    """Only the low key_bits bits order the keys; high bits ride along (stably)."""
    keys = rng.integers(0, 2**32, 3001, dtype=np.uint32)
    for key_bits in (1, 7, 16, 31):
        check_sort(
            runtime, RadixSort(runtime, key_bits), keys.copy(), key_bits, f"key_bits={key_bits}"
        )


@pytest.mark.parametrize("shape", ["split", "onesweep", "gpu"])
def test_short_last_digit(runtime, rng, shape):
    """key_bits that are not a multiple of the digit: the last pass sorts fewer
    bits (for 8-bit digits also 4 or fewer, where the tile needs one split only)."""
    for key_bits in (1, 3, 4, 5, 9, 12, 17, 31):
        sorter = RadixSort(runtime, key_bits, params=GPU_SHAPES[shape])
        for n in (1, 4099, 20_000):
            check_sort(
                runtime,
                sorter,
                random_keys(rng, n, key_bits),
                key_bits,
                f"{shape} key_bits={key_bits}",
            )


@pytest.mark.parametrize("shape", ["split", "onesweep", "gpu", "cpu"])
def test_equal_and_extreme_keys(runtime, rng, shape):
    """All keys equal (one digit fills whole tiles), keys equal to the split
    shape's padding key 0xFFFFFFFF in a partial tile, and keys from {0, 2^32-1}."""
    params = GPU_SHAPES.get(shape) or RadixSort.default_params(runtime.traits, "cpu")
    sorter = RadixSort(runtime, 32, params=params)
    n = 3 * 4096 + 17
    for keys in (
        np.full(n, 7, np.uint32),
        np.full(n, 0xFFFFFFFF, np.uint32),
        rng.choice(np.array([0, 0xFFFFFFFF], np.uint32), n),
    ):
        check_sort(runtime, sorter, keys, 32, f"{shape} keys from {np.unique(keys)}")


def test_launches_per_shape(runtime):
    """8-bit digits: 4 passes of (histogram, table scan, scatter) where 4-bit
    digits need 8; onesweep counts once and launches once per pass; no copy
    back after an even number of passes."""
    keys = cla.to_device(runtime.queue, np.arange(5000, dtype=np.uint32)[::-1].copy())
    launches = {}
    for shape, params in GPU_SHAPES.items():
        sorter = RadixSort(runtime, 32, with_values=False, params=params)
        sorter(keys)  # build first
        before = runtime.counters["launches"]
        sorter(keys)
        launches[shape] = runtime.counters["launches"] - before
    scan_launches = launches["split"] / 4 - 2
    assert scan_launches >= 1
    assert launches == {
        "split": 4 * (2 + scan_launches),
        "onesweep": 1 + 4,
        "gpu": 8 * (2 + scan_launches),
    }
    assert np.array_equal(keys.get(), np.arange(5000, dtype=np.uint32))


def test_onesweep_falls_back_when_its_guard_fails(runtime, rng, monkeypatch):
    """A device where the look-back cannot be trusted sorts with the split shape."""
    from rbgen.primitives import radix_sort

    monkeypatch.setattr(radix_sort, "onesweep_works", lambda runtime, params: False)
    sorter = RadixSort(runtime, 32, params=GPU_SHAPES["onesweep"])
    assert sorter.program(5000)[0] == RadixSort.default_params(runtime.traits, "split")
    check_sort(runtime, sorter, random_keys(rng, 5000), 32, "onesweep fallback")


@pytest.mark.parametrize("shape", ["cpu", "gpu", "split", "onesweep"])
def test_device_count(runtime, rng, shape):
    """A device count sorts only the prefix and leaves the tail untouched."""
    sorter = RadixSort(runtime, params=RadixSort.default_params(runtime.traits, shape))
    capacity = 6000
    keys = random_keys(rng, capacity)
    for count in (0, 1, 2345, capacity, 10**7):
        m = min(count, capacity)
        d_keys = cla.to_device(runtime.queue, keys)
        d_values = cla.to_device(runtime.queue, np.arange(capacity, dtype=np.uint32))
        sorter(d_keys, d_values, n=cla.to_device(runtime.queue, np.array([count], np.uint32)))
        order = np.argsort(keys[:m], kind="stable")
        out_keys, out_values = d_keys.get(), d_values.get()
        assert np.array_equal(out_keys[:m], keys[:m][order]), f"count={count}"
        assert np.array_equal(out_values[:m], order), f"count={count}"
        assert np.array_equal(out_keys[m:], keys[m:]), f"count={count}"
        assert np.array_equal(out_values[m:], np.arange(m, capacity)), f"count={count}"


def test_host_count_prefix(runtime, rng):
    keys = random_keys(rng, 5000)
    d_keys = cla.to_device(runtime.queue, keys)
    RadixSort(runtime, with_values=False)(d_keys, n=4321)
    out = d_keys.get()
    assert np.array_equal(out[:4321], np.sort(keys[:4321]))
    assert np.array_equal(out[4321:], keys[4321:])


def test_float_keys_through_bit_flip(runtime, rng):
    """Floats (negatives, zeros of both signs, infinities) sort like numpy's stable sort."""
    x = rng.standard_normal(10_001).astype(np.float32) * 1e3
    x[:6] = [0.0, -0.0, np.inf, -np.inf, 1e-40, -1e-40]
    x[6:1000] = np.round(x[6:1000])  # duplicates
    d_x = cla.to_device(runtime.queue, x)
    d_keys = float_to_sortable_uint(d_x, runtime)
    assert np.array_equal(d_keys.get(), float_to_sortable_uint(x))
    d_values = cla.to_device(runtime.queue, np.arange(x.size, dtype=np.uint32))
    RadixSort(runtime)(d_keys, d_values)
    order = np.argsort(x, kind="stable")
    # numpy orders -0.0 and 0.0 as equal; the flip puts -0.0 first: compare values
    assert np.array_equal(sortable_uint_to_float(d_keys, runtime).get(), x[order])
    assert np.array_equal(sortable_uint_to_float(d_keys.get()), x[order])
    nonzero = x[d_values.get()] != 0
    assert np.array_equal(d_values.get()[nonzero], order[x[order] != 0])


def test_onesweep_needs_a_work_item_per_digit(runtime):
    with pytest.raises(RbgenError, match="smaller than the 256 digits"):
        RadixSort(runtime, params=dict(GPU_SHAPES["onesweep"], work_group_size=128))
