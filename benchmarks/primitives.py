"""Throughput of rbgen's primitives beside baselines measured in the same run.

    python benchmarks/primitives.py [--device D] [--n N] [--repeats R] [--only scan|sort]
                                    [--ptx DIR]

Baselines: numpy on the host always; on a GPU also pyopencl's own
``pyopencl.algorithm.RadixSort`` and, when importable with CUDA, ``torch.sort``
and ``torch.cumsum``. The device's copy bandwidth (``enqueue_copy`` and a
float4 copy kernel) is measured too, and the scan is reported as a fraction
of it (a scan moves at least the bytes of one copy: read n, write n). Scan
rows: the default `Scan` (tuned or heuristic; its choice in brackets), then
uint32 with reduce-then-scan ("r-t-s") and every chained candidate explicitly
(work-group size x elements per work-item, "lb K" when a look-back step
polls K < work-group-size predecessors, "group" when tiles follow group ids
instead of tickets), then small scans: the kernels' own device time (sum of
the call's launch events, start to end), the span of the markers around one
call (that includes the host's time to enqueue it: the device idles until
the launch arrives), host wall time per call (200 calls queued back to back)
and launches per call. ``--only scan`` stops after those; ``--ptx DIR``
writes each chained candidate's program binary (PTX text on NVIDIA) there
and reports whether it uses local-memory stack (``.local``: private arrays
not kept in registers). The key-value sort is also timed (and checked) at
each of its GPU-shape search-space points, rows "sort kv <shape> <bits>b
<WG>x<ITEMS> [launches per sort]"; ``--only sort`` times the sorts and their
baselines only.

Device times come from OpenCL event timestamps (markers around each run on a
profiling queue, median of R runs); host baselines from ``perf_counter``
(median). Sort inputs are restored before every run, outside the timing.
Uses the tuned parameters if ``rbgen tune`` was run, else the heuristics.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time
from pathlib import Path

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

import rbgen
from rbgen import tuning
from rbgen.primitives import BoundSearch, Compact, Fill, RadixSort, Reduce, Scan, radix_sort

COPY_SOURCE = """
__kernel void copy_float4(__global const float4* src, __global float4* dst, const uint count)
{
    /* one float4 per work-item; a work group is responsible for 256 of them */
    uint i = get_global_id(0);
    if (i < count)
        dst[i] = src[i];
}
"""


def host_ms(fn, repeats, prepare=None):
    times = []
    for _ in range(repeats):
        if prepare is not None:
            prepare()
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def device_ms(runtime, fn, repeats, prepare=None):
    fn()  # warm-up: builds programs, first-touch of buffers
    runtime.queue.finish()
    run = lambda: fn()  # noqa: E731 - time_runs reads .prepare from the callable
    run.prepare = prepare
    return tuning.time_runs(runtime, run, repeats)


class Table:
    def __init__(self, n):
        self.n = n
        self.rows = []

    def add(self, name, ms, bytes_moved, baseline=None, baseline_ms=None, elements=None):
        self.rows.append((name, ms, bytes_moved, baseline, baseline_ms, elements or self.n))

    def print(self):
        head = (
            f"{'primitive':<38}{'ms':>9}{'Melem/s':>10}{'GB/s':>8}  "
            f"{'baseline':<34}{'ms':>9}{'speedup':>9}"
        )
        print(head)
        print("-" * len(head))
        for name, ms, nbytes, base, base_ms, elements in self.rows:
            melem = elements / ms / 1e3
            gbs = nbytes / ms / 1e6 if nbytes else float("nan")
            line = f"{name:<38}{ms:9.3f}{melem:10.1f}{gbs:8.1f}"
            if base is not None:
                line += f"  {base:<34}{base_ms:9.3f}{base_ms / ms:8.2f}x"
            print(line)


def copy_bandwidth(runtime, n, repeats):
    src = cla.to_device(runtime.queue, np.ones(n, np.float32))
    dst = cla.empty_like(src)
    copy_ms = device_ms(
        runtime, lambda: cl.enqueue_copy(runtime.queue, dst.data, src.data), repeats
    )
    kernel = cl.Program(runtime.context, COPY_SOURCE).build().copy_float4
    count = n // 4
    kernel.set_args(src.data, dst.data, np.uint32(count))
    wg = min(256, runtime.traits.max_work_group_size)
    kernel_ms = device_ms(
        runtime,
        lambda: cl.enqueue_nd_range_kernel(runtime.queue, kernel, (-(-count // wg) * wg,), (wg,)),
        repeats,
    )
    return copy_ms, kernel_ms


def torch_cumsum_ms(n, repeats):
    """torch.cumsum (CUB) of n int32 on CUDA in ms, or None (with the reason printed)."""
    try:
        import torch

        if not torch.cuda.is_available():
            raise RuntimeError("CUDA not available")
    except Exception as err:  # noqa: BLE001 - a baseline that cannot run is reported, not fatal
        print(f"torch.cumsum baseline skipped: {type(err).__name__}: {err}")
        return None
    ints = torch.randint(0, 8, (n,), dtype=torch.int32, device="cuda")
    torch.cumsum(ints, 0, dtype=torch.int32)
    torch.cuda.synchronize()
    times = []
    for _ in range(repeats):
        start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        start.record()
        torch.cumsum(ints, 0, dtype=torch.int32)
        end.record()
        torch.cuda.synchronize()
        times.append(start.elapsed_time(end))
    return statistics.median(times)


def scan_label(params):
    if params["shape"] == "chained":
        lookback = params.get("lookback", params["work_group_size"])
        return (
            f"chained {params['work_group_size']}x{params['items_per_thread']}"
            + ("" if lookback == params["work_group_size"] else f" lb {lookback}")
            + (" group" if params.get("order") == "group" else "")
        )
    if params["shape"] == "gpu":
        return f"r-t-s {params['work_group_size']}x{params['items_per_thread']}"
    return f"r-t-s {params['work_items']} chunks"


def scan_rows(runtime, table, n, repeats, rng):
    """Scan rows: the default Scan (tuned or heuristic) for uint32 and float32,
    then uint32 inclusive with reduce-then-scan and every chained candidate
    explicitly, beside numpy and (on CUDA) torch.cumsum. Returns the default
    uint32 scan's ms and ``{label: ms}`` of the chained candidates."""
    from rbgen.primitives.scan import chained_search_space

    q, traits = runtime.queue, runtime.traits
    small = rng.integers(0, 8, n).astype(np.uint32)
    floats = rng.random(n, dtype=np.float32)
    for dtype, host, label in ((np.uint32, small, "uint32"), (np.float32, floats, "float32")):
        src = cla.to_device(q, host)
        dst = cla.empty_like(src)
        scan = Scan(runtime, dtype, inclusive=True)
        ms = device_ms(runtime, lambda: scan(src, dst), repeats)
        used = scan_label(scan.program(n)[0])
        base = host_ms(lambda: np.cumsum(host), repeats)
        table.add(
            f"scan {label} [{used}]",
            ms,
            8 * n,
            f"np.cumsum({label}) [-> {np.cumsum(host[:1]).dtype}]",
            base,
        )
        if dtype == np.uint32:
            scan_ms = ms
            cumsum = torch_cumsum_ms(n, repeats) if traits.is_gpu else None
            if cumsum is not None:
                table.add(
                    f"scan {label} [{used}]", ms, 8 * n, "torch.cumsum(int32->int32) [CUDA]", cumsum
                )
    src = cla.to_device(q, small)
    dst = cla.empty_like(src)
    expected = np.cumsum(small, dtype=np.uint32)
    base_same = host_ms(lambda: np.cumsum(small, dtype=np.uint32), repeats)
    chained_ms = {}
    for params in [Scan.default_params(traits)] + chained_search_space(traits):
        scan = Scan(runtime, np.uint32, inclusive=True, params=params)
        used = scan.program(n)[0]  # the fallback if a chained point failed its guard
        ms = device_ms(runtime, lambda: scan(src, dst), repeats)
        name = scan_label(params) + ("" if used == params else " FAILED GUARD")
        if not np.array_equal(dst.get(), expected):
            name += " WRONG"
        table.add(f"scan uint32 {name}", ms, 8 * n, "np.cumsum(uint32, dtype=uint32)", base_same)
        if params["shape"] == "chained" and used == params:
            chained_ms[scan_label(params)] = ms
    return scan_ms, chained_ms


def scan_summary(runtime, n, best_copy, scan_ms, chained_ms, repeats):
    """Scan against copy bandwidth, then small scans: device time and host
    wall time per call (launches cost ~13 us each on NVIDIA's driver)."""
    traits = runtime.traits
    line = (
        f"copy bandwidth {8 * n / best_copy / 1e6:.1f} GB/s; scan uint32 reaches "
        f"{100 * best_copy / scan_ms:.0f}% of it (default Scan)"
    )
    default = scan_label(Scan.default_params(traits, "chained"))
    if default in chained_ms:
        line += f", {100 * best_copy / chained_ms[default]:.0f}% ({default}, heuristic)"
    if chained_ms:
        best = min(chained_ms, key=chained_ms.get)
        line += f", {100 * best_copy / chained_ms[best]:.0f}% ({best}, fastest chained)"
    print(line)
    print(
        f"{'small scans uint32':<34}{'kernel us':>10}{'marker us':>10}{'wall us/call':>13}"
        f"{'launches':>9}"
    )
    for size in (1 << 12, 1 << 16, 1 << 20):
        src = cla.to_device(runtime.queue, np.ones(size, np.uint32))
        dst = cla.empty_like(src)
        for params in (Scan.default_params(traits), Scan.default_params(traits, "chained")):
            scan = Scan(runtime, np.uint32, params=params)
            marker = 1e3 * device_ms(runtime, lambda: scan(src, dst), repeats)
            kernel = 1e3 * statistics.median(
                launch_ms(runtime, lambda: scan(src, dst)) for _ in range(repeats)
            )
            launches = runtime.counters["launches"]
            calls = 200
            t0 = time.perf_counter()
            for _ in range(calls):
                scan(src, dst)
            runtime.queue.finish()
            wall = (time.perf_counter() - t0) * 1e6 / calls
            launches = (runtime.counters["launches"] - launches) // calls
            print(
                f"  n=2^{size.bit_length() - 1:<3} {scan_label(params):<24}{kernel:10.1f}"
                f"{marker:10.1f}{wall:13.1f}{launches:9d}"
            )


def launch_ms(runtime, fn):
    """Device milliseconds of the kernels ``fn`` launches (each event's start
    to end, summed): what the device itself spends, without host gaps."""
    events = []
    real = runtime.launch

    def recording_launch(*args, **kwargs):
        event = real(*args, **kwargs)
        events.append(event)
        return event

    runtime.launch = recording_launch
    try:
        fn()
    finally:
        del runtime.launch  # back to the class's method
    cl.wait_for_events(events)
    return sum(e.profile.end - e.profile.start for e in events) * 1e-6


def write_ptx(runtime, directory, n):
    """Each chained candidate's program binary into ``directory`` (PTX text on
    NVIDIA; other drivers' binaries are written as they come), with a line per
    candidate saying whether the PTX declares local-memory stack."""
    from rbgen.primitives.scan import chained_search_space

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    for params in chained_search_space(runtime.traits):
        scan = Scan(runtime, np.uint32, inclusive=True, params=params)
        _, compiled = scan.program(n)
        binary = compiled.program.get_info(cl.program_info.BINARIES)[0]
        name = scan_label(params).replace(" ", "_") + ".ptx"
        (directory / name).write_bytes(binary)
        text = binary.decode("latin-1")
        stack = [line.strip() for line in text.splitlines() if ".local" in line]
        print(
            f"{name:<32}{len(binary):9d} bytes  "
            f"{'local stack: ' + '; '.join(stack[:3]) if stack else 'no .local'}"
        )


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="device choice for rbgen.Runtime")
    parser.add_argument(
        "--n", type=int, default=None, help="elements (default 2^24 on a GPU, 2^22 otherwise)"
    )
    parser.add_argument("--repeats", type=int, default=None, help="runs per measurement")
    parser.add_argument(
        "--only",
        choices=("scan", "sort"),
        default=None,
        help="scan: only the copy baseline and the scan variants (~30 s on a GPU); "
        "sort: only the sorts (all variants) and their baselines",
    )
    parser.add_argument(
        "--ptx",
        default=None,
        metavar="DIR",
        help="write the chained scan candidates' program binaries (PTX on "
        "NVIDIA) to DIR and report local-memory stack use",
    )
    args = parser.parse_args(argv)

    runtime = rbgen.Runtime(args.device, profiling=True)
    traits = runtime.traits
    n = args.n or (1 << 24 if traits.is_gpu else 1 << 22)
    repeats = args.repeats or (20 if traits.is_gpu else 5)
    q = runtime.queue
    rng = np.random.default_rng(0)
    print(f"device: {traits.describe()}")
    print(f"n = {n}, median of {repeats} runs; tuned entries: {len(tuning.describe_cache(traits))}")

    table = Table(n)
    if args.ptx:
        write_ptx(runtime, args.ptx, n)
    if args.only == "sort":
        sorts(runtime, table, n, repeats, rng)
        table.print()
        print(f"program cache: {rbgen.codegen.PROGRAMS.stats}")
        return
    copy_ms, kernel_ms = copy_bandwidth(runtime, n, repeats)
    best_copy = min(copy_ms, kernel_ms)
    table.add("copy (enqueue_copy)", copy_ms, 8 * n)
    table.add("copy (float4 kernel)", kernel_ms, 8 * n)

    # scan
    scan_ms, chained_ms = scan_rows(runtime, table, n, repeats, rng)
    if args.only == "scan":
        table.print()
        scan_summary(runtime, n, best_copy, scan_ms, chained_ms, repeats)
        return

    # reduce, fill, compact, bound search
    floats = rng.random(n, dtype=np.float32)
    src = cla.to_device(q, floats)
    out = cla.empty(q, 1, np.float32)
    reduce = Reduce(runtime, np.float32, "sum")
    table.add(
        "reduce sum float32",
        device_ms(runtime, lambda: reduce(src, out), repeats),
        4 * n,
        "np.sum(float32)",
        host_ms(lambda: floats.sum(), repeats),
    )
    fill_array = cla.empty(q, n, np.uint32)
    fill = Fill(runtime, np.uint32)
    host_array = np.empty(n, np.uint32)
    table.add(
        "fill uint32",
        device_ms(runtime, lambda: fill(fill_array, 7), repeats),
        4 * n,
        "ndarray.fill",
        host_ms(lambda: host_array.fill(7), repeats),
    )
    flags = (rng.random(n) < 0.25).astype(np.uint32)
    d_flags, kept, count = (
        cla.to_device(q, flags),
        cla.empty(q, n, np.uint32),
        cla.empty(q, 1, np.uint32),
    )
    compact = Compact(runtime)
    table.add(
        "compact (25% kept)",
        device_ms(runtime, lambda: compact(d_flags, kept, count), repeats),
        4 * n + n,
        "np.flatnonzero",
        host_ms(lambda: np.flatnonzero(flags), repeats),
    )
    keys = np.sort(rng.integers(0, n, n, dtype=np.uint32))
    queries = rng.integers(0, n, n, dtype=np.uint32)[
        : n // 16
    ]  # random probes: ~log2(n) misses each
    d_keys, d_queries, found = (
        cla.to_device(q, keys),
        cla.to_device(q, queries),
        cla.empty(q, n, np.uint32),
    )
    search = BoundSearch(runtime, "lower")
    table.add(
        "bound search (n/16 in n)",
        device_ms(runtime, lambda: search(d_keys, d_queries, found), repeats),
        0,
        "np.searchsorted",
        host_ms(lambda: np.searchsorted(keys, queries), max(1, repeats // 2)),
        elements=queries.size,
    )

    sorts(runtime, table, n, repeats, rng)
    table.print()
    scan_summary(runtime, n, best_copy, scan_ms, chained_ms, repeats)
    print(
        f"program cache: {rbgen.codegen.PROGRAMS.stats}; launches: {runtime.counters['launches']}"
    )


def sorts(runtime, table, n, repeats, rng):
    """Sort rows: the default key-value and keys-only sorts against numpy, each
    variant, and on a GPU the GPU baselines."""
    q = runtime.queue
    sort_keys = rng.integers(0, 2**32, n, dtype=np.uint32)
    sort_values = np.arange(n, dtype=np.uint32)
    src_keys, src_values = cla.to_device(q, sort_keys), cla.to_device(q, sort_values)
    work_keys, work_values = cla.empty_like(src_keys), cla.empty_like(src_values)

    def restore():
        cl.enqueue_copy(q, work_keys.data, src_keys.data)
        cl.enqueue_copy(q, work_values.data, src_values.data)

    kv, keys_only = (
        RadixSort(runtime, 32, with_values=True),
        RadixSort(runtime, 32, with_values=False),
    )
    host_reps = max(1, min(repeats, 3))
    kv_ms = device_ms(runtime, lambda: kv(work_keys, work_values), repeats, restore)
    table.add(
        "sort key-value uint32",
        kv_ms,
        0,
        "np.argsort(stable)+gather",
        host_ms(
            lambda: (lambda o: (sort_keys[o], sort_values[o]))(
                np.argsort(sort_keys, kind="stable")
            ),
            host_reps,
        ),
    )
    table.add(
        "sort keys uint32",
        device_ms(runtime, lambda: keys_only(work_keys), repeats, restore),
        0,
        "np.sort",
        host_ms(lambda: np.sort(sort_keys), host_reps),
    )

    order = np.argsort(sort_keys, kind="stable").astype(np.uint32)
    sort_variants(
        runtime,
        table,
        repeats,
        work_keys,
        work_values,
        restore,
        (sort_keys[order], sort_values[order]),
    )
    if runtime.traits.is_gpu:
        gpu_baselines(runtime, table, n, repeats, sort_keys, sort_values, kv_ms)


def sort_variants(runtime, table, repeats, work_keys, work_values, restore, expected):
    """The key-value sort at every GPU-shape point of its search space (on a CPU
    device: of a GPU's) and the tiled shape with 8-bit digits, each checked
    against ``expected`` (keys, values). Bytes: each pass reads the keys twice
    and the values once and writes both (20 bytes per element), 32 / bits passes."""
    traits = runtime.traits
    gpu_traits = traits if traits.is_gpu else dataclasses.replace(traits, is_gpu=True)
    points = [p for p in radix_sort.search_space(gpu_traits) if p["shape"] != "cpu"]
    tiled = RadixSort.default_params(gpu_traits, "gpu")
    points.append(
        dict(tiled, radix_bits=8, work_group_size=max(64, tiled["wavefront"]), items_per_thread=16)
    )
    for params in radix_sort.unique_params(points):
        sorter = RadixSort(runtime, 32, with_values=True, params=params)
        ms = device_ms(runtime, lambda: sorter(work_keys, work_values), repeats, restore)
        restore()
        before = runtime.counters["launches"]
        sorter(work_keys, work_values)
        launches = runtime.counters["launches"] - before
        right = np.array_equal(work_keys.get(), expected[0]) and np.array_equal(
            work_values.get(), expected[1]
        )
        bits, shape = params["radix_bits"], params["shape"]
        used = sorter.program(table.n)[0]["shape"]  # onesweep falls back if its guard fails
        shape = shape if used == shape else f"{shape}->{used}"
        name = (
            f"sort kv {shape} {bits}b {params['work_group_size']}x"
            f"{params['items_per_thread']} [{launches}]" + ("" if right else " WRONG")
        )
        table.add(name, ms, 20 * table.n * -(-32 // bits))


def gpu_baselines(runtime, table, n, repeats, sort_keys, sort_values, kv_ms):
    """pyopencl's RadixSort on the same device; torch.sort/cumsum on CUDA if present."""
    q = runtime.queue
    try:
        from pyopencl.algorithm import RadixSort as PyopenclRadixSort
        from pyopencl.scan import GenericScanKernel

        sorter = PyopenclRadixSort(
            runtime.context,
            "uint *keys, uint *values",
            key_expr="keys[i]",
            sort_arg_names=["keys", "values"],
            scan_kernel=GenericScanKernel,
        )
        d_keys, d_values = cla.to_device(q, sort_keys), cla.to_device(q, sort_values)
        ms = device_ms(runtime, lambda: sorter(d_keys, d_values, key_bits=32, queue=q)[1], repeats)
        table.add("sort key-value uint32", kv_ms, 0, "pyopencl.algorithm.RadixSort", ms)
    except Exception as err:  # noqa: BLE001 - a baseline that cannot run is reported, not fatal
        print(f"pyopencl RadixSort baseline skipped: {type(err).__name__}: {err}")
    try:
        import torch

        if not torch.cuda.is_available():
            raise RuntimeError("CUDA not available")
    except Exception as err:  # noqa: BLE001
        print(f"torch baselines skipped: {type(err).__name__}: {err}")
        return
    keys = torch.from_numpy(sort_keys.view(np.int32).copy()).cuda()

    def cuda_ms(fn):
        fn()
        torch.cuda.synchronize()
        times = []
        for _ in range(repeats):
            start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            start.record()
            fn()
            end.record()
            torch.cuda.synchronize()
            times.append(start.elapsed_time(end))
        return statistics.median(times)

    table.add(
        "sort key-value uint32",
        kv_ms,
        0,
        "torch.sort(int32, stable) [CUDA]",
        cuda_ms(lambda: torch.sort(keys, stable=True)),
    )


if __name__ == "__main__":
    main()
