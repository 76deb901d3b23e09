"""Rendering cost: one frame of 1,000 bodies (and more) drawn by rbgen.render.

    python benchmarks/render.py [--bodies 1000 8000] [--size 640x360] [--frames 20]
                                [--out benchmarks/results]

For each body count, two scenes: the BoxBox lattice (boxes on a ground slab,
rbgen.scenes) and a heap of every shape kind on a ground plane (spheres,
boxes, capsules and hulls, random orientations). ms/frame = the median over
``--frames`` frames of `Renderer.render` (instance upload, shadow pass,
colour pass, read-back into numpy), after one frame that builds the meshes;
the spread is the lowest and highest frame. Baseline, measured in the same
run: the same frames without the shadow pass. Writes the results as JSON
(rbgen.bench's form) and a Markdown table under ``--out``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import numpy as np

from rbgen import bench
from rbgen.render import Bodies, Frame
from rbgen.render.renderer import Renderer, gl_context
from rbgen.scenes import boxbox_scene
from rbgen.shapes import Box, Capsule, ConvexHull, Plane, Sphere


def boxbox(n: int):
    side = max(1, round(n ** (1 / 3)))
    scene = boxbox_scene(side, side, side)
    count = len(scene.positions)
    bodies = Bodies.make(
        [Box(scene.ground_half_extents), Box(scene.half_extents)],
        np.r_[0, np.ones(count, int)],
        static=np.r_[True, np.zeros(count, bool)],
    )
    positions = np.vstack([scene.ground_position, scene.positions])
    q = np.tile([0.0, 0.0, 0.0, 1.0], (count + 1, 1))
    return bodies, Frame.make(positions, q, count + 1)


def heap(n: int):
    rng = np.random.default_rng(0)
    shapes = [
        Plane((0, 1, 0), 0.0),
        Sphere(0.5),
        Box((0.5, 0.4, 0.3)),
        Capsule(0.3, 0.4),
        ConvexHull(rng.normal(size=(20, 3)) * 0.5),
    ]
    index = np.r_[0, rng.integers(1, 5, n)]
    extent = 0.6 * n ** (1 / 3) + 2
    positions = np.c_[
        rng.uniform(-extent, extent, n + 1),
        rng.uniform(0.5, extent, n + 1),
        rng.uniform(-extent, extent, n + 1),
    ]
    positions[0] = 0
    q = rng.normal(size=(n + 1, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    q[0] = (0, 0, 0, 1)
    return Bodies.make(shapes, index, static=index == 0), Frame.make(positions, q, n + 1)


def time_frames(renderer: Renderer, bodies, frame, frames: int) -> list[float]:
    renderer.render(bodies, frame)  # meshes and buffers made
    samples = []
    for _ in range(frames):
        start = time.perf_counter()
        renderer.render(bodies, frame)
        samples.append(1e3 * (time.perf_counter() - start))
    return samples


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bodies", type=int, nargs="+", default=[1000, 8000])
    parser.add_argument("--size", default="640x360")
    parser.add_argument("--frames", type=int, default=20)
    bench.add_out_argument(parser)
    args = parser.parse_args(argv)
    width, height = (int(v) for v in args.size.split("x"))
    gl = gl_context().info
    print(
        f"OpenGL: {gl['GL_RENDERER']} ({gl['GL_VERSION']}), {os.cpu_count()} CPUs, "
        f"{width}x{height}, median of {args.frames} frames; baseline: no shadow pass"
    )
    shaded, flat = Renderer(width, height), Renderer(width, height, shadows=False)
    results = []
    for n in args.bodies:
        for name, make in (("boxbox", boxbox), ("heap of every kind", heap)):
            bodies, frame = make(n)
            ours = time_frames(shaded, bodies, frame, args.frames)
            base = time_frames(flat, bodies, frame, args.frames)
            result = {
                "name": f"{name} {bodies.count - 1}",
                "bodies": bodies.count - 1,
                "ms": statistics.median(ours),
                "ms_spread": [min(ours), max(ours)],
                "baseline": {
                    "name": "no shadow pass",
                    "ms": statistics.median(base),
                    "ms_spread": [min(base), max(base)],
                },
            }
            results.append(result)
            print(
                f"{result['name']:>28}: {result['ms']:7.1f} ms/frame "
                f"({min(ours):.1f}-{max(ours):.1f}); no shadow pass "
                f"{result['baseline']['ms']:.1f}",
                flush=True,
            )
    record = bench.make_record(
        "benchmarks/render.py",
        results,
        None,
        {
            "size": [width, height],
            "frames": args.frames,
            "gl_renderer": gl["GL_RENDERER"],
            "gl_version": gl["GL_VERSION"],
            "samples": shaded._msaa.color_attachments[0].samples,
            "llvmpipe_threads": os.environ.get("LP_NUM_THREADS"),
        },
    )
    if args.out:
        print(f"wrote {bench.write_results(record, args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
