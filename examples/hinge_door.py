"""A motorised door: a plate on a vertical hinge, its motor turning it at 1 rad/s with at
most 200 N m, sweeps a row of boxes off a table-top; its limit (100 degrees) stops it.

python examples/hinge_door.py [--steps 300] [--device D]

Prints the door's angle and speed and how far the boxes were pushed.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import rbgen


def build(device=None):
    """(world, door id, box ids)."""
    world = rbgen.World(device, substeps=4)
    world.add_static(rbgen.Box((10, 1, 10)), position=(0, -1, 0))
    # the door: 2 m wide along +x from its hinge at the origin, 1 m tall, 10 cm thick
    door = world.add_body(rbgen.Box((1.0, 0.5, 0.05)), mass=20.0, position=(1.0, 0.55, 0.0))
    world.add_joint(
        rbgen.HingeJoint(
            door,
            None,
            anchor=(0.0, 0.55, 0.0),
            axis=(0.0, 1.0, 0.0),
            limits=(-np.radians(100), np.radians(100)),
            motor=(1.0, 200.0),
        )
    )
    boxes = world.add_bodies(
        rbgen.Box((0.15, 0.15, 0.15)),
        mass=2.0,
        positions=[[x, 0.15, -0.4] for x in (0.5, 0.9, 1.3, 1.7)],
    )
    return world, door, boxes


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    world, door, boxes = build(args.device)
    start = world.positions[boxes].copy()
    for step in range(args.steps):
        world.step(1 / 60)
        if step % 30 == 29:
            q = world.orientations[door].astype(float)
            angle = np.degrees(2 * np.arctan2(q[1], q[3]))
            speed = world.angular_velocities[door][1]
            print(f"step {step + 1:4d}: door at {angle:7.2f} deg, {speed:+.3f} rad/s")
    moved = np.linalg.norm(world.positions[boxes] - start, axis=1)
    print("boxes pushed (m):", np.round(moved, 2))
    return 0 if np.all(np.isfinite(world.positions)) else 1


if __name__ == "__main__":
    sys.exit(main())
