"""A 2-D pyramid of unit boxes (N rows) standing on the ground; prints how far the top box moved.

python examples/pyramid.py [--n 20] [--steps 600] [--device D]
"""

from __future__ import annotations

import argparse
import sys

from rbgen.harness import run_scene


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=20)
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    summary = run_scene("pyramid", args.n, args.steps, device=args.device, progress=True)
    return 0 if summary["nans"] == 0 and summary["sunk"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
