"""Make the README's pictures with rbgen itself.

    python docs/images/make_pictures.py [--device D] [--steps 300]

box_pile_8000.png: the 8,000-box pile (rbgen.harness's box_pile) after ``--steps``
steps of 1/60 s, settled; boxbox.png: the 8,000-box BoxBox lattice at its start.
Both 960x540 with 4 samples a pixel, reduced to 256 colours when a full-colour
PNG would pass 300 KB.
"""
from __future__ import annotations

import argparse
import os
import sys

from rbgen.harness import build_scene
from rbgen.render import Camera, render_world

HERE = os.path.dirname(os.path.abspath(__file__))
LIMIT = 300_000


def shrink(path: str) -> None:
    """Reduce ``path`` to 256 colours if it is larger than `LIMIT` bytes."""
    from PIL import Image

    if os.path.getsize(path) <= LIMIT:
        return
    with Image.open(path) as image:
        small = image.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT,
                                              dither=Image.Dither.NONE)
    small.save(path, optimize=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None)
    parser.add_argument("--steps", type=int, default=300)
    args = parser.parse_args(argv)

    world, _, _, _ = build_scene("box_pile", 8000, args.device)
    for _ in range(args.steps):
        world.step(1 / 60)
    path = os.path.join(HERE, "box_pile_8000.png")
    render_world(world, path, camera=Camera(eye=(88.0, 42.0, 98.0), target=(29.0, 1.0, 29.0),
                                            fov=35.0))
    shrink(path)
    print(f"wrote {path} ({os.path.getsize(path):,} bytes) after {args.steps} steps")

    world, _, _, _ = build_scene("boxbox", 8000, args.device)
    path = os.path.join(HERE, "boxbox.png")
    render_world(world, path, camera=Camera(eye=(82.0, 70.0, 96.0), target=(21.0, 17.0, 21.0),
                                            fov=35.0))
    shrink(path)
    print(f"wrote {path} ({os.path.getsize(path):,} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
