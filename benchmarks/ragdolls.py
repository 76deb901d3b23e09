"""Ragdolls on a pile of boxes: ms/step against the ragdoll count, and what joints cost.

    python benchmarks/ragdolls.py [--device D] [--n 10 30 100] [--steps 120] [--warmup 60]
                                  [--options JSON] [--out DIR]

For each N, the ragdolls scene (`rbgen.harness`: N ragdolls of 11 bodies and 10
joints dropped 1.4 m onto unit boxes, 4 substeps of 5 + 2 sweeps) is timed after
``--warmup`` steps (the fall; the pile forms while timed), and so is its baseline,
measured in the same run: the same bodies without their joints
(``ragdoll_joints=False``: the parts fall apart; its time is the contacts' alone). Each
result carries ms/step (median of 10 blocks), launches and blocking reads per step, the
scene's sanity, and ``joint_cost`` (ms with joints over ms without). Targets (issue 26):
PoCL, 2 cores, 100 ragdolls <= 10 ms/step; H200, 10,000 ragdolls <= 4 ms/step. JSON
(rbgen.bench's format, kind "ragdolls") under --out.
"""

from __future__ import annotations

import argparse
import sys

from rbgen import bench
from rbgen.harness import run_scene

TARGETS = {"cpu": (100, 10.0), "gpu": (10_000, 4.0)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None)
    parser.add_argument("--n", type=int, nargs="+", default=[10, 30, 100])
    parser.add_argument("--steps", type=int, default=120)
    parser.add_argument("--warmup", type=int, default=60)
    parser.add_argument(
        "--options", type=bench.world_options, default={}, help="World options as JSON"
    )
    bench.add_out_argument(parser)
    args = parser.parse_args(argv)
    options = args.options
    device = bench.device_record(args.device)
    results = []
    for n in args.n:
        pair = {}
        for joints in (False, True):
            summary = run_scene(
                "ragdolls",
                n,
                args.steps,
                device=args.device,
                progress=False,
                warmup=args.warmup,
                ragdoll_joints=joints,
                **options,
            )
            result = bench.scene_result(summary, args.warmup)
            result["name"] = f"ragdolls {n}" + ("" if joints else " (no joints)")
            result["ragdolls"] = n
            result["joints"] = 10 * n if joints else 0
            pair[joints] = result
        with_joints, baseline = pair[True], pair[False]
        with_joints["baseline"] = baseline["name"]
        with_joints["joint_cost"] = with_joints["ms"] / max(baseline["ms"], 1e-9)
        results += [baseline, with_joints]
        print(bench.format_result(baseline), flush=True)
        print(
            f"{bench.format_result(with_joints)}; joints cost x{with_joints['joint_cost']:.2f}",
            flush=True,
        )
    target_n, target_ms = TARGETS["gpu" if device["type"] == "gpu" else "cpu"]
    for r in results:
        if r["joints"] and r["ragdolls"] == target_n:
            verdict = "meets" if r["ms"] <= target_ms else "MISSES"
            print(f"target {target_n} ragdolls <= {target_ms} ms/step: {r['ms']:.2f}: {verdict}")
    record = bench.make_record(
        "ragdolls",
        results,
        device,
        {"steps": args.steps, "warmup": args.warmup, "world_options": options, "dt": 1 / 60},
    )
    if args.out:
        print("wrote", bench.write_results(record, args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
