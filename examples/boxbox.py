"""Bullet3's BoxBox lattice (1000, 8000, 27000 or 111375 boxes) settling on the ground.

python examples/boxbox.py [--n 8000] [--steps 200] [--device D]
"""

from __future__ import annotations

import argparse
import sys

from rbgen.harness import run_scene


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=8000)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    summary = run_scene("boxbox", args.n, args.steps, device=args.device, progress=True)
    return 0 if summary["nans"] == 0 and summary["sunk"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
