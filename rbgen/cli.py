"""The ``rbgen`` command: info, demo, run, tune, bench, export."""

from __future__ import annotations

import argparse
import importlib
import sys
import time

import numpy as np


def _optional(module: str):
    """Import an rbgen module that a later stage of the project provides."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as err:
        if err.name == module:
            return None
        raise


def cmd_info(args) -> int:
    """List every device with its traits and tuned entries, marking with ``*`` the one
    rbgen uses: ``--device`` (else ``RBGEN_DEVICE``, else the default), resolved as a
    Runtime resolves it (`rbgen.device.resolve_device`): a GPU shape ``shape:NAME`` marks
    the CPU device that stands in and shows the GPU traits it is planned for. A choice
    that names no device is an error naming it (exit 2), after the listing."""
    import os

    from .device import ENV_DEVICE, DeviceTraits, build_failure, list_devices, resolve_device
    from .errors import DeviceNotFoundError

    entries = list_devices()
    if not entries:
        print("no OpenCL devices found")
        return 1
    choice, source = args.device, "--device"
    if choice is None:
        choice, source = os.environ.get(ENV_DEVICE) or None, ENV_DEVICE
    chosen, planned, problem = None, None, None
    try:
        chosen, planned = resolve_device(choice)
    except Exception as err:  # noqa: BLE001 - still list the devices
        if choice is not None:
            problem = f"{source} {choice!r}: {err}"
        # (no choice: none compiles a kernel; each is listed with the compiler's words)
    tuning = _optional("rbgen.tuning")

    def tuned(traits, indent: str) -> None:
        if tuning is not None and hasattr(tuning, "describe_cache"):
            lines = tuning.describe_cache(traits)
            print(f"{indent}tuned entries: {len(lines)}")
            for line in lines:
                print(f"{indent}  {line}")

    for entry in entries:
        traits = DeviceTraits.of(entry.device)
        mark = "*" if entry.device == chosen else " "
        print(f"{mark} {entry.index}  {traits.describe()}")
        print(f"        fingerprint {traits.fingerprint}, OpenCL {traits.opencl_version}")
        failure = build_failure(entry.device)
        if failure is not None:
            print(f"        cannot compile a kernel: {failure}")
        tuned(traits, "        ")
        if mark == "*" and planned is not None and planned != traits:
            print(f"        chosen as {choice}: planned for as {planned.describe()}")
            print(f"          fingerprint {planned.fingerprint}")
            tuned(planned, "          ")
    if problem is not None:
        raise DeviceNotFoundError(problem)
    if chosen is None:
        print(
            "no device here compiles a kernel (install the system's PoCL, e.g. Debian's "
            "pocl-opencl-icd)"
        )
        return 1
    if choice is None:
        print("(* = the device rbgen uses by default; set RBGEN_DEVICE or pass --device to change)")
    else:
        print(f"(* = the device rbgen uses: {source} {choice})")
    return 0


def cmd_export(args) -> int:
    from .device import Runtime
    from .export import default_specs, export_kernels, export_world

    if args.world:
        world, fresh = _world_for_export(args.world, args.n, args.device)
        command = " ".join(
            [
                "rbgen export --world",
                args.world,
                *(["--n", str(args.n)] if args.n else []),
                *(["--dt", repr(args.dt)] if args.dt != 1 / 60 else []),
                *(["--grow-rungs", str(args.grow_rungs)] if args.grow_rungs else []),
                "--out",
                args.out,
            ]
        )
        from .world import World

        # a WorldBatch's step is recorded for C++ hosts only through its World; its
        # reset launches are not in the schedule format yet, so it exports without one
        recorded = not args.no_schedule and isinstance(world, World)
        if not args.no_schedule and not recorded:
            print(
                f"note: {type(world).__name__} exports its kernels, header and plan; "
                f"a C++ schedule is recorded for a World only"
            )
        manifest = export_world(
            world,
            args.out,
            build=fresh if recorded else None,
            dt=args.dt,
            grow_rungs=args.grow_rungs,
            command=command,
        )
        for entry in manifest["files"]:
            names = ", ".join(k["name"] for k in entry["kernels"])
            print(f"  {args.out}/{entry['file']}: {names}")
        schedule = ", schedule.json, data/" if recorded else ""
        print(
            f"wrote the {len(manifest['files'])} kernel files this World runs, plan.json, "
            f"manifest.json{schedule} and {manifest['header']} to {args.out} (for "
            f"{world.runtime.traits.device_name}; plan: {world.plan.describe()})"
        )
        return 0
    runtime = Runtime(args.device)
    overrides = {}
    for item in args.param or []:
        name, _, value = item.partition("=")
        overrides[name] = _parse_value(value)
    specs = default_specs(runtime.traits, args.kernel)
    if overrides:
        overridden = []
        for s in specs:
            template = s.template
            assert template is not None  # default_specs makes every spec from its template
            overridden.append(
                template.spec(
                    **{**s.values, **{k: v for k, v in overrides.items() if k in template.params}}
                )
            )
        specs = overridden
    manifest = export_kernels(specs, args.out, runtime.traits)
    for entry in manifest["files"]:
        names = ", ".join(k["name"] for k in entry["kernels"])
        print(f"  {args.out}/{entry['file']}: {names}")
    print(
        f"wrote {len(manifest['files'])} kernel files, manifest.json and "
        f"{manifest['header']} to {args.out} (for {runtime.traits.device_name})"
    )
    return 0


def _world_for_export(scene: str, n: int | None, device):
    """The World of a preset scene (``rbgen.harness.SCENES``) or of a Python file whose
    ``build(device)`` returns one (or a WorldBatch), stepped once so that its kernels are
    built, and a function that makes a fresh one on the same runtime (the schedule's
    recordings)."""
    from pathlib import Path

    from .batch import WorldBatch
    from .errors import RbgenError
    from .harness import SCENES, build_scene
    from .world import World

    if scene in SCENES:
        world = build_scene(scene, n or 1000, device)[0]
        runtime = world.runtime

        def fresh():
            return build_scene(scene, n or 1000, runtime)[0]
    elif scene.endswith(".py") and Path(scene).is_file():
        namespace: dict = {"__name__": "rbgen_export_scene", "__file__": scene}
        exec(compile(Path(scene).read_text(), scene, "exec"), namespace)  # noqa: S102
        build = namespace.get("build")
        if not callable(build):
            raise RbgenError(
                f"export --world {scene}: the file defines no build(device) "
                f"function returning a World"
            )
        world = build(device)
        if not isinstance(world, (World, WorldBatch)):
            raise RbgenError(
                f"export --world {scene}: build(device) returned "
                f"{type(world).__name__}, not an rbgen.World or rbgen.WorldBatch"
            )
        runtime = world.runtime

        def fresh():
            return namespace["build"](runtime)
    else:
        raise RbgenError(
            f"export --world: {scene!r} is neither a scene ({', '.join(SCENES)}) "
            f"nor a Python file with build(device)"
        )
    world.step(1 / 60)
    world.statistics()  # (waits for the step: its kernels are built and run)
    return world, fresh


def _parse_value(text: str):
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    if text in ("True", "False"):
        return text == "True"
    if "," in text:
        return tuple(_parse_value(t) for t in text.split(",") if t)
    return text


def cmd_tune(args) -> int:
    tuning = _optional("rbgen.tuning")
    if tuning is None:
        print("the autotuner is not available in this build", file=sys.stderr)
        return 1
    from .device import Runtime
    from .plan_tuning import tune_plan

    runtime = Runtime(args.device, profiling=True)
    if args.what in ("all", "primitives"):
        tuning.tune_all(runtime, progress=True, quick=args.quick)
    if args.what in ("all", "plan"):
        print("tuning the plan (whole World steps of a standard scene)", file=sys.stderr)
        entry = tune_plan(
            runtime,
            quick=args.quick,
            progress=lambda line: print(line, file=sys.stderr, flush=True),
        )
        print(f"plan: {entry['values']} ({entry['scene']})")
    return 0


def cmd_run(args) -> int:
    demo = _optional("rbgen.harness")
    if demo is None or not hasattr(demo, "run_scene"):
        print("scene simulation needs the World (not available in this build)", file=sys.stderr)
        return 1
    options = {
        k: v for k, v in (("solver", args.solver), ("iterations", args.iterations)) if v is not None
    }
    from .cli_extras import run_scene_recorded

    run_scene_recorded(
        args, args.scene, args.n, args.steps, device=args.device, progress=True, **options
    )
    return 0


def cmd_demo(args) -> int:
    demo = _optional("rbgen.harness")
    if demo is not None and hasattr(demo, "run_scene"):
        from .cli_extras import run_scene_recorded

        run_scene_recorded(
            args,
            "box_pile",
            args.n or 1000,
            args.steps or 300,
            demo=True,
            device=args.device,
            progress=True,
        )
        return 0
    return integrate_demo(args.n or 100_000, args.steps or 60, args.device)


def integrate_demo(n: int, steps: int, device=None) -> int:
    """Integrate and bound ``n`` tumbling boxes on the device and check the result."""
    import pyopencl.array as cla

    from . import layouts
    from .device import Runtime
    from .pipeline.aabbs import WorldAabbs
    from .pipeline.integrate import Integrator
    from .shapes import Box, ShapeTable

    runtime = Runtime(device)
    print(f"device: {runtime.traits.describe()}")
    t0 = time.perf_counter()
    integrator = Integrator(runtime)
    aabbs_stage = WorldAabbs(runtime, ("box",))
    print(
        f"kernels ready in {time.perf_counter() - t0:.2f} s (built or loaded from the disk cache)"
    )

    rng = np.random.default_rng(1)
    table = ShapeTable()
    box = Box((0.5, 0.25, 1.0))
    table.add(box)
    shapes, hull_vertices = table.pack()
    bodies = layouts.BODY.zeros(n)
    bodies["position"][:, :3] = rng.uniform(-100, 100, (n, 3))
    bodies["orientation"][:, 3] = 1.0
    bodies["linear_velocity"][:, :3] = rng.normal(0, 5, (n, 3))
    bodies["angular_velocity"][:, :3] = rng.normal(0, 3, (n, 3))
    bodies["inv_mass"] = 1.0
    q = runtime.queue
    d_bodies = cla.to_device(q, bodies)
    d_shapes = cla.to_device(q, shapes)
    d_verts = cla.to_device(q, hull_vertices)
    d_aabbs = cla.empty(q, n, layouts.AABB.dtype)
    dt = 1.0 / 60.0
    q.finish()
    t0 = time.perf_counter()
    for _ in range(steps):
        integrator(d_bodies, n, dt)
        aabbs_stage(d_bodies, d_shapes, d_verts, d_aabbs, n)
    q.finish()
    elapsed = time.perf_counter() - t0
    out, boxes = d_bodies.get(), d_aabbs.get()
    expected_y = (
        bodies["position"][:, 1]
        + bodies["linear_velocity"][:, 1] * steps * dt
        - 9.81 * dt * dt * steps * (steps + 1) / 2
    )
    drift = np.abs(out["position"][:, 1] - expected_y).max()
    qnorm = np.abs(np.linalg.norm(out["orientation"], axis=1) - 1).max()
    inside = np.all(
        (boxes["lower"][:, :3] <= out["position"][:, :3])
        & (out["position"][:, :3] <= boxes["upper"][:, :3])
    )
    print(
        f"integrated and bounded {n:,} boxes for {steps} steps: "
        f"{1e3 * elapsed / steps:.3f} ms/step "
        f"({runtime.counters['launches'] // steps} launches/step)"
    )
    print(
        f"checks: max |y - closed form| = {drift:.2e} m, max | |q| - 1 | = {qnorm:.1e}, "
        f"every centre inside its AABB: {bool(inside)}, "
        f"NaNs: {int(np.isnan(out['position']).sum())}"
    )
    return 0 if inside and drift < 1e-2 and qnorm < 1e-5 else 1


def main(argv=None) -> int:
    from . import cli_extras

    parser = argparse.ArgumentParser(prog="rbgen", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("info", help="list OpenCL devices, their traits and tuned entries")
    p.add_argument("--device", default=None)
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("demo", help="run the main demo on the default device")
    p.add_argument("--device", default=None)
    p.add_argument("--n", type=int, default=None)
    p.add_argument("--steps", type=int, default=None)
    cli_extras.add_record_options(p, demo=True)
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("run", help="simulate a named scene")
    p.add_argument("scene")
    p.add_argument("--n", type=int, default=1000)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--device", default=None)
    p.add_argument(
        "--solver",
        default=None,
        choices=("pgs", "jacobi"),
        help="contact solver (default pgs: batched Gauss-Seidel; jacobi: mass "
        "splitting, no batching, softer tall stacks at equal sweeps)",
    )
    p.add_argument("--iterations", type=int, default=None, help="velocity sweeps a step")
    cli_extras.add_record_options(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("tune", help="autotune the kernel families and the plan for a device")
    p.add_argument("--device", default=None)
    p.add_argument("--quick", action="store_true", help="fewer sizes and repeats")
    p.add_argument(
        "--what",
        default="all",
        choices=("all", "primitives", "plan"),
        help="the primitives' parameters, the plan's (batching, release sweeps, "
        "colouring rounds, group counts: whole World steps), or both",
    )
    p.set_defaults(func=cmd_tune)

    cli_extras.add_bench_parser(sub)
    cli_extras.add_sweep_parser(sub)

    p = sub.add_parser("export", help="write .cl kernels, manifest.json and the C header")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument(
        "--world",
        default=None,
        help="export exactly what this World runs: a scene name (box_pile, boxbox, "
        "pyramid; size --n) or a Python file whose build(device) returns a World",
    )
    p.add_argument("--n", type=int, default=None, help="the --world scene's size")
    p.add_argument("--device", default=None, help="device whose specialisations to export")
    p.add_argument(
        "--kernel", action="append", help="template path or substring (repeatable; default: all)"
    )
    p.add_argument("--param", action="append", help="NAME=VALUE override (repeatable)")
    p.add_argument(
        "--dt",
        type=float,
        default=1 / 60,
        help="--world: the step the schedule is recorded at (default 1/60 s)",
    )
    p.add_argument(
        "--grow-rungs",
        type=int,
        default=None,
        help="--world: the schedule covers each capacity up to 2^N times its "
        "initial value (default 2)",
    )
    p.add_argument(
        "--no-schedule",
        action="store_true",
        help="--world: kernels, header and plan only (no schedule.json, data/)",
    )
    p.set_defaults(func=cmd_export)

    args = parser.parse_args(argv)
    from .errors import RbgenError

    try:
        return args.func(args)
    except RbgenError as err:
        print(f"rbgen: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
