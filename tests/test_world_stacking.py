"""Stacking at dt = 1/60 with the World's default substeps and sweeps (GPU: 8 substeps of
2 + 1; CPU: 4 substeps of 3 + 1 with the block normal solve).

* A 20-row pyramid of unit boxes (210 boxes, 2 cm gaps within a row) holds:
  its top box moves < 1 cm over 600 steps (issue 24's bar).
* A loose grid of boxes (1.5 m pitch, +-5 cm jitter) dropped on the ground comes to rest: max speed
  < 0.05 m/s by step 300 and no box sunk more than 2 cm into the ground
  (bottom face above y = -0.02). Both batching modes. The 8,000-box version is a benchmark
  (benchmarks/scenes.py, examples/box_pile.py); this is a 4 x 4 x 4 one.
* Global batching holds a 30-layer BoxBox lattice off the ground (< 5 mm), and with the
  fast-math solver it stays finite.
The pyramid and the dropped grid run every batching mode with the device's default
solver build, and global and slabs batching (a GPU's and a CPU's default) also with the
solver built with -cl-fast-relaxed-math (``fast_math``, the GPU default), so that a CPU
checks that build too.
"""

from __future__ import annotations

import numpy as np
import pytest

import rbgen
from rbgen.pipeline.batching import MODES as BATCHINGS
from rbgen.scenes import boxbox_scene, pile_positions, pyramid_positions
from rbgen.world import World

DT = 1 / 60


#: (batching, fast_math): every mode with the device's default build (None), and the
#: GPU's and the CPU's default modes with the fast-math build
STACKING_CASES = [(mode, None) for mode in BATCHINGS] + [("global", True), ("slabs", True)]
STACKING_IDS = [f"{mode}-{'fast' if fast else 'default'}" for mode, fast in STACKING_CASES]


@pytest.mark.gpu_shape
@pytest.mark.parametrize("batching, fast_math", STACKING_CASES, ids=STACKING_IDS)
def test_pyramid_of_20_rows_holds(runtime, batching, fast_math, request):
    """Issue 24's bar: the top box moves < 1 cm in 600 steps at the default efforts (PoCL,
    CPU default: 0.71-0.75 cm on global and slabs; the H200's shape: 0.33-0.56 cm)."""
    if not runtime.traits.is_gpu and batching == "cells":
        request.applymarker(
            pytest.mark.xfail(
                strict=True,
                reason="issue 24: the CPU default 4 x (3 + 1) on cells batching (not a CPU's "
                "default batching) lets the top move 1.10 cm",
            )
        )
    world = World(runtime, batching=batching, fast_math=fast_math)
    world.add_static(rbgen.Box((50, 1, 50)), position=(0, -1, 0))
    ids = world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, positions=pyramid_positions(20))
    top = ids[-1]
    start = world.positions[top]
    for _ in range(600):
        world.step(DT)
    assert np.linalg.norm(world.positions[top] - start) < 0.01
    if batching == "global":
        assert world.statistics()["groups_used"] == 1  # one connected pile: one work group
    else:
        assert world.statistics()["groups_used"] > 1


def drop_grid(world, seed=1):
    """The ground and 4 x 4 x 4 unit boxes at 1.5 m pitch, +-5 cm jitter: the boxes' ids."""
    world.add_static(rbgen.Box((50, 1, 50)), position=(0, -1, 0))
    positions = pile_positions(64, layers=4, jitter=0.05, seed=seed)
    return world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, positions=positions)


#: (batching, fast_math) cases where a box at a stack top keeps rocking under the block
#: normal solve at the device's default substeps, per device kind: the CPU's 4 of 3 + 1
#: sweeps off slabs (max speed at step 300 on PoCL: global 0.060, cells 0.140, global with
#: fast math 0.060 m/s), the GPU's 8 of 2 + 1 off global batching (in the H200's shape:
#: cells 0.204, slabs 0.287 m/s)
ROCKING = {
    "cpu": {("global", None), ("cells", None), ("global", True)},
    "gpu": {("cells", None), ("slabs", None), ("slabs", True)},
}


@pytest.mark.gpu_shape
@pytest.mark.parametrize("batching, fast_math", STACKING_CASES, ids=STACKING_IDS)
def test_dropped_grid_comes_to_rest(request, runtime, batching, fast_math):
    """A fixed jitter (seed 1). Measured over seeds 0-7 on PoCL at 1 substep of 10 + 4
    (max speed at step 300): components and slabs 0.000 for all eight; cells (cpu shape,
    block solve) 0.088 and 0.244 for seeds 0 and 6, 0.000 for the others: a box at a stack
    top can keep rocking under the block solve there (a known limit, reported with issue #6
    for later work), so this miniature is a regression check of one scene, not proof that
    every jitter settles. With the devices' default substeps the block rocks this seed too
    off their default batching (`ROCKING`)."""
    if (batching, fast_math) in ROCKING[runtime.traits.kind]:
        request.applymarker(
            pytest.mark.xfail(
                strict=True,
                reason="block normal solve at the device's default substeps (few sweeps "
                "each) leaves a box rocking off the device's default batching (issue #6's "
                "limit; issue 24: piles must settle)",
            )
        )
    world = World(runtime, batching=batching, fast_math=fast_math)
    ids = drop_grid(world)
    for _ in range(300):
        world.step(DT)
    speeds = np.linalg.norm(world.linear_velocities[ids], axis=1)
    assert speeds.max() < 0.05
    # lowest corner of every box above -2 cm
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    q = world.orientations[ids]
    lowest = []
    for p, (x, y, z, w) in zip(world.positions[ids], q):
        rot = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
        lowest.append((p + corners @ rot.T)[:, 1].min())
    assert min(lowest) > -0.02
    assert np.all(np.isfinite(world.positions))


def test_global_batching_holds_a_tall_lattice_off_the_ground(runtime):
    """The BoxBox lattice 30 layers tall (6 x 30 x 6 boxes, each on 4 below): global
    batching's first-fit colouring puts every ground contact in batch 0, and the solver
    walks the batches from the highest down, so the ground rows come after the weight
    above has been passed down. Walked upwards instead, the bottom boxes sank 1.3-2.1 cm
    into the ground over 120 steps on PoCL; walked downwards 0.07 cm. No bottom face
    more than 5 mm under the ground (centre below y = 0.995) over 60 steps."""
    scene = boxbox_scene(6, 30, 6)
    world = World(runtime, batching="global")
    world.add_static(rbgen.Box(scene.ground_half_extents), position=scene.ground_position)
    ids = world.add_bodies(
        rbgen.Box(scene.half_extents), mass=scene.mass, positions=scene.positions
    )
    lowest = np.inf
    for step in range(60):
        world.step(DT)
        if step % 10 == 9:
            lowest = min(lowest, float(world.positions[ids][:, 1].min()))
    assert lowest > 1.0 - 0.005
    assert world.statistics()["batches"] <= 9  # the lattice's 8 contacts a box: 8 colours
    assert np.all(np.isfinite(world.positions))


@pytest.mark.gpu_shape
def test_global_batching_with_the_fast_math_solver_stays_finite(runtime):
    """The same 30-layer lattice, global batching, the solver built with
    -cl-fast-relaxed-math (the GPU default): every body finite after three steps. The
    friction clamp limit / sqrt(|f|^2) became limit * rsqrt(|f|^2) in PoCL's fast-math
    build, infinite for a denormal |f|^2 (flushed to zero) and NaN with the limit 0 of a
    point that does not push: 147 of 1,080 velocities NaN in the first step, from 6
    sweeps on (NVIDIA's build ran these lattices finite)."""
    scene = boxbox_scene(6, 30, 6)
    world = World(runtime, batching="global", fast_math=True)
    world.add_static(rbgen.Box(scene.ground_half_extents), position=scene.ground_position)
    world.add_bodies(rbgen.Box(scene.half_extents), mass=scene.mass, positions=scene.positions)
    for _ in range(3):
        world.step(DT)
    assert np.all(np.isfinite(world.positions)) and np.all(np.isfinite(world.linear_velocities))
