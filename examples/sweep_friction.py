"""A friction sweep on Dask: how far a box slides, against the closed form d = v0^2 / (2 mu g).

    python examples/sweep_friction.py [--workers 2] [--v0 3] [--scheduler ADDRESS]

One World per friction coefficient mu (the box's and the ground's: the contact's is
sqrt(mu_a mu_b) = mu), each a Dask task (rbgen.sweep; without --scheduler a LocalCluster
of --workers processes, each pinned to a device). A unit box launched at v0 along x
slides until friction stops it after d = v0^2 / (2 mu g); with steps of dt (velocity
first, then position) it stops after d - v0 dt / 2 (when v0 / (mu g dt) is whole; a
part-step more otherwise). The table compares both; exits 1 if a run is more than 1 %
from the stepped form.
"""

from __future__ import annotations

import argparse
import math
import sys

import rbgen

DT = 1 / 60
G = 9.81


def sliding_box(friction, v0):
    """A unit box resting on the ground, launched along x at v0."""
    world = rbgen.World()
    world.add_static(rbgen.Plane((0, 1, 0), 0.0), friction=friction)
    world.add_body(
        rbgen.Box((0.5, 0.5, 0.5)),
        position=(0.0, 0.5, 0.0),
        linear_velocity=(v0, 0.0, 0.0),
        friction=friction,
    )
    return world


def slid(world) -> dict:
    """The measurement: distance slid and the speed left."""
    return {
        "distance": float(world.positions[1][0]),
        "speed": float(abs(world.linear_velocities[1][0])),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frictions", default="0.1,0.2,0.3,0.5,0.8")
    parser.add_argument("--v0", type=float, default=3.0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--scheduler", default=None, help="a Dask scheduler's address")
    args = parser.parse_args(argv)
    frictions = [float(f) for f in args.frictions.split(",")]
    # long enough for the slowest to stop (t = v0 / (mu g)), plus a second at rest
    steps = math.ceil(args.v0 / (min(frictions) * G) / DT) + 60
    client = None
    if args.scheduler:
        import distributed

        client = distributed.Client(args.scheduler)
    table = rbgen.sweep(
        sliding_box,
        [{"friction": mu, "v0": args.v0} for mu in frictions],
        steps,
        client=client,
        workers=args.workers,
        measure=slid,
    )
    print(f"{'mu':>5} {'slid (m)':>9} {'v0^2/(2 mu g)':>14} {'- v0 dt/2':>10} {'error':>7}  device")
    worst = 0.0
    for row in table:
        mu = row["params"]["friction"]
        if not row["ok"]:
            print(f"{mu:5.2f} FAILED: {row['error'].splitlines()[0]}")
            worst = math.inf
            continue
        closed = args.v0**2 / (2 * mu * G)
        stepped = closed - args.v0 * DT / 2
        error = row["distance"] / stepped - 1
        worst = max(worst, abs(error))
        print(
            f"{mu:5.2f} {row['distance']:9.4f} {closed:14.4f} {stepped:10.4f} "
            f"{100 * error:6.2f}%  {row['device']}"
        )
    return 0 if worst <= 0.01 else 1


if __name__ == "__main__":
    sys.exit(main())
