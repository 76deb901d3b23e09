"""Midphase benchmark: the triangle walks of N bodies resting on a terrain, local-memory
subtrees against the global-memory walk (Bullet3's), on the same pairs in the same run.

    python benchmarks/midphase.py [--device D] [--cells 1000] [--bodies 10000]
                                  [--repeats 20] [--order grid|shuffled|both]
                                  [--brute-force 256] [--out benchmarks/results]

The scene: the terrain of the `terrain` scene (2 x cells^2 triangles, rbgen.scenes) and
``--bodies`` bodies (boxes, hulls, spheres, as the rain's) resting on it on a square grid
of 1.6 m, each paired with the terrain, as the broadphase hands them over. ``--order``:
the pair list in grid order (neighbours in the list are neighbours on the ground, as
after a rain added row by row) or shuffled (no two neighbours in a work group: the
staged subtrees are shared by nobody).

For every point of the tuner's space (`rbgen.pipeline.midphase.search_space`: both
traversals, subtree sizes, work-group sizes) and each order: the median device time of
the whole triangle expansion (count walk, scan, write walk) over ``--repeats`` runs,
with the global walk of the same work-group size as the named baseline, the output
compared pair for pair with the baseline's, and the reuse the local walk gets (walks
that reach a staged subtree per staging: 1 means every staged subtree served one pair).
A brute-force check (every triangle box against a body's box, numpy) covers
``--brute-force`` random bodies. Results: JSON and Markdown under ``--out`` (rbgen.bench,
kind "benchmarks/midphase.py").
"""

from __future__ import annotations

import argparse
import statistics
import sys

import numpy as np


def resting_scene(runtime, cells: int, count: int, seed: int = 0):
    """The terrain and ``count`` bodies resting on it (a box's bottom on the ground under
    its centre), with their world AABBs on the device."""
    import pyopencl.array as cla

    import rbgen
    from rbgen import layouts, scenes
    from rbgen.harness import terrain_shapes
    from rbgen.pipeline.aabbs import WorldAabbs
    from rbgen.shapes import ShapeTable

    heights = scenes.terrain_heights(cells)
    mesh = rbgen.TriangleMesh(*scenes.height_field(heights), name="terrain")
    table = ShapeTable()
    table.add(mesh)
    shapes = terrain_shapes()
    index = [table.add(shapes[k]) for k in (0, 1, 4)]  # box, hull, sphere
    side = int(np.ceil(np.sqrt(count)))
    extent = cells * scenes.TERRAIN_SPACING
    start = 0.5 * (extent - 1.6 * (side - 1))
    i, k = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    x, z = (start + 1.6 * i.ravel())[:count], (start + 1.6 * k.ravel())[:count]
    cell = np.clip(np.stack([x, z], 1).astype(int), 0, cells)
    bodies = layouts.BODY.zeros(count + 1)
    bodies["orientation"][:, 3] = 1.0
    bodies["shape"][0] = 0
    bodies["shape"][1:] = np.random.default_rng(seed).choice(index, count)
    bodies["inv_mass"][1:] = 1.0
    bodies["position"][1:, :3] = np.stack([x, heights[cell[:, 0], cell[:, 1]] + 0.3, z], 1)
    q = runtime.queue
    packed = table.pack_all().to_device(q)
    d_bodies = cla.to_device(q, bodies)
    aabbs = cla.empty(q, len(bodies), layouts.AABB.dtype)
    WorldAabbs(runtime, table.type_names())(
        d_bodies, packed.shapes, packed.vertices, aabbs, len(bodies), 0.02
    )
    return mesh, table, bodies, packed, d_bodies, aabbs


def measure(runtime, midphase, args, repeats: int) -> list[float]:
    import pyopencl as cl

    samples = []
    for _ in range(repeats):
        runtime.queue.finish()
        start = cl.enqueue_marker(runtime.queue)
        midphase.enqueue(*args)
        end = cl.enqueue_marker(runtime.queue)
        end.wait()
        samples.append(1e-6 * (end.profile.end - start.profile.start))
    return samples


def reuse(
    mesh, found: np.ndarray, pairs: np.ndarray, work_group_size: int, subtree_nodes: int
) -> float:
    """Walks that reach a staged subtree per staging, for the groups of consecutive pairs
    of the list (from the subtrees of the triangles found: what a group stages at least)."""
    subtrees = mesh.bvh.subtrees(subtree_nodes)
    index = mesh.bvh.nodes["index"]
    leaf_subtree = np.empty(mesh.triangle_count, np.int64)
    for s, (root, size) in enumerate(subtrees):
        leaves = index[root : root + size]
        leaf_subtree[leaves[leaves >= 0]] = s
    place = np.empty(len(pairs), np.int64)
    place[pairs["b"].astype(np.int64) - 1] = np.arange(len(pairs))
    pair = place[found["b"].astype(np.int64) - 1]
    visits = np.unique(np.stack([pair, leaf_subtree[found["sub"].astype(np.int64) - 1]], 1), axis=0)
    groups = np.unique(np.stack([visits[:, 0] // work_group_size, visits[:, 1]], 1), axis=0)
    return len(visits) / max(1, len(groups))


def main(argv=None) -> int:
    from rbgen import bench

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None)
    parser.add_argument("--cells", type=int, default=1000)
    parser.add_argument("--bodies", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--order", choices=("grid", "shuffled", "both"), default="both")
    parser.add_argument("--brute-force", type=int, default=256)
    bench.add_out_argument(parser)
    args = parser.parse_args(argv)

    import time

    import pyopencl.array as cla

    from rbgen import layouts
    from rbgen.device import Runtime
    from rbgen.pipeline import midphase_reference as reference
    from rbgen.pipeline.midphase import Midphase, default_params, search_space

    runtime = Runtime(args.device, profiling=True)
    t0 = time.perf_counter()
    mesh, table, bodies, packed, d_bodies, aabbs = resting_scene(runtime, args.cells, args.bodies)
    build_s = time.perf_counter() - t0
    print(f"# {runtime.traits.describe()}")
    print(
        f"# terrain {mesh.triangle_count:,} triangles ({mesh.nbytes() / mesh.triangle_count:.1f} "
        f"B/triangle on the device), {args.bodies:,} resting bodies; scene built in "
        f"{build_s:.1f} s; device time of the whole expansion (count walk, scan, write "
        f"walk), median of {args.repeats}"
    )
    orders = ("grid", "shuffled") if args.order == "both" else (args.order,)
    rng = np.random.default_rng(0)
    results = []
    default = default_params(runtime.traits)
    print(
        f"{'order':>8} {'traversal':>9} {'wg':>4} {'subtree':>7} {'ms':>8} {'spread':>15} "
        f"{'x global':>8} {'pairs out':>10} {'equal':>5} {'reuse':>6}"
    )
    for order in orders:
        pairs = layouts.PAIR.zeros(args.bodies)
        pairs["a"], pairs["b"] = 0, np.arange(1, args.bodies + 1)
        if order == "shuffled":
            pairs = pairs[rng.permutation(args.bodies)]
        d_pairs = cla.to_device(runtime.queue, pairs)
        count = cla.to_device(runtime.queue, np.array([args.bodies], np.uint32))
        call = (d_bodies, len(bodies), packed, aabbs, d_pairs, count)
        baselines = {}
        for params in sorted(
            search_space(runtime.traits),
            key=lambda p: (p["work_group_size"], p["traversal"] != "global", p["subtree_nodes"]),
        ):
            midphase = Midphase(runtime, table, params=params, capacity=16 * args.bodies)
            found = midphase.find_pairs(*call)  # warm-up: builds, grows
            samples = measure(runtime, midphase, call, args.repeats)
            ms = statistics.median(samples)
            name = f"{order} {params['traversal']} wg={params['work_group_size']}" + (
                f" subtree={params['subtree_nodes']}" if params["subtree_nodes"] else ""
            )
            if params["traversal"] == "global":
                baselines[params["work_group_size"]] = (name, ms, found)
            base_name, base_ms, base_found = baselines[params["work_group_size"]]
            equal = bool(np.array_equal(found, base_found))
            shared = (
                reuse(mesh, found, pairs, params["work_group_size"], params["subtree_nodes"])
                if params["subtree_nodes"]
                else None
            )
            results.append(
                {
                    "name": name,
                    "ms": ms,
                    "ms_spread": [min(samples), max(samples)],
                    "params": params,
                    "order": order,
                    "pairs_out": len(found),
                    "equal_to_baseline": equal,
                    "reuse": shared,
                    "heuristic_default": params == default,
                    "baseline": None
                    if params["traversal"] == "global"
                    else {"name": base_name, "ms": base_ms},
                }
            )
            print(
                f"{order:>8} {params['traversal']:>9} {params['work_group_size']:>4} "
                f"{params['subtree_nodes'] or '-':>7} {ms:>8.3f} "
                f"{min(samples):>7.3f}-{max(samples):<7.3f} {base_ms / ms:>7.2f}x "
                f"{len(found):>10,} {'yes' if equal else 'NO':>5} "
                f"{'-' if shared is None else f'{shared:.1f}':>6}"
                + ("  (default)" if params == default else ""),
                flush=True,
            )
    # brute force on a sample of the bodies: every triangle box against each one's box
    sample = np.sort(rng.choice(args.bodies, min(args.brute_force, args.bodies), replace=False))
    sample_pairs = layouts.PAIR.zeros(len(sample))
    sample_pairs["a"], sample_pairs["b"] = 0, sample + 1
    expected = reference.brute_force(mesh, bodies, aabbs.get(), sample_pairs)
    found = baselines[min(baselines)][2]
    mine = found[np.isin(found["b"], sample + 1)]
    mine = mine[np.lexsort((mine["sub"], mine["b"]))]
    brute_ok = bool(np.array_equal(mine, expected))
    print(
        f"brute force on {len(sample)} bodies: {len(expected):,} candidates, "
        f"{'equal' if brute_ok else 'DIFFERENT'}; all {len(found):,} candidates of "
        f"{args.bodies:,} bodies: {len(found) / args.bodies:.2f} triangles a body"
    )
    if args.out:
        settings = {
            "cells": args.cells,
            "triangles": mesh.triangle_count,
            "bodies": args.bodies,
            "repeats": args.repeats,
            "bytes_per_triangle": mesh.nbytes() / mesh.triangle_count,
            "scene_build_s": build_s,
            "brute_force_bodies": int(len(sample)),
            "brute_force_candidates": int(len(expected)),
            "brute_force_equal": brute_ok,
            "timing": "median device time (profiling markers) of the triangle "
            "expansion: count walk, scan, write walk",
        }
        record = bench.make_record(
            "benchmarks/midphase.py", results, bench.device_record(args.device), settings
        )
        print(f"wrote {bench.write_results(record, args.out)}")
    return 0 if brute_ok and all(r["equal_to_baseline"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
