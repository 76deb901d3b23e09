"""Where the host time of World.step goes: a cProfile of N steps of a scene.

usage: python benchmarks/profile_step.py [--device D] [--scene boxbox] [--n 1000] [--steps 30]
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time


def main() -> None:
    from rbgen.harness import build_scene

    parser = argparse.ArgumentParser()
    parser.add_argument("--device", default=None)
    parser.add_argument("--scene", default="boxbox")
    parser.add_argument("--n", type=int, default=1000)
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--top", type=int, default=20)
    args = parser.parse_args()
    world = build_scene(args.scene, args.n, args.device)[0]
    for _ in range(10):
        world.step(1 / 60)
    world.runtime.queue.finish()
    profile = cProfile.Profile()
    launches = world.runtime.counters["launches"]
    t0 = time.perf_counter()
    profile.enable()
    for _ in range(args.steps):
        world.step(1 / 60)
    profile.disable()
    host = (time.perf_counter() - t0) / args.steps
    world.runtime.queue.finish()
    total = (time.perf_counter() - t0) / args.steps
    per_step = (world.runtime.counters["launches"] - launches) / args.steps
    print(
        f"{args.scene} n={args.n} on {world.runtime.traits.device_name}: "
        f"host {1e3 * host:.2f} ms/step "
        f"(profiled), with drain {1e3 * total:.2f} ms/step, {per_step:.0f} launches/step"
    )
    pstats.Stats(profile).sort_stats("tottime").print_stats(args.top)


if __name__ == "__main__":
    main()
