"""Device time per kernel of a World step (OpenCL profiling events), largest first.

usage: python benchmarks/kernel_times.py [--device D] [--scene boxbox] [--n 8000] [--steps 10]
                                         [--batching M] [--normal-solve S] [--sleeping]
                                         [--warmup 5]

Per kernel: the median over the timed steps of its time in one step (robust to
a step slowed by other processes on a shared CPU), and its launches per step.
"""

from __future__ import annotations

import argparse

import numpy as np
from kernel_events import KernelEvents

from rbgen.pipeline.batching import MODES as BATCHING_MODES


def main() -> None:
    from rbgen.device import Runtime
    from rbgen.harness import build_scene

    parser = argparse.ArgumentParser()
    parser.add_argument("--device", default=None)
    parser.add_argument("--scene", default="boxbox")
    parser.add_argument("--n", type=int, default=8000)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--batching", default=None, choices=BATCHING_MODES)
    parser.add_argument("--normal-solve", default=None, choices=["block", "sequential"])
    parser.add_argument("--top", type=int, default=15)
    parser.add_argument(
        "--sleeping", action="store_true", help="World option sleeping=True (its kernels' cost)"
    )
    parser.add_argument(
        "--warmup", type=int, default=5, help="steps before the timed ones (a pile settling)"
    )
    args = parser.parse_args()
    runtime = Runtime(args.device, profiling=True)
    options = {"batching": args.batching} if args.batching else {}
    if args.normal_solve:
        options["normal_solve"] = args.normal_solve
    if args.sleeping:
        options["sleeping"] = True
    world = build_scene(args.scene, args.n, runtime, **options)[0]
    for _ in range(args.warmup):
        world.step(1 / 60)
    runtime.queue.finish()

    with KernelEvents() as launches:
        for step in range(args.steps):
            launches.step = step
            world.step(1 / 60)
        runtime.queue.finish()
    per_step, counts = launches.per_step_ms(args.steps), launches.counts()
    totals = {name: float(np.median(ms)) for name, ms in per_step.items()}
    total = float(np.median(sum(per_step.values())))
    print(
        f"{args.scene} n={args.n} on {runtime.traits.device_name}: kernel time {total:.3f} ms/step "
        f"(medians over {args.steps} steps), {len(launches.events) / args.steps:.0f} launches/step"
    )
    for name, ms in sorted(totals.items(), key=lambda kv: -kv[1])[: args.top]:
        print(f"  {ms:9.3f} ms  {counts[name] / args.steps:5.1f}x  {name}")


if __name__ == "__main__":
    main()
