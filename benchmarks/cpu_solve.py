"""The CPU path's step time against a baseline tree, alternated in one run.

usage: PYTHONPATH=. python benchmarks/cpu_solve.py --baseline DIR [--device D] [--n 8000]
                                                    [--steps 10] [--rounds 3] [--scene boxbox]

DIR is a copy of another commit's ``rbgen`` (e.g. ``git archive BASE rbgen | tar -x -C
DIR``). Each round runs one process on the baseline, then one on this tree (the order
alternating from round to round), each building the scene with the default options,
stepping 5 steps to warm up and then ``--steps`` timed steps: wall ms/step (the steps
enqueued back to back, one ``queue.finish()`` at the end) and device ms/step per kernel
(OpenCL profiling events, medians over the steps), and the process's CPU time per step
(user + system, all threads: the work, less sensitive than wall time to other processes
on a shared machine). Both trees run the same steps, so
their end positions are compared too (``identical``: bit for bit). Prints a table and
writes the JSON to benchmarks/results/cpu_solve-<device>-<time>.json.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import pathlib
import subprocess
import sys

import numpy as np
from kernel_events import KernelEvents

HERE = pathlib.Path(__file__).resolve().parent


def _cpu_seconds() -> float:
    """CPU time of this process's threads so far (user + system): the work done, which
    other processes on a shared machine change less than wall time."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def worker(device, scene: str, n: int, steps: int, out: str) -> None:
    """One measurement in this process's rbgen (PYTHONPATH): JSON to ``out``."""
    import time

    from rbgen.device import Runtime
    from rbgen.harness import build_scene

    runtime = Runtime(device, profiling=True)
    world = build_scene(scene, n, runtime)[0]
    for _ in range(5):
        world.step(1 / 60)
    runtime.queue.finish()
    with KernelEvents() as launches:
        start, cpu_start = time.perf_counter(), _cpu_seconds()
        for step in range(steps):
            launches.step = step
            world.step(1 / 60)
        runtime.queue.finish()
        wall = (time.perf_counter() - start) / steps * 1e3
        cpu = (_cpu_seconds() - cpu_start) / steps * 1e3
    per_step = launches.per_step_ms(steps)
    result = {
        "device": runtime.traits.device_name,
        "wall_ms": wall,
        "cpu_ms": cpu,
        "kernel_ms": float(np.median(sum(per_step.values()))),
        "kernels": {name: float(np.median(ms)) for name, ms in per_step.items()},
        "launches": len(launches.events) / steps,
        "positions": np.asarray(world.positions, np.float32).tolist(),
    }
    pathlib.Path(out).write_text(json.dumps(result))


def measure(tree: str, device, scene: str, n: int, steps: int) -> dict:
    out = pathlib.Path(os.environ.get("TMPDIR", "/tmp")) / f"cpu_solve_{os.getpid()}.json"
    env = dict(os.environ, PYTHONPATH=tree)
    subprocess.run(
        [
            sys.executable,
            __file__,
            *(("--device", device) if device else ()),
            "--worker",
            str(out),
            "--scene",
            scene,
            "--n",
            str(n),
            "--steps",
            str(steps),
        ],
        env=env,
        cwd=tree,
        check=True,
        stderr=subprocess.DEVNULL,
    )
    result = json.loads(out.read_text())
    out.unlink()
    return result


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--baseline", help="a directory holding the baseline's rbgen")
    parser.add_argument(
        "--device", default=None, help="an OpenCL device choice (e.g. portable: PoCL)"
    )
    parser.add_argument("--scene", default="boxbox")
    parser.add_argument("--n", type=int, default=8000)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.device, args.scene, args.n, args.steps, args.worker)
        return
    if not args.baseline:
        parser.error("--baseline DIR is required")
    trees = {"baseline": str(pathlib.Path(args.baseline).resolve()), "current": str(HERE.parent)}
    runs: dict = {"baseline": [], "current": []}
    for r in range(args.rounds):
        order = ["baseline", "current"] if r % 2 == 0 else ["current", "baseline"]
        for name in order:
            runs[name].append(measure(trees[name], args.device, args.scene, args.n, args.steps))
            last = runs[name][-1]
            print(
                f"round {r}: {name:8s} wall {last['wall_ms']:7.2f} ms/step, "
                f"cpu {last['cpu_ms']:7.2f}, kernels {last['kernel_ms']:7.2f}",
                flush=True,
            )
    identical = all(
        np.array_equal(np.array(b["positions"]), np.array(c["positions"]))
        for b, c in zip(runs["baseline"], runs["current"])
    )
    summary = {}
    for name, results in runs.items():
        kernels = {
            k: float(np.median([r["kernels"].get(k, 0.0) for r in results]))
            for k in results[0]["kernels"]
        }
        summary[name] = {
            "wall_ms": float(np.median([r["wall_ms"] for r in results])),
            "cpu_ms": float(np.median([r["cpu_ms"] for r in results])),
            "kernel_ms": float(np.median([r["kernel_ms"] for r in results])),
            "launches": results[0]["launches"],
            "kernels": kernels,
        }
    print(
        f"\n{args.scene} n={args.n}, {args.steps} steps, medians of {args.rounds} "
        f"alternated runs; end positions {'identical' if identical else 'DIFFER'}"
    )
    names = sorted(
        set(summary["baseline"]["kernels"]) | set(summary["current"]["kernels"]),
        key=lambda k: -summary["baseline"]["kernels"].get(k, 0.0),
    )
    print(f"{'':32s} {'baseline':>10s} {'current':>10s}")
    for label in ("wall_ms", "cpu_ms", "kernel_ms", "launches"):
        print(f"{label:32s} {summary['baseline'][label]:10.2f} {summary['current'][label]:10.2f}")
    for k in names[:12]:
        print(
            f"  {k:30s} {summary['baseline']['kernels'].get(k, 0.0):10.3f} "
            f"{summary['current']['kernels'].get(k, 0.0):10.3f}"
        )
    device = runs["current"][0]["device"].replace(" ", "-").lower()
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    path = HERE / "results" / f"cpu_solve-{device}-{stamp}.json"
    record = {
        "benchmark": "cpu_solve",
        "scene": args.scene,
        "n": args.n,
        "steps": args.steps,
        "rounds": args.rounds,
        "baseline": args.baseline,
        "identical_end_positions": identical,
        "summary": summary,
        "runs": {
            k: [{kk: vv for kk, vv in r.items() if kk != "positions"} for r in v]
            for k, v in runs.items()
        },
    }
    path.write_text(json.dumps(record, indent=1))
    print(f"wrote {path.relative_to(HERE.parent)}")


if __name__ == "__main__":
    main()
