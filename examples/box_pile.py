"""Boxes dropped in a loose grid onto the ground; prints progress and a summary.

python examples/box_pile.py [--n 8000] [--steps 300] [--device D]
"""

from __future__ import annotations

import argparse
import sys

from rbgen.harness import run_scene


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=8000)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    summary = run_scene("box_pile", args.n, args.steps, device=args.device, progress=True)
    return 0 if summary["nans"] == 0 and summary["sunk"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
