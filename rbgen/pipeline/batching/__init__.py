"""Constraint batching: no two constraints of a batch share a dynamic body.

PGS solves constraints one after another; on a parallel device the constraints of
one batch are solved at once, which is only correct if none of them touch the same
dynamic body (static bodies never move, so they are ignored).

A batcher colours the step's **constraint edges** (`layouts.CONSTRAINT_EDGE`: two
bodies, an item naming the constraint by kind and index, an inherited colour, a point;
`rbgen.pipeline.constraints` writes them), not the constraints themselves, so that
contacts and every joint kind share the colours and the launches. It lays the edges out
in **groups** (level 1: one per work group of a solver launch, groups of one launch
share no dynamic body) made of **batches** (level 2: edges of a batch share no dynamic
body). After a call its device arrays describe the result: ``order`` (the edges' items
sorted by group, then batch), ``group_batches`` (per group, ``max_batches + 1``
absolute offsets into ``order``) and ``group_batch_count``; ``launch_plan`` lists the
(first group, group count) of each solver launch of a sweep. The solver reads these
directly, so every count stays on the device.

One module per algorithm, chosen by name (`make_batcher`):

``global`` (global_colouring.py)
    One group of all edges, coloured by one persistent launch over every compute unit,
    each edge keeping last step's colour where it still holds; solved by the PGS
    solver's persistent launch. Two launches a step whatever the size.
``cells``, ``slabs`` (spatial.py)
    Harada's spatial groups: cells (8 colours, any pile spreads over the device) or
    slabs across one horizontal axis (2 colours, a stack whole in one group); a
    sweep is one solver launch per colour plus one for the leftovers.

`batch_host` is the sequential greedy reference the device results are tested against.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from ...device import DeviceTraits, Runtime
from ...errors import RbgenError

#: batching algorithms by name (see the module docstring)
#: the spatial algorithms (spatial.py), and every algorithm: global colouring first
SPATIAL_MODES = ("cells", "slabs", "columns")
MODES = ("global",) + SPATIAL_MODES
#: how a solver walks a group (see `rbgen.pipeline.solvers.pgs`): "lanes": a work
#: group's lanes solve a batch together, batch after batch; "serial": one work-item
#: solves its group's constraints in index order (a group is one batch)
SOLVE_FORMS = ("lanes", "serial")


def default_solve_form(traits: DeviceTraits) -> str:
    """lanes on GPUs (thousands of lanes, cheap barriers in a work group); serial on CPUs
    (a core runs one work-item at a time, so Gauss-Seidel proper costs nothing more)."""
    return "lanes" if traits.is_gpu else "serial"


class Batcher(Protocol):
    """What the PGS solver and the World need from a batching algorithm."""

    runtime: Runtime
    #: the algorithm's name (one of MODES)
    mode: str
    #: "lanes" or "serial": the solve form the batches are laid out for
    solve_form: str
    #: batch slots per group (the layout of group_batches); the last is solved serially
    max_batches: int
    group_count: int
    #: (first group, group count) of each solver launch of a sweep
    launch_plan: list[tuple[int, int]]
    #: edge items by group then batch; per group max_batches + 1 offsets into order; and
    #: each group's batch count (device arrays, valid after a call)
    order: Any
    group_batches: Any
    group_batch_count: Any

    def __call__(self, edges, edge_count, bodies, body_count: int, edge_capacity: int) -> None:
        """Enqueue the batching of the first ``edge_count[0]`` constraint edges (a device
        uint32 array(1)); ``edge_capacity`` bounds the count."""

    def configure(self, *, cell_size: float, slab_axis, column_axis=None) -> None:
        """Scene geometry of the spatial algorithms (the others ignore it)."""

    def read_batches(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Host copy of (order, per-group batch offsets, batch counts): blocking reads."""


def make_batcher(runtime: Runtime, mode: str, **options) -> Batcher:
    """The batcher of algorithm ``mode`` (one of MODES); options go to its constructor."""
    from .global_colouring import GlobalBatcher
    from .spatial import SpatialBatcher

    if mode == "global":
        return GlobalBatcher(runtime, **options)
    if mode in SPATIAL_MODES:
        return SpatialBatcher(runtime, mode=mode, **options)
    raise RbgenError(f"batching must be one of {MODES}, got {mode!r}")


def batch_host(body_a, body_b, dynamic) -> np.ndarray:
    """Reference: sequential first-fit colouring; returns the batch of every edge.

    ``dynamic`` is a boolean per body; edges between two static bodies go to batch 0.
    """
    body_a, body_b = np.asarray(body_a), np.asarray(body_b)
    dynamic = np.asarray(dynamic, bool)
    used: dict[int, set[int]] = {}
    batches = np.zeros(len(body_a), np.int64)
    for i, (a, b) in enumerate(zip(body_a, body_b)):
        bodies = [x for x in (int(a), int(b)) if dynamic[x]]
        taken = set().union(*(used.get(x, set()) for x in bodies)) if bodies else set()
        k = 0
        while k in taken:
            k += 1
        batches[i] = k
        for x in bodies:
            used.setdefault(x, set()).add(k)
    return batches


def read_batches(batcher) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Host copy of a batcher's (order, per-group batch offsets, batch counts)."""
    read = batcher.runtime.read
    offsets = read(batcher.group_batches).reshape(batcher.group_count, batcher.max_batches + 1)
    return read(batcher.order), offsets, read(batcher.group_batch_count)
