"""Broadphase: the pairs of bodies whose world AABBs overlap.

Every algorithm reads the world AABBs (`Aabb` layout) and optional uint32
static flags (1 = static), and fills the same pair buffer (see `pairs`): `Pair`
records (a, b, RB_WHOLE_BODY) with a < b, sorted by (a, b), never two static bodies, with the
count on the device and an overflow protocol that never drops a pair.

Touching rule: boxes are closed. Two AABBs overlap when, on every axis,
``lower_a <= upper_b`` and ``lower_b <= upper_a``; boxes that share only a
face, an edge or a corner are a pair (a box resting on another touches it
exactly, and the narrowphase must see that contact).

Algorithms, chosen per world by name with `make_broadphase` (options in
brackets; every one also takes ``capacity`` and ``work_group_size``):

``"grid"``  uniform grid (grid.py): similar sizes, any density
            [large_factor, fine_factor (owner emission's two levels),
            emission="owner"|"slot",
            bucketing="list" (owner) | "sort"|"count" (slot)];
``"sap"``   one-axis sweep and prune (sap.py): no cell size to choose
            [large_factor, shape="gpu"|"cpu"];
``"sap3"``  incremental three-axis sweep and prune (sap3.py): coherent motion,
            pairs updated from the changes of the sorted axes
            [full="grid"|"sap", full_options, max_moves_per_body].

The query protocol (``enqueue`` / ``check`` / ``find_pairs``) is in base.py,
the pair buffer and its overflow contract in pairs.py.
"""

from __future__ import annotations

from ...errors import RbgenError
from .base import Broadphase
from .grid import GridBroadphase
from .sap import SapBroadphase
from .sap3 import IncrementalSapBroadphase

BROADPHASES = {
    "grid": GridBroadphase,
    "sap": SapBroadphase,
    "sap3": IncrementalSapBroadphase,
}


def make_broadphase(runtime, name: str = "grid", **options) -> Broadphase:
    """A broadphase by name ("grid", "sap", "sap3"); options go to its constructor."""
    try:
        cls = BROADPHASES[name]
    except (KeyError, TypeError):
        raise RbgenError(
            f"unknown broadphase {name!r}; choose one of {sorted(BROADPHASES)}"
        ) from None
    try:
        return cls(runtime, **options)
    except TypeError as err:
        raise RbgenError(f"broadphase {name!r}: bad option ({err})") from None


__all__ = [
    "Broadphase",
    "GridBroadphase",
    "SapBroadphase",
    "IncrementalSapBroadphase",
    "make_broadphase",
    "BROADPHASES",
]
