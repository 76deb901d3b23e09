"""Broadphase pair finding on the BoxBox scene (ground + N boxes), per algorithm.

For each size and algorithm: one warm-up query (builds kernels, grows the pair
buffer), then ``--repeats`` complete queries (``enqueue`` + ``check``). Reported:
the median device time (profiling markers around the query's enqueues), the
median wall time (enqueue to completed status read), launches per query, the
pairs found and the reference count from a numpy grid (``grid_pairs``), with
``ok`` when the device pair list equals the reference exactly.

An algorithm may carry options: ``grid:emission=slot`` (the default is owner),
``sap:shape=gpu``, ``sap3:full=sap``.

sap3 is measured in steady state (the same boxes every query, as in a resting
stack): its incremental path then finds no endpoint crossings.

usage: python benchmarks/broadphase.py [--device D] [--sizes 8000 27000 111375]
                                       [--algorithms grid sap sap3] [--repeats 10]
                                       [--profile]  (adds the slowest kernels of a query)
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def measure(runtime, name: str, aabbs, static, reference, repeats: int) -> dict:
    import pyopencl as cl

    from rbgen.pipeline.broadphase import make_broadphase

    algorithm, _, text = name.partition(":")
    options = {}
    for item in filter(None, text.split(",")):
        key, _, value = item.partition("=")
        options[key] = int(value) if value.isdigit() else value
    broadphase = make_broadphase(runtime, algorithm, **options)
    count = broadphase.find_pairs(aabbs, static)  # warm-up: build, grow
    broadphase.find_pairs(aabbs, static)  # sap3: its incremental path too
    pairs = broadphase.host_pairs()
    ok = pairs.shape == reference.shape and bool(np.array_equal(pairs, reference))
    device_ms, wall_ms, launches = [], [], []
    for _ in range(repeats):
        runtime.queue.finish()
        before = runtime.counters["launches"]
        t0 = time.perf_counter()
        start = cl.enqueue_marker(runtime.queue)
        broadphase.enqueue(aabbs, static)
        end = cl.enqueue_marker(runtime.queue)
        complete = broadphase.check()
        end.wait()
        wall_ms.append(1e3 * (time.perf_counter() - t0))
        launches.append(runtime.counters["launches"] - before)
        if not complete:
            raise RuntimeError(f"{name}: query incomplete after warm-up")
        device_ms.append(1e-6 * (end.profile.end - start.profile.start))
    return {
        "algorithm": name,
        "pairs": count,
        "ok": ok,
        "device_ms": statistics.median(device_ms),
        "wall_ms": statistics.median(wall_ms),
        "launches": int(statistics.median(launches)),
        "broadphase": broadphase,
    }


def kernel_breakdown(runtime, broadphase, aabbs, static) -> list[tuple[float, str]]:
    """(ms, kernel name) of one more query, from an event per launch, slowest first."""
    from rbgen.launch import BoundKernel

    events, launch, bound_launch = [], runtime.launch, BoundKernel.launch

    def recording_launch(kernel, global_size, local_size, wait_for=None):
        event = launch(kernel, global_size, local_size, wait_for)
        events.append((kernel.function_name, event))
        return event

    def recording_bound_launch(self, global_size, local_size, wait_for=None):
        event = bound_launch(self, global_size, local_size, wait_for)
        events.append((self.kernel.function_name, event))
        return event

    runtime.launch, BoundKernel.launch = recording_launch, recording_bound_launch
    try:
        broadphase.enqueue(aabbs, static)
        broadphase.check()
        runtime.queue.finish()
    finally:
        runtime.launch, BoundKernel.launch = launch, bound_launch
    totals: dict[str, float] = {}
    for name, event in events:
        totals[name] = totals.get(name, 0.0) + 1e-6 * (event.profile.end - event.profile.start)
    return sorted(((ms, name) for name, ms in totals.items()), reverse=True)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="device choice passed to rbgen.Runtime")
    parser.add_argument("--sizes", type=int, nargs="+", default=[8000, 27000, 111375])
    parser.add_argument("--algorithms", nargs="+", default=["grid", "sap", "sap3"])
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument(
        "--profile", action="store_true", help="also print the time per kernel of one query"
    )
    args = parser.parse_args(argv)

    import pyopencl.array as cla

    from rbgen.device import Runtime
    from rbgen.pipeline.broadphase.reference import grid_pairs
    from rbgen.scenes import scene_aabbs, standard_boxbox_scene

    runtime = Runtime(args.device, profiling=True)
    print(f"device: {runtime.traits.describe()}")
    width = max(9, *(len(a) for a in args.algorithms))
    print(
        f"{'boxes':>7} {'algorithm':>{width}} {'device ms':>10} {'wall ms':>9} {'launches':>8} "
        f"{'pairs':>8} {'reference':>9} {'ok':>3}"
    )
    for size in args.sizes:
        aabbs, static = scene_aabbs(standard_boxbox_scene(size))
        reference = grid_pairs(aabbs, static)
        device_aabbs = cla.to_device(runtime.queue, aabbs)
        device_static = cla.to_device(runtime.queue, static)
        for name in args.algorithms:
            row = measure(runtime, name, device_aabbs, device_static, reference, args.repeats)
            print(
                f"{size:>7} {name:>{width}} {row['device_ms']:>10.3f} {row['wall_ms']:>9.3f} "
                f"{row['launches']:>8} {row['pairs']:>8} {len(reference):>9} "
                f"{'yes' if row['ok'] else 'NO':>3}",
                flush=True,
            )
            if args.profile:
                for ms, kernel in kernel_breakdown(
                    runtime, row["broadphase"], device_aabbs, device_static
                )[:8]:
                    print(f"{'':>{width + 9}} {ms:>10.3f}  {kernel}")


if __name__ == "__main__":
    main()
