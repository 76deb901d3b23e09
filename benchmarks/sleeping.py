"""Sleeping islands: what a dropped pile costs once it rests, with sleeping off and on.

    python benchmarks/sleeping.py [--device D] [--n 1000 8000] [--steps 600] [--tail 100]
                                  [--repeats 2] [--options JSON] [--out DIR]

For each N, the box_pile scene (`rbgen.harness`: N unit boxes dropped in 5 layers onto a
ground slab) is stepped ``--steps`` steps with sleeping off (the baseline) and on,
alternated in one run (``--repeats`` times each, off first): the last ``--tail`` steps are
timed in blocks of 10 (each block ends with ``queue.finish()``; ms/step is the median
block's), the earlier ones are the fall and the settling. Each result carries ms/step,
the bodies asleep (every 100 steps and at the end), the largest body speed at the end,
launches and blocking reads per step, and (sleeping on) ``speedup``: the baseline's ms
over its own, from the medians over the repeats. JSON (rbgen.bench's format, kind
"sleeping") under --out.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from rbgen import bench
from rbgen.harness import build_scene

BLOCK = 10


def run_pile(n: int, steps: int, tail: int, device, sleeping: bool, options: dict) -> dict:
    """One run: the pile stepped ``steps`` steps, the last ``tail`` timed."""
    world, ids = build_scene("box_pile", n, device, sleeping=sleeping, **options)[:2]
    dt = 1 / 60
    asleep_by_step = {}
    for k in range(1, steps - tail + 1):
        world.step(dt)
        if k % 100 == 0:  # (a blocking read, outside the timed steps)
            asleep_by_step[k] = int(world.asleep[ids].sum())
    world.statistics()  # (drains the queue: the timed blocks start empty)
    queue = world.runtime.queue
    blocks = []
    for _ in range(max(1, tail // BLOCK)):
        start = time.perf_counter()
        for _ in range(BLOCK):
            world.step(dt)
        queue.finish()
        blocks.append(1e3 * (time.perf_counter() - start) / BLOCK)
    counters = world.last_step_counters
    v = np.asarray(world.linear_velocities)[ids]
    w = np.asarray(world.angular_velocities)[ids]
    positions = np.asarray(world.positions)[ids]
    return {
        "ms": statistics.median(blocks),
        "blocks": blocks,
        "asleep": int(world.asleep[ids].sum()),
        "asleep_by_step": asleep_by_step,
        "max_speed": float(np.linalg.norm(v, axis=1).max()),
        "max_spin": float(np.linalg.norm(w, axis=1).max()),
        "nan": int((~np.isfinite(positions)).any(axis=1).sum()),
        "sunk": int((positions[:, 1] < 0.4).sum()),
        "launches": counters["launches"],
        "blocking_reads": counters["blocking_reads"],
        "plan": world.plan.describe(),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None)
    parser.add_argument("--n", type=int, nargs="+", default=[1000, 8000])
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--tail", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument(
        "--options", type=bench.world_options, default={}, help="World options as JSON"
    )
    bench.add_out_argument(parser)
    args = parser.parse_args(argv)
    options = args.options
    device = bench.device_record(args.device)
    results = []
    for n in args.n:
        runs: dict[bool, list[dict]] = {False: [], True: []}
        for _ in range(args.repeats):
            for sleeping in (False, True):  # (alternated: the machine's load hits both)
                runs[sleeping].append(
                    run_pile(n, args.steps, args.tail, args.device, sleeping, options)
                )
        pair = {}
        for sleeping, done in runs.items():
            ms = [r["ms"] for r in done]
            last = done[-1]
            name = f"box_pile {n} sleeping {'on' if sleeping else 'off'}"
            pair[sleeping] = {
                "name": name,
                "ms": statistics.median(ms),
                "ms_spread": [min(ms), max(ms)],
                "baseline": None,
                "bodies": n,
                "sleeping": sleeping,
                "runs": done,
                **{
                    k: last[k]
                    for k in ("asleep", "asleep_by_step", "max_speed", "max_spin", "nan", "sunk")
                },
                "launches": last["launches"],
                "blocking_reads": last["blocking_reads"],
                "plan": last["plan"],
            }
        off, on = pair[False], pair[True]
        on["baseline"] = off["name"]
        on["speedup"] = off["ms"] / max(on["ms"], 1e-9)
        for r in (off, on):
            print(
                f"{r['name']}: {r['ms']:.2f} ms/step over the last {args.tail} of {args.steps} "
                f"steps (runs {', '.join(f'{x:.2f}' for x in r['ms_spread'])}), asleep "
                f"{r['asleep']}/{n}, max speed {r['max_speed']:.4f} m/s, spin "
                f"{r['max_spin']:.4f} rad/s, nan {r['nan']}, sunk {r['sunk']}, "
                f"{r['launches']} launches, {r['blocking_reads']} blocking reads a step; "
                f"asleep by step {r['asleep_by_step']}",
                flush=True,
            )
        print(f"box_pile {n}: sleeping on is x{on['speedup']:.2f} the speed of off", flush=True)
        results += [off, on]
    record = bench.make_record(
        "sleeping",
        results,
        device,
        {
            "steps": args.steps,
            "tail": args.tail,
            "repeats": args.repeats,
            "world_options": options,
            "dt": 1 / 60,
            "plan": results[0]["plan"] if results else None,
        },
    )
    if args.out:
        print("wrote", bench.write_results(record, args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
