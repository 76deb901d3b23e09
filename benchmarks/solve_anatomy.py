"""Where a World's solve time goes: the BoxBox lattice at the default and at settings that each
take one part of the solve away, timed per kernel in one run.

    python benchmarks/solve_anatomy.py [--device D] [--sizes 1000 111375] [--steps 20]
                                       [--warmup 20] [--out DIR]

Per size, these runs (World options beside the defaults):

``default``        the World's defaults: the baseline every other row names;
``one_sweep``      iterations=1 (one velocity sweep a substep, so no shock sweep either);
``no_push``        position_iterations=0 (no split-impulse push rows);
``half_substeps``  substeps halved.

Each run: wall ms/step (the median of `TIMING_BLOCKS` blocks; the queue profiles, so a
little above a World's without), the kernels' device time a step (profiling events; median
over ``--steps`` steps after ``--warmup``), the solve kernel's share, launches, and what the
device's compiler made of the solve kernel (`rbgen.codegen.kernel_resources`). Then, from the
differences against ``default`` (each divided by the default's substeps): what one velocity
sweep, the push rows and one whole substep cost the solve a substep, and a velocity sweep's
cost per colour (a colour is a phase of the sweep: its batch, then a barrier). A
difference measures the default's parts only where the settings barely change the scene's
trajectory (the lattice at rest), which is why the lattice is the scene.

JSON (rbgen.bench's form, kind "solve_anatomy"; each row's baseline is ``default`` at the
same size) and a Markdown table go under ``--out`` (benchmarks/results; '' for none).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from kernel_events import KernelEvents

from rbgen import bench
from rbgen.codegen import kernel_names, kernel_resources
from rbgen.device import Runtime
from rbgen.harness import build_scene

#: the kernel of the PGS solve (every sweep of a persistent launch)
SOLVE_KERNEL = "solve_groups"
#: blocks of steps the wall time is taken over (each ended by draining the queue, so that
#: the host's lead over the device carries on within a block, as in a World's run)
TIMING_BLOCKS = 4


def variants(substeps: int) -> dict[str, dict]:
    """Name -> World options of each run, for a default of ``substeps`` substeps."""
    return {
        "default": {},
        "one_sweep": {"iterations": 1},
        "no_push": {"position_iterations": 0},
        "half_substeps": {"substeps": max(1, substeps // 2)},
    }


def time_run(runtime: Runtime, n: int, options: dict, steps: int, warmup: int) -> dict:
    """One run: wall and kernel ms/step, the solve's ms/step, launches a step, colours."""
    world = build_scene("boxbox", n, runtime, **options)[0]
    for _ in range(warmup):
        world.step(1 / 60)
    runtime.queue.finish()
    walls = []  # ms/step of each block of steps, ended by draining the queue
    block = max(1, steps // TIMING_BLOCKS)
    with KernelEvents() as launches:
        start, in_block = time.perf_counter(), 0
        for step in range(steps):
            launches.step = step
            world.step(1 / 60)
            in_block += 1
            if in_block == block or step + 1 == steps:
                runtime.queue.finish()
                now = time.perf_counter()
                walls.append(1e3 * (now - start) / in_block)
                start, in_block = now, 0
    per_step = launches.per_step_ms(steps)
    kernel = sum(per_step.values())
    solve = per_step.get(SOLVE_KERNEL, np.zeros(steps))
    return {
        "wall_ms": float(np.median(walls)),
        "wall_spread": [float(np.min(walls)), float(np.max(walls))],
        "kernel_ms": float(np.median(kernel)),
        "solve_ms": float(np.median(solve)),
        "launches": len(launches.events) / steps,
        "substeps": int(world.substeps),
        # (after the clock: small reads) the colours of the last step's largest group
        "batches": int(world.statistics(contacts=False)["batches"]),
        "solve_resources": solve_resources(world),
    }


def solve_resources(world) -> dict:
    """What the device's compiler made of the World's solve kernel
    (`rbgen.codegen.kernel_resources`: on NVIDIA a largest work group of 256 means over 128
    registers a work-item, and private memory is what it spilled)."""
    for spec, options in world.kernel_specs():
        if SOLVE_KERNEL in kernel_names(spec.source):
            return kernel_resources(world.runtime, spec, options)[SOLVE_KERNEL]
    return {}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="rbgen device choice (index or name)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 111375])
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--warmup", type=int, default=20)
    bench.add_out_argument(parser)
    args = parser.parse_args()
    runtime = Runtime(args.device, profiling=True)
    print(f"solve anatomy on {runtime.traits.describe()}", flush=True)
    results = []
    for n in args.sizes:
        default = time_run(runtime, n, {}, args.steps, args.warmup)
        substeps = default["substeps"]
        runs = {"default": default}
        for name, options in variants(substeps).items():
            if name != "default":
                runs[name] = time_run(runtime, n, options, args.steps, args.warmup)
        print(f"\nBoxBox {n:,} ({substeps} substeps by default)")
        print(f"  {'run':14} {'wall ms':>8} {'kernels':>8} {'solve':>8} {'launches':>8}")
        for name, r in runs.items():
            print(
                f"  {name:14} {r['wall_ms']:8.3f} {r['kernel_ms']:8.3f} {r['solve_ms']:8.3f} "
                f"{r['launches']:8.1f}"
            )
            results.append(
                {
                    "name": f"boxbox {n} {name}",
                    "ms": r["wall_ms"],
                    "ms_spread": r["wall_spread"],
                    "baseline": None
                    if name == "default"
                    else {"name": f"boxbox {n} default", "ms": default["wall_ms"]},
                    **{
                        k: r[k]
                        for k in (
                            "kernel_ms",
                            "solve_ms",
                            "launches",
                            "substeps",
                            "batches",
                            "solve_resources",
                        )
                    },
                }
            )
        solve = default["solve_ms"]
        sweep = (solve - runs["one_sweep"]["solve_ms"]) / substeps
        push = (solve - runs["no_push"]["solve_ms"]) / substeps
        removed = substeps - runs["half_substeps"]["substeps"]
        substep = (solve - runs["half_substeps"]["solve_ms"]) / max(1, removed)
        colours = max(1, default["batches"])
        print(f"  {SOLVE_KERNEL} on this device: {default['solve_resources']}")
        print(
            f"  a substep of the default costs the solve {substep:.3f} ms: a velocity sweep "
            f"{sweep:.3f} ms ({1e3 * sweep / colours:.1f} us a colour of {colours}), the push "
            f"rows {push:.3f} ms (differences against default)"
        )
    if args.out:
        record = bench.make_record(
            "solve_anatomy",
            results,
            bench.device_record(args.device),
            {"sizes": args.sizes, "steps": args.steps, "warmup": args.warmup},
        )
        print(f"wrote {bench.write_results(record, args.out)}")


if __name__ == "__main__":
    main()
