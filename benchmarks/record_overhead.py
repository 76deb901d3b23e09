"""What recording costs a simulation step: a recorder against a bare copy of the transforms.

    python benchmarks/record_overhead.py [--device D] [--sizes 1000 8000] [--steps 300]
                                         [--every 2 10] [--formats usd mp4] [--blocking]
                                         [--out benchmarks/results]

For each BoxBox size and recording interval K, the same run (rbgen.harness.run_scene,
``--steps`` timed steps after 10 warm-up steps) these ways:

``none``         no hook: the plain ms/step;
``copy``         every K steps one blocking read of the transforms (World.positions and
                 .orientations, which drain the queue and copy the body buffer to the
                 host once) and nothing else: the baseline;
``pending``      every K steps one snapshot (World.snapshot_frame: a non-blocking copy
                 of the body buffer into pinned memory), resolved at the next snapshot,
                 and nothing else: what a recording's copy costs without the drain;
``usd``          every K steps a USD recorder captures the frame (a snapshot, as
                 rbgen.record.record_hook takes it; kept in memory, written at the end);
``mp4``, ``gif`` every K steps a recorder in a background process captures the
                 frame (rendering and encoding off the simulation's thread).

With ``--blocking``, each recorder also runs with a blocking read at each capture (the
recorders' reads before snapshots), as ``<format>-blocking``.

A recording keeps its promise when ``usd`` and ``mp4`` cost about what ``pending``
costs (their ms/step minus ``none``'s, times K: ms per recorded frame); ``copy`` minus
``pending`` is what draining the queue at each frame cost. Writes JSON (rbgen.bench's
form; each row's baseline is ``copy`` at the same K) and a Markdown table under
``--out``. A format whose needs are missing (an OpenGL context, imageio-ffmpeg for MP4,
usd-core for USD) is left out, with the reason.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from functools import partial

from rbgen import bench
from rbgen.harness import run_scene
from rbgen.record import Recorder, record_hook
from rbgen.render.scene import frame_of

WARMUP = 10


def copy_hook(every: int):
    def on_step(world, step):
        if step % every == 0:
            frame_of(world)

    return on_step


def pending_hook(every: int):
    """A snapshot every ``every`` steps, the previous one resolved then (as a recorder
    does); ``on_step.frames`` counts the snapshots."""
    held: list = []

    def on_step(world, step):
        if step % every == 0:
            held.append(world.snapshot_frame())
            on_step.frames += 1
            if len(held) > 1:
                held.pop(0).result()

    on_step.frames = 0
    return on_step


def measure(n, steps, device, on_step=None) -> dict:
    return run_scene(
        "boxbox", n, steps, device=device, progress=False, warmup=WARMUP, on_step=on_step
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 8000])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--every", type=int, nargs="+", default=[2, 10])
    parser.add_argument(
        "--formats", nargs="+", default=["usd", "mp4"], choices=["usd", "mp4", "gif"]
    )
    parser.add_argument(
        "--blocking",
        action="store_true",
        help="also run each recorder with a blocking read at each capture",
    )
    bench.add_out_argument(parser)
    args = parser.parse_args(argv)
    gl, left_out = None, {}
    try:
        from rbgen.render.renderer import gl_context

        gl = gl_context().info["GL_RENDERER"]
    except Exception as err:  # noqa: BLE001 - reported, the rendered formats left out
        left_out.update({f: str(err) for f in ("mp4", "gif")})
    for kind, module in (("usd", "pxr"), ("mp4", "imageio_ffmpeg")):
        try:
            __import__(module)
        except ImportError as err:
            left_out.setdefault(kind, str(err))
    formats = [f for f in args.formats if f not in left_out]
    print(
        f"BoxBox, {args.steps} steps after {WARMUP} warm-up; OpenGL: {gl}; recording "
        f"{formats}"
        + "".join(f"; {f} left out: {left_out[f]}" for f in args.formats if f in left_out)
    )
    results = []
    with tempfile.TemporaryDirectory() as scratch:
        for n in args.sizes:
            none = measure(n, args.steps, args.device)
            print(
                f"{n:>7,} boxes, no recording: {none['ms_per_step']:.3f} ms/step "
                f"({none['device']})",
                flush=True,
            )
            for every in args.every:
                copy = measure(n, args.steps, args.device, copy_hook(every))
                base = {
                    "name": f"transform copy every {every}",
                    "ms": copy["ms_per_step"],
                    "ms_spread": _spread(copy),
                }
                line = (
                    f"  every {every:>3}: copy {copy['ms_per_step']:.3f} ms/step "
                    f"(+{_per_frame(copy, none, every):.3f} ms a frame)"
                )

                def row(kind, run, frames):
                    results.append(
                        {
                            "name": f"boxbox {n} {kind} every {every}",
                            "bodies": n,
                            "every": every,
                            "recorder": kind,
                            "ms": run["ms_per_step"],
                            "ms_spread": _spread(run),
                            "ms_no_recording": none["ms_per_step"],
                            "ms_per_frame": _per_frame(run, none, every),
                            "copy_ms_per_frame": _per_frame(copy, none, every),
                            "frames": frames,
                            "baseline": base,
                        }
                    )
                    return (
                        f"; {kind} {run['ms_per_step']:.3f} ms/step "
                        f"(+{_per_frame(run, none, every):.3f} ms a frame)"
                    )

                hook = pending_hook(every)
                line += row("pending", measure(n, args.steps, args.device, hook), hook.frames)
                for kind in formats:
                    for reads, make_hook in (
                        ("", record_hook),
                        ("-blocking", partial(record_hook, blocking=True)),
                    ):
                        if reads and not args.blocking:
                            continue
                        recorder = Recorder(
                            os.path.join(scratch, f"r.{kind}"), background=kind != "usd"
                        )
                        run = measure(n, args.steps, args.device, make_hook([recorder], every))
                        recorder.close()
                        line += row(kind + reads, run, recorder.frames)
                print(line, flush=True)
    device = bench.device_record(args.device)
    record = bench.make_record(
        "benchmarks/record_overhead.py",
        results,
        device,
        {
            "scene": "boxbox",
            "steps": args.steps,
            "warmup": WARMUP,
            "gl_renderer": gl,
            "every": args.every,
            "formats": formats,
            "left_out": left_out,
        },
    )
    if args.out:
        print(f"wrote {bench.write_results(record, args.out)}")
    return 0


def _spread(summary) -> list:
    blocks = summary["ms_per_step_blocks"]
    return [min(blocks), max(blocks)]


def _per_frame(run, none, every) -> float:
    return (run["ms_per_step"] - none["ms_per_step"]) * every


if __name__ == "__main__":
    sys.exit(main())
