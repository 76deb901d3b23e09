"""A rain of boxes, rocks, tables, dumbbells, spheres and capsules onto a procedural
terrain of 2,000,000 triangles; prints progress and a summary.

    python examples/terrain.py [--n 2000] [--steps 600] [--cells 1000] [--device D]
                               [--picture terrain.png]

The terrain is a static `rbgen.TriangleMesh` (its BVH built once, on the host, when it is
made); the tables and dumbbells are `rbgen.Compound`s. ``--cells`` sets the height field's
size (2 x cells^2 triangles). ``--picture`` writes a PNG of the end.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from rbgen import scenes
from rbgen.harness import build_scene


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=2000)
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--cells", type=int, default=scenes.TERRAIN_CELLS)
    parser.add_argument("--device", default=None)
    parser.add_argument("--picture", default=None)
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    world, ids, _, _ = build_scene("terrain", args.n, args.device, terrain_cells=args.cells)
    mesh = world._bodies.shapes.shapes[0]
    print(
        f"terrain of {mesh.triangle_count:,} triangles and {len(ids):,} bodies built in "
        f"{time.perf_counter() - t0:.1f} s on {world.runtime.traits.describe()}",
        flush=True,
    )
    t0 = time.perf_counter()
    for step in range(1, args.steps + 1):
        world.step(1 / 60)
        if step % 60 == 0:
            speeds = np.linalg.norm(world.linear_velocities[ids], axis=1)
            print(
                f"  {step / 60:4.1f} s: max speed {speeds.max():6.3f} m/s, median "
                f"{np.median(speeds):.4f} m/s, {1e3 * (time.perf_counter() - t0) / step:7.2f} "
                f"ms/step so far",
                flush=True,
            )
    stats = world.statistics()
    positions = world.positions[ids]
    print(
        f"{stats['pairs']:,} pairs, {stats['manifolds']:,} manifolds, {stats['contacts']:,} "
        f"contact points; redone steps {world.overflows}; NaN "
        f"{int(np.isnan(positions).any(axis=1).sum())}"
    )
    if args.picture:
        print(f"wrote {world.render(args.picture)}")
    return 0 if np.all(np.isfinite(positions)) else 1


if __name__ == "__main__":
    sys.exit(main())
