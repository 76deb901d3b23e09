"""Whether a box scene holds: measures of where its boxes went.

A time counts only for a scene that holds, so every timed scene reports
these beside its ms/step (`rbgen.harness.run_scene`, `rbgen.bench`):

``displaced``   boxes whose centre moved more than `DISPLACED` sideways
                (across gravity, the y axis here) from where it started: a
                lattice, a stack or a settled pile should not spread;
``layer_drop``  per layer of the start (boxes at one height, to 1 cm), the
                median fall of its boxes in metres: the BoxBox lattice rests
                as built, so every layer's drop should stay near zero, and a
                layer that sinks into the one below shows here first;
``moving``      (given the velocities) boxes faster than `RESTING_SPEED` at
                the end, of those that should rest (`overhanging`: the BoxBox
                lattice's edge boxes start with their centres on the edge of
                what holds them, and may topple): a scene that rests as built
                should be still. A stack can keep its layers' heights while
                its boxes fall and are pushed back up every substep (a
                treadmill: positions held, velocities not), which neither
                count above sees.
"""

from __future__ import annotations

import numpy as np

#: metres a box may move sideways before it counts as displaced
DISPLACED = 0.5
#: m/s: a box faster than this is not at rest (the issue's bar for a settled pile, and
#: Box2D v3's sleep threshold)
RESTING_SPEED = 0.05
#: start heights closer than this (m) are one layer
LAYER_TOLERANCE = 0.01
#: scenes built in the air (their layers' drops are the fall, not a failure to hold)
DROPPED_SCENES = ("box_pile", "ragdolls", "terrain")
#: scenes whose bodies fall and spread as they land (a body moved sideways is no failure)
SPREADING_SCENES = ("ragdolls",)


def start_layers(positions: np.ndarray) -> tuple[int, np.ndarray]:
    """How many layers the start ``positions`` ((N, 3), y up) form (heights within
    `LAYER_TOLERANCE`), and each box's layer, lowest 0."""
    heights = np.round(np.asarray(positions, float)[:, 1] / LAYER_TOLERANCE).astype(np.int64)
    layers, layer_of = np.unique(heights, return_inverse=True)
    return len(layers), layer_of


def settling(start: np.ndarray, end: np.ndarray, velocities=None, resting=None) -> dict:
    """``{"displaced": int, "layer_drop": [median fall (m) of each start layer, lowest
    first]}`` of boxes from ``start`` to ``end`` ((N, 3) centres, y up), and with
    ``velocities`` ((N, 3) linear velocities at the end) ``"moving"``: how many of the
    boxes ``resting`` names (an (N,) mask of those that should rest; all by default) are
    faster than `RESTING_SPEED` (a NaN counts as moving)."""
    start = np.asarray(start, float).reshape(-1, 3)
    end = np.asarray(end, float).reshape(-1, 3)
    moving = {}
    if velocities is not None:
        speed = np.linalg.norm(np.asarray(velocities, float).reshape(-1, 3), axis=1)
        judged = np.ones(len(speed), bool) if resting is None else np.asarray(resting, bool)
        moving = {"moving": int(np.sum(~(speed[judged] <= RESTING_SPEED)))}
    if len(start) == 0:
        return {"displaced": 0, "layer_drop": [], **moving}
    sideways = np.hypot(end[:, 0] - start[:, 0], end[:, 2] - start[:, 2])
    displaced = int(np.sum(~(sideways <= DISPLACED)))  # (a NaN counts as displaced)
    layers, layer_of = start_layers(start)
    drop = start[:, 1] - end[:, 1]
    medians = [float(np.median(drop[layer_of == k])) for k in range(layers)]
    return {"displaced": displaced, "layer_drop": medians, **moving}


def overhanging(positions: np.ndarray, half_extents) -> np.ndarray:
    """(N,) mask: the boxes (one size, ``half_extents``, axis-aligned, in layers along y
    as `settling` groups them) whose centre starts on or past the edge of what holds them:
    outside, or on the border of, the bounding rectangle (x, z) of the footprints they
    share with the boxes of the layer below. The lowest layer stands on the ground and
    never overhangs. Such a box balances at best, and may topple: the BoxBox lattice's
    edge rows (`rbgen.scenes.boxbox_scene`) are."""
    positions = np.asarray(positions, float).reshape(-1, 3)
    hx, _, hz = (float(v) for v in np.asarray(half_extents, float).reshape(3))
    result = np.zeros(len(positions), bool)
    if len(positions) == 0:
        return result
    layers, layer_of = start_layers(positions)
    # (one box a cell of 2 hx by 2 hz within a layer: two boxes of one layer closer
    # than that in both x and z would overlap)
    cells = np.floor(positions[:, [0, 2]] / (2 * np.array([hx, hz]))).astype(np.int64)
    tolerance = 1e-6 * max(hx, hz)
    for k in range(1, layers):
        upper = np.flatnonzero(layer_of == k)
        lower = np.flatnonzero(layer_of == k - 1)
        keys = cells[lower, 0] * (1 << 32) + cells[lower, 1]
        order = np.argsort(keys)
        keys, lower = keys[order], lower[order]
        x, z = positions[upper, 0], positions[upper, 2]
        lo = np.stack([np.full(len(upper), np.inf)] * 2, axis=1)
        hi = -lo
        for dx in (-1, 0, 1):
            for dz in (-1, 0, 1):
                want = (cells[upper, 0] + dx) * (1 << 32) + cells[upper, 1] + dz
                at = np.minimum(np.searchsorted(keys, want), len(keys) - 1)
                below = lower[at]
                bx, bz = positions[below, 0], positions[below, 2]
                x0, x1 = np.maximum(x - hx, bx - hx), np.minimum(x + hx, bx + hx)
                z0, z1 = np.maximum(z - hz, bz - hz), np.minimum(z + hz, bz + hz)
                shares = (keys[at] == want) & (x1 - x0 > tolerance) & (z1 - z0 > tolerance)
                lo[shares] = np.minimum(lo[shares], np.stack([x0, z0], 1)[shares])
                hi[shares] = np.maximum(hi[shares], np.stack([x1, z1], 1)[shares])
        inside = (
            (lo[:, 0] + tolerance < x)
            & (x < hi[:, 0] - tolerance)
            & (lo[:, 1] + tolerance < z)
            & (z < hi[:, 1] - tolerance)
        )
        result[upper] = ~inside
    return result


def displaced_text(scene: str, displaced: int) -> str:
    """The displaced count as a summary line shows it: for a scene whose bodies spread by
    design (`SPREADING_SCENES`), counted as moved sideways and marked as not judged, so
    that it does not read as a failure."""
    if scene in SPREADING_SCENES:
        return f"moved sideways {displaced} (not judged: dropped)"
    return f"displaced {displaced}"


def moving_text(scene: str, moving) -> str:
    """The moving count as a summary line shows it ("" where it was not measured): for a
    scene built in the air (`DROPPED_SCENES`) marked as not judged, as its bodies may
    still be landing."""
    if moving is None:
        return ""
    judged = "" if scene not in DROPPED_SCENES else " (not judged: dropped)"
    return f", moving {moving}{judged}"


def holding_drops(scene: str, drops) -> list[float]:
    """The layer drops (m) that say whether ``scene`` held: none for a scene built in the
    air (`DROPPED_SCENES`), whose layers fall by design."""
    return [] if scene in DROPPED_SCENES else list(drops or [])


def worst_drop_mm(scene: str, drops) -> float | None:
    """The largest layer drop of ``scene`` (by size, in mm), None where drops say nothing."""
    drops = holding_drops(scene, drops)
    return 1e3 * max(drops, key=abs) if drops else None
