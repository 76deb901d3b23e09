"""BoxBox scene benchmark: the whole World step (broadphase to integration).

    python benchmarks/scenes.py [--device D] [--sizes 1000 8000 27000 111375]
                                [--steps 100] [--warmup 10] [--batching MODE]
                                [--solver pgs|jacobi] [--substeps S] [--iterations N]
                                [--position-iterations P] [--relaxation R]
                                [--release-sweeps N]

For each size, after ``--warmup`` steps: ms/step = the median over 10 blocks of
``--steps``/10 steps, all enqueued back to back and ended by one queue.finish(),
each block clocked by the host at its boundaries (rbgen.harness explains why that is
the device's time; ``mean``: all the timed steps' time over their number), kernel
launches and blocking reads per step, broadphase pairs, manifolds and contact points of the last
step, the
batches of the largest group, and a sanity line (NaNs, boxes sunk more than
2 cm below their resting height, boxes displaced more than 0.5 m sideways, max
speed). The rows are also written as JSON and Markdown (rbgen.bench's form, kind
"benchmarks/scenes.py"; no baseline) under ``--out`` (default
benchmarks/results; ``--out ''`` writes nothing).
"""

from __future__ import annotations

import argparse
import sys

from rbgen import bench
from rbgen.harness import run_scene
from rbgen.pipeline.batching import MODES as BATCHING_MODES
from rbgen.pipeline.solvers import SOLVERS


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="rbgen device choice (index or name)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 8000, 27000, 111375])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--warmup", type=int, default=10)
    parser.add_argument(
        "--scene",
        default="boxbox",
        choices=["boxbox", "box_pile", "pyramid"],
        help="pyramid: --sizes are its rows",
    )
    parser.add_argument(
        "--batching",
        default=None,
        choices=BATCHING_MODES,
        help="batching (default: the plan's: global on NVIDIA GPUs, cells on "
        "other GPUs, slabs on CPUs)",
    )
    parser.add_argument(
        "--solver",
        default="pgs",
        choices=SOLVERS,
        help="contact solver: pgs (batched Gauss-Seidel, the default) or jacobi "
        "(mass splitting, no batching)",
    )
    parser.add_argument(
        "--substeps", type=int, default=None, help="solver substeps (default: the World's)"
    )
    parser.add_argument(
        "--iterations", type=int, default=None, help="velocity sweeps (default: the World's)"
    )
    parser.add_argument(
        "--position-iterations",
        type=int,
        default=None,
        help="position sweeps (default: the World's)",
    )
    parser.add_argument(
        "--relaxation",
        type=float,
        default=None,
        help="successive over-relaxation of every row (default: the World's)",
    )
    parser.add_argument(
        "--normal-solve",
        default=None,
        choices=["block", "sequential"],
        help="a manifold's normal rows as one block or one by one (default: "
        "the plan's: block where lanes solve a batch, else one by one)",
    )
    parser.add_argument(
        "--release-sweeps",
        type=int,
        default=None,
        help="PGS with the block solve: the last N velocity (and position) "
        "sweeps may release points, the earlier ones take the block's "
        "all-pushing solution or the rows (default: the plan's; >= "
        "--iterations: every sweep)",
    )
    bench.add_out_argument(parser)
    args = parser.parse_args(argv)

    # only what was asked for: every other setting is the World's default (rbgen.settings)
    options = {
        name: value
        for name, value in (
            ("substeps", args.substeps),
            ("iterations", args.iterations),
            ("position_iterations", args.position_iterations),
            ("relaxation", args.relaxation),
        )
        if value is not None
    }
    options["solver"] = args.solver
    if args.normal_solve:
        options["normal_solve"] = args.normal_solve
    if args.release_sweeps is not None:
        options["plan"] = {"release_sweeps": args.release_sweeps}
    if args.batching:
        options["batching"] = args.batching
    rows = []
    for n in args.sizes:
        s = run_scene(
            args.scene,
            n,
            args.steps,
            device=args.device,
            progress=False,
            warmup=args.warmup,
            **options,
        )
        rows.append(s)
        if len(rows) == 1:
            print(
                f"device: {s['device']}; {args.scene}, {args.steps} steps after {args.warmup} "
                f"warm-up, dt 1/60, {s['substeps']} substeps of {s['iterations']} + "
                f"{s['position_iterations']} sweeps; plan: {s['plan']}"
            )
            print(
                f"{'boxes':>8} {'ms/step':>9} {'mean':>6} {'launch':>7} {'reads':>6} {'pairs':>9} "
                f"{'manifolds':>10} {'points':>9} {'batches':>8} {'batching':>10} | sanity"
            )
        print(
            f"{s['bodies']:>8,} {s['ms_per_step']:>9.2f} {s['ms_per_step_mean']:>6.2f} "
            f"{s['launches_per_step']:>7} "
            f"{s['blocking_reads_per_step']:>6} {s['pairs']:>9,} {s['manifolds']:>10,} "
            f"{s['contacts']:>9,} {s['batches']:>8} {s['batching'] or '-':>10} | NaN {s['nans']}, "
            f"sunk {s['sunk']}, displaced {s['displaced']}, "
            f"max speed {s['max_speed']:.3f} m/s, "
            f"top box moved {100 * s['last_box_moved']:.1f} cm, "
            f"redone steps {s['overflows']}",
            flush=True,
        )
    if args.out:
        settings = {
            "scene": args.scene,
            "steps": args.steps,
            "warmup": args.warmup,
            "dt": 1 / 60,
            "world_options": options,
        }
        record = bench.make_record(
            "benchmarks/scenes.py",
            [bench.scene_result(s, args.warmup) for s in rows],
            bench.device_record(args.device),
            settings,
        )
        print(f"wrote {bench.write_results(record, args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
