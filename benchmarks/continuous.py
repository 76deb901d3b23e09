"""Continuous collision: the tunnelling table, and BoxBox's step time against a baseline.

    python benchmarks/continuous.py [--device D] [--baseline REV] [--tree REV]
                                    [--size 8000] [--steps 100] [--warmup 10] [--rounds 3]
                                    [--skip-cost] [--out DIR]

1. Tunnelling: a sphere and a box (inner radius r = 5 cm, 1 kg) shot along +z at a
   static wall from 1 m before its face, without gravity, at 10, 50, 100 and 200 m/s
   (dt 1/60: up to 67 r a step), for 20 steps; walls: a Plane and static Boxes 1 cm,
   5 cm, 10 cm and 50 cm thick. Each cell is the deepest reach of the body's surface
   past the wall's face (mm; <= 0: it never touched deeper than its face) and "through"
   when its centre ended beyond the face. Holds when no body passes and no reach
   exceeds FAST_FRACTION r (`rbgen.pipeline.prepare`).
2. Cost (the baseline): BoxBox with ``--size`` boxes (no fast body: its boxes rest), both at
   one substep of 10 + 4 sweeps (`EFFORT`; the World's default effort differs by device and
   release), timed by ``benchmarks/scenes.py`` in ``--tree`` and in ``--baseline`` (git
   revisions of this repository, or directories holding their rbgen/ and benchmarks/;
   by default the continuous-collision branch's head 652f79d and its branch point 06bc3af,
   which differ by continuous collision alone: this tree differs from the branch point by
   everything merged since; ``--tree .`` times it all the same), each run in its own
   process, alternating the two ``--rounds`` times so that drift of the machine falls on
   both; each side's time is the median of its rounds' ms/step (each itself a median of
   10 blocks), and the fastest block of all its rounds (the least disturbed on a shared
   machine). Also compared: pairs, manifolds and contact points (equal when nothing is
   fast). (A tree whose scenes.py has no ``--substeps`` runs its one substep.)

Run it from the repository root with this tree's rbgen first on the path
(``PYTHONPATH=. python benchmarks/continuous.py``). Writes a JSON and Markdown record
(`rbgen.bench`, kind "continuous") under ``--out`` (default benchmarks/results; '' for
none).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

import numpy as np

from rbgen import bench

ROOT = Path(__file__).resolve().parent.parent
DT = 1 / 60
R = 0.05
SPEEDS = (10.0, 50.0, 100.0, 200.0)
WALLS = ("plane", 0.01, 0.05, 0.10, 0.50)  # full thicknesses of the static boxes (m)


def reach_past_face(world, body, kind) -> float:
    """How far the body's surface reaches past z = 0 (sphere: z + r; box: its corners)."""
    z = float(world.positions[body, 2])
    if kind == "sphere":
        return z + R
    x, y, zq, w = world.orientations[body].astype(np.float64)
    row = np.array([2 * (x * zq - w * y), 2 * (y * zq + w * x), 1 - 2 * (x * x + y * y)])
    corners = np.array([[i, j, k] for i in (-R, R) for j in (-R, R) for k in (-R, R)])
    return z + float(np.max(corners @ row))


def shoot(device, kind, speed, wall):
    """(deepest reach past the face, centre ended beyond it)."""
    import rbgen

    world = rbgen.World(device, gravity=(0, 0, 0))
    if wall == "plane":
        world.add_static(rbgen.Plane((0, 0, -1), 0.0))
    else:
        world.add_static(rbgen.Box((5, 5, wall / 2)), position=(0, 0, wall / 2))
    shape = rbgen.Sphere(R) if kind == "sphere" else rbgen.Box((R, R, R))
    body = world.add_body(shape, mass=1.0, position=(0, 0, -1 - R), linear_velocity=(0, 0, speed))
    deepest = -np.inf
    for _ in range(20):
        world.step(DT)
        deepest = max(deepest, reach_past_face(world, body, kind))
    return deepest, bool(world.positions[body, 2] > 0.0)


def tunnelling(device) -> list[dict]:
    from rbgen.pipeline import prepare

    # (the same bound for an rbgen without continuous collision, e.g. the baseline's tree
    # on PYTHONPATH, so that its table can be printed too)
    fast_fraction = getattr(prepare, "FAST_FRACTION", 0.5)
    rows = []
    print(f"{'wall':>10} {'body':>7} " + " ".join(f"{f'{v:g} m/s':>14}" for v in SPEEDS))
    for wall in WALLS:
        for kind in ("sphere", "box"):
            cells = []
            for speed in SPEEDS:
                deepest, through = shoot(device, kind, speed, wall)
                holds = not through and deepest <= fast_fraction * R
                cells.append(f"{1e3 * deepest:+8.2f} mm{' through' if through else ''}")
                rows.append(
                    {
                        "wall": wall if wall == "plane" else f"box {100 * wall:g} cm",
                        "body": kind,
                        "speed": speed,
                        "deepest_m": deepest,
                        "through": through,
                        "holds": holds,
                    }
                )
            name = wall if wall == "plane" else f"box {100 * wall:g}cm"
            print(f"{name:>10} {kind:>7} " + " ".join(f"{c:>14}" for c in cells), flush=True)
    return rows


def export_tree(revision: str, into: Path) -> Path:
    """``revision``'s rbgen and benchmarks, written under ``into`` (git archive); a
    directory holding them (a machine without the repository's history) is used as it is."""
    if (Path(revision) / "rbgen").is_dir():
        return Path(revision).resolve()
    into.mkdir(parents=True, exist_ok=True)
    archive = into / "tree.tar"
    with open(archive, "wb") as out:
        subprocess.run(
            ["git", "-C", str(ROOT), "archive", revision, "rbgen", "benchmarks"],
            stdout=out,
            check=True,
        )
    tree = into / revision
    with tarfile.open(archive) as tar:
        tar.extractall(tree, filter="data")
    return tree


#: (velocity, position) sweeps of the BoxBox timing, at one substep, in both trees
EFFORT = (10, 4)


def time_boxbox(tree: Path, args) -> dict:
    """benchmarks/scenes.py of ``tree`` in its own process: its BoxBox result."""
    with tempfile.TemporaryDirectory() as out:
        command = [sys.executable, "benchmarks/scenes.py", "--sizes", str(args.size)]
        command += ["--steps", str(args.steps), "--warmup", str(args.warmup), "--out", out]
        # one effort for both trees (a baseline from before substepping has one substep and
        # no --substeps): what differs is then only continuous collision
        command += ["--iterations", str(EFFORT[0]), "--position-iterations", str(EFFORT[1])]
        if "--substeps" in (tree / "benchmarks" / "scenes.py").read_text():
            command += ["--substeps", "1"]
        if args.device is not None:
            command += ["--device", str(args.device)]
        # (the tree's own rbgen first, whatever rbgen the interpreter has installed)
        path = os.pathsep.join(p for p in (str(tree), os.environ.get("PYTHONPATH")) if p)
        env = {**os.environ, "PYTHONPATH": path}
        subprocess.run(command, cwd=tree, env=env, check=True, stdout=subprocess.DEVNULL)
        (path,) = Path(out).glob("*.json")
        return json.loads(path.read_text())["results"][0]


def cost(args) -> dict:
    with tempfile.TemporaryDirectory() as scratch:
        baseline_tree = export_tree(args.baseline, Path(scratch) / "baseline")
        timed_tree = export_tree(args.tree, Path(scratch) / "tree")
        runs: dict[str, list] = {"baseline": [], "timed": []}
        for round_ in range(args.rounds):
            for name, tree in (("baseline", baseline_tree), ("timed", timed_tree)):
                result = time_boxbox(tree, args)
                runs[name].append(result)
                print(
                    f"round {round_ + 1}: {name:>9} {result['ms']:8.2f} ms/step (fastest block "
                    f"{min(result['ms_blocks']):.2f}), pairs "
                    f"{result['pairs']:,}, manifolds {result['manifolds']:,}, points "
                    f"{result['contacts']:,}",
                    flush=True,
                )
    times = {name: [r["ms"] for r in rs] for name, rs in runs.items()}
    base, this = (statistics.median(times[n]) for n in ("baseline", "timed"))
    # (on a shared machine the fastest block of all rounds is the least disturbed)
    fastest = {name: min(min(r["ms_blocks"]) for r in rs) for name, rs in runs.items()}
    same_contacts = all(
        runs["baseline"][0][k] == runs["timed"][0][k] for k in ("pairs", "manifolds", "contacts")
    )
    print(
        f"BoxBox {args.size}: baseline ({args.baseline}) {base:.2f} ms/step "
        f"[{min(times['baseline']):.2f}, {max(times['baseline']):.2f}], {args.tree} {this:.2f} "
        f"[{min(times['timed']):.2f}, {max(times['timed']):.2f}], ratio "
        f"{this / base:.3f}; fastest blocks {fastest['baseline']:.2f} and "
        f"{fastest['timed']:.2f} (ratio {fastest['timed'] / fastest['baseline']:.3f}); "
        f"same pairs, manifolds and points: {same_contacts}"
    )
    return {
        "name": f"boxbox {args.size}",
        "ms": this,
        "ms_spread": [min(times["timed"]), max(times["timed"])],
        "baseline": {
            "name": f"{args.baseline} (no continuous collision)",
            "ms": base,
            "ms_spread": [min(times["baseline"]), max(times["baseline"])],
        },
        "ratio": this / base,
        "tree": args.tree,
        "fastest_block_ms": fastest,
        "same_contacts": same_contacts,
        "runs": {name: [r["ms"] for r in rs] for name, rs in runs.items()},
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="rbgen device choice (index or name)")
    parser.add_argument(
        "--baseline",
        default="06bc3af",
        help="git revision (or a directory with its rbgen/ and benchmarks/) to compare with",
    )
    parser.add_argument(
        "--tree",
        default="652f79d",
        help="git revision (or a directory with its rbgen/ and benchmarks/; '.': this tree) "
        "to time against the baseline",
    )
    parser.add_argument("--size", type=int, default=8000, help="BoxBox boxes")
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--warmup", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--skip-cost", action="store_true", help="only the tunnelling table")
    bench.add_out_argument(parser)
    args = parser.parse_args(argv)

    table = tunnelling(args.device)
    tunnel_ok = all(r["holds"] for r in table)
    print(f"tunnelling: {'holds' if tunnel_ok else 'FAILS'} ({len(table)} cases)")
    results = [
        {
            "name": "tunnelling",
            "ms": 0.0,
            "ms_spread": [0.0, 0.0],
            "baseline": None,
            "holds": tunnel_ok,
            "cases": table,
        }
    ]
    if not args.skip_cost:
        results.append(cost(args))
    if args.out:
        record = bench.make_record(
            "continuous",
            results,
            bench.device_record(args.device),
            {"dt": DT, "size": args.size, "steps": args.steps, "rounds": args.rounds},
        )
        print(f"wrote {bench.write_results(record, args.out)}")
    return 0 if tunnel_ok else 1


if __name__ == "__main__":
    sys.exit(main())
