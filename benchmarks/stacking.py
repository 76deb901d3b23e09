"""Whether stacks hold: the quality targets of the contact solver, measured from the start.

    python benchmarks/stacking.py [--device D] [--quick] [--only NAME ...] [--options JSON]
                                  [--out DIR]

Each case builds a scene through the public API, steps it at dt 1/60 with the World's
defaults (plus ``--options``) and compares what it measures with its target:

``lattice_N``        BoxBox, N boxes, 120 steps: boxes displaced > 0.5 m sideways and boxes
                     that should rest moving faster than ``RESTING_SPEED`` (<= 0.5% each),
                     and the top layer's median drop (<= 2 cm)
``pyramid_20``       20-row pyramid, 600 steps: the top box's motion (< 1 cm)
``pyramid_40``       40-row pyramid, 600 steps: the top box's motion (< 5 cm: it stands)
``column_30``        30 unit boxes stacked, 600 steps: the largest sideways drift (< 1 cm)
``heavy_on_column``  a 100 kg box on a column of ten 1 kg boxes, 600 steps: drift (< 1 cm)
                     and the heavy box's drop (< 2 cm)
``pile_S``           1,000 boxes dropped in a loose grid (arrangement S: pitch, layers, jitter
                     and tilt vary), 300 steps: the fastest box (< 0.05 m/s: at rest)

It prints a table (case, target, measured, ms/step, holds) and records JSON under
``--out`` (benchmarks/results by default) in rbgen.bench's format. The baseline to quote
beside a new solver is the same script on the previous commit, run in the same session.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import rbgen
from rbgen import bench, scenes
from rbgen.sanity import RESTING_SPEED, overhanging, settling

DT = 1 / 60


def _ground(world, half=60.0):
    world.add_static(rbgen.Box((half, 1, half)), position=(0, -1, 0))


def _run(world, steps):
    """(seconds per step, the World) after ``steps`` steps (one finish at the end)."""
    world.step(DT)  # builds the kernels (not timed)
    world.statistics()
    start = time.perf_counter()
    for _ in range(steps - 1):
        world.step(DT)
    world.statistics()
    return (time.perf_counter() - start) / max(1, steps - 1)


def lattice(device, n, options):
    s = scenes.standard_boxbox_scene(n)
    world = rbgen.World(device, **options)
    world.add_static(rbgen.Box(s.ground_half_extents), position=s.ground_position)
    ids = world.add_bodies(rbgen.Box(s.half_extents), mass=s.mass, positions=s.positions)
    start = world.positions[ids]
    seconds = _run(world, 120)
    resting = ~overhanging(start, s.half_extents)
    result = settling(start, world.positions[ids], world.linear_velocities[ids], resting)
    top = result["layer_drop"][-1]
    limit = bench.DISPLACED_FRACTION * n
    ok = result["displaced"] <= limit and result["moving"] <= limit and top <= bench.TOP_DROP
    return (
        f"displaced, moving > {RESTING_SPEED} m/s <= {limit:.0f}; top drop <= 2 cm",
        f"displaced {result['displaced']}, moving {result['moving']}, top drop {100 * top:.1f} cm",
        seconds,
        ok,
        {
            "displaced": result["displaced"],
            "moving": result["moving"],
            "top_drop": top,
            "layer_drop": result["layer_drop"],
        },
    )


def pyramid(device, rows, options, limit):
    world = rbgen.World(device, **options)
    _ground(world, rows + 10)
    ids = world.add_bodies(
        rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, positions=scenes.pyramid_positions(rows)
    )
    start = world.positions[ids[-1]]
    seconds = _run(world, 600)
    moved = float(np.linalg.norm(world.positions[ids[-1]] - start))
    return (
        f"top moves < {100 * limit:.0f} cm",
        f"top moved {100 * moved:.2f} cm",
        seconds,
        moved < limit,
        {"top_moved": moved},
    )


def column(device, options, count=30, heavy=None):
    world = rbgen.World(device, **options)
    _ground(world)
    start = np.array([[0.0, 0.5 + k, 0.0] for k in range(count)])
    ids = world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, positions=start)
    if heavy:
        top = world.add_body(rbgen.Box((0.5, 0.5, 0.5)), mass=heavy, position=(0, 0.5 + count, 0))
        ids = np.r_[ids, top]
        start = np.r_[start, [[0.0, 0.5 + count, 0.0]]]
    seconds = _run(world, 600)
    p = world.positions[ids]
    drift = float(np.hypot(p[:, 0] - start[:, 0], p[:, 2] - start[:, 2]).max())
    drop = float(start[-1, 1] - p[-1, 1])
    ok = drift < 0.01 and (not heavy or drop < 0.02)
    target = "drift < 1 cm" + (", heavy box drops < 2 cm" if heavy else "")
    measured = f"drift {100 * drift:.2f} cm" + (f", drop {100 * drop:.2f} cm" if heavy else "")
    return target, measured, seconds, ok, {"drift": drift, "drop": drop}


#: arrangements of the dropped piles: (pitch, layers, jitter, tilt)
PILES = ((1.5, 5, 0.01, 0.0), (1.3, 8, 0.05, 0.0), (2.0, 3, 0.02, 0.02))


def pile(device, seed, options):
    rng = np.random.default_rng(seed)
    pitch, layers, jitter, tilt = PILES[seed % len(PILES)]
    world = rbgen.World(device, **options)
    positions = scenes.pile_positions(1000, layers=layers, pitch=pitch, jitter=jitter, seed=seed)
    _ground(world, 80)
    q = rng.normal(size=(1000, 4)) * [tilt, tilt, tilt, 1]
    ids = world.add_bodies(
        rbgen.Box((0.5, 0.5, 0.5)),
        mass=1.0,
        positions=positions,
        orientations=q / np.linalg.norm(q, axis=1)[:, None],
    )
    seconds = _run(world, 300)
    speed = float(np.linalg.norm(world.linear_velocities[ids], axis=1).max())
    return (
        "max speed < 0.05 m/s",
        f"max speed {speed:.3f} m/s",
        seconds,
        speed < 0.05,
        {"max_speed": speed},
    )


def cases(quick: bool):
    sizes = (1000,) if quick else (8000, 27000, 111375)
    out = [(f"lattice_{n}", lambda d, o, n=n: lattice(d, n, o)) for n in sizes]
    out += [("pyramid_20", lambda d, o: pyramid(d, 20, o, 0.01))]
    if not quick:
        out += [("pyramid_40", lambda d, o: pyramid(d, 40, o, 0.05))]
    out += [
        ("column_30", lambda d, o: column(d, o)),
        ("heavy_on_column", lambda d, o: column(d, o, count=10, heavy=100.0)),
    ]
    out += [(f"pile_{s}", lambda d, o, s=s: pile(d, s, o)) for s in ((0,) if quick else (0, 1, 2))]
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None)
    parser.add_argument("--quick", action="store_true", help="small sizes only")
    parser.add_argument("--only", nargs="*", default=None, help="case names to run")
    parser.add_argument(
        "--options",
        type=bench.world_options,
        default={},
        help="World options (JSON) for every case",
    )
    bench.add_out_argument(parser)
    args = parser.parse_args(argv)
    options = args.options
    results = []
    print(f"{'case':18} {'target':44} {'measured':34} {'ms/step':>8}  holds", flush=True)
    for name, run in cases(args.quick):
        if args.only and name not in args.only:
            continue
        target, measured, seconds, ok, detail = run(args.device, options)
        print(
            f"{name:18} {target:44} {measured:34} {1e3 * seconds:8.2f}  {'yes' if ok else 'NO'}",
            flush=True,
        )
        results.append(
            {
                "name": name,
                "ms": 1e3 * seconds,
                "ms_spread": [1e3 * seconds] * 2,
                "baseline": None,
                "target": target,
                "measured": measured,
                "holds": ok,
                "detail": detail,
            }
        )
    record = bench.make_record(
        "stacking", results, bench.device_record(args.device), {"options": options, "dt": DT}
    )
    if args.out:
        print(f"wrote {bench.write_results(record, args.out)}")
    return 0 if all(r["holds"] for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
