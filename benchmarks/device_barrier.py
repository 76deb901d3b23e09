"""What a device-wide barrier costs (common/device_barrier.cl.mako), the floor under every phase of
a persistent launch (a colour of a PGS sweep, a colouring round).

    python benchmarks/device_barrier.py [--device D] [--phases 2000] [--out DIR]

A persistent launch of G work groups x W lanes passes ``--phases`` device-wide barriers; in each
phase ``touch`` lanes first read another lane's word and write their own (one dependent global
hop, as a batch's constraints read the velocities the last batch wrote). The time a barrier is
the difference between that launch and one of a single phase, over the phases (profiling
events, the best of 3). G is 1, 4, 16 and one group per compute unit (a persistent launch's
own: the only size whose groups all run at once everywhere), W 256 (the PGS solve's) and 64.
The baseline, timed in the same run: one work group of W lanes with a work-group barrier per
phase, the least a phase can cost.

JSON (rbgen.bench's form, kind "device_barrier") and a Markdown table go under ``--out``
(benchmarks/results; '' for none).
"""

from __future__ import annotations

import argparse

import numpy as np
import pyopencl as cl

from rbgen import bench, layouts
from rbgen.codegen import TEMPLATE_DIR
from rbgen.device import Runtime
from rbgen.pipeline.device_barrier import barrier_buffer, persistent_groups

KERNELS = r"""
__kernel void phases(volatile __global uint* sync, const uint count,
                     volatile __global float* data, const uint touch)
{
    __local uint ok;
    device_barrier_start(sync, &ok);
    const uint lane = get_local_id(0) * get_num_groups(0) + get_group_id(0);
    for (uint p = 0; p < count; ++p) {
        if (lane < touch) {
            const uint other = (lane * 7919u + p) % touch;
            data[lane] = data[other] + 1.0f;
        }
        device_barrier(sync, &ok);
    }
    device_barrier_leave(sync);
}

__kernel void local_phases(const uint count, volatile __global float* data, const uint touch)
{
    const uint lane = get_local_id(0);
    for (uint p = 0; p < count; ++p) {
        if (lane < touch) {
            const uint other = (lane * 7919u + p) % touch;
            data[lane] = data[other] + 1.0f;
        }
        barrier(CLK_GLOBAL_MEM_FENCE);
    }
}
"""


def per_phase_us(launch, phases: int) -> float:
    """µs a phase: a launch of ``phases`` + 1 phases less one of a single phase, over
    ``phases`` (0 where the difference is below the timer's noise)."""
    return max(0.0, (best_us(lambda: launch(phases + 1)) - best_us(lambda: launch(1))) / phases)


def best_us(launch, repeats: int = 3) -> float:
    """The shortest of ``repeats`` launches' device time (µs)."""
    times = []
    for _ in range(repeats):
        event = launch()
        event.wait()
        times.append(1e-3 * (event.profile.end - event.profile.start))
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="rbgen device choice (index or name)")
    parser.add_argument("--phases", type=int, default=2000)
    bench.add_out_argument(parser)
    args = parser.parse_args()
    runtime = Runtime(args.device, profiling=True)
    barrier = (TEMPLATE_DIR / "common" / "device_barrier.cl.mako").read_text()
    source = layouts.cl_constants() + "\n" + barrier + KERNELS
    program = cl.Program(runtime.context, source).build()
    phases_kernel = cl.Kernel(program, "phases")
    local_kernel = cl.Kernel(program, "local_phases")
    queue = runtime.queue
    most = persistent_groups(runtime.traits)
    data = cl.Buffer(runtime.context, cl.mem_flags.READ_WRITE, 4 << 20)
    phases = max(1, int(args.phases))
    print(f"device-wide barrier on {runtime.traits.describe()}: up to {most} groups", flush=True)
    results = []
    for lanes, groups in [(w, g) for w in (256, 64) for g in sorted({1, 4, 16, most})]:
        if groups > most:
            continue
        lanes = min(lanes, runtime.traits.max_work_group_size)
        for touch in (0, groups * lanes):
            label = "no work" if touch == 0 else "a dependent hop a lane"

            def local(count, touch=touch, lanes=lanes):
                return local_kernel(
                    queue, (lanes,), (lanes,), np.uint32(count), data, np.uint32(min(touch, lanes))
                )

            floor = per_phase_us(local, phases)
            sync = barrier_buffer(runtime)

            def persistent(count, touch=touch, lanes=lanes, sync=sync, groups=groups):
                return phases_kernel(
                    queue,
                    (groups * lanes,),
                    (lanes,),
                    sync.data,
                    np.uint32(count),
                    data,
                    np.uint32(touch),
                )

            per = per_phase_us(persistent, phases)
            abandoned = int(sync.get()[layouts.BARRIER_ABANDONED])
            print(
                f"  {groups} x {lanes} lanes, {label}: {per:6.3f} us a barrier "
                f"(one work group's barrier: {floor:6.3f} us){' ABANDONED' if abandoned else ''}",
                flush=True,
            )
            results.append(
                {
                    "name": f"{groups} x {lanes}, {label}",
                    "ms": per * 1e-3,
                    "ms_spread": [per * 1e-3, per * 1e-3],
                    "baseline": {
                        "name": f"one work group of {lanes}, {label}",
                        "ms": floor * 1e-3,
                    },
                    "abandoned": bool(abandoned),
                }
            )
    if args.out:
        record = bench.make_record(
            "device_barrier", results, bench.device_record(args.device), {"phases": phases}
        )
        print(f"wrote {bench.write_results(record, args.out)}")


if __name__ == "__main__":
    main()
