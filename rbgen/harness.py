"""Named scenes run through the World, with timing and a sanity summary.

`run_scene` is what ``rbgen run SCENE`` / ``rbgen demo``, the examples and
``benchmarks/scenes.py`` call, so a number printed by one means the same as
in the others. Scenes:

``box_pile``  ``n`` unit boxes dropped in a loose grid (5 layers, 1.5 m
              pitch, 1 cm jitter) onto a static ground slab: they land in
              columns of 5 and should be at rest by step 300;
``boxbox``    Bullet3's BoxBox lattice (rbgen.scenes; ``n`` one of its
              standard sizes, or any n, rounded to a cube);
``pyramid``   a 2-D pyramid of unit boxes with ``n`` rows (2 cm gaps);
``ragdolls``  ``n`` ragdolls (11 bodies, 10 joints each: `rbgen.ragdolls`) standing in a
              grid (1 m x 0.6 m pitch) 1.4 m above a pile of unit boxes (one per
              four ragdolls, on the ground) and dropped; 4 solver substeps of 5 + 2
              sweeps unless the World options say otherwise (`RAGDOLL_SETTINGS`);
``terrain``   ``n`` mixed bodies (boxes, hulls, compounds, a tenth spheres and
              capsules) rained in 4 layers onto a procedural terrain of
              2 x 1000^2 triangles (``terrain_cells=`` among the World options picks
              another size; rbgen.scenes.terrain_heights); its "sunk" counts bodies
              fallen below the terrain's lowest point.

Timing: the timed steps are enqueued back to back as in a simulation loop
(the host checks a step's overflow report two steps later, so it never drains
the queue, and it runs at most two steps ahead of the device) and end with
one ``queue.finish()``. They are clocked in `TIMING_BLOCKS` blocks by the
host's clock at the block boundaries (in steady state the host is the same
number of steps ahead at every boundary, so a block's time is the device's);
ms/step is the median block's time per step, robust to a block that a
neighbour on the machine slowed, and the mean of all is kept too. A
``queue.finish()`` per block would cost each block a refill of the pipeline,
which small scenes on a GPU would show. With ``progress`` a line after
each block reads the velocities back, which drains the queue; its time is
left out of both blocks.
Warm-up steps build and load the kernels.
"""

from __future__ import annotations

import time

import numpy as np

from . import sanity
from . import scenes as scene_data
from .errors import RbgenError
from .launch import launches_by_kernel
from .shapes import Box
from .world import World

SCENES = ("box_pile", "boxbox", "pyramid", "ragdolls", "terrain")

#: the ragdolls scene's solver settings unless the World options say otherwise (README:
#: joint guidance): 4 substeps of 5 velocity and 2 push sweeps (the stiffness comes from
#: the substeps; the default 10 + 4 sweeps a substep settle the pile no better)
RAGDOLL_SETTINGS = {"substeps": 4, "iterations": 5, "position_iterations": 2}

#: the timed steps are clocked in this many blocks (see the module docstring);
#: ms_per_step is the median block's (a block that a neighbour on the machine slowed
#: does not move it)
TIMING_BLOCKS = 10

#: layers of the box_pile grid (8,000 boxes: 40 x 5 x 40 at a 1.5 m pitch)
PILE_LAYERS = 5


def build_scene(name: str, n: int, device=None, **world_options):
    """(world, ids of the dynamic boxes, ground top height, box half extent)."""
    if name not in SCENES:
        raise RbgenError(f"unknown scene {name!r}; choose one of {list(SCENES)}")
    if not isinstance(n, (int, np.integer)) or n < 1:
        raise RbgenError(f"scene size n must be a positive integer, got {n!r}")
    if name == "terrain":
        return _terrain_scene(int(n), device, **world_options)
    if name == "ragdolls":
        return _ragdoll_scene(int(n), device, **world_options)
    world = World(device, **world_options)
    if name == "boxbox":
        if int(n) in scene_data.STANDARD_BOXBOX_DIMS:
            scene = scene_data.standard_boxbox_scene(int(n))
        else:
            side = max(1, round(n ** (1 / 3)))
            scene = scene_data.boxbox_scene(side, side, side)
        world.add_static(Box(scene.ground_half_extents), position=scene.ground_position)
        ids = world.add_bodies(Box(scene.half_extents), mass=scene.mass, positions=scene.positions)
        return world, ids, float(scene.ground_offset), float(scene.half_extents[1])
    if name == "box_pile":
        positions = scene_data.pile_positions(int(n), PILE_LAYERS)
        side = int(np.ceil(np.sqrt(n / min(PILE_LAYERS, int(n)))))
        extent = 1.5 * side / 2 + 10
        world.add_static(
            Box((extent, 1, extent)), position=(1.5 * (side - 1) / 2, -1, 1.5 * (side - 1) / 2)
        )
        ids = world.add_bodies(Box((0.5, 0.5, 0.5)), mass=1.0, positions=positions)
        return world, ids, 0.0, 0.5
    rows = int(n)
    positions = scene_data.pyramid_positions(rows)
    world.add_static(Box((rows + 10, 1, 10)), position=(0, -1, 0))
    ids = world.add_bodies(Box((0.5, 0.5, 0.5)), mass=1.0, positions=positions)
    return world, ids, 0.0, 0.5


def ragdoll_origins(n: int) -> np.ndarray:
    """Pelvis centres of ``n`` ragdolls in a square grid (1 m x 0.6 m pitch), their soles
    1.4 m above the top of the box pile (2 m above the ground)."""
    side = int(np.ceil(np.sqrt(n)))
    i = np.arange(n)
    from .ragdolls import BELOW_PELVIS

    return np.stack([1.0 * (i % side), np.full(n, 2.4 + BELOW_PELVIS), 0.6 * (i // side)], 1)


def _ragdoll_scene(n: int, device, ragdoll_joints: bool = True, **world_options):
    """The ragdolls scene (see the module docstring): (world, dynamic ids, 0, the thinnest
    part's radius). ``ragdoll_joints=False``: the same bodies without their joints (the
    benchmarks' baseline: what the joints cost)."""
    from .ragdolls import add_ragdolls

    world_options = {**RAGDOLL_SETTINGS, **world_options}
    world = World(device, **world_options)
    origins = ragdoll_origins(n)
    low, high = origins.min(axis=0), origins.max(axis=0)
    centre = (low + high) / 2
    extent = max(high[0] - low[0], high[2] - low[2]) / 2 + 10
    world.add_static(Box((extent, 1, extent)), position=(centre[0], -1, centre[2]))
    # one unit box under every second ragdoll of every second row
    under = origins[(np.arange(n) % 2 == 0) & ((np.arange(n) // int(np.ceil(np.sqrt(n)))) % 2 == 0)]
    boxes = world.add_bodies(
        Box((0.5, 0.5, 0.5)),
        mass=1.0,
        positions=np.c_[under[:, 0], np.full(len(under), 0.5), under[:, 2]],
    )
    bodies, _ = add_ragdolls(world, origins, joints=bool(ragdoll_joints))
    return world, np.concatenate([boxes, bodies.reshape(-1)]), 0.0, 0.045


def terrain_shapes() -> list:
    """The terrain scene's bodies, in the order of their shares of the rain: a box, a
    hull, a table (a compound of a top on four legs), a dumbbell (two spheres on a bar),
    a sphere and a capsule."""
    from .compound import Compound
    from .shapes import Capsule, ConvexHull, Sphere

    rng = np.random.default_rng(7)
    legs = [(Box((0.04, 0.2, 0.04)), (x * 0.3, -0.2, z * 0.2)) for x in (-1, 1) for z in (-1, 1)]
    return [
        Box((0.35, 0.25, 0.3)),
        ConvexHull(rng.normal(size=(14, 3)) * (0.35, 0.25, 0.3), name="rock"),
        Compound([(Box((0.4, 0.04, 0.3)), (0, 0.02, 0))] + legs, name="table"),
        Compound(
            [
                (Sphere(0.2), (-0.4, 0, 0)),
                (Sphere(0.2), (0.4, 0, 0)),
                (Box((0.35, 0.05, 0.05)), (0, 0, 0)),
            ],
            name="dumbbell",
        ),
        Sphere(0.3),
        Capsule(0.2, 0.25),
    ]


#: the shares of `terrain_shapes` in the rain (round shapes roll, so few of them)
TERRAIN_SHARES = (0.3, 0.3, 0.15, 0.15, 0.05, 0.05)


def _terrain_scene(
    n: int,
    device,
    terrain_cells: int = scene_data.TERRAIN_CELLS,
    terrain_ground: str = "mesh",
    **world_options,
):
    """The terrain scene; ``terrain_ground="plane"``: the same rain onto a plane at the
    terrain's lowest height instead (the benchmarks' baseline)."""
    from .mesh import TriangleMesh
    from .shapes import Plane

    if terrain_ground not in ("mesh", "plane"):
        raise RbgenError(f"terrain_ground must be 'mesh' or 'plane', got {terrain_ground!r}")
    heights = scene_data.terrain_heights(terrain_cells)
    world = World(device, **world_options)
    if terrain_ground == "mesh":
        vertices, triangles = scene_data.height_field(heights)
        world.add_static(TriangleMesh(vertices, triangles, name="terrain"))
    else:
        world.add_static(Plane((0, 1, 0), float(heights.min())))
    positions = scene_data.rain_positions(n, heights)
    kinds = np.random.default_rng(1).choice(len(TERRAIN_SHARES), n, p=TERRAIN_SHARES)
    orientations = np.random.default_rng(2).normal(size=(n, 4))
    orientations /= np.linalg.norm(orientations, axis=1, keepdims=True)
    ids: list = []
    for k, shape in enumerate(terrain_shapes()):
        chosen = np.flatnonzero(kinds == k)
        if len(chosen):
            ids.append(
                world.add_bodies(
                    shape, mass=1.0, positions=positions[chosen], orientations=orientations[chosen]
                )
            )
    return (
        world,
        np.sort(np.concatenate(ids)) if ids else np.zeros(0, int),
        float(heights.min()) - 1.0,
        0.0,
    )


def run_scene(
    name: str,
    n: int,
    steps: int,
    device=None,
    progress: bool = True,
    *,
    warmup: int = 0,
    dt: float = 1 / 60,
    on_step=None,
    **world_options,
) -> dict:
    """Build scene ``name`` of size ``n``, run ``warmup`` then ``steps`` steps; return a summary.

    The summary: device, bodies, steps, ms_per_step (the median of the ms/step of
    `TIMING_BLOCKS` blocks of steps, each ending when its steps have run, so that no block
    carries another's work; ms_per_step_mean: the mean of all), launches and
    blocking_reads per step (of the last step), pairs / manifolds / contacts / batches of the last
    step, the batching, solver and normal solve it used with the release sweeps (0 for a
    sequential normal solve, None: every sweep), the broadphase's algorithm at the end,
    plan_fallbacks (choices given up during the run), launches_by_kernel (of the last step),
    overflows (redone steps) and overflows_by_stage, and sanity: nans, sunk (boxes whose
    centre is more than 2 cm below its resting height), max_speed (m/s), and
    last_box_moved (m; the top box of a pyramid), with displaced and layer_drop
    (`rbgen.sanity.settling`); ms_per_step_blocks: each block's ms/step, and
    batches_blocks / manifolds_blocks: the colours and manifolds of each block's last step
    (read after its clock stopped).

    ``on_step(world, step)``, if given, is called before the first timed step (step 0)
    and after each timed step (step 1, 2, ...), inside the timing blocks, so that what
    it costs (a recorder's copy of the transforms, `rbgen.record.record_hook`) shows in
    ms_per_step.
    """
    world, ids, ground_top, half = build_scene(name, n, device, **world_options)
    queue = world.runtime.queue
    start = world.positions[ids]
    top_start = start[-1] if len(ids) else np.zeros(3)
    if progress:
        print(f"{name}: {len(ids):,} boxes on {world.runtime.traits.describe()}", flush=True)
    for _ in range(int(warmup)):
        world.step(dt)
    queue.finish()
    block = max(1, int(steps) // TIMING_BLOCKS)
    blocks = []  # (seconds, steps) of each block (the last may be shorter)
    block_counts = []  # (batches, manifolds) of each block's last step
    if on_step is not None:
        on_step(world, 0)
    block_start = time.perf_counter()
    by_kernel: dict[str, int] = {}
    for s in range(int(steps)):
        if s + 1 == steps:  # (the last step's launches by kernel name: a driver query each)
            with launches_by_kernel(world.runtime) as by_kernel:
                world.step(dt)
        else:
            world.step(dt)
        if on_step is not None:
            on_step(world, s + 1)
        if (s + 1) % block == 0 or s + 1 == steps:
            # the block's steps have all run when its clock stops (else the read-backs
            # below, outside the clock, would hide the steps still in flight)
            queue.finish()
            now = time.perf_counter()
            blocks.append((now - block_start, s % block + 1))
            # (after the clock stopped: small reads, the counts of the block's last step,
            # to set beside its time: a step's cost follows its colours and manifolds)
            counts = world.statistics(contacts=False)
            block_counts.append((counts["batches"], counts["manifolds"]))
            if progress:
                speed = np.linalg.norm(world.linear_velocities[ids], axis=1).max()
                print(
                    f"  step {s + 1:5d}: {1e3 * blocks[-1][0] / blocks[-1][1]:8.2f} ms/step, "
                    f"max speed {speed:.3f} m/s",
                    flush=True,
                )
            block_start = time.perf_counter()
    block_ms = [1e3 * seconds / count for seconds, count in blocks]
    elapsed = sum(seconds for seconds, _ in blocks)  # (without the progress read-backs)
    stats = world.statistics()
    positions = world.positions[ids]
    velocities = world.linear_velocities[ids]
    speeds = np.linalg.norm(velocities, axis=1)
    summary = {
        "scene": name,
        "device": world.runtime.traits.device_name,
        "bodies": len(ids),
        "steps": int(steps),
        "ms_per_step": float(np.median(block_ms)) if block_ms else 0.0,
        "ms_per_step_mean": 1e3 * elapsed / max(1, int(steps)),
        "launches_per_step": stats["launches"],
        "blocking_reads_per_step": stats["blocking_reads"],
        "pairs": stats["pairs"],
        "manifolds": stats["manifolds"],
        "contacts": stats["contacts"],
        "batches": stats["batches"],
        "groups_used": stats["groups_used"],
        "batching": stats["batching"],
        "solver": stats["solver"],
        "normal_solve": stats["normal_solve"],
        # (only a block normal solve releases points; a sequential one has no release sweeps)
        "release_sweeps": world.release_sweeps,
        "plan": world.plan.describe(),
        # choices the World gave up during the run (`World.fallbacks`; `stats["broadphase"]`
        # says why the broadphase did)
        "plan_fallbacks": world.fallbacks,
        "broadphase": stats["broadphase"],
        # the last step's launches by kernel name (they add up to launches_per_step)
        "launches_by_kernel": dict(sorted(by_kernel.items())),
        # the effort the step ran at (the World's defaults unless the options said otherwise)
        "substeps": world.substeps,
        "iterations": world.iterations,
        "position_iterations": world.position_iterations,
        "overflows": world.overflows,
        "overflows_by_stage": world.overflows_by_stage,
        "nans": int(np.isnan(positions).any(axis=1).sum()),
        "sunk": int((positions[:, 1] < ground_top + half - 0.02).sum()),
        "max_speed": float(speeds.max()) if len(speeds) else 0.0,
        "last_box_moved": float(np.linalg.norm(positions[-1] - top_start)) if len(ids) else 0.0,
        "ms_per_step_blocks": block_ms,
        "batches_blocks": [b for b, _ in block_counts],
        "manifolds_blocks": [m for _, m in block_counts],
        # displaced, layer_drop, moving (of the boxes built at rest that do not overhang)
        **sanity.settling(start, positions, velocities, _resting(name, start, half)),
    }
    if progress:
        print(format_summary(summary), flush=True)
    return summary


def _resting(name: str, start: np.ndarray, half: float):
    """The boxes of scene ``name`` that should rest (`rbgen.sanity.settling`'s ``resting``):
    those that do not overhang (cubes of half extent ``half``: `rbgen.sanity.overhanging`);
    None (every body) for a scene built in the air, whose count is shown but not judged."""
    if name in sanity.DROPPED_SCENES:
        return None
    return ~sanity.overhanging(start, np.full(3, half))


def format_summary(s: dict) -> str:
    return (
        f"{s['scene']} {s['bodies']:,} bodies: {s['ms_per_step']:.2f} ms/step, "
        f"{s['launches_per_step']} launches and {s['blocking_reads_per_step']} blocking reads "
        f"per step; {s['pairs']:,} pairs, {s['manifolds']:,} manifolds, {s['contacts']:,} "
        f"contact points, "
        + (
            f"{s['batches']} batches in the largest group ({s['batching']} batching)"
            if s["solver"] == "pgs"
            else "Jacobi solver, no batching"
        )
        + f"; sanity: NaNs {s['nans']}, "
        f"sunk {s['sunk']}, {sanity.displaced_text(s['scene'], s.get('displaced', 0))}"
        f"{sanity.moving_text(s['scene'], s.get('moving'))}, max speed {s['max_speed']:.3f} m/s, "
        f"overflows {s['overflows']}, "
        f"last box moved {100 * s['last_box_moved']:.2f} cm"
        + _layer_drops(sanity.holding_drops(s["scene"], s.get("layer_drop")))
    )


def _layer_drops(drops: list) -> str:
    """The start layers' median drops for the summary line (`rbgen.sanity.holding_drops`:
    none for a dropped scene), in mm as `rbgen.bench` prints them: every layer up to 12
    of them, else the top layer's and the largest (the JSON record keeps them all)."""
    if not drops:
        return ""
    mm = [1e3 * d for d in drops]
    if len(mm) <= 12:
        return ", layer drops (mm, bottom to top) " + " ".join(f"{d:.1f}" for d in mm)
    worst = int(np.argmax(np.abs(mm)))
    return (
        f", layer drops: top {mm[-1]:.1f} mm, largest {mm[worst]:.1f} mm "
        f"(layer {worst + 1} of {len(mm)})"
    )
