"""Scan against numpy's float64 cumsum.

Integer inputs are small (0..7) and float inputs are small integers too, so
every partial sum up to 2^20+3 elements is exact in float32 and the
comparison is exact; one test uses real-valued floats with a tolerance
proportional to the running sum of magnitudes. The full boundary size list
runs on the device's heuristic default point for every dtype and mode; every
other search-space point (the device's own space and the reference GPUs' --
see primitive_spaces) runs the reduced size list on uint32 exclusive and
float32 inclusive (GPU-shape points on a CPU device: uint32 exclusive only).
"""
import numpy as np
import pyopencl.array as cla
import pytest

from rbgen.primitives import Scan
from rbgen.primitives.scan import search_space

from .primitive_spaces import FULL_SIZES, REDUCED_SIZES, all_points, label

DTYPES = [np.uint32, np.int32, np.float32]


def reference(x, inclusive):
    s = np.cumsum(x.astype(np.float64))
    if not inclusive:
        s = np.concatenate([[0.0], s[:-1]])[: len(x)]
    return s


def run_scan(runtime, scan, x, in_place=False, n=None):
    src = cla.to_device(runtime.queue, x)
    dst = src if in_place else cla.to_device(runtime.queue, np.full_like(x, 7))
    total = cla.zeros(runtime.queue, 1, x.dtype)
    scan(src, dst, n=n, total=total)
    return dst.get(), total.get()[0]


def small_values(rng, n, dtype):
    values = rng.integers(-3 if dtype == np.int32 else 0, 8, n)
    return values.astype(dtype)


@pytest.mark.parametrize("dtype", DTYPES, ids=lambda d: np.dtype(d).name)
@pytest.mark.parametrize("inclusive", [False, True], ids=["exclusive", "inclusive"])
def test_default_point_full_sizes(runtime, rng, dtype, inclusive):
    scan = Scan(runtime, dtype, inclusive)
    for n in FULL_SIZES:
        x = small_values(rng, n, dtype)
        out, total = run_scan(runtime, scan, x)
        ref = reference(x, inclusive)
        assert np.array_equal(out, ref.astype(dtype)), f"n={n}"
        assert total == x.astype(np.float64).sum(), f"n={n}"


def test_every_search_space_point(runtime, rng):
    for params in all_points(search_space, runtime.traits):
        # GPU-shape points on a CPU device: one variant only (PoCL compiles them slowly)
        gpu_on_cpu = params["shape"] == "gpu" and not runtime.traits.is_gpu
        variants = ((np.uint32, False),) if gpu_on_cpu else ((np.uint32, False), (np.float32, True))
        for dtype, inclusive in variants:
            scan = Scan(runtime, dtype, inclusive, params=params)
            for n in REDUCED_SIZES:
                x = small_values(rng, n, dtype)
                out, total = run_scan(runtime, scan, x, in_place=(n == 1000))
                assert np.array_equal(out, reference(x, inclusive).astype(dtype)), \
                    f"{label(params)} dtype={np.dtype(dtype).name} n={n}"
                assert total == x.astype(np.float64).sum(), f"{label(params)} n={n}"


def test_float_rounding_is_bounded(runtime, rng):
    """Real-valued floats: |error| <= 1e-5 * running sum of |x| (float32 has eps 6e-8)."""
    x = rng.uniform(-1.0, 1.0, 2**18 + 5).astype(np.float32)
    for inclusive in (False, True):
        out, _ = run_scan(runtime, Scan(runtime, np.float32, inclusive), x)
        bound = 1e-5 * reference(np.abs(x), inclusive) + 1e-6
        assert np.all(np.abs(out - reference(x, inclusive)) <= bound)


def test_uint_sums_wrap_like_c(runtime, rng):
    x = rng.integers(2**31, 2**32, 5000, dtype=np.uint32)
    out, total = run_scan(runtime, Scan(runtime, np.uint32, inclusive=True), x)
    assert np.array_equal(out, np.cumsum(x, dtype=np.uint64).astype(np.uint32))
    assert total == np.uint32(x.sum(dtype=np.uint64) % 2**32)


@pytest.mark.parametrize("shape", ["cpu", "gpu"])
def test_device_count(runtime, rng, shape):
    """A device count scans only its prefix, leaves the rest of dst alone and
    clamps to the capacity; nothing is read back before the results."""
    params = Scan.default_params(runtime.traits, shape)
    scan = Scan(runtime, np.uint32, params=params)
    capacity = 5000
    x = small_values(rng, capacity, np.uint32)
    for count in (0, 1, 777, 4999, 5000, 10**6):
        d_count = cla.to_device(runtime.queue, np.array([count], np.uint32))
        out, total = run_scan(runtime, scan, x, n=d_count)
        m = min(count, capacity)
        assert np.array_equal(out[:m], reference(x[:m], False)), f"count={count}"
        assert np.all(out[m:] == 7), f"count={count}"
        assert total == x[:m].sum()


def test_host_count_prefix(runtime, rng):
    x = small_values(rng, 3000, np.int32)
    out, total = run_scan(runtime, Scan(runtime, np.int32, inclusive=True), x, n=1234)
    assert np.array_equal(out[:1234], reference(x[:1234], True))
    assert np.all(out[1234:] == 7)
    assert total == x[:1234].sum()


def chained_points(traits):
    """The chained scan's own space, plus a GPU-like point on CPU devices."""
    from rbgen.primitives.scan import chained_search_space
    from .primitive_spaces import NVIDIA
    points = list(chained_search_space(traits))
    if not traits.is_gpu:
        points.append(chained_search_space(NVIDIA)[0])
    return points


def test_chained_scan_every_point(runtime, rng):
    """The opt-in single-pass scan: reduced size list plus a many-tile size, every point."""
    for params in chained_points(runtime.traits):
        tile = params["work_group_size"] * params["items_per_thread"]
        for dtype, inclusive in ((np.uint32, False), (np.float32, True)):
            scan = Scan(runtime, dtype, inclusive, chained=True, params=params)
            assert scan.program(1000)[0] == params  # the guard passed: no fallback
            for n in REDUCED_SIZES + [7 * tile + 3]:
                x = small_values(rng, n, dtype)
                out, total = run_scan(runtime, scan, x, in_place=(n == 1000))
                assert np.array_equal(out, reference(x, inclusive).astype(dtype)), \
                    f"{label(params)} n={n}"
                assert total == x.astype(np.float64).sum()


def test_chained_scan_device_count(runtime, rng):
    scan = Scan(runtime, np.uint32, chained=True)
    x = small_values(rng, 50_000, np.uint32)
    for count in (0, 1, 33_333, 10**6):
        m = min(count, x.size)
        out, total = run_scan(runtime, scan, x,
                              n=cla.to_device(runtime.queue, np.array([count], np.uint32)))
        assert np.array_equal(out[:m], reference(x[:m], False)) and np.all(out[m:] == 7)
        assert total == x[:m].sum()


def test_chained_scan_guard_falls_back(runtime, rng, monkeypatch):
    """When the guard reports failure (it warns then) the scan runs reduce-then-scan."""
    from rbgen.primitives import scan as scan_module
    monkeypatch.setattr(scan_module, "chained_scan_works", lambda rt, params: False)
    scan = Scan(runtime, np.int32, inclusive=True, chained=True)
    params, _ = scan.program(5000)
    assert params == Scan.default_params(runtime.traits)
    x = small_values(rng, 5000, np.int32)
    out, _ = run_scan(runtime, scan, x)
    assert np.array_equal(out, reference(x, True))
