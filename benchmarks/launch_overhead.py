"""Host cost of the pieces of one kernel launch through pyopencl, on a device.

Prints microseconds per call of: set_args with 6 buffers + 3 scalars, one
scalar set_arg, one buffer set_arg, enqueue_nd_range_kernel (args already
set), and a launch + finish round trip. These bound how fast a step of N
launches can be issued from Python (README of the device recipe: 12-17 us per
launch on NVIDIA's OpenCL driver).

usage: python benchmarks/launch_overhead.py [--device D]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

SOURCE = """
__kernel void probe(__global float* a, __global float* b, __global float* c,
                    __global float* d, __global float* e, __global float* f,
                    const float r, const uint first, const uint flags)
{
    if (get_global_id(0) == 0 && first == 12345u)
        a[0] = r + b[0] + c[0] + d[0] + e[0] + f[0] + (float)flags;
}
"""


def per_call_us(fn, n=2000) -> float:
    fn()
    t0 = time.perf_counter()
    for _i in range(n):
        fn()
    return (time.perf_counter() - t0) / n * 1e6


def main() -> None:
    from rbgen.device import Runtime

    parser = argparse.ArgumentParser()
    parser.add_argument("--device", default=None)
    args = parser.parse_args()
    rt = Runtime(args.device)
    q = rt.queue
    kernel = cl.Program(rt.context, SOURCE).build().probe
    bufs = [cla.zeros(q, 16, np.float32).data for _ in range(6)]
    scalars = [np.float32(1), np.uint32(2), np.uint32(3)]
    kernel.set_args(*bufs, *scalars)
    rows = [
        ("set_args (6 buffers + 3 scalars)", per_call_us(lambda: kernel.set_args(*bufs, *scalars))),
        ("set_arg, one scalar", per_call_us(lambda: kernel.set_arg(7, scalars[1]))),
        ("set_arg, one buffer", per_call_us(lambda: kernel.set_arg(0, bufs[0]))),
        (
            "enqueue_nd_range_kernel",
            per_call_us(lambda: cl.enqueue_nd_range_kernel(q, kernel, (256,), (64,)), 5000),
        ),
    ]
    q.finish()

    def round_trip():
        cl.enqueue_nd_range_kernel(q, kernel, (256,), (64,))
        q.finish()

    rows.append(("launch + finish", per_call_us(round_trip, 500)))
    print(f"device: {rt.traits.describe()}")
    for name, us in rows:
        print(f"  {name:<36}{us:8.2f} us")


if __name__ == "__main__":
    main()
