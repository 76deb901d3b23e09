"""End states of a few scenes after a fixed number of steps, to compare two versions of rbgen.

    python benchmarks/end_states.py record OUT.npz [--device D] [--quick] [--options JSON]
    python benchmarks/end_states.py compare A.npz B.npz

``record`` runs each scene with the World's defaults through the public API only (so the
same script runs on any version) and saves every body's position, orientation and
velocities; ``compare`` prints, per scene, whether the two files are equal bit for bit and
the largest difference otherwise. A refactoring that was not meant to change the physics
must compare equal on the same device.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import rbgen
from rbgen import bench, scenes


def _boxbox(world, n):
    scene = scenes.standard_boxbox_scene(n)
    world.add_static(rbgen.Box(scene.ground_half_extents), position=scene.ground_position)
    world.add_bodies(rbgen.Box(scene.half_extents), mass=scene.mass, positions=scene.positions)


def _pile(world, n):
    side = int(np.ceil(np.sqrt(n / 5)))
    i, j, k = np.meshgrid(np.arange(side), np.arange(5), np.arange(side), indexing="ij")
    p = np.stack([1.5 * i, 1.0 + 1.5 * j, 1.5 * k], -1).reshape(-1, 3)[:n]
    p = p + np.random.default_rng(0).uniform(-0.01, 0.01, p.shape)
    world.add_static(
        rbgen.Box((1.5 * side / 2 + 10, 1, 1.5 * side / 2 + 10)),
        position=(1.5 * (side - 1) / 2, -1, 1.5 * (side - 1) / 2),
    )
    world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, positions=p)


def _pyramid(world, rows):
    p = np.array(
        [
            [(i - (rows - r - 1) / 2) * 1.02, 0.5 + r, 0.0]
            for r in range(rows)
            for i in range(rows - r)
        ]
    )
    world.add_static(rbgen.Box((rows + 10, 1, 10)), position=(0, -1, 0))
    world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, positions=p)


def _mixed(world, n):
    """Spheres, capsules, boxes and hulls dropped on a plane and a box."""
    rng = np.random.default_rng(7)
    world.add_static(rbgen.Plane((0, 1, 0), 0.0))
    world.add_static(rbgen.Box((2, 0.5, 2)), position=(0, 0.5, 0))
    hull = rbgen.ConvexHull(rng.normal(size=(12, 3)) * 0.4)
    shapes = [rbgen.Sphere(0.3), rbgen.Capsule(0.2, 0.3), rbgen.Box((0.3, 0.2, 0.4)), hull]
    side = int(np.ceil(np.sqrt(n / 4)))
    for k, shape in enumerate(shapes):
        i, j = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
        p = np.stack([1.1 * i - side / 2, 2.0 + 1.2 * k + 0 * i, 1.1 * j - side / 2], -1)
        p = p.reshape(-1, 3)[: n // 4] + rng.uniform(-0.05, 0.05, (n // 4, 3))
        q = rng.normal(size=(len(p), 4))
        world.add_bodies(
            shape, mass=1.0 + k, positions=p, orientations=q / np.linalg.norm(q, axis=1)[:, None]
        )


#: name -> (builder, size, steps, World options)
SCENES = {
    "boxbox_1000": (_boxbox, 1000, 120, {}),
    "boxbox_8000": (_boxbox, 8000, 60, {}),
    "pile_1000": (_pile, 1000, 150, {}),
    "pyramid_12": (_pyramid, 12, 200, {}),
    "mixed_400": (_mixed, 400, 150, {}),
    "mixed_400_sap": (_mixed, 400, 100, {"broadphase": "sap"}),
    "boxbox_1000_jacobi": (_boxbox, 1000, 60, {"solver": "jacobi"}),
    "pyramid_12_cells": (_pyramid, 12, 100, {"batching": "cells"}),
}
QUICK = ("boxbox_1000", "pile_1000", "pyramid_12", "mixed_400")


def record(path: str, device=None, quick: bool = False, extra: dict | None = None) -> None:
    """Run the scenes (``extra``: World options added to every scene's) and save their
    end states."""
    out = {}
    for name, (build, n, steps, options) in SCENES.items():
        if quick and name not in QUICK:
            continue
        world = rbgen.World(device, **options, **(extra or {}))
        build(world, n)
        for _ in range(steps):
            world.step(1 / 60)
        for field in ("positions", "orientations", "linear_velocities", "angular_velocities"):
            out[f"{name}/{field}"] = getattr(world, field)
        print(f"{name}: {world.body_count} bodies, {steps} steps", flush=True)
    np.savez(path, **out)


def compare(a: str, b: str) -> int:
    fa, fb = np.load(a), np.load(b)
    names = sorted({k.split("/")[0] for k in fa.files} & {k.split("/")[0] for k in fb.files})
    differ = 0
    for name in names:
        worst = 0.0
        same = True
        for field in ("positions", "orientations", "linear_velocities", "angular_velocities"):
            x, y = fa[f"{name}/{field}"], fb[f"{name}/{field}"]
            if x.shape != y.shape or x.tobytes() != y.tobytes():
                same = False
                worst = max(worst, float(np.abs(x - y).max()) if x.shape == y.shape else np.inf)
        differ += not same
        print(f"{name:22s} {'bit for bit' if same else f'DIFFERS (max |diff| {worst:.3g})'}")
    return 1 if differ else 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("record")
    p.add_argument("out")
    p.add_argument("--device", default=None)
    p.add_argument("--quick", action="store_true")
    p.add_argument(
        "--options",
        type=bench.world_options,
        default={},
        help="World options (JSON) for every scene",
    )
    p = sub.add_parser("compare")
    p.add_argument("a")
    p.add_argument("b")
    args = parser.parse_args(argv)
    if args.command == "record":
        record(args.out, args.device, args.quick, args.options)
        return 0
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
