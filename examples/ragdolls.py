"""Ragdolls (11 bodies, 10 joints each) dropped on a pile of boxes: the ragdolls scene.

python examples/ragdolls.py [--n 100] [--steps 600] [--device D]

Prints ms/step and the sanity summary (a pile at rest has a max speed near 0).
"""

from __future__ import annotations

import argparse
import sys

from rbgen.harness import run_scene


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100)
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    summary = run_scene("ragdolls", args.n, args.steps, device=args.device, progress=True)
    return 0 if summary["nans"] == 0 and summary["sunk"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
