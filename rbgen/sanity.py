"""Whether a box scene holds: measures of where its boxes went.

A time counts only for a scene that holds, so every timed scene reports
these beside its ms/step (`rbgen.harness.run_scene`, `rbgen.bench`):

``displaced``   boxes whose centre moved more than `DISPLACED` sideways
                (across gravity, the y axis here) from where it started: a
                lattice, a stack or a settled pile should not spread;
``layer_drop``  per layer of the start (boxes at one height, to 1 cm), the
                median fall of its boxes in metres: the BoxBox lattice rests
                as built, so every layer's drop should stay near zero, and a
                layer that sinks into the one below shows here first.
"""

from __future__ import annotations

import numpy as np

#: metres a box may move sideways before it counts as displaced
DISPLACED = 0.5
#: start heights closer than this (m) are one layer
LAYER_TOLERANCE = 0.01
#: scenes built in the air (their layers' drops are the fall, not a failure to hold)
DROPPED_SCENES = ("box_pile", "ragdolls", "terrain")
#: scenes whose bodies fall and spread as they land (a body moved sideways is no failure)
SPREADING_SCENES = ("ragdolls",)


def settling(start: np.ndarray, end: np.ndarray) -> dict:
    """``{"displaced": int, "layer_drop": [median fall (m) of each start layer, lowest
    first]}`` of boxes from ``start`` to ``end`` ((N, 3) centres, y up)."""
    start = np.asarray(start, float).reshape(-1, 3)
    end = np.asarray(end, float).reshape(-1, 3)
    if len(start) == 0:
        return {"displaced": 0, "layer_drop": []}
    sideways = np.hypot(end[:, 0] - start[:, 0], end[:, 2] - start[:, 2])
    displaced = int(np.sum(~(sideways <= DISPLACED)))  # (a NaN counts as displaced)
    heights = np.round(start[:, 1] / LAYER_TOLERANCE).astype(np.int64)
    layers, layer_of = np.unique(heights, return_inverse=True)
    drop = start[:, 1] - end[:, 1]
    medians = [float(np.median(drop[layer_of == k])) for k in range(len(layers))]
    return {"displaced": displaced, "layer_drop": medians}


def displaced_text(scene: str, displaced: int) -> str:
    """The displaced count as a summary line shows it: for a scene whose bodies spread by
    design (`SPREADING_SCENES`), counted as moved sideways and marked as not judged, so
    that it does not read as a failure."""
    if scene in SPREADING_SCENES:
        return f"moved sideways {displaced} (not judged: dropped)"
    return f"displaced {displaced}"


def holding_drops(scene: str, drops) -> list[float]:
    """The layer drops (m) that say whether ``scene`` held: none for a scene built in the
    air (`DROPPED_SCENES`), whose layers fall by design."""
    return [] if scene in DROPPED_SCENES else list(drops or [])


def worst_drop_mm(scene: str, drops) -> float | None:
    """The largest layer drop of ``scene`` (by size, in mm), None where drops say nothing."""
    drops = holding_drops(scene, drops)
    return 1e3 * max(drops, key=abs) if drops else None
