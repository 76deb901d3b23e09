"""A hanging chain: N capsule links on ball joints, hung from the world and let go 30
degrees from the vertical; prints how far the chain's joints are apart (its stretch).

python examples/chain.py [--n 100] [--steps 300] [--substeps 8] [--device D]

The joint guidance (README, Joints): a chain of light links needs 4 substeps, 8 to hold
its length within 1% as it swings.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import rbgen

LINK = 0.1  # m between joints; a link is a capsule 8 cm long, 2 cm apart from the next
TOP = 12.0  # m: the height the chain hangs from


def build(n: int, substeps: int, device=None):
    """(world, link ids, joint ids): the chain straight, 30 degrees from the vertical,
    hung from (0, TOP, 0)."""
    world = rbgen.World(device, substeps=substeps)
    tilt = np.radians(30)
    down = np.array([np.sin(tilt), -np.cos(tilt), 0.0])
    centres = np.array([[0.0, TOP, 0.0] + (i + 0.5) * LINK * down for i in range(n)])
    turn = [0.0, 0.0, np.sin(tilt / 2), np.cos(tilt / 2)]  # capsules along y, tilted
    ids = world.add_bodies(
        rbgen.Capsule(0.02, 0.02), mass=1.0, positions=centres, orientations=np.tile(turn, (n, 1))
    )
    joints = world.add_joints(
        rbgen.BallJoint,
        a=ids,
        b=[None] + [int(i) for i in ids[:-1]],
        anchor=centres - LINK / 2 * down,
    )
    return world, ids, joints


def stretch(world, ids) -> float:
    """The chain's length along its link centres over its length at rest, minus 1."""
    points = np.vstack([[0.0, TOP, 0.0], world.positions[ids].astype(float)])
    length = np.linalg.norm(np.diff(points, axis=0), axis=1).sum()
    return length / (LINK * (len(ids) - 0.5)) - 1.0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--substeps", type=int, default=8)
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    world, ids, _ = build(args.n, args.substeps, args.device)
    worst = 0.0
    for step in range(args.steps):
        world.step(1 / 60)
        if step % 30 == 29:
            now = stretch(world, ids)
            worst = max(worst, abs(now))
            tip = world.positions[ids[-1]]
            print(f"step {step + 1:4d}: stretch {100 * now:+.3f}%, tip at {np.round(tip, 2)}")
    print(f"largest stretch {100 * worst:.3f}% ({args.n} links, {args.substeps} substeps)")
    return 0 if worst < 0.01 else 1


if __name__ == "__main__":
    sys.exit(main())
