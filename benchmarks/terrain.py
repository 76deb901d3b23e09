"""Terrain benchmark: whole World steps of bodies resting on a triangle-mesh terrain, the
midphase's share, and the same rain on a plane as the named baseline.

    python benchmarks/terrain.py [--device D] [--cells 1000] [--bodies 10000]
                                 [--steps 100] [--warmup 600] [--repeats 20]
                                 [--out benchmarks/results]

The scene is `rbgen run terrain` (rbgen.harness: a procedural height field of
2 x cells^2 triangles, a rain of boxes, hulls, compounds and a few spheres and capsules
in 4 layers). After ``--warmup`` steps (long enough for the rain to come to rest), the
timed steps are clocked as rbgen.harness clocks every scene (median of 10 blocks,
enqueued back to back, no blocking read); then the midphase alone (the step's expansion,
on the last step's pairs and AABBs, copied to a profiling queue of its own: count walk,
scan, write walk) is timed by device events, median of ``--repeats``, with the World's
parameters and both traversals on the same pairs. Baseline,
measured in the same run: the same rain on a plane at the terrain's lowest height
(no midphase, no triangles), so the difference is what the mesh costs. Results: JSON and
Markdown under ``--out`` (rbgen.bench, kind "benchmarks/terrain.py").
"""

from __future__ import annotations

import argparse
import statistics
import sys


def last_inputs(world) -> dict:
    """The last step's midphase inputs, read back (after the timed steps)."""
    bp = world._pipeline.broadphase.broadphase
    count = int(world.runtime.read(bp.count)[0])
    return {
        "bodies": world.runtime.read(world._device.bodies)[: world._device.count],
        "aabbs": world.runtime.read(world._pipeline.prepare.aabbs)[: world._device.count],
        "pairs": world.runtime.read(bp.pairs)[: max(count, 1)],
        "count": count,
        "shape_indices": world._device.shape_indices,
        "table": world._bodies.shapes,
        "margin": world.settings.contact_margin,
    }


def midphase_ms(runtime, inputs: dict, params: dict, repeats: int):
    """Median device ms of the midphase with ``params`` on ``inputs`` (a profiling
    ``runtime`` of its own: the World's queue is not slowed by profiling), its samples and
    the pairs it wrote."""
    import numpy as np
    import pyopencl as cl
    import pyopencl.array as cla

    from rbgen.pipeline.midphase import Midphase

    q = runtime.queue
    table = inputs["table"]
    call = (
        cla.to_device(q, inputs["bodies"]),
        len(inputs["bodies"]),
        table.pack_all().to_device(q),
        cla.to_device(q, inputs["aabbs"]),
        cla.to_device(q, inputs["pairs"]),
        cla.to_device(q, np.array([inputs["count"]], np.uint32)),
        inputs["margin"],
        inputs["shape_indices"],
    )
    midphase = Midphase(runtime, table, params=params, capacity=8 * max(1, inputs["count"]))
    found = midphase.find_pairs(*call)  # warm-up (builds, grows)
    samples = []
    for _ in range(repeats):
        q.finish()
        start = cl.enqueue_marker(q)
        midphase.enqueue(*call)
        end = cl.enqueue_marker(q)
        end.wait()
        samples.append(1e-6 * (end.profile.end - start.profile.start))
    return statistics.median(samples), samples, len(found)


def main(argv=None) -> int:
    from rbgen import bench

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None)
    parser.add_argument("--cells", type=int, default=1000)
    parser.add_argument("--bodies", type=int, default=10_000)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--warmup", type=int, default=600)
    parser.add_argument("--repeats", type=int, default=20)
    bench.add_out_argument(parser)
    args = parser.parse_args(argv)

    from rbgen.device import Runtime
    from rbgen.harness import run_scene
    from rbgen.pipeline.midphase import default_params

    runtime = Runtime(args.device)
    kept = {}

    def keep(world, step):
        kept["world"] = world

    rows = []
    for ground in ("mesh", "plane"):
        summary = run_scene(
            "terrain",
            args.bodies,
            args.steps,
            device=runtime,
            progress=False,
            warmup=args.warmup,
            on_step=keep,
            terrain_cells=args.cells,
            terrain_ground=ground,
        )
        rows.append(summary)
        if ground == "mesh":
            world = kept["world"]
            stage = world._pipeline["midphase"].midphase
            triangles = stage.table.shapes[0].triangle_count
            own = dict(stage.triangle_params)
            inputs = last_inputs(world)
            profiling = Runtime(args.device, profiling=True)
            walks = {"world's": midphase_ms(profiling, inputs, own, args.repeats)}
            for traversal, subtree in (("global", 0), ("local", 128)):
                params = {
                    "work_group_size": own["work_group_size"],
                    "traversal": traversal,
                    "subtree_nodes": subtree,
                }
                walks[f"{traversal}"] = midphase_ms(profiling, inputs, params, args.repeats)
            del world, kept["world"]
    mesh, plane = rows
    print(f"# {runtime.traits.describe()}")
    print(
        f"# terrain {triangles:,} triangles, {args.bodies:,} bodies, {args.warmup} warm-up "
        f"steps, {args.steps} timed; plan: {mesh['plan']}; midphase {own} "
        f"(heuristic {default_params(runtime.traits)})"
    )
    print(f"{'case':>34} {'ms':>9} {'spread':>17} {'vs baseline':>11}")
    results = []
    for name, s, base in (
        ("whole step, terrain", mesh, plane),
        ("whole step, plane (baseline)", plane, None),
    ):
        blocks = s["ms_per_step_blocks"]
        extra = "" if base is None else f"+{s['ms_per_step'] - base['ms_per_step']:.3f} ms"
        results.append(
            {
                "name": name,
                "ms": s["ms_per_step"],
                "ms_spread": [min(blocks), max(blocks)],
                "summary": {k: v for k, v in s.items() if k != "ms_per_step_blocks"},
                "baseline": None
                if base is None
                else {"name": "whole step, plane (baseline)", "ms": base["ms_per_step"]},
            }
        )
        print(
            f"{name:>34} {s['ms_per_step']:>9.3f} {min(blocks):>8.3f}-{max(blocks):<8.3f} "
            f"{extra:>11}"
            f"  ({s['pairs']:,} pairs, {s['manifolds']:,} manifolds, {s['contacts']:,} points,"
            f" NaN {s['nans']}, sunk {s['sunk']}, max speed {s['max_speed']:.2f} m/s, "
            f"redone {s['overflows']})"
        )
    global_ms = walks["global"][0]
    for label, (ms, samples, found) in walks.items():
        name = f"midphase, {label} walk"
        results.append(
            {
                "name": name,
                "ms": ms,
                "ms_spread": [min(samples), max(samples)],
                "pairs_out": found,
                "baseline": None
                if label == "global"
                else {"name": "midphase, global walk", "ms": global_ms},
            }
        )
        print(
            f"{name:>34} {ms:>9.3f} {min(samples):>8.3f}-{max(samples):<8.3f} "
            f"{global_ms / ms:>10.2f}x  ({found:,} pairs out)"
        )
    if args.out:
        settings = {
            "cells": args.cells,
            "triangles": triangles,
            "bodies": args.bodies,
            "steps": args.steps,
            "warmup": args.warmup,
            "repeats": args.repeats,
            "dt": 1 / 60,
            "midphase_params": own,
            "timing": "whole step: median of 10 blocks (rbgen.harness); midphase: "
            "median device time (profiling markers) on the last step's "
            "inputs",
        }
        record = bench.make_record(
            "benchmarks/terrain.py", results, bench.device_record(args.device), settings
        )
        print(f"wrote {bench.write_results(record, args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
