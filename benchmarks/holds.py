"""Whether the BoxBox lattices hold, and at what cost: the default against substep candidates.

    python benchmarks/holds.py [--device D] [--sizes 1000 8000 27000 111375]
                               [--candidates default s2 s4 s8 ...] [--steps 120]
                               [--repeat R] [--trace K] [--trace-steps T]
                               [--window-from S] [--out DIR]

Issue 24's table in one run: each BoxBox lattice is built through the public API and
stepped ``--steps`` steps (dt 1/60) from its start, once per candidate:

``default``  the World's defaults (the baseline every other row names; the shock sweep
             runs, as it does by default wherever it can)
``no_shock`` the defaults without the shock sweep (shock_propagation=False)
``s1``       one substep of 10 velocity + 4 position sweeps (the GPU default before substeps)
``s2``       substeps=2, 5 velocity + 2 position sweeps a substep
``s4``       substeps=4, 3 + 1
``s8``       substeps=8, 2 + 1
``s4_41``    substeps=4, 4 + 1; ``s4_52``: 5 + 2
``cells_s4``, ``cells_s8``  cells batching at 4 x (3 + 1) and 8 x (2 + 1)
``s8_31``    substeps=8, 3 + 1 (the cost of the shock candidates at 8 substeps)
``shock_s8_21``, ``shock_s8_31``, ``shock_s4_31``  the shock sweep at 8 x (2 + 1),
             8 x (3 + 1) and 4 x (3 + 1): the last velocity sweep of each substep is the
             shock sweep
``shock_release1``  the default with only the last velocity sweep of a substep solving each
             manifold's complete block (plan release_sweeps=1; the earlier one takes its
             all-pushing solution: a cheaper sweep)
(every candidate but ``default`` and those named ``shock_*`` runs without the shock sweep)
(every candidate keeps the default block normal solve; ``normal_solve`` is a World option
for a candidate that wants the sequential one)

A candidate is a dict of World options; ``--repeat R`` runs every candidate R times per
size, alternating them (a shared machine's noise falls on all alike), and reports each
run and the median. The first step (which builds the kernels) is not timed; ms/step is
the median of the timing blocks of the remaining steps (`rbgen.harness.run_scene`). Each
row: ms/step, kernel launches and blocking reads a step, boxes displaced more than 0.5 m
sideways, boxes moving faster than `rbgen.sanity.RESTING_SPEED` at the end, the top layer's
median drop, and whether the lattice holds (<= 0.5% displaced, <= 0.5% moving and a top drop
<= 2 cm: the issue's bar, and a lattice at rest rather than one whose boxes fall and are
pushed back up every substep). JSON (rbgen.bench's form, kind "holds") goes under
``--out`` (benchmarks/results by default; '' for none). ``--trace K`` also steps each
candidate's lattice ``--trace-steps`` steps (300 by default) and samples it every K steps
(`trace_lattice`): a bar met at one instant may be a phase of a lattice that sways or breathes,
so the samples from ``--window-from`` (step 100) on are also judged as a whole (`window`):
the bar at every sample, the top drop's swing, and the median speed at the end.
"""

from __future__ import annotations

import argparse
import statistics
import sys

import numpy as np

from rbgen import bench, sanity
from rbgen.harness import build_scene, run_scene

#: name -> World options (beside the defaults); each says whether it runs the shock sweep
#: (those before it was the default do not: their records were measured without it)
CANDIDATES = {
    "default": {},
    "no_shock": {"shock_propagation": False},
    "s1": {"substeps": 1, "iterations": 10, "position_iterations": 4, "shock_propagation": False},
    "s2": {"substeps": 2, "iterations": 5, "position_iterations": 2, "shock_propagation": False},
    "s4": {"substeps": 4, "iterations": 3, "position_iterations": 1, "shock_propagation": False},
    "s8": {"substeps": 8, "iterations": 2, "position_iterations": 1, "shock_propagation": False},
    "s4_52": {"substeps": 4, "iterations": 5, "position_iterations": 2, "shock_propagation": False},
    "s4_41": {"substeps": 4, "iterations": 4, "position_iterations": 1, "shock_propagation": False},
    "cells_s4": {
        "batching": "cells",
        "substeps": 4,
        "iterations": 3,
        "position_iterations": 1,
        "shock_propagation": False,
    },
    "cells_s8": {
        "batching": "cells",
        "substeps": 8,
        "iterations": 2,
        "position_iterations": 1,
        "shock_propagation": False,
    },
    "s8_31": {"substeps": 8, "iterations": 3, "position_iterations": 1, "shock_propagation": False},
    "shock_s8_21": {
        "substeps": 8,
        "iterations": 2,
        "position_iterations": 1,
        "shock_propagation": True,
    },
    "shock_s8_31": {
        "substeps": 8,
        "iterations": 3,
        "position_iterations": 1,
        "shock_propagation": True,
    },
    "shock_s4_31": {
        "substeps": 4,
        "iterations": 3,
        "position_iterations": 1,
        "shock_propagation": True,
    },
    "shock_release1": {"plan": {"release_sweeps": 1}, "shock_propagation": True},
    "shock_columns": {"batching": "columns", "shock_propagation": True},
}
BASELINE = "default"


def _holds(n: int, s: dict) -> bool:
    """Whether a lattice of ``n`` boxes holds (the issue's bar, and at rest)."""
    top = s["layer_drop"][-1] if s["layer_drop"] else 0.0
    limit = bench.DISPLACED_FRACTION * n
    return (
        s["displaced"] <= limit
        and s.get("moving", 0) <= limit
        and top <= bench.TOP_DROP
        and s["nans"] == 0
    )


def _row(n: int, name: str, s: dict, median: bool = False) -> bool:
    """Print one candidate's row; whether its lattice holds."""
    top = s["layer_drop"][-1] if s["layer_drop"] else 0.0
    ok = _holds(n, s)
    print(
        f"{n:>8,} {name:12} {s['ms_per_step']:>8.2f} {s['launches_per_step']:>8} "
        f"{s['blocking_reads_per_step']:>5} {s['displaced']:>9} {s.get('moving', '-'):>6} "
        f"{100 * top:>7.2f}cm  {'yes' if ok else 'NO'}{'  (median)' if median else ''}",
        flush=True,
    )
    return ok


def trace_lattice(n: int, options: dict, device, steps: int, every: int) -> list[dict]:
    """The lattice of ``n`` boxes stepped ``steps`` steps from its start with ``options``,
    sampled every ``every`` steps: displaced boxes, moving boxes (`rbgen.sanity.settling`),
    the top layer's median drop and the worst layer's (m), and the boxes' median speed
    (m/s). A lattice that holds at one step
    may be swaying or breathing: its top drop then swings from sample to sample, and its
    displaced count grows."""
    world, ids, _, half = build_scene("boxbox", n, device, **options)
    start = world.positions[ids]
    resting = ~sanity.overhanging(start, np.full(3, half))
    trace = []
    for k in range(1, steps + 1):
        world.step(1 / 60)
        if k % every == 0 or k == steps:
            velocities = world.linear_velocities[ids]
            settled = sanity.settling(start, world.positions[ids], velocities, resting)
            drops = settled["layer_drop"] or [0.0]
            speed = np.linalg.norm(velocities, axis=1)
            trace.append(
                {
                    "step": k,
                    "displaced": settled["displaced"],
                    "moving": settled["moving"],
                    "top_drop": drops[-1],
                    "worst_drop": max(drops),
                    "median_speed": float(np.median(speed)),
                }
            )
    return trace


def window(n: int, trace: list[dict], start: int) -> dict:
    """The trace's samples from step ``start`` on, judged as a whole: the issue's bar
    (<= 0.5% displaced and moving, top drop <= 2 cm) met at every sample (``holds``), the top
    drop's least and greatest (its swing: a breathing lattice passes or fails a one-instant
    bar by phase), the most displaced and moving, and the median speed at the last sample
    (m/s: a lattice at rest reads near zero). None where no sample is that late."""
    late = [t for t in trace if t["step"] >= start]
    if not late:
        return {"start": start, "holds": None}
    tops = [t["top_drop"] for t in late]
    worst = max(t["displaced"] for t in late)
    moving = max(t["moving"] for t in late)
    return {
        "start": start,
        "samples": len(late),
        "top_drop_min": min(tops),
        "top_drop_max": max(tops),
        "displaced_max": worst,
        "moving_max": moving,
        "end_median_speed": late[-1]["median_speed"],
        "holds": worst <= bench.DISPLACED_FRACTION * n
        and moving <= bench.DISPLACED_FRACTION * n
        and max(tops) <= bench.TOP_DROP,
    }


def _print_window(w: dict) -> None:
    if w["holds"] is None:
        print(f"  window from step {w['start']}: no sample", flush=True)
        return
    print(
        f"  window from step {w['start']} ({w['samples']} samples): top drop "
        f"{100 * w['top_drop_min']:.2f}-{100 * w['top_drop_max']:.2f} cm, displaced <= "
        f"{w['displaced_max']}, moving <= {w['moving_max']}, median speed at the end "
        f"{w['end_median_speed']:.4f} m/s: "
        f"{'holds' if w['holds'] else 'does NOT hold'} throughout",
        flush=True,
    )


def _print_trace(n: int, name: str, trace: list[dict]) -> None:
    print(f"  trace of {n:,} {name}: step displaced moving top_cm worst_cm median_m/s", flush=True)
    for t in trace:
        print(
            f"  {t['step']:>6} {t['displaced']:>9} {t['moving']:>6} {100 * t['top_drop']:>7.2f} "
            f"{100 * t['worst_drop']:>8.2f} {t['median_speed']:>10.4f}",
            flush=True,
        )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="rbgen device choice (index or name)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 8000, 27000, 111375])
    parser.add_argument(
        "--candidates", nargs="+", default=list(CANDIDATES), choices=list(CANDIDATES)
    )
    parser.add_argument("--steps", type=int, default=120, help="steps from the start")
    parser.add_argument(
        "--repeat", type=int, default=1, help="runs of each candidate, alternated (median)"
    )
    parser.add_argument(
        "--trace",
        type=int,
        default=0,
        metavar="K",
        help="also step each candidate's lattice --trace-steps steps, sampling every K "
        "(trace_lattice); 0: no trace",
    )
    parser.add_argument("--trace-steps", type=int, default=300)
    parser.add_argument(
        "--window-from",
        type=int,
        default=100,
        help="the trace's window starts at this step (judged as a whole: `window`)",
    )
    bench.add_out_argument(parser)
    args = parser.parse_args(argv)
    if args.trace < 0 or (args.trace and args.trace_steps < 1):
        parser.error("--trace must be >= 0 and --trace-steps >= 1")
    if args.trace and not 0 <= args.window_from <= args.trace_steps:
        parser.error(f"--window-from must be in [0, --trace-steps = {args.trace_steps}]")
    candidates = [BASELINE] + [c for c in args.candidates if c != BASELINE]

    results = []
    print(
        f"{'boxes':>8} {'candidate':12} {'ms/step':>8} {'launches':>8} {'reads':>5} "
        f"{'displaced':>9} {'moving':>6} {'top drop':>9}  holds",
        flush=True,
    )
    for n in args.sizes:
        base = None
        runs: dict[str, list[dict]] = {name: [] for name in candidates}
        for _ in range(max(1, args.repeat)):
            for name in candidates:
                s = run_scene(
                    "boxbox",
                    n,
                    args.steps - 1,
                    device=args.device,
                    progress=False,
                    warmup=1,
                    **CANDIDATES[name],
                )
                runs[name].append(s)
                _row(n, name, s)
        if args.repeat > 1:
            print(f"{n:,} boxes, median of {args.repeat} alternated runs:", flush=True)
        for name in candidates:
            ms = [s["ms_per_step"] for s in runs[name]]
            s = dict(runs[name][len(ms) // 2], ms_per_step=statistics.median(ms))
            ok = _row(n, name, s, median=True) if args.repeat > 1 else _holds(n, s)
            top = s["layer_drop"][-1] if s["layer_drop"] else 0.0
            result = bench.scene_result(s, 1)
            result.update(
                name=f"boxbox {n} {name}",
                candidate=name,
                options=CANDIDATES[name],
                top_drop=top,
                holds=ok,
                runs_ms=ms,
                baseline=base,
            )
            if args.trace:
                result["trace"] = trace_lattice(
                    n, CANDIDATES[name], args.device, args.trace_steps, args.trace
                )
                _print_trace(n, name, result["trace"])
                result["window"] = window(n, result["trace"], args.window_from)
                _print_window(result["window"])
            results.append(result)
            if name == BASELINE:
                base = {"name": f"boxbox {n} {BASELINE}", "ms": s["ms_per_step"]}
    if args.out:
        record = bench.make_record(
            "holds",
            results,
            bench.device_record(args.device),
            {
                "steps": args.steps,
                "dt": 1 / 60,
                "candidates": {c: CANDIDATES[c] for c in candidates},
                "trace": (
                    {
                        "every": args.trace,
                        "steps": args.trace_steps,
                        "window_from": args.window_from,
                    }
                    if args.trace
                    else None
                ),
            },
        )
        print(f"wrote {bench.write_results(record, args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
