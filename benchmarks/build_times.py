"""Cold and warm build times of the integrate kernel (and world AABBs) on a device.

cold: a fresh rbgen cache directory (and, for PoCL, its own kernel cache off:
      run with POCL_KERNEL_CACHE=0 to exclude it; this script sets it when it
      starts a child process for the cold measurement);
warm: a new ProgramCache over the cache directory the cold build filled, as a
      second process would see it (binary loaded from disk);
memory: the same ProgramCache again.

usage: python benchmarks/build_times.py [--device D]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def measure(device, cache_root: Path, template_names):
    from rbgen.codegen import ProgramCache
    from rbgen.device import Runtime
    from rbgen.pipeline import aabbs, integrate

    rt = Runtime(device)
    templates = {"integrate": integrate.TEMPLATE, "world_aabbs": aabbs.TEMPLATE}
    rows = []
    for name in template_names:
        spec = templates[name].default_spec(rt.traits)
        cold_cache = ProgramCache(cache_root)
        t0 = time.perf_counter()
        cold_cache.build(rt, spec.source, (), spec)
        cold = time.perf_counter() - t0
        warm = []
        for _ in range(5):
            cache = ProgramCache(cache_root)
            t0 = time.perf_counter()
            cache.build(rt, spec.source, (), spec)
            warm.append(time.perf_counter() - t0)
            assert cache.stats["disk_hits"] == 1
        t0 = time.perf_counter()
        cache.build(rt, spec.source, (), spec)
        mem = time.perf_counter() - t0
        rows.append((name, cold, statistics.median(warm), mem))
    return rt.traits.device_name, rows


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--device", default=None)
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        name, rows = measure(args.device, Path(args.child), ["integrate", "world_aabbs"])
        for r in rows:
            print("ROW", *r)
        print("DEVICE", name)
        return
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, POCL_KERNEL_CACHE="0")
        cmd = [sys.executable, __file__, "--child", tmp] + (
            ["--device", args.device] if args.device else []
        )
        out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout
    device = next(line[7:] for line in out.splitlines() if line.startswith("DEVICE"))
    print(
        f"build times on {device} (cold: empty rbgen cache, PoCL cache off; "
        "warm: binary from rbgen's disk cache)"
    )
    print(f"{'kernel':<14}{'cold ms':>10}{'warm ms':>10}{'memory us':>11}")
    for line in out.splitlines():
        if line.startswith("ROW"):
            _, name, cold, warm, mem = line.split()
            print(
                f"{name:<14}{float(cold) * 1e3:>10.1f}{float(warm) * 1e3:>10.1f}"
                f"{float(mem) * 1e6:>11.1f}"
            )


if __name__ == "__main__":
    main()
