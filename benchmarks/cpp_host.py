"""The C++ host beside the Python World: BoxBox ms/step, the host's time and the device's.

    python benchmarks/cpp_host.py [--device D] [--sizes 1000 27000] [--steps 200]
                                  [--warmup 20] [--build DIR] [--out benchmarks/results]

For each size, in one run on one device: the BoxBox World is exported with its schedule
(`rbgen.export.export_world`), and the same steps are timed in the C++ host
(``examples/cpp``'s ``rbgen_run``, built here with CMake, or with the compiler alone where
CMake is missing) and in the Python World, the same way on both sides:

* **ms/step**: after ``--warmup`` steps, ``--steps`` steps enqueued back to back and ended by
  one finish, clocked in 10 blocks at their boundaries (rbgen.harness's way): the median
  block, robust to a neighbour on the machine. It is the device's time when the host keeps
  ahead of it, else the host's;
* **host**: the time spent in step() less the time it waited for the device (the step
  reports' reads; the final finish), per step: what the host itself costs;
* **device**: the steps' commands (kernels, fills, copies) timed by profiling events, in a
  separate run on a profiling queue (events cost host time), per step.

Both hosts end in the same state (same device, kernels, order): the script checks it bit
for bit and says so. Results: JSON and Markdown in rbgen.bench's form (kind
"benchmarks/cpp_host.py") under ``--out`` ('' for none): per size a row for each measure,
the C++ host's figure with the Python World's as the baseline.

The OpenCL headers and loader are looked for in the usual places, in CUDA's toolkit and in
``.clh`` (a copy of a machine's ``/usr/include/CL`` carried along: ``mkdir -p .clh && cp -r
/usr/include/CL .clh/``); ``--cl-include`` and ``--cl-library`` name them.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyopencl as cl

from rbgen import bench
from rbgen.device import Runtime
from rbgen.export import export_world
from rbgen.harness import build_scene

ROOT = Path(__file__).resolve().parent.parent
DT = 1 / 60
BLOCKS = 10


# ---------------------------------------------------------------------------- building


def find_opencl(include: str | None, library: str | None) -> tuple[str | None, str | None]:
    """(include dir holding CL/cl.h, libOpenCL path), or None where not found."""
    if include is None:
        for candidate in (
            "/usr/include",
            "/usr/local/include",
            "/usr/local/cuda/include",
            os.path.join(os.environ.get("CUDA_HOME", "/nonexistent"), "include"),
            str(ROOT / ".clh"),
        ):
            if os.path.isfile(os.path.join(candidate, "CL", "cl.h")):
                include = candidate
                break
    if library is None:
        patterns = [
            "/usr/lib/x86_64-linux-gnu/libOpenCL.so",
            "/usr/lib64/libOpenCL.so",
            "/usr/lib/libOpenCL.so",
            "/usr/local/cuda/lib64/libOpenCL.so",
            "/usr/lib/x86_64-linux-gnu/libOpenCL.so.1",
            "/usr/local/cuda/lib64/libOpenCL.so.1",
            os.path.join(
                os.path.dirname(cl.__file__), os.pardir, "pyopencl.libs", "libOpenCL*.so*"
            ),
        ]
        for pattern in patterns:
            found = sorted(glob.glob(pattern))
            if found:
                library = os.path.realpath(found[0])
                break
    return include, library


def build_host(build: Path, include: str | None, library: str | None) -> Path:
    """Build examples/cpp into ``build`` (CMake, else the compiler directly)."""
    binary = build / "rbgen_run"
    include, library = find_opencl(include, library)
    if include is None or library is None:
        raise SystemExit(
            f"the OpenCL headers ({include or 'CL/cl.h not found'}) or loader "
            f"({library or 'libOpenCL not found'}) are missing: on Debian, apt-get "
            f"install ocl-icd-opencl-dev opencl-headers; elsewhere carry a copy of "
            f"/usr/include/CL as .clh/CL, or give --cl-include and --cl-library"
        )
    build.mkdir(parents=True, exist_ok=True)
    if shutil.which("cmake"):
        configure = [
            "cmake",
            "-S",
            str(ROOT / "examples" / "cpp"),
            "-B",
            str(build),
            "-DCMAKE_BUILD_TYPE=Release",
            f"-DOpenCL_INCLUDE_DIR={include}",
            f"-DOpenCL_LIBRARY={library}",
        ]
        steps = [configure, ["cmake", "--build", str(build), "-j", str(os.cpu_count() or 2)]]
    else:
        compiler = os.environ.get("CXX") or shutil.which("c++") or shutil.which("g++")
        if compiler is None:
            raise SystemExit("neither CMake nor a C++ compiler is installed")
        host = ROOT / "rbgen" / "host"
        steps = [
            [
                compiler,
                "-O2",
                "-std=c++17",
                f"-I{host}",
                f"-I{include}",
                str(host / "rbgen_host.cpp"),
                str(ROOT / "examples" / "cpp" / "rbgen_run.cpp"),
                library,
                f"-Wl,-rpath,{os.path.dirname(library)}",
                "-o",
                str(binary),
            ]
        ]
    for command in steps:
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode:
            raise SystemExit(
                f"building the C++ host failed: {' '.join(command)}\n"
                f"{done.stdout[-3000:]}{done.stderr[-3000:]}"
            )
    return binary


# ---------------------------------------------------------------------------- timing


def run_cpp(binary: Path, export: Path, steps: int, warmup: int, *options: str) -> dict:
    done = subprocess.run(
        [
            str(binary),
            str(export),
            str(steps),
            "--warmup",
            str(warmup),
            "--blocks",
            str(BLOCKS),
            "--json",
            *options,
        ],
        capture_output=True,
        text=True,
        timeout=3600,
    )
    if done.returncode or "result " not in done.stdout:
        raise SystemExit(f"rbgen_run failed ({done.returncode}):\n{done.stdout}{done.stderr}")
    return json.loads(done.stdout.split("result ", 1)[1].splitlines()[0])


def run_python(device, n: int, steps: int, warmup: int) -> dict:
    """The Python World, timed as rbgen_run times the C++ host (see the module docstring)."""
    runtime = Runtime(device)
    world = build_scene("boxbox", n, runtime)[0]
    guard, waited = world._guard, [0.0]
    problems = guard.problems

    def timed_problems(entry):  # the wait for a step report's read, inside World.step
        t = time.perf_counter()
        try:
            return problems(entry)
        finally:
            waited[0] += time.perf_counter() - t

    guard.problems = timed_problems
    for _ in range(warmup):
        world.step(DT)
    world._finish_pending()
    runtime.queue.finish()
    sizes = [steps // BLOCKS + (steps % BLOCKS if b == BLOCKS - 1 else 0) for b in range(BLOCKS)]
    block_ms, block_host_ms = [], []
    launches = world.runtime.counters["launches"]
    start_all = time.perf_counter()
    for b, count in enumerate(sizes):
        start, wait0, inside = time.perf_counter(), waited[0], 0.0
        for _ in range(count):
            t = time.perf_counter()
            world.step(DT)
            inside += time.perf_counter() - t
        if b == BLOCKS - 1:
            t = time.perf_counter()
            world._finish_pending()
            w = time.perf_counter()
            runtime.queue.finish()
            waited[0] += time.perf_counter() - w
            inside += time.perf_counter() - t
        if count:
            block_ms.append(1e3 * (time.perf_counter() - start) / count)
            block_host_ms.append(1e3 * (inside - (waited[0] - wait0)) / count)
    wall = time.perf_counter() - start_all
    launches = (world.runtime.counters["launches"] - launches) / max(1, steps)
    return {
        "ms_per_step": float(np.median(block_ms)),
        "ms_spread": [min(block_ms), max(block_ms)],
        "ms_mean": 1e3 * wall / max(1, steps),
        "host_ms_per_step": float(np.median(block_host_ms)),
        "launches_per_step": launches,
        "overflows": world.overflows,
        "state": [
            world.positions,
            world.orientations,
            world.linear_velocities,
            world.angular_velocities,
        ],
        "plan": world.plan.describe(),
    }


def profile_python(device, n: int, steps: int, warmup: int) -> float:
    """The device's ms per step in the Python World's commands, from profiling events."""
    runtime = Runtime(device, profiling=True)
    world = build_scene("boxbox", n, runtime)[0]
    for _ in range(warmup):
        world.step(DT)
    world._finish_pending()
    runtime.queue.finish()
    events: list = []
    saved = cl.enqueue_nd_range_kernel, cl.enqueue_fill_buffer, cl.enqueue_copy

    def keep(original, device_only=False):
        def enqueue(queue, *args, **kwargs):
            event = original(queue, *args, **kwargs)
            if queue.int_ptr == runtime.queue.int_ptr and (
                not device_only or all(isinstance(a, cl.MemoryObjectHolder) for a in args[:2])
            ):
                events.append(event)
            return event

        return enqueue

    cl.enqueue_nd_range_kernel = keep(saved[0])
    cl.enqueue_fill_buffer = keep(saved[1])
    cl.enqueue_copy = keep(saved[2], device_only=True)
    try:
        for _ in range(steps):
            world.step(DT)
        world._finish_pending()
        runtime.queue.finish()
    finally:
        cl.enqueue_nd_range_kernel, cl.enqueue_fill_buffer, cl.enqueue_copy = saved
    total = sum(e.profile.end - e.profile.start for e in events)
    return 1e-6 * total / max(1, steps)


def cpp_state(path: Path, bodies: int) -> list[np.ndarray]:
    raw = np.fromfile(path, np.float32)
    p, q, v, w = np.split(raw, np.cumsum([3 * bodies, 4 * bodies, 3 * bodies]))
    return [p.reshape(-1, 3), q.reshape(-1, 4), v.reshape(-1, 3), w.reshape(-1, 3)]


# ---------------------------------------------------------------------------- main


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="rbgen device choice (index or name)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 27000])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--warmup", type=int, default=20)
    parser.add_argument("--build", default=None, help="a directory to build rbgen_run in (kept)")
    parser.add_argument("--cl-include", default=None, help="the directory holding CL/cl.h")
    parser.add_argument("--cl-library", default=None, help="libOpenCL to link against")
    bench.add_out_argument(parser)
    args = parser.parse_args(argv)

    work = Path(tempfile.mkdtemp(prefix="rbgen-cpp-host-"))
    build = Path(args.build) if args.build else work / "build"
    binary = build / "rbgen_run"
    if not binary.is_file():
        t = time.perf_counter()
        binary = build_host(build, args.cl_include, args.cl_library)
        print(f"built {binary} in {time.perf_counter() - t:.1f} s", flush=True)
    runtime = Runtime(args.device)
    print(f"device: {runtime.traits.describe()}", flush=True)
    rows, results = [], []
    for n in args.sizes:
        t = time.perf_counter()
        world = build_scene("boxbox", n, runtime)[0]
        world.step(DT)
        world.statistics()
        export = work / f"boxbox{n}"
        export_world(world, export, build=lambda n=n: build_scene("boxbox", n, runtime)[0])
        schedule = json.loads((export / "schedule.json").read_text())
        commands = len(schedule["steps"]["variants"][0])
        bodies = schedule["bodies"]["count"]
        print(
            f"boxbox {n}: exported in {time.perf_counter() - t:.1f} s ({commands} commands a "
            f"step, plan: {world.plan.describe()})",
            flush=True,
        )
        del world
        dump = work / f"state{n}.bin"
        cpp = run_cpp(binary, export, args.steps, args.warmup, "--dump", str(dump))
        cpp["device_ms_per_step"] = run_cpp(binary, export, args.steps, args.warmup, "--profile")[
            "device_ms_per_step"
        ]
        python = run_python(args.device, n, args.steps, args.warmup)
        python["device_ms_per_step"] = profile_python(args.device, n, args.steps, args.warmup)
        same = all(
            a.tobytes() == b.tobytes() for a, b in zip(cpp_state(dump, bodies), python.pop("state"))
        )
        rows.append((n, cpp, python, same, commands))
        print(f"{'':>8} {'ms/step':>9} {'host ms':>9} {'device ms':>10}")
        for name, r in (("C++", cpp), ("Python", python)):
            print(
                f"{name:>8} {r['ms_per_step']:9.3f} {r['host_ms_per_step']:9.3f} "
                f"{r['device_ms_per_step']:10.3f}"
            )
        print(
            f"  end states bit for bit: {same}; launches/step (Python) "
            f"{python['launches_per_step']:.0f}; overflows C++ {cpp['overflows']}, Python "
            f"{python['overflows']}",
            flush=True,
        )
        for measure, key in (
            ("wall", "ms_per_step"),
            ("host", "host_ms_per_step"),
            ("device", "device_ms_per_step"),
        ):
            spread = cpp["ms_spread"] if key == "ms_per_step" else [cpp[key], cpp[key]]
            base_spread = (
                python["ms_spread"] if key == "ms_per_step" else [python[key], python[key]]
            )
            results.append(
                {
                    "name": f"boxbox {n}: {measure} ms/step, C++ host",
                    "ms": cpp[key],
                    "ms_spread": spread,
                    "scene": "boxbox",
                    "bodies": bodies,
                    "measure": measure,
                    "steps": args.steps,
                    "warmup": args.warmup,
                    "commands_per_step": commands,
                    "same_end_state": same,
                    "baseline": {
                        "name": "Python World",
                        "ms": python[key],
                        "ms_spread": base_spread,
                    },
                }
            )
    print("\nsize    | C++ ms/step host device | Python ms/step host device | bit for bit")
    for n, cpp, python, same, _ in rows:
        print(
            f"{n:>7} | {cpp['ms_per_step']:8.3f} {cpp['host_ms_per_step']:6.3f} "
            f"{cpp['device_ms_per_step']:6.3f} | {python['ms_per_step']:8.3f} "
            f"{python['host_ms_per_step']:6.3f} {python['device_ms_per_step']:6.3f} | {same}"
        )
    if args.out:
        settings = {
            "scene": "boxbox",
            "sizes": args.sizes,
            "steps": args.steps,
            "warmup": args.warmup,
            "dt": DT,
            "blocks": BLOCKS,
        }
        record = bench.make_record(
            "benchmarks/cpp_host.py", results, bench.device_record(args.device), settings
        )
        print(f"wrote {bench.write_results(record, args.out)}")
    shutil.rmtree(work, ignore_errors=True)  # (the exports; a --build directory is kept)
    return 0 if all(same for *_, same, _ in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
