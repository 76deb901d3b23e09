"""The parts of the ``rbgen`` command that record, show progress and benchmark.

`rbgen.cli` adds these options and subcommands: ``--record PATH`` (repeatable;
``.png``, ``.gif``, ``.mp4``, ``.usd``), ``--record-every``, ``--record-size``
and ``--fps`` on ``rbgen run`` and ``rbgen demo`` (which records a short
animation unless ``--no-record``), a progress bar on long runs, and
``rbgen bench``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .errors import RbgenError

#: what ``rbgen demo`` writes when no --record is given
DEMO_RECORDING = "rbgen-demo.mp4"
#: the demo's recording: a frame every this many steps, at this size (small, so that
#: rendering on two CPU cores stays a few seconds)
DEMO_EVERY = 5
DEMO_SIZE = (480, 270)
#: a run shows a bar only after this many seconds (a short run shows none)
BAR_DELAY = 1.0


def add_record_options(parser: argparse.ArgumentParser, demo: bool = False) -> None:
    """--record, --record-every, --record-size, --fps (and --no-record for the demo)."""
    parser.add_argument(
        "--record",
        action="append",
        metavar="PATH",
        help="write the run to PATH: .png (last frame), .gif, .mp4, .usd "
        "(repeatable)" + (f"; default {DEMO_RECORDING}" if demo else ""),
    )
    if demo:
        parser.add_argument("--no-record", action="store_true", help="record nothing")
    parser.add_argument(
        "--record-every",
        type=int,
        default=None,
        metavar="K",
        help=f"a frame every K steps (default {DEMO_EVERY if demo else 2})",
    )
    parser.add_argument(
        "--record-size",
        default=None,
        metavar="WxH",
        help="image size (default {}x{})".format(*(DEMO_SIZE if demo else (640, 360))),
    )
    parser.add_argument(
        "--fps", type=float, default=None, help="frames per second (default: real time, 60 / K)"
    )


def _size(text: str | None, default) -> tuple[int, int]:
    if text is None:
        return default
    try:
        width, height = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise RbgenError(
            f"--record-size must be WIDTHxHEIGHT, e.g. 640x360, got {text!r}"
        ) from None
    return width, height


def run_scene_recorded(args, scene: str, n: int, steps: int, demo: bool = False, **options) -> dict:
    """`rbgen.harness.run_scene` with the recordings and progress bar that ``args`` ask for;
    prints each recording's path. Recorders are made (and their paths checked) before
    anything is simulated."""
    from . import progress
    from .harness import run_scene
    from .record import Recorder, record_hook

    paths = list(args.record or [])
    if demo and not paths and not args.no_record:
        paths = [DEMO_RECORDING]
    every = args.record_every or (DEMO_EVERY if demo else 2)
    if every < 1:
        raise RbgenError(f"--record-every must be a positive integer, got {every}")
    width, height = _size(args.record_size, DEMO_SIZE if demo else (640, 360))
    fps = args.fps or 60.0 / every
    recorders = [Recorder(path, width=width, height=height, fps=fps) for path in paths]
    hooks = [record_hook(recorders, every)] if recorders else []
    with progress.bar(total=steps, desc=scene, unit="step", delay=BAR_DELAY) as steps_bar:
        hooks.append(lambda world, step: steps_bar.update(1) if step else None)

        def on_step(world, step):
            for hook in hooks:
                hook(world, step)

        try:
            with progress.printing_above():
                summary = run_scene(scene, n, steps, on_step=on_step, **options)
        except BaseException:
            for recorder in recorders:
                recorder.abort()
            raise
    for recorder in recorders:
        path = recorder.close()
        print(f"wrote {Path(path).resolve()} ({recorder.frames} frames)", flush=True)
    return summary


def add_bench_parser(sub) -> None:
    """The ``rbgen bench`` subcommand."""
    p = sub.add_parser(
        "bench", help="time the standard scenes; write JSON and Markdown under benchmarks/results/"
    )
    p.add_argument("--device", default=None)
    p.add_argument("--quick", action="store_true", help="small sizes only")
    p.add_argument("--scene", action="append", help="only this scene (repeatable)")
    p.add_argument("--steps", type=int, default=None, help="timed steps of every scene")
    p.add_argument("--out", default=None, help="results directory (default benchmarks/results)")
    p.add_argument(
        "--readme",
        default=None,
        metavar="README.md",
        help="then regenerate the performance table in this README",
    )
    p.add_argument(
        "--no-run",
        action="store_true",
        help="run nothing; only regenerate --readme's table from the results",
    )
    p.set_defaults(func=cmd_bench)


def cmd_bench(args) -> int:
    from . import bench

    out = Path(args.out) if args.out else bench.RESULTS_DIR
    if not args.no_run:
        path, record = bench.run(
            args.device, quick=args.quick, scenes=args.scene, steps=args.steps, out_dir=out
        )
        print(bench.markdown(record))
        print(f"wrote {path} and {path.with_suffix('.md')}")
    elif not args.readme:
        raise RbgenError("--no-run only regenerates a table: give --readme README.md")
    if args.readme:
        changed = bench.update_readme(args.readme, out)
        print(f"{args.readme}: performance table {'updated' if changed else 'unchanged'}")
    return 0


def add_sweep_parser(sub) -> None:
    """The ``rbgen sweep`` subcommand (`rbgen.sweep` on Dask)."""
    p = sub.add_parser(
        "sweep",
        help="run a scene for every combination of parameter values as Dask tasks",
    )
    p.add_argument(
        "scene",
        help="a scene name (box_pile, boxbox, pyramid, terrain; --param values are World "
        "options) or a Python file whose build(**params) returns a World or WorldBatch",
    )
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=V1,V2,...",
        help="a parameter and its values (repeatable: every combination is run)",
    )
    p.add_argument("--n", type=int, default=100, help="the named scene's size")
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--dt", type=float, default=1 / 60)
    p.add_argument(
        "--scheduler", default=None, help="a Dask scheduler address (default: a LocalCluster)"
    )
    p.add_argument("--workers", type=int, default=None, help="LocalCluster worker processes")
    p.add_argument(
        "--devices",
        default=None,
        help="comma-separated device choices, worker rank r of a host takes the r-th "
        "(default: the host's GPUs in order)",
    )
    p.add_argument(
        "--timeout",
        type=float,
        default=None,
        help="seconds a parameter set may run on its worker; one that overruns fails its "
        "row (default: no limit)",
    )
    p.add_argument("--out", default=None, help="write the table as JSON here")
    p.set_defaults(func=cmd_sweep)


def _value(text: str):
    """A command-line parameter value: an int, a float, a boolean or the text."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


def parse_params(specs) -> list[dict]:
    """Every combination of ``NAME=V1,V2`` values (``specs``: the --param strings)."""
    import itertools

    names, values = [], []
    for spec in specs:
        name, sep, text = spec.partition("=")
        if not sep or not name.strip() or not text.strip():
            raise RbgenError(f"--param must be NAME=V1,V2,..., got {spec!r}")
        names.append(name.strip())
        values.append([_value(v.strip()) for v in text.split(",")])
    return [dict(zip(names, combo)) for combo in itertools.product(*values)]


def scene_world(scene: str, n: int, **options):
    """A named scene's World with ``options`` (a sweep's build for scene names)."""
    from .harness import build_scene

    return build_scene(scene, n, **options)[0]


def sweep_build(scene: str, n: int):
    """The build function of ``rbgen sweep SCENE``: a named scene, or a file's build."""
    import functools
    import importlib.util

    if not scene.endswith(".py"):
        return functools.partial(scene_world, scene, n)
    path = Path(scene)
    if not path.is_file():
        raise RbgenError(f"sweep: no file {scene!r}")
    spec = importlib.util.spec_from_file_location(f"rbgen_sweep_{path.stem}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)  # (not in sys.modules: pickled by value)
    spec.loader.exec_module(module)
    build = getattr(module, "build", None)
    if not callable(build):
        raise RbgenError(f"sweep: {scene} has no function build(**params)")
    return build


def cmd_sweep(args) -> int:
    import json

    from .sweep import summary, sweep

    params = parse_params(args.param) or [{}]
    client = None
    if args.scheduler:
        import distributed

        client = distributed.Client(args.scheduler)
    devices = args.devices.split(",") if args.devices else None
    table = sweep(
        sweep_build(args.scene, args.n),
        params,
        args.steps,
        client=client,
        dt=args.dt,
        measure=summary,
        workers=args.workers,
        devices=devices,
        timeout=args.timeout,
    )
    for row in table:
        result = (
            f"{row['mean_height']:.4f} mean height, {row['max_speed']:.4f} m/s max, "
            f"{row['seconds']:.2f} s on {row['device']}"
            if row["ok"]
            else f"FAILED: {row['error'].splitlines()[0]}"
        )
        print(f"{row['params']}: {result}")
    if args.out:
        Path(args.out).write_text(json.dumps(table, indent=2, default=str))
        print(f"wrote {args.out}")
    return 0 if all(row["ok"] for row in table) else 1
