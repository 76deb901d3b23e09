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

import dataclasses

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

from rbgen.device import DeviceTraits, list_devices
from rbgen.errors import RbgenError
from rbgen.primitives import Scan
from rbgen.primitives._base import unique_params
from rbgen.primitives.scan import chained_search_space, search_space

from .primitive_spaces import AMD, FULL_SIZES, NVIDIA, REDUCED_SIZES, all_points, label

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
    """Reduce-then-scan points (the chained ones have their own tests below)."""
    for params in all_points(search_space, runtime.traits):
        if params["shape"] == "chained":
            continue
        # GPU-shape points on a CPU device: one variant only (PoCL compiles them slowly)
        gpu_on_cpu = params["shape"] == "gpu" and not runtime.traits.is_gpu
        variants = ((np.uint32, False),) if gpu_on_cpu else ((np.uint32, False), (np.float32, True))
        for dtype, inclusive in variants:
            scan = Scan(runtime, dtype, inclusive, params=params)
            for n in REDUCED_SIZES:
                x = small_values(rng, n, dtype)
                out, total = run_scan(runtime, scan, x, in_place=(n == 1000))
                assert np.array_equal(out, reference(x, inclusive).astype(dtype)), (
                    f"{label(params)} dtype={np.dtype(dtype).name} n={n}"
                )
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


def chained_points():
    """The chained scan's whole space on every device present and on the
    reference NVIDIA GPU, plus the AMD reference's default point (wavefront
    64) and the CPU shape taking tiles by group id, each point tested on
    every device (PoCL compiles a GPU-shape point in 10-20 s)."""
    traits = [DeviceTraits.of(entry.device) for entry in list_devices()] + [NVIDIA]
    cpu = dataclasses.replace(NVIDIA, is_gpu=False)
    return unique_params(
        [p for t in traits for p in chained_search_space(t)]
        + chained_search_space(AMD)[:1]
        + [dict(Scan.default_params(cpu, "chained"), order="group")]
    )


def scan_with_count(runtime, scan, x, count, capacity):
    """Scan the first ``count`` of ``capacity`` elements, the count on the device."""
    src = cla.to_device(runtime.queue, np.concatenate([x, np.ones(capacity - x.size, x.dtype)]))
    dst = cla.to_device(runtime.queue, np.full(capacity, 7, x.dtype))
    total = cla.to_device(runtime.queue, np.full(1, 5, x.dtype))
    d_count = cla.to_device(runtime.queue, np.array([count], np.uint32))
    scan(src, dst, n=d_count, total=total)
    return dst.get(), total.get()[0]


@pytest.mark.parametrize("params", chained_points(), ids=label)
def test_chained_scan_every_point(runtime, rng, params):
    """Every point of the chained space, every dtype and mode, the full boundary
    list plus sizes around a tile; odd sizes get a device count (capacity + 5)
    and every scan writes its total to a device array."""
    if params["work_group_size"] > runtime.traits.max_work_group_size:
        pytest.skip("work group larger than this device allows")
    tile = params["work_group_size"] * params["items_per_thread"]
    sizes = FULL_SIZES + [tile - 1, tile, 3 * tile + 1]
    for dtype in DTYPES:
        for inclusive in (False, True):
            scan = Scan(runtime, dtype, inclusive, params=params)
            assert scan.program(1000)[0] == params  # the guard passed: no fallback
            for n in sizes:
                x = small_values(rng, n, dtype)
                what = f"{label(params)} {np.dtype(dtype).name} inclusive={inclusive} n={n}"
                if n % 2:
                    out, total = scan_with_count(runtime, scan, x, n, n + 5)
                    assert np.all(out[n:] == 7), what
                    out = out[:n]
                else:
                    out, total = run_scan(runtime, scan, x, in_place=(n == 1000))
                assert np.array_equal(out, reference(x, inclusive).astype(dtype)), what
                assert total == x.astype(np.float64).sum(), what


def test_chained_scan_device_count(runtime, rng):
    """Device counts of 0, 1, a middle value and more than the capacity (clamped)."""
    scan = Scan(runtime, np.uint32, chained=True)
    x = small_values(rng, 50_000, np.uint32)
    for count in (0, 1, 33_333, 10**6):
        m = min(count, x.size)
        out, total = run_scan(
            runtime, scan, x, n=cla.to_device(runtime.queue, np.array([count], np.uint32))
        )
        assert np.array_equal(out[:m], reference(x[:m], False)) and np.all(out[m:] == 7)
        assert total == x[:m].sum()


@pytest.mark.parametrize("shape", ["cpu", "gpu"])
def test_chained_scan_many_calls_in_a_row(runtime, rng, shape):
    """Calls queued back to back (no wait between them) on one Scan, sizes
    growing and shrinking, new data each time: a tile must never take a word
    left by an earlier call (other epoch) for its predecessor's. Then the
    ticket counter is back at zero and the state was zeroed only once."""
    traits = runtime.traits if shape == runtime.traits.kind else NVIDIA
    params = Scan.default_params(traits, "chained")
    tile = params["work_group_size"] * params["items_per_thread"]
    scan = Scan(runtime, np.int32, inclusive=True, params=params)
    sizes = [9 * tile + 5, 2 * tile, 9 * tile + 5, 1, 5 * tile - 1, 0, 9 * tile + 5, 33] * 4
    fills = []
    real_fill = cl.enqueue_fill_buffer

    def counted_fill(*args, **kwargs):
        fills.append(args)
        return real_fill(*args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(cl, "enqueue_fill_buffer", counted_fill)
        inputs, outputs, totals = [], [], []
        for n in sizes:
            x = small_values(rng, n, np.int32)
            src = cla.to_device(runtime.queue, x)
            inputs.append(x)
            outputs.append(cla.empty_like(src))
            totals.append(cla.zeros(runtime.queue, 1, np.int32))
            scan(src, outputs[-1], total=totals[-1])
        for x, out, total in zip(inputs, outputs, totals):
            assert np.array_equal(out.get(), reference(x, True)), f"n={x.size}"
            assert total.get()[0] == x.sum(), f"n={x.size}"
    assert sum(1 for args in fills if args[1] is scan._state) == 1  # at allocation only
    counters = np.empty(2, np.uint32)
    cl.enqueue_copy(runtime.queue, counters, scan._state, is_blocking=True)
    assert counters[0] == 0 and counters[1] == 0  # tickets reset, no spin limit hit


def test_chained_scan_ignores_words_of_other_epochs(runtime, rng):
    """Fill the tile words with INCLUSIVE words of the wrong epochs (the
    previous one, the next one, zero) carrying wrong values: the result must
    not change. Also across the epoch wrap, where the state is zeroed again."""
    from rbgen.primitives.scan import EPOCHS

    scan = Scan(runtime, np.uint32, chained=True)
    params = scan.program(100_000)[0]
    tile = params["work_group_size"] * params["items_per_thread"]
    n = 7 * tile + 3
    x = small_values(rng, n, np.uint32)
    out, _ = run_scan(runtime, scan, x)  # allocates the state
    assert np.array_equal(out, reference(x, False))
    for next_epoch in (scan._epoch + 1, EPOCHS - 1, 1):
        scan._epoch = next_epoch - 1
        words = np.empty(scan._state.size // 8, np.uint64)
        for i, epoch in enumerate((next_epoch - 1, next_epoch + 1, 0)):
            low = (epoch % EPOCHS << 2) | 2  # INCLUSIVE
            values = rng.integers(1, 1000, words[1 + i :: 3].size, dtype=np.uint64)
            words[1 + i :: 3] = (values << np.uint64(32)) | np.uint64(low)
        words[0] = 0
        cl.enqueue_copy(runtime.queue, scan._state, words)
        out, total = run_scan(runtime, scan, x)
        assert np.array_equal(out, reference(x, False)), f"epoch {next_epoch}"
        assert total == x.sum()
        out, total = run_scan(runtime, scan, x)  # the epoch after (wrapped: zeroed and 1)
        assert np.array_equal(out, reference(x, False)), f"epoch after {next_epoch}"
    assert scan._epoch == 2


def test_chained_tile_words(runtime, rng):
    """The device helpers that pack and read tile words: a word of another
    epoch (earlier, later, zeroed state) reads as empty, one of this epoch
    gives back its status and value bits (any float, negative ints)."""
    from rbgen.primitives.scan import CHAINED, EPOCHS

    source = CHAINED.spec(
        dtype="float", inclusive=False, **Scan.default_params(runtime.traits, "chained", strip=True)
    ).source
    source += """
__kernel void read_words(__global const ulong* words, const uint epoch, __global uint* status,
                         __global float* values)
{
    uint i = get_global_id(0);
    status[i] = word_status(words[i], epoch);
    values[i] = as_float((uint)(words[i] >> 32));
}
__kernel void make_words(__global const uint* status, __global const uint* epochs,
                         __global const float* values, __global ulong* words)
{
    uint i = get_global_id(0);
    words[i] = tile_word(status[i], epochs[i], values[i]);
}
"""
    program = cl.Program(runtime.context, source).build()
    count = 600
    epoch = int(rng.integers(2, EPOCHS - 1))
    epochs = rng.choice([epoch - 1, epoch, epoch + 1, 0, EPOCHS - 1], count).astype(np.uint32)
    status = rng.integers(1, 3, count).astype(np.uint32)
    values = rng.normal(0, 1e6, count).astype(np.float32)
    d = {
        k: cla.to_device(runtime.queue, v)
        for k, v in (("status", status), ("epochs", epochs), ("values", values))
    }
    words = cla.empty(runtime.queue, count, np.uint64)
    program.make_words(
        runtime.queue,
        (count,),
        None,
        d["status"].data,
        d["epochs"].data,
        d["values"].data,
        words.data,
    )
    got_status = cla.empty(runtime.queue, count, np.uint32)
    got_values = cla.empty(runtime.queue, count, np.float32)
    program.read_words(
        runtime.queue,
        (count,),
        None,
        words.data,
        np.uint32(epoch),
        got_status.data,
        got_values.data,
    )
    assert np.array_equal(got_status.get(), np.where(epochs == epoch, status, 0))
    assert np.array_equal(got_values.get().view(np.uint32), values.view(np.uint32))


@pytest.mark.parametrize("n", [0, 1, 5000, 3 * 10**5])
def test_chained_scan_is_one_launch(runtime, rng, n):
    scan = Scan(runtime, np.uint32, chained=True)
    x = small_values(rng, max(n, 1), np.uint32)
    src, dst = cla.to_device(runtime.queue, x), cla.empty(runtime.queue, x.size, np.uint32)
    scan(src, dst, n=n)  # builds and runs the guard
    before = runtime.counters["launches"]
    scan(src, dst, n=n)
    assert runtime.counters["launches"] == before + 1
    assert np.array_equal(dst.get()[:n], reference(x[:n], False))


def test_chained_params_are_checked(runtime):
    """Contradictory chained parameters fail at construction, naming the parameter."""
    gpu = Scan.default_params(NVIDIA, "chained")
    cpu = Scan.default_params(dataclasses.replace(NVIDIA, is_gpu=False), "chained")
    with pytest.raises(RbgenError, match="items_per_thread=128"):
        Scan(runtime, params=dict(gpu, items_per_thread=128))
    with pytest.raises(RbgenError, match="wavefront=1"):
        Scan(runtime, params=dict(gpu, wavefront=1))
    with pytest.raises(RbgenError, match="items_per_thread=2"):
        Scan(runtime, params=dict(gpu, items_per_thread=2))
    with pytest.raises(RbgenError, match="lookback=16"):
        Scan(runtime, params=dict(gpu, lookback=16))  # narrower than a wavefront
    with pytest.raises(RbgenError, match="lookback=512"):
        Scan(runtime, params=dict(gpu, lookback=512))  # more than one per work-item
    with pytest.raises(RbgenError, match="lookback=32"):
        Scan(runtime, params=dict(cpu, lookback=32))  # the serial shape polls one
    with pytest.raises(RbgenError, match="lookback"):
        Scan(runtime, params={k: v for k, v in gpu.items() if k != "lookback"})
    with pytest.raises(RbgenError, match="chained=True contradicts"):
        Scan(runtime, chained=True, params=Scan.default_params(runtime.traits))


LOOK_BACK_KERNEL = """
__kernel void run_look_back(__global const ulong* words, __global uint* failed, const uint epoch,
                            __global const uint* tiles, __global T* before)
{
    __local T window_values[2 * LOOKBACK];
    __local uint marks[2];
    if (get_local_id(0) == 0)
        marks[0] = marks[1] = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    before[get_global_id(0)] = look_back(words, failed, tiles[get_group_id(0)], epoch,
                                         window_values, marks);
}
"""


@pytest.mark.parametrize("lookback", [32, 256])
def test_chained_look_back_over_many_windows(runtime, rng, lookback):
    """The GPU shape's look-back on prepared tile words (every predecessor
    published; INCLUSIVE ones rare, so a tile may walk many windows, or back
    to tile 0): every work-item of a group gets the sum of the predecessors
    up to and including the nearest INCLUSIVE one."""
    from rbgen.primitives.scan import CHAINED, EPOCHS

    params = dict(Scan.default_params(NVIDIA, "chained", strip=True), lookback=lookback)
    wg = params["work_group_size"]
    if wg > runtime.traits.max_work_group_size:
        pytest.skip("work group larger than this device allows")
    program = cl.Program(
        runtime.context,
        CHAINED.spec(dtype="uint", inclusive=False, **params).source + LOOK_BACK_KERNEL,
    ).build()
    count = 3000
    epoch = int(rng.integers(1, EPOCHS))
    status = np.where(rng.random(count) < 0.004, 2, 1).astype(np.uint64)  # INCLUSIVE : AGGREGATE
    values = rng.integers(0, 2**32, count, dtype=np.uint64)
    words = (values << np.uint64(32)) | (np.uint64(epoch) << np.uint64(2)) | status
    inclusive = np.flatnonzero(status == 2)
    tiles = np.unique(
        np.concatenate(
            [
                [0, 1, 2, lookback - 1, lookback, lookback + 1, 2 * lookback + 3, count - 1],
                inclusive + 1,
                inclusive[:5] + lookback,
                rng.integers(0, count, 40),
            ]
        )
    ).astype(np.uint32)
    tiles = tiles[tiles < count]
    d_words = cla.to_device(runtime.queue, words)
    failed = cla.zeros(runtime.queue, 1, np.uint32)
    d_tiles = cla.to_device(runtime.queue, tiles)
    before = cla.empty(runtime.queue, tiles.size * wg, np.uint32)
    program.run_look_back(
        runtime.queue,
        (tiles.size * wg,),
        (wg,),
        d_words.data,
        failed.data,
        np.uint32(epoch),
        d_tiles.data,
        before.data,
    )
    got = before.get().reshape(tiles.size, wg)
    for row, tile in zip(got, tiles):
        nearest = inclusive[inclusive < tile]
        first = nearest[-1] if nearest.size else 0
        expected = values[first:tile].sum() % 2**32
        assert np.all(row == expected), f"lookback={lookback} tile={tile} (from {first})"
    assert failed.get()[0] == 0


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


def test_chained_guard_needs_64_bit_atomics(runtime, monkeypatch):
    """A device without the extension fails the guard with a warning naming it."""
    from rbgen.primitives import _base
    from rbgen.primitives import scan as scan_module

    monkeypatch.setattr(scan_module, "CHAINED_EXTENSION", "cl_khr_not_a_real_extension")
    monkeypatch.setattr(_base, "DEVICE_CHECKS", {})
    params = Scan.default_params(runtime.traits, "chained")
    with pytest.warns(RuntimeWarning, match="cl_khr_not_a_real_extension"):
        assert not scan_module.chained_scan_works(runtime, params)
