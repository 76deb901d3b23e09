"""Broadphase pair finding per algorithm: the BoxBox scene (ground + N boxes), ragdolls.

For each input and algorithm: one warm-up query (builds kernels, grows the pair
buffer), then ``--repeats`` complete queries (``enqueue`` + ``check``). Inputs: BoxBox
with each of ``--sizes`` boxes, and the ragdolls scene (`rbgen.harness`: ragdoll parts
falling on a pile of boxes, two sizes) with each of ``--ragdolls`` ragdolls, its world
AABBs after ``--steps`` steps. Reported:
the median device time (profiling markers around the query's enqueues), the
median wall time (enqueue to completed status read), launches per query, the
pairs found and the reference count from a numpy grid (``grid_pairs``), with
``ok`` when the device pair list equals the reference exactly.

An algorithm may carry options: ``grid:emission=slot`` (the default is owner),
``sap:shape=gpu``, ``sap3:full=sap``.

sap3 is measured in steady state (the same boxes every query, as in a resting
stack): its incremental path then finds no endpoint crossings.

``--baseline REV`` (a git revision of this repository, or a directory holding its
rbgen/) times the same inputs with that tree's rbgen as well, each tree in its own
process, alternating ``--rounds`` times (drift of the machine falls on both); the rows
are labelled by tree.

usage: python benchmarks/broadphase.py [--device D] [--sizes 8000 27000 111375]
                                       [--ragdolls 300] [--steps 60]
                                       [--algorithms grid sap sap3] [--repeats 10]
                                       [--baseline REV] [--rounds 2]
                                       [--profile]  (adds the slowest kernels of a query)
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def measure(runtime, name: str, aabbs, static, reference, repeats: int) -> dict:
    import pyopencl as cl

    from rbgen.pipeline.broadphase import make_broadphase

    algorithm, _, text = name.partition(":")
    options = {}
    for item in filter(None, text.split(",")):
        key, _, value = item.partition("=")
        options[key] = int(value) if value.isdigit() else value
    broadphase = make_broadphase(runtime, algorithm, **options)
    count = broadphase.find_pairs(aabbs, static)  # warm-up: build, grow
    broadphase.find_pairs(aabbs, static)  # sap3: its incremental path too
    pairs = broadphase.host_pairs()
    ok = pairs.shape == reference.shape and bool(np.array_equal(pairs, reference))
    device_ms, wall_ms, launches = [], [], []
    for _ in range(repeats):
        runtime.queue.finish()
        before = runtime.counters["launches"]
        t0 = time.perf_counter()
        start = cl.enqueue_marker(runtime.queue)
        broadphase.enqueue(aabbs, static)
        end = cl.enqueue_marker(runtime.queue)
        complete = broadphase.check()
        end.wait()
        wall_ms.append(1e3 * (time.perf_counter() - t0))
        launches.append(runtime.counters["launches"] - before)
        if not complete:
            raise RuntimeError(f"{name}: query incomplete after warm-up")
        device_ms.append(1e-6 * (end.profile.end - start.profile.start))
    return {
        "algorithm": name,
        "pairs": count,
        "ok": ok,
        "device_ms": statistics.median(device_ms),
        "wall_ms": statistics.median(wall_ms),
        "launches": int(statistics.median(launches)),
        "broadphase": broadphase,
    }


def kernel_breakdown(runtime, broadphase, aabbs, static) -> list[tuple[float, str]]:
    """(ms, kernel name) of one more query, from an event per launch, slowest first."""
    from rbgen.launch import BoundKernel

    events, launch, bound_launch = [], runtime.launch, BoundKernel.launch

    def recording_launch(kernel, global_size, local_size, wait_for=None):
        event = launch(kernel, global_size, local_size, wait_for)
        events.append((kernel.function_name, event))
        return event

    def recording_bound_launch(self, global_size, local_size, wait_for=None):
        event = bound_launch(self, global_size, local_size, wait_for)
        events.append((self.kernel.function_name, event))
        return event

    runtime.launch, BoundKernel.launch = recording_launch, recording_bound_launch
    try:
        broadphase.enqueue(aabbs, static)
        broadphase.check()
        runtime.queue.finish()
    finally:
        runtime.launch, BoundKernel.launch = launch, bound_launch
    totals: dict[str, float] = {}
    for name, event in events:
        totals[name] = totals.get(name, 0.0) + 1e-6 * (event.profile.end - event.profile.start)
    return sorted(((ms, name) for name, ms in totals.items()), reverse=True)


def export_tree(revision: str, into: Path) -> Path:
    """``revision``'s rbgen written under ``into`` (git archive); a directory holding an
    rbgen/ is used as it is."""
    if (Path(revision) / "rbgen").is_dir():
        return Path(revision).resolve()
    archive = into / "tree.tar"
    with open(archive, "wb") as out:
        subprocess.run(
            ["git", "-C", str(ROOT), "archive", revision, "rbgen"], stdout=out, check=True
        )
    tree = into / "baseline"
    with tarfile.open(archive) as tar:
        tar.extractall(tree, filter="data")
    return tree


def make_inputs(args) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(label, aabbs, static) of every input the arguments name."""
    from rbgen.scenes import scene_aabbs, standard_boxbox_scene

    inputs = []
    for size in args.sizes:
        aabbs, static = scene_aabbs(standard_boxbox_scene(size))
        inputs.append((f"boxbox {size}", aabbs, static))
    if args.ragdolls:
        from grid_candidates import scene_aabbs_after  # (this script's directory)

        for n in args.ragdolls:
            aabbs, words = scene_aabbs_after("ragdolls", n, args.steps, args.device)
            inputs.append((f"ragdolls {n}", aabbs, words))
    return inputs


def run_trees(args, inputs) -> None:
    """This script on the saved inputs in each tree's process, ``--rounds`` times."""
    with tempfile.TemporaryDirectory() as scratch:
        files = []
        for k, (label, aabbs, static) in enumerate(inputs):
            files.append(os.path.join(scratch, f"input{k}.npz"))
            np.savez(files[-1], aabbs=aabbs, static=static, label=label)
        trees = [
            (f"baseline {args.baseline}", export_tree(args.baseline, Path(scratch))),
            ("this tree", ROOT),
        ]
        command = [
            sys.executable,
            __file__,
            "--inputs",
            *files,
            "--repeats",
            str(args.repeats),
            "--algorithms",
            *args.algorithms,
        ]
        if args.device:
            command += ["--device", args.device]
        if args.profile:
            command.append("--profile")
        for round_ in range(args.rounds):
            for label, tree in trees:
                env = {**os.environ, "PYTHONPATH": str(tree)}
                print(f"round {round_ + 1}, {label}:", flush=True)
                subprocess.run(command, env=env, check=True)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="device choice passed to rbgen.Runtime")
    parser.add_argument("--sizes", type=int, nargs="*", default=[8000, 27000, 111375])
    parser.add_argument("--ragdolls", type=int, nargs="*", default=[])
    parser.add_argument("--steps", type=int, default=60, help="ragdolls: steps before")
    parser.add_argument("--baseline", default=None, help="git revision or tree to compare")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--inputs", nargs="*", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--algorithms", nargs="+", default=["grid", "sap", "sap3"])
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument(
        "--profile", action="store_true", help="also print the time per kernel of one query"
    )
    args = parser.parse_args(argv)

    import pyopencl.array as cla

    from rbgen.device import Runtime
    from rbgen.pipeline.broadphase.reference import grid_pairs

    if args.inputs is None:
        inputs = make_inputs(args)
        if args.baseline:
            run_trees(args, inputs)
            return
    else:
        inputs = []
        for path in args.inputs:
            with np.load(path) as saved:
                inputs.append((str(saved["label"]), saved["aabbs"], saved["static"]))
    runtime = Runtime(args.device, profiling=True)
    print(f"device: {runtime.traits.describe()}")
    width = max(9, *(len(a) for a in args.algorithms))
    print(
        f"{'input':>14} {'algorithm':>{width}} {'device ms':>10} {'wall ms':>9} {'launches':>8} "
        f"{'pairs':>8} {'reference':>9} {'ok':>3}"
    )
    for label, aabbs, static in inputs:
        reference = grid_pairs(aabbs, static)
        device_aabbs = cla.to_device(runtime.queue, aabbs)
        device_static = cla.to_device(runtime.queue, static)
        for name in args.algorithms:
            row = measure(runtime, name, device_aabbs, device_static, reference, args.repeats)
            print(
                f"{label:>14} {name:>{width}} {row['device_ms']:>10.3f} {row['wall_ms']:>9.3f} "
                f"{row['launches']:>8} {row['pairs']:>8} {len(reference):>9} "
                f"{'yes' if row['ok'] else 'NO':>3}",
                flush=True,
            )
            if args.profile:
                for ms, kernel in kernel_breakdown(
                    runtime, row["broadphase"], device_aabbs, device_static
                )[:8]:
                    print(f"{'':>{width + 16}} {ms:>10.3f}  {kernel}")


if __name__ == "__main__":
    main()
