"""Narrowphase benchmark: contacts of the BoxBox scene's candidate pairs.

    python benchmarks/narrowphase.py [--device D] [--sizes 27000 111375]
                                     [--ground box|plane] [--box-path box_box box hull gauss]
                                     [--clip fused separate] [--placement-tile 256 1024]
                                     [--routing auto queues]
                                     [--hulls]

Scene: rbgen.scenes.boxbox_scene (cubes of half extent 1 on a ground whose top
is y = 0). A fresh scene only touches exactly (separation 0), so every layer
j is lowered by ``sink * (j + 1)`` (default 0.01): each resting contact then
penetrates by ``sink``. Candidate pairs come from a numpy uniform grid on the
host (AABBs grown by the margin), the ground being body 0 paired with the
bottom layer. Each configuration runs once cold (empty best-axis cache), then
``--repeat`` times warm; we report the warm median of the total enqueue-to-
finish wall time and of each stage's kernel time (OpenCL events), the launch
count and the contact counts. No scipy here (the GPU machine has none), except
for the opt-in ``--hulls`` table (hull-hull edge axes: unique directions vs
Gauss map), which cooks hulls with qhull.
"""
from __future__ import annotations

import argparse
import itertools
import time


import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from rbgen import Runtime, layouts
from rbgen.pipeline.narrowphase import Narrowphase
from rbgen.scenes import standard_boxbox_scene
from rbgen.shapes import Box, Plane, ShapeTable


def grid_pairs(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """(a, b) with a < b for every pair of overlapping AABBs (numpy uniform grid).

    Cell size = the largest AABB extent, each box hashed by its lower corner,
    so overlapping boxes are in the same or neighbouring cells.
    """
    n = len(lower)
    cell = float((upper - lower).max())
    coords = np.floor(lower / cell).astype(np.int64)
    coords -= coords.min(axis=0) - 1
    dims = coords.max(axis=0) + 2

    def key(c):
        return (c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2]

    order = np.argsort(key(coords), kind="stable")
    sorted_keys = key(coords)[order]
    found = []
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                k = key(coords + (dx, dy, dz))
                lo = np.searchsorted(sorted_keys, k, "left")
                hi = np.searchsorted(sorted_keys, k, "right")
                counts = hi - lo
                i = np.repeat(np.arange(n), counts)
                starts = np.repeat(lo - np.cumsum(counts) + counts, counts)
                j = order[starts + np.arange(len(i))]
                keep = (i < j) & np.all(lower[i] <= upper[j], axis=1) & np.all(lower[j] <= upper[i], axis=1)
                found.append(np.column_stack([i[keep], j[keep]]))
    pairs = np.unique(np.concatenate(found), axis=0)
    return pairs


def build(count: int, ground: str, sink: float, margin: float):
    scene = standard_boxbox_scene(count)
    positions = scene.positions.astype(np.float64).copy()
    layer = np.rint((positions[:, 1] - 1.0) / 2.0)
    positions[:, 1] -= sink * (layer + 1)
    table = ShapeTable()
    cube = table.add(Box(scene.half_extents))
    if ground == "plane":
        floor = table.add(Plane(scene.ground_normal, scene.ground_offset))
        ground_position = np.zeros(3)
    else:
        floor = table.add(Box(scene.ground_half_extents))
        ground_position = scene.ground_position
    bodies = layouts.BODY.zeros(count + 1)
    bodies["orientation"][:, 3] = 1.0
    bodies["shape"] = cube
    bodies["shape"][0] = floor
    bodies["position"][0, :3] = ground_position
    bodies["position"][1:, :3] = positions
    bodies["inv_mass"][1:] = 1.0
    bodies["friction"] = 0.6
    he = scene.half_extents
    box_pairs = grid_pairs(positions - he - margin, positions + he + margin) + 1
    on_ground = np.nonzero(positions[:, 1] - he[1] <= scene.ground_offset + margin)[0] + 1
    ground_pairs = np.column_stack([np.zeros_like(on_ground), on_ground])
    idx = np.concatenate([ground_pairs, box_pairs])
    idx = idx[np.lexsort((idx[:, 1], idx[:, 0]))]
    pairs = layouts.PAIR.zeros(len(idx))
    pairs["a"], pairs["b"] = idx[:, 0], idx[:, 1]
    return table, bodies, pairs


def event_ms(event) -> float:
    return (event.profile.end - event.profile.start) * 1e-6


def run(runtime: Runtime, scene, count: int, ground: str, box_path: str, margin: float,
        repeat: int, shapes: dict | None = None) -> dict:
    table, bodies, pairs = scene
    q = runtime.queue
    # "box_box": the closed-form 15-axis kernel; "box": the generic test with closed-form
    # box projection and 3 x 3 edge directions; "hull": boxes as hulls (vertex projection),
    # same directions; "gauss": boxes as hulls, Gauss-map edge pairs
    if box_path == "box_box":
        narrowphase = Narrowphase(runtime, table, box_path="box_box", **(shapes or {}))
    else:
        narrowphase = Narrowphase(runtime, table, box_path="box" if box_path == "box" else "hull",
                                  **(shapes or {}),
                                  edge_axes={"box_box": "gauss_map" if box_path == "gauss"
                                             else "directions"})
    packed = table.pack_all().to_device(q)
    d_bodies, d_pairs = cla.to_device(q, bodies), cla.to_device(q, pairs)
    pair_count = cla.to_device(q, np.array([len(pairs)], np.uint32))
    manifolds = cla.empty(q, len(pairs), layouts.CONTACT_MANIFOLD.dtype)
    manifold_count, overflow = cla.zeros(q, 1, np.uint32), cla.zeros(q, 1, np.uint32)
    args = (d_bodies, packed, d_pairs, pair_count, manifolds, manifold_count, overflow, margin)
    narrowphase.enqueue(*args)  # cold: empty best-axis cache
    q.finish()
    walls, stages = [], []
    launches0 = runtime.counters["launches"]
    for _ in range(repeat):
        t0 = time.perf_counter()
        events = narrowphase.enqueue(*args)
        q.finish()
        walls.append(time.perf_counter() - t0)
        stages.append({k: event_ms(e) for k, e in events.items()})
    launches = (runtime.counters["launches"] - launches0) // repeat
    result = manifolds.get()[: int(manifold_count.get()[0])]
    assert overflow.get()[0] == 0
    return {
        "count": count, "ground": ground, "box_path": box_path, "pairs": len(pairs),
        "manifolds": len(result), "points": int(result["point_count"].sum()),
        "total_ms": 1e3 * float(np.median(walls)), "launches": launches,
        "stages": {k: float(np.median([s[k] for s in stages])) for k in stages[0]},
    }


def hull_comparison(runtime: Runtime, repeat: int) -> None:
    """Hull-hull separating-axis stage, edge axes by unique directions vs Gauss map.

    Random pairs of three hulls of one kind, about three quarters touching, with
    a cold best-axis cache each time. Cooking hulls needs scipy (qhull), so this
    table is opt-in (``--hulls``).
    """
    import trimesh

    from rbgen.shapes import ConvexHull

    rng = np.random.default_rng(1)
    makers = [("random 16 points", lambda k: ConvexHull(rng.normal(size=(16, 3)), name=f"h{k}"), 4000),
              ("icosphere(1)", lambda k: ConvexHull.from_trimesh(trimesh.creation.icosphere(1)), 500),
              ("icosphere(2)", lambda k: ConvexHull.from_trimesh(trimesh.creation.icosphere(2)), 100)]
    q = runtime.queue
    print(f"{'hulls':>18} {'V':>4} {'E':>4} {'dirs':>4} {'pairs':>6} {'touch':>6} "
          f"{'directions ms':>14} {'gauss_map ms':>13}")
    for label, make, n in makers:
        table = ShapeTable()
        ids = [table.add(make(k)) for k in range(3)]
        shapes = rng.choice(ids, 2 * n)
        pa = rng.uniform(-50, 50, (n, 3))
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        pb = pa + d * rng.uniform(1.0, 2.2, (n, 1))
        bodies = layouts.BODY.zeros(2 * n)
        bodies["shape"] = shapes
        bodies["position"][:, :3] = np.stack([pa, pb], axis=1).reshape(-1, 3)
        quats = rng.normal(size=(2 * n, 4))
        bodies["orientation"] = quats / np.linalg.norm(quats, axis=1, keepdims=True)
        pairs = layouts.PAIR.zeros(n)
        pairs["a"], pairs["b"] = np.arange(0, 2 * n, 2), np.arange(1, 2 * n, 2)
        packed = table.pack_all().to_device(q)
        args = (cla.to_device(q, bodies), packed, cla.to_device(q, pairs),
                cla.to_device(q, np.array([n], np.uint32)),
                cla.empty(q, n, layouts.CONTACT_MANIFOLD.dtype), cla.zeros(q, 1, np.uint32),
                cla.zeros(q, 1, np.uint32), 0.0)
        times = {}
        for edge_axes in ("directions", "gauss_map"):
            narrowphase = Narrowphase(runtime, table, edge_axes={"hull_hull": edge_axes})
            narrowphase.enqueue(*args)
            samples = []
            for _ in range(repeat):
                cl.enqueue_fill_buffer(q, narrowphase.sat_cache.data, np.uint32(0), 0,
                                       narrowphase.sat_cache.nbytes)
                events = narrowphase.enqueue(*args)
                q.finish()
                samples.append(event_ms(events["sat_hull_hull"]))
            times[edge_axes] = float(np.median(samples))
        c = table.shapes[ids[0]].cooked()
        print(f"{label:>18} {len(c.vertices):>4} {len(c.edges):>4} {len(c.edge_directions):>4} "
              f"{n:>6} {int(args[5].get()[0]):>6} {times['directions']:>14.2f} "
              f"{times['gauss_map']:>13.2f}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="device choice for rbgen.Runtime")
    parser.add_argument("--sizes", type=int, nargs="+", default=[27_000, 111_375])
    parser.add_argument("--ground", choices=("box", "plane"), default="box")
    parser.add_argument("--clip", nargs="+", choices=("fused", "separate"), default=["fused"],
                        help="fused: clip_incident_face reduces and stores (one launch); "
                             "separate: reduce_contacts does (two smaller kernels)")
    parser.add_argument("--routing", nargs="+", choices=("auto", "queues"), default=["auto"],
                        help="auto: box-only worlds skip classify_pairs; queues: always classify")
    parser.add_argument("--placement-tile", type=int, nargs="+", default=[None],
                        help="pairs per scatter_manifolds work group (default: per device)")
    parser.add_argument("--box-path", nargs="+", choices=("box_box", "box", "hull", "gauss"),
                        default=["box_box", "box", "hull", "gauss"],
                        help="box_box: closed-form 15-axis kernel; box: generic test, closed-form "
                             "box projection; hull: boxes as hulls; gauss: boxes as hulls with "
                             "Gauss-map edge pairs")
    parser.add_argument("--sink", type=float, default=0.01)
    parser.add_argument("--margin", type=float, default=0.0)
    parser.add_argument("--repeat", type=int, default=10)
    parser.add_argument("--hulls", action="store_true",
                        help="also compare hull-hull edge axes (needs scipy for hull cooking)")
    args = parser.parse_args(argv)
    runtime = Runtime(args.device, profiling=True)
    print(f"# {runtime.traits.describe()}")
    print(f"# BoxBox, ground={args.ground}, layers sunk by {args.sink} each, margin={args.margin}; "
          f"warm median of {args.repeat}; stage times are kernel times (ms)")
    rows = []
    for count in args.sizes:
        scene = build(count, args.ground, args.sink, args.margin)
        for box_path in args.box_path:
            for clip, tile, routing in itertools.product(args.clip, args.placement_tile,
                                                         args.routing):
                shapes = {"reduce_in_clip": clip == "fused", "placement_tile": tile,
                          "routing": routing}
                row = run(runtime, scene, count, args.ground, box_path, args.margin, args.repeat,
                          shapes)
                row["box_path"] = "/".join(str(v) for v in (box_path, clip, tile, routing) if v)
                rows.append(row)
    stage_names = list(dict.fromkeys(k for r in rows for k in r["stages"]))
    header = (f"{'boxes':>7} {'path':>26} {'pairs':>7} {'manif':>7} {'points':>7} {'total':>8} "
              f"{'launch':>6} " + " ".join(f"{s[:12]:>12}" for s in stage_names))
    print(header)
    for r in rows:
        print(f"{r['count']:>7} {r['box_path']:>26} {r['pairs']:>7} {r['manifolds']:>7} "
              f"{r['points']:>7} {r['total_ms']:>8.3f} {r['launches']:>6} "
              + " ".join(f"{r['stages'].get(s, float('nan')):>12.3f}" for s in stage_names))
    if args.hulls:
        hull_comparison(runtime, max(1, min(args.repeat, 3)))


if __name__ == "__main__":
    main()
