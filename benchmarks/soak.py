"""Soak: a churned scene stepped for a long time; memory, step time and determinism.

    python benchmarks/soak.py [--steps 100000] [--bodies 400] [--churn-every 10]
                              [--churn 8] [--runs 2] [--device D]

Runs the scene of `rbgen.soak` ``--runs`` times from the same seed and prints a table
(steps; bodies, this process's resident memory, the World's device bytes and the median
step time after the warm-up and at the end; the final state's digest), then whether the
runs ended bit for bit equal and whether memory held: the device bytes may not grow
after the warm-up, resident memory by at most ``--rss-slack`` MiB. Exit status 1 when a
check fails.
"""

from __future__ import annotations

import argparse
import sys

import rbgen
from rbgen.soak import run_soak, table


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--bodies", type=int, default=400)
    parser.add_argument("--churn-every", type=int, default=10)
    parser.add_argument("--churn", type=int, default=8)
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--rss-slack",
        type=float,
        default=32.0,
        help="MiB resident memory may grow after the warm-up",
    )
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    runtime = rbgen.Runtime(args.device)
    print(f"device: {runtime.traits.describe()}", flush=True)
    results = []
    for run in range(args.runs):
        results.append(
            run_soak(
                runtime,
                args.steps,
                bodies=args.bodies,
                churn_every=args.churn_every,
                churn=args.churn,
                seed=args.seed,
                progress=True,
            )
        )
        print(f"run {run + 1} done", flush=True)
    print(table(results))
    same = len({r.digest for r in results}) == 1
    device_held = all(r.device_end <= r.device_start for r in results)
    rss_held = all(r.rss_end - r.rss_start <= args.rss_slack * 2**20 for r in results)
    print(
        f"runs bit for bit equal: {same}; device bytes held: {device_held}; "
        f"resident memory within {args.rss_slack:g} MiB: {rss_held}"
    )
    return 0 if same and device_held and rss_held else 1


if __name__ == "__main__":
    sys.exit(main())
