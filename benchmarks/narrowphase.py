"""Narrowphase benchmark: contacts of the BoxBox scene's candidate pairs, beside a baseline.

    python benchmarks/narrowphase.py [--device D] [--sizes 27000 111375]
                                     [--ground box|plane] [--placement-tile 256 1024]
                                     [--hulls]

Scene: rbgen.scenes.boxbox_scene (cubes of half extent 1 on a ground whose top
is y = 0). A fresh scene only touches exactly (separation 0), so every layer
j is lowered by ``sink * (j + 1)`` (default 0.01): each resting contact then
penetrates by ``sink``. Candidate pairs come from a numpy uniform grid on the
host (AABBs grown by the margin), the ground being body 0 paired with the
bottom layer.

Two worlds of that geometry run in the same process: "boxes", the production
path (box pairs through the closed-form 15-axis separating-axis kernel), and
the baseline "hulls", the same boxes (and box ground) cooked as ConvexHulls
(the generic separating-axis test: vertex projection, Gauss-map edge pairs).
Each runs once cold (empty best-axis cache), then ``--repeat`` times warm; we
report the warm median of the total enqueue-to-finish wall time and of each
stage's kernel time (OpenCL events), the launch count, the contact counts and
the speed-up over the baseline. ``--hulls`` adds the hull-hull
separating-axis stage on hulls of growing size, beside box-shaped hulls (8
vertices) as the baseline.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from rbgen import Runtime, layouts
from rbgen.pipeline.narrowphase import Narrowphase
from rbgen.scenes import standard_boxbox_scene
from rbgen.shapes import Box, ConvexHull, Plane, ShapeTable

#: the production path and the baseline it is compared with
PATHS = ("boxes", "hulls")


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
                keep = (
                    (i < j)
                    & np.all(lower[i] <= upper[j], axis=1)
                    & np.all(lower[j] <= upper[i], axis=1)
                )
                found.append(np.column_stack([i[keep], j[keep]]))
    pairs = np.unique(np.concatenate(found), axis=0)
    return pairs


def cuboid(half_extents, path: str):
    """A Box, or for the "hulls" baseline the ConvexHull of its corners."""
    box = Box(half_extents)
    return box if path == "boxes" else ConvexHull(box.local_vertices(), name="box as hull")


def build(count: int, ground: str, sink: float, margin: float, path: str):
    scene = standard_boxbox_scene(count)
    positions = scene.positions.astype(np.float64).copy()
    layer = np.rint((positions[:, 1] - 1.0) / 2.0)
    positions[:, 1] -= sink * (layer + 1)
    table = ShapeTable()
    cube = table.add(cuboid(scene.half_extents, path))
    if ground == "plane":
        floor = table.add(Plane(scene.ground_normal, scene.ground_offset))
        ground_position = np.zeros(3)
    else:
        floor = table.add(cuboid(scene.ground_half_extents, path))
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


def run(runtime: Runtime, scene, repeat: int, margin: float, placement_tile=None) -> dict:
    table, bodies, pairs = scene
    q = runtime.queue
    narrowphase = Narrowphase(runtime, table, placement_tile=placement_tile)
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
        "pairs": len(pairs),
        "manifolds": len(result),
        "points": int(result["point_count"].sum()),
        "total_ms": 1e3 * float(np.median(walls)),
        "launches": launches,
        "stages": {k: float(np.median([s[k] for s in stages])) for k in stages[0]},
    }


def hull_sizes(runtime: Runtime, repeat: int) -> None:
    """Hull-hull separating-axis stage time by hull size, box-shaped hulls first (baseline).

    Random pairs of three hulls of one kind, about three quarters touching, with
    a cold best-axis cache each time.
    """
    import trimesh

    rng = np.random.default_rng(1)

    def icosphere(subdivisions):
        return lambda k: ConvexHull.from_trimesh(trimesh.creation.icosphere(subdivisions))

    makers = [
        ("box as hull (baseline)", lambda k: cuboid(rng.uniform(0.4, 0.8, 3), "hulls"), 4000),
        ("random 16 points", lambda k: ConvexHull(rng.normal(size=(16, 3))), 4000),
        ("icosphere(1)", icosphere(1), 500),
        ("icosphere(2)", icosphere(2), 100),
    ]
    q = runtime.queue
    print(
        f"{'hulls':>24} {'V':>4} {'E':>4} {'pairs':>6} {'touch':>6} {'sat ms':>8} "
        f"{'us/pair':>8} {'x baseline':>10}"
    )
    baseline = None
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
        args = (
            cla.to_device(q, bodies),
            packed,
            cla.to_device(q, pairs),
            cla.to_device(q, np.array([n], np.uint32)),
            cla.empty(q, n, layouts.CONTACT_MANIFOLD.dtype),
            cla.zeros(q, 1, np.uint32),
            cla.zeros(q, 1, np.uint32),
            0.0,
        )
        narrowphase = Narrowphase(runtime, table)
        narrowphase.enqueue(*args)
        samples = []
        for _ in range(repeat):
            cl.enqueue_fill_buffer(
                q, narrowphase.sat_cache.data, np.uint32(0), 0, narrowphase.sat_cache.nbytes
            )
            events = narrowphase.enqueue(*args)
            q.finish()
            samples.append(event_ms(events["sat_hull_hull"]))
        per_pair = 1e3 * float(np.median(samples)) / n
        baseline = baseline or per_pair
        c = table.shapes[ids[0]].cooked()
        print(
            f"{label:>24} {len(c.vertices):>4} {len(c.edges):>4} {n:>6} "
            f"{int(args[5].get()[0]):>6} {float(np.median(samples)):>8.2f} {per_pair:>8.3f} "
            f"{per_pair / baseline:>10.2f}"
        )


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="device choice for rbgen.Runtime")
    parser.add_argument("--sizes", type=int, nargs="+", default=[27_000, 111_375])
    parser.add_argument("--ground", choices=("box", "plane"), default="box")
    parser.add_argument(
        "--placement-tile",
        type=int,
        nargs="+",
        default=[None],
        help="pairs per scatter_manifolds work group (default: per device)",
    )
    parser.add_argument("--sink", type=float, default=0.01)
    parser.add_argument("--margin", type=float, default=0.0)
    parser.add_argument("--repeat", type=int, default=10)
    parser.add_argument(
        "--hulls", action="store_true", help="also time the hull-hull test by hull size"
    )
    args = parser.parse_args(argv)
    runtime = Runtime(args.device, profiling=True)
    print(f"# {runtime.traits.describe()}")
    print(
        f"# BoxBox, ground={args.ground}, layers sunk by {args.sink} each, margin={args.margin}; "
        f"warm median of {args.repeat}; stage times are kernel times (ms); baseline: the same "
        f"boxes as ConvexHulls (generic separating-axis test)"
    )
    rows = []
    for count in args.sizes:
        for tile in args.placement_tile:
            measured = {
                path: run(
                    runtime,
                    build(count, args.ground, args.sink, args.margin, path),
                    args.repeat,
                    args.margin,
                    tile,
                )
                for path in PATHS
            }
            for path in PATHS:
                row = measured[path]
                row["path"] = path if tile is None else f"{path}/{tile}"
                row["count"] = count
                row["speedup"] = measured["hulls"]["total_ms"] / row["total_ms"]
                rows.append(row)
    stage_names = list(dict.fromkeys(k for r in rows for k in r["stages"]))
    header = (
        f"{'boxes':>7} {'path':>12} {'pairs':>7} {'manif':>7} {'points':>7} {'total':>8} "
        f"{'vs hulls':>8} {'launch':>6} " + " ".join(f"{s[:14]:>14}" for s in stage_names)
    )
    print(header)
    for r in rows:
        print(
            f"{r['count']:>7} {r['path']:>12} {r['pairs']:>7} {r['manifolds']:>7} "
            f"{r['points']:>7} {r['total_ms']:>8.3f} {r['speedup']:>7.2f}x {r['launches']:>6} "
            + " ".join(f"{r['stages'].get(s, float('nan')):>14.3f}" for s in stage_names)
        )
    if args.hulls:
        hull_sizes(runtime, max(1, min(args.repeat, 3)))


if __name__ == "__main__":
    main()
