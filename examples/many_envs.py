"""Many environments in one pipeline: stacks of boxes pushed by random forces, with resets.

    python examples/many_envs.py [--envs 4096] [--steps 300] [--device D]

Each environment is a column of 4 unit boxes on the shared ground (rbgen.WorldBatch);
every step each box gets a random horizontal push (the "actions", one (envs, 4, 3)
array); every 20 steps the environments whose top box fell below 2 m (the column
toppled) are reset to the initial stack, as a learning loop resets finished episodes.
Prints ms/step, body-steps/s and the resets. ``--envs 16`` runs it small on a CPU.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import rbgen

DT = 1 / 60
BOXES = 4


def column(device=None):
    """One environment: 4 unit boxes stacked on the ground plane."""
    world = rbgen.World(device)
    world.add_static(rbgen.Plane((0, 1, 0), 0.0))
    positions = [[0.0, 0.5 + k, 0.0] for k in range(BOXES)]
    world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, positions=positions)
    return world


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--push", type=float, default=40.0, help="largest push (N)")
    parser.add_argument("--device", default=None)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    batch = rbgen.WorldBatch(args.envs, lambda: column(args.device))
    rng = np.random.default_rng(args.seed)
    resets = 0
    batch.step(DT)  # builds the kernels (not timed)
    start = time.perf_counter()
    for step in range(1, args.steps):
        push = rng.uniform(-args.push, args.push, (args.envs, BOXES, 3))
        push[..., 1] = 0.0
        batch.apply_forces(push)
        batch.step(DT)
        if step % 20 == 0:
            top = batch.positions[:, -1, 1]  # one read of every environment
            fallen = np.flatnonzero(top < 2.0)
            batch.reset(fallen)
            resets += len(fallen)
    batch.statistics()  # (waits for the last step)
    seconds = (time.perf_counter() - start) / max(1, args.steps - 1)
    heights = batch.positions[:, :, 1]
    bodies = args.envs * BOXES
    print(
        f"{args.envs} environments x {BOXES} boxes on {batch.runtime.traits.device_name}: "
        f"{1e3 * seconds:.2f} ms/step ({bodies / seconds / 1e6:.2f} M body-steps/s, "
        f"resets and observations included), {resets} resets, "
        f"{batch.last_step_counters['launches']} launches a step"
    )
    print(f"heights: min {heights.min():.3f} m, max {heights.max():.3f} m")
    finite = bool(np.all(np.isfinite(heights)))
    return 0 if finite and heights.min() > 0.3 else 1


if __name__ == "__main__":
    sys.exit(main())
