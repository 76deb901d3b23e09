"""Throughput of many environments in one pipeline against the number of environments.

    python benchmarks/many_envs.py [--device D] [--envs 1,16,256,4096,16384] [--quick]
                                   [--steps 100] [--repeats 3] [--options JSON] [--out DIR]

Each environment: 16 unit boxes (4 columns of 4, 1.05 m apart) on the shared ground
plane, pushed every step by random horizontal forces (one (envs, 16, 3) array through
`WorldBatch.apply_forces`, as a learning loop's actions), all environments in the same
space (rbgen.WorldBatch). Baseline, named ``world_N`` and measured in the same run: one
World of the same N x 16 boxes with the environments set apart in space (a 5 m grid,
so none touch), the same ground and the same pushes -- what the batch costs over the
plain pipeline for the same bodies. ``--options``: World options (JSON) for both, so that a
solver setting is compared on the same scene.

Per N it prints and records ms/step (median of ``--repeats`` runs of ``--steps`` steps,
the spread), body-steps/s, launches and blocking reads a step. JSON and Markdown go to
``--out`` (benchmarks/results) in rbgen.bench's format. The issue's target on an H200:
4,096 environments x 16 boxes <= 1.5 ms/step (>= 40M body-steps/s).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import rbgen
from rbgen import bench

DT = 1 / 60
BOXES = 16
#: environments of the baseline World lie on a square grid of this pitch (m)
PITCH = 5.0


def env_positions() -> np.ndarray:
    """(16, 3): 4 columns of 4 unit boxes, 1.05 m apart."""
    columns = [(0.0, 0.0), (1.05, 0.0), (0.0, 1.05), (1.05, 1.05)]
    return np.array([[x, 0.5 + k, z] for x, z in columns for k in range(4)])


def boxes_on_ground(device, positions, options=None):
    """A World (``options``) of unit boxes at ``positions`` on the ground plane."""
    world = rbgen.World(device, **(options or {}))
    world.add_static(rbgen.Plane((0, 1, 0), 0.0))
    world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, positions=positions)
    return world


def one_env(device, options=None):
    return boxes_on_ground(device, env_positions(), options)


def spread_world(device, envs: int, options=None):
    """The baseline: the same bodies in one World, environments 5 m apart."""
    side = int(np.ceil(np.sqrt(envs)))
    k = np.arange(envs)
    offsets = np.stack([(k % side) * PITCH, np.zeros(envs), (k // side) * PITCH], axis=1)
    positions = (offsets[:, None, :] + env_positions()[None]).reshape(-1, 3)
    return boxes_on_ground(device, positions, options)


def timed(sim, push, envs: int, steps: int, repeats: int, batch: bool):
    """(ms per step of each repeat, the step's counters); pushes every step."""
    rng = np.random.default_rng(0)
    forces = rng.uniform(-push, push, (8, envs, BOXES, 3))
    forces[..., 1] = 0.0
    ids = np.arange(1, 1 + envs * BOXES)

    def step(k):
        if batch:
            sim.apply_forces(forces[k % 8])
        else:
            sim.apply_forces(ids, forces[k % 8].reshape(-1, 3))
        sim.step(DT)

    for k in range(3):  # builds the kernels, grows the buffers (not timed)
        step(k)
    sim.statistics()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for k in range(steps):
            step(k)
        sim.statistics()  # waits for the last step
        times.append(1e3 * (time.perf_counter() - start) / steps)
    return times, dict(sim.last_step_counters)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None)
    parser.add_argument("--envs", default="1,4,16,64,256,1024,4096,16384")
    parser.add_argument("--quick", action="store_true", help="N up to 256 (a CPU)")
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--push", type=float, default=20.0)
    parser.add_argument(
        "--options",
        type=bench.world_options,
        default={},
        help="World options (JSON) for the batch and its baseline",
    )
    bench.add_out_argument(parser)
    args = parser.parse_args(argv)
    sizes = [int(n) for n in args.envs.split(",")]
    if args.quick:
        sizes = [n for n in sizes if n <= 256]
    results = []
    print(
        f"{'envs':>6} {'bodies':>8} {'batch ms':>9} {'Mbody-steps/s':>14} {'world ms':>9} "
        f"{'launches':>8} {'reads':>5}",
        flush=True,
    )
    for envs in sizes:
        batch = rbgen.WorldBatch(envs, lambda: one_env(args.device, args.options))
        batch_times, counters = timed(batch, args.push, envs, args.steps, args.repeats, True)
        world = spread_world(args.device, envs, args.options)
        world_times, world_counters = timed(world, args.push, envs, args.steps, args.repeats, False)
        bodies = envs * BOXES
        ms, base_ms = statistics.median(batch_times), statistics.median(world_times)
        rate = bodies / ms * 1e3
        print(
            f"{envs:6d} {bodies:8d} {ms:9.3f} {rate / 1e6:14.3f} {base_ms:9.3f} "
            f"{counters['launches']:8d} {counters['blocking_reads']:5d}",
            flush=True,
        )
        results.append(
            {
                "name": f"batch_{envs}",
                "envs": envs,
                "bodies": bodies,
                "ms": ms,
                "ms_spread": [min(batch_times), max(batch_times)],
                "body_steps_per_s": rate,
                "launches_per_step": counters["launches"],
                "blocking_reads_per_step": counters["blocking_reads"],
                "baseline": {
                    "name": f"world_{envs}",
                    "ms": base_ms,
                    "ms_spread": [min(world_times), max(world_times)],
                    "body_steps_per_s": bodies / base_ms * 1e3,
                    "launches_per_step": world_counters["launches"],
                },
                "plan": batch.plan.describe(),
            }
        )
    record = bench.make_record(
        "many_envs",
        results,
        bench.device_record(args.device),
        {
            "dt": DT,
            "steps": args.steps,
            "repeats": args.repeats,
            "boxes_per_env": BOXES,
            "options": args.options,
        },
    )
    if args.out:
        print(f"wrote {bench.write_results(record, args.out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
