"""Boxes dropped in a loose grid onto the ground; prints progress and a summary.

    python examples/box_pile.py [--n 8000] [--steps 300] [--device D]
"""
from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from rbgen.demo import run_scene  # noqa: E402


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
