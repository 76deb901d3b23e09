"""Constraint batching: no two constraints of a batch share a dynamic body.

PGS solves constraints one after another; on a GPU, the constraints of one
batch are solved at the same time, which is only correct if none of them
touch the same dynamic body (static bodies never move, so they are ignored).

Two levels, after Harada's two-level solver:

1. **Groups** (one solver work group each), in one of these modes:

   * ``components``: the components of the contact graph over dynamic
     bodies are found on the device (lock-free union-find); a component goes
     whole to the group its root hashes to. No dynamic body is touched by two
     groups, so the solver needs no synchronisation between work groups: ONE
     launch per step. But a single pile is one group, solved by one work
     group (a bottleneck for 100k boxes on a GPU, one core of a CPU).
   * ``cells`` (Harada): constraints go to spatial cells of 8 colours; the
     cells of one colour share no body (cell size >= body size), so a colour
     runs as one launch over many work groups; bodies are claimed per colour
     and a constraint losing a claim (oversized body) goes to a leftover
     group run alone. 9 launches per sweep, and any pile spreads over
     the whole device.
   * ``global`` (the default on NVIDIA GPUs): one group of all constraints,
     coloured by one launch over every compute unit (``batching_global.cl.mako``:
     the previous step's colour of each body pair where it still holds, then
     Jones-Plassmann rounds with global body marks, a grid barrier between
     phases; the first ``ordered_rounds`` rounds colour first-fit in index
     order, the fewest colours, over as many steps as it takes), for the
     solver's grid variant, whose work groups all take part
     in every batch: one launch for the colouring and one for the solve, and
     the whole device busy (H200 BoxBox 8,000: 0.80 ms a step on 2026-12-03,
     against 3.52 with cells in an earlier run; 111,375: 3.63 against 7.51).
   * ``single`` (the default on other GPUs while every body fits the local memory):
     one group of all constraints, coloured by one work group with its body
     marks in local memory (``batching_single.cl.mako``: one launch), for a
     resident solve (`rbgen.pipeline.solver`) that keeps every velocity in
     local memory: one launch for the whole solve. A 1,000-box scene keeps
     one compute unit busy, but its step is 14 launches instead of 116.
   * ``columns``: cells infinite along gravity (``column_axes``: two unit
     vectors spanning the horizontal plane), 4 colours of their parities: 5
     launches per sweep, and a stack stays whole in one group. For low piles
     (H100: the dropped 8,000-box pile 1.26 ms a step against 1.71 with cells;
     BoxBox 8,000: 5.8 against 6.7 ms), not tall ones (BoxBox 27,000 / 111,375,
     30 / 48 layers: 10.1 / 22.2 ms against 7.7 / 12.4, a column's group
     being long, and more boxes sunk > 2 cm: 188 / 1,912 against 84 / 603).
   * ``slabs`` (the CPU default): the cells are slabs across one horizontal
     axis (``slab_axis``), 2 colours: 3 launches per sweep, a pile spreads
     over a few cores, and a slab holds whole stacks, solved in index order
     by one work-item (measured on PoCL, 20-row pyramid, 600 steps: its top
     moves 2.8 cm with slabs, 2.3 with components, 7.7 with cells, all
     solving the normal rows one after another).
2. **Batches** inside a group (``shape="gpu"``), coloured by one work group
   with barriers (maximal independent sets grown by rounds of
   lowest-priority-wins). The last batch slot takes any remainder and is
   solved by a single lane. With ``shape="cpu"`` the solver runs a group in
   one work-item, so there is no level 2: a group is one batch, its
   constraints listed in index order by a single work-item (deterministic).

`batch_host` is the sequential greedy reference; the device result is
checked against the same invariants in tests. Counts stay on the device.
"""
from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array

from ..codegen import compile_spec, KernelTemplate, Param, power_of_two, work_group_size_param
from ..device import DeviceTraits, Runtime
from ..errors import RbgenError
from .grid import grid_groups, sync_buffer

MODES = ("components", "cells", "columns", "slabs", "single", "global")
#: kernel shapes (match the solver's: see `rbgen.pipeline.solver`)
SHAPES = ("gpu", "cpu")

TEMPLATE = KernelTemplate(
    "pipeline/batching.cl.mako",
    [
        work_group_size_param("lanes of the batching work group (and of the per-item kernels); "
                              "more lanes colour a large group faster"),
        Param("max_batches", power_of_two(2, 4096),
              "batch slots per group; the last slot holds the remainder, solved serially, "
              "so this bounds local memory, not correctness", "a power of two from 2 to 4096"),
        Param("mode", MODES,
              "level 1: components (one solver launch per step, one group per pile), "
              "cells (8 colour launches + leftovers per sweep, piles spread over the device) "
              "or slabs (2 colour launches + leftovers per sweep, piles spread over a few "
              "CPU cores)"),
        Param("shape", SHAPES,
              "gpu: level-2 batches for a work group's lanes; cpu: none (a group is solved by "
              "one work-item), groups listed by a single work-item"),
    ],
    doc="Level-1 groups (contact-graph components, coloured cells or slabs); level-2 batches per "
        "work group.",
    roles={"constraints": "inout", "parent": "inout", "body_owner": "inout",
           "all_body_stamps": "inout", "group_counts": "inout"},
    defaults=lambda traits: {"work_group_size": default_work_group_size(traits),
                             "max_batches": 128, "mode": default_mode(traits),
                             "shape": traits.kind},
)

#: colours of the spatial modes: parity of 3 cell coordinates, or of the slab index
MODE_COLOURS = {"cells": 8, "columns": 4, "slabs": 2}


#: the batch slots of the one-group modes (single, global)
ONE_GROUP_BATCHES = Param("max_batches", power_of_two(2, 4096),
                          "batch slots (the solver's layout of group_batches); the last is "
                          "the serial remainder", "a power of two from 2 to 4096")

SINGLE_TEMPLATE = KernelTemplate(
    "pipeline/batching_single.cl.mako",
    [
        work_group_size_param("lanes of the one work group that colours every constraint"),
        ONE_GROUP_BATCHES,
        Param("max_bodies", lambda v: isinstance(v, int) and 1 <= v <= 1 << 16,
              "bodies whose marks fit the local memory (12 bytes a body); body indices must "
              "stay below it", "an integer from 1 to 65536"),
    ],
    doc="Single mode: one work group colours all constraints (Jones-Plassmann rounds with "
        "local body marks).",
    roles={"constraint_colour": "inout"},
    defaults=lambda traits: {"work_group_size": default_single_work_group_size(traits),
                             "max_batches": 128,
                             "max_bodies": single_capacity(traits)},
)

GLOBAL_TEMPLATE = KernelTemplate(
    "pipeline/batching_global.cl.mako",
    [
        work_group_size_param("lanes of each of the launch's work groups (one per compute unit)"),
        ONE_GROUP_BATCHES,
    ],
    doc="Global mode: one launch over the whole device colours all constraints (the previous "
        "step's colours where they still hold, Jones-Plassmann rounds for the rest, global "
        "body marks and a grid barrier between phases).",
    roles={"constraints": "inout", "constraint_colour": "inout", "pairs": "inout",
           "bids": "inout", "used": "inout", "state": "inout"},
    defaults=lambda traits: {"work_group_size": default_global_work_group_size(traits),
                             "max_batches": 128},
)


def default_global_work_group_size(traits: DeviceTraits) -> int:
    """256 on GPUs (one group per compute unit: the lanes are the device's parallelism);
    64 on CPUs."""
    return min(256 if traits.is_gpu else 64, traits.max_work_group_size)


#: global mode: Jones-Plassmann rounds a step that bid constraint indices (first-fit in
#: index order: BoxBox 1,000 / 8,000 in 8 colours, the fewest their bodies' 8 contacts
#: allow, against 11-12 with hashed bids) before the rest bid hashes, provisionally
#: coloured; the index-order colouring of BoxBox 8,000 (228 rounds) is reached in 4 steps
ORDERED_ROUNDS = 64


#: local bytes per body of the single-mode colouring: a bid and a 64-bit colour mask
SINGLE_BYTES_PER_BODY = 12


#: most bodies single mode is built for, whatever the local memory (CPUs report
#: hundreds of KiB): one work group walking every batch is no way to solve more
SINGLE_MAX_BODIES = 8192


def single_capacity(traits: DeviceTraits) -> int:
    """Bodies whose colouring marks fit the local memory (a multiple of 64; 3,968 in
    48 KiB), keeping 1.5 KiB for the batch counters; at most SINGLE_MAX_BODIES."""
    fit = (traits.local_mem_size - 1536) // SINGLE_BYTES_PER_BODY // 64 * 64
    return max(0, min(SINGLE_MAX_BODIES, fit))


def default_single_work_group_size(traits: DeviceTraits) -> int:
    """1,024 lanes on GPUs (a round touches every uncoloured constraint once); 64 on CPUs."""
    return min(1024 if traits.is_gpu else 64, traits.max_work_group_size)


def default_mode(traits: DeviceTraits) -> str:
    """cells on GPUs (a large pile must spread over many compute units); slabs on CPUs
    (a pile spreads over the few cores, stacks stay whole; a PoCL launch costs ~5 us)."""
    return "cells" if traits.is_gpu else "slabs"


def default_work_group_size(traits: DeviceTraits) -> int:
    """128 on GPUs (enough lanes per batch of a pile); 16 on CPUs (few cores, cheap barriers)."""
    return min(128 if traits.is_gpu else 16, traits.max_work_group_size)


def default_group_count(traits: DeviceTraits) -> int:
    """Groups per colour: two per compute unit on GPUs; eight per core on CPUs, whose groups
    are single work-items of uneven size (cells, slabs) that PoCL's threads take in turn."""
    return max(1, min(1024, (2 if traits.is_gpu else 8) * traits.compute_units))


def _unit4(vector, name: str) -> np.ndarray:
    """A direction as the float4 kernel argument (unit length, w = 0); a zero or
    non-finite one is refused, naming the setting."""
    axis = np.zeros(4, np.float32)
    axis[:3] = vector
    norm = float(np.linalg.norm(axis))
    if not np.isfinite(norm) or norm == 0.0:
        raise RbgenError(f"{name} must be a non-zero finite vector, got {vector!r}")
    return axis / norm


def batch_host(body_a, body_b, dynamic) -> np.ndarray:
    """Reference: sequential first-fit colouring; returns the batch of every constraint.

    ``dynamic`` is a boolean per body; constraints between two static bodies go
    to batch 0.
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


class ConstraintBatcher:
    """Owns the batching kernels and scratch; call it once per step.

    After a call, the device arrays ``order`` (constraint indices sorted by
    group then batch), ``group_batches`` (per group, ``max_batches + 1``
    absolute offsets into ``order``) and ``group_batch_count`` describe the
    batches; the solver reads them directly, one launch per entry of
    ``launch_plan`` ((first group, group count) of groups that may run
    concurrently). ``mode="cells"`` and ``"slabs"`` need ``cell_size`` (at least
    the largest dynamic body's diameter plus the contact margin; smaller only
    costs leftovers); slabs lie across ``slab_axis`` (a unit vector, x by
    default; the World picks the widest horizontal axis). ``batches`` says whether groups are split into level-2 batches
    (shape "gpu") or are one batch each (shape "cpu").
    """

    def __init__(self, runtime: Runtime, *, mode: str | None = None, group_count: int | None = None,
                 cell_size: float | None = None, max_batches: int = 128,
                 work_group_size: int | None = None, shape: str | None = None,
                 max_bodies: int | None = None, ordered_rounds: int = ORDERED_ROUNDS):
        self.runtime = runtime
        traits = runtime.traits
        self.mode = mode or default_mode(traits)
        if self.mode not in MODES:
            raise RbgenError(f"batching mode must be one of {MODES}, got {mode!r}")
        self.shape = shape or traits.kind
        if self.shape not in SHAPES:
            raise RbgenError(f"batching shape must be one of {SHAPES}, got {shape!r}")
        if self.mode in ("single", "global") and self.shape != "gpu":
            raise RbgenError(f"batching mode {self.mode!r} colours for the gpu-shaped solver: "
                             f"it needs shape='gpu'")
        self.batches = self.shape == "gpu"
        self.max_batches = int(max_batches)
        if not isinstance(ordered_rounds, (int, np.integer)) or not 0 <= ordered_rounds < 2**32:
            raise RbgenError(f"ordered_rounds must be a non-negative integer, got {ordered_rounds!r}")
        #: global mode: rounds a step that bid constraint indices (see ORDERED_ROUNDS)
        self.ordered_rounds = int(ordered_rounds)
        self.cell_size = None if cell_size is None else float(cell_size)
        self.slab_axis = (1.0, 0.0, 0.0)
        #: two unit vectors spanning the plane across gravity (columns mode)
        self.column_axes = ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0))
        #: colours of the spatial modes (without the leftover group)
        self.cell_colours = MODE_COLOURS.get(self.mode, 0)
        if self.mode == "single":
            self.max_bodies = int(max_bodies or single_capacity(traits))
            self.work_group_size = work_group_size or default_single_work_group_size(traits)
            self.groups_per_colour = self.group_count = self.colours = 1
            self.launch_plan = [(0, 1)]
            self.spec = SINGLE_TEMPLATE.spec(work_group_size=self.work_group_size,
                                             max_batches=self.max_batches,
                                             max_bodies=self.max_bodies)
            names = ["colour_single"]
        elif self.mode == "global":
            self.max_bodies = None
            self.work_group_size = work_group_size or default_global_work_group_size(traits)
            self.groups_per_colour = self.group_count = self.colours = 1
            self.launch_plan = [(0, 1)]
            self.spec = GLOBAL_TEMPLATE.spec(work_group_size=self.work_group_size,
                                             max_batches=self.max_batches)
            #: the grid barrier's words, 2 lost flags, the highest colour, the batch
            #: counters (the layout of colour_global's STATE_*)
            self.state = sync_buffer(runtime, 3 + self.max_batches + 1)
            names = ["colour_global"]
        else:
            self.max_bodies = None
            self.work_group_size = work_group_size or default_work_group_size(traits)
            per_colour = int(group_count or default_group_count(traits))
            if per_colour < 1:
                raise RbgenError(f"group_count must be >= 1, got {group_count!r}")
            if self.cell_colours:
                colours = self.cell_colours
                self.groups_per_colour = per_colour
                self.group_count = colours * per_colour + 1
                self.colours = colours + 1
                self.launch_plan = [(c * per_colour, per_colour) for c in range(colours)]
                self.launch_plan.append((colours * per_colour, 1))
            else:
                self.groups_per_colour = self.group_count = per_colour
                self.colours = 1
                self.launch_plan = [(0, per_colour)]
            self.spec = TEMPLATE.spec(work_group_size=self.work_group_size,
                                      max_batches=self.max_batches, mode=self.mode,
                                      shape=self.shape)
            names = ["reset_batching"]
            names += ["link_bodies", "assign_groups"] if self.mode == "components" \
                else ["assign_cells"]
            names += ["scan_groups", "scatter_groups", "batch_groups"] if self.batches \
                else ["list_groups"]
        program = compile_spec(runtime, self.spec)
        self._kernels = {name: runtime.bound(program.kernel(name)) for name in names}
        self.body_capacity = self.constraint_capacity = 0
        queue, g = runtime.queue, self.group_count
        self.group_counts = cl_array.zeros(queue, g, np.uint32)
        self.group_offsets = cl_array.zeros(queue, g + 1, np.uint32)
        self.group_batches = cl_array.zeros(queue, g * (self.max_batches + 1), np.uint32)
        self.group_batch_count = cl_array.zeros(queue, g, np.uint32)

    def ensure_capacity(self, body_capacity: int, constraint_capacity: int) -> None:
        """Grow the per-body and per-constraint scratch (never shrinks)."""
        queue = self.runtime.queue
        if body_capacity > self.body_capacity and self.mode == "single":
            if body_capacity > self.max_bodies:
                raise RbgenError(f"batching mode 'single' holds at most {self.max_bodies} "
                                 f"bodies (max_bodies), got {body_capacity}")
            self.body_capacity = int(body_capacity)
        elif body_capacity > self.body_capacity and self.mode == "global":
            self.body_capacity = int(body_capacity)
            n = max(1, self.body_capacity)
            self.body_bids = cl_array.empty(queue, 2 * n, np.uint32)  # two rounds' bids
            self.body_colours = cl_array.empty(queue, 4 * n, np.uint32)  # 2 64-bit masks
        elif body_capacity > self.body_capacity:
            self.body_capacity = int(body_capacity)
            n = max(1, self.body_capacity)
            if self.batches:  # level-2 marks, one set per colour
                self.body_stamp = cl_array.empty(queue, self.colours * n, np.uint32)
                self.body_taken = cl_array.empty(queue, self.colours * n, np.uint32)
            self.body_links = cl_array.empty(  # union-find parents, or per-colour cell claims
                queue, max(1, self.cell_colours) * n, np.uint32)
        if constraint_capacity > self.constraint_capacity:
            self.constraint_capacity = int(constraint_capacity)
            n = max(1, self.constraint_capacity)
            self.order = cl_array.empty(queue, n, np.uint32)
            if self.mode in ("single", "global"):  # per constraint: its colour
                self.constraint_batch = cl_array.empty(queue, n, np.uint32)
                if self.mode == "global":  # and its dynamic bodies
                    self.constraint_pairs = cl_array.empty(queue, 2 * n, np.uint32)
                return
            #: per constraint: its slot in its group's list (gpu shape) or its group (cpu)
            self.constraint_slot = cl_array.empty(queue, n, np.uint32)
            if self.batches:
                (self.constraint_batch, self.constraint_blocked,
                 self.group_list) = (cl_array.empty(queue, n, np.uint32) for _ in range(3))

    def __call__(self, constraints, constraint_count, bodies, body_count: int,
                 constraint_capacity: int) -> None:
        """Batch the first ``constraint_count[0]`` constraints (a device uint32 array(1)).

        ``constraint_capacity`` bounds the count and sizes the launches.
        """
        if self.cell_colours and not self.cell_size:
            raise RbgenError(f"batching mode {self.mode!r} needs a positive cell_size")
        self.ensure_capacity(body_count, constraint_capacity)
        k, wg = self._kernels, self.work_group_size
        if self.mode == "single":
            k["colour_single"].bind(constraints, constraint_count, bodies, self.constraint_batch,
                                    self.order, self.group_batches, self.group_batch_count,
                                    np.uint32(body_count)).launch(wg, wg)
            return
        if self.mode == "global":
            k["colour_global"].bind(constraints, constraint_count, bodies, self.constraint_batch,
                                    self.order, self.group_batches, self.group_batch_count,
                                    self.constraint_pairs, self.body_bids, self.body_colours,
                                    self.state, np.uint32(body_count),
                                    np.uint32(self.ordered_rounds)
                                    ).launch(grid_groups(self.runtime.traits) * wg, wg)
            return
        g, n = self.group_count, self.body_capacity
        marks = max(1, self.cell_colours) * n
        if self.batches:
            marks = max(marks, self.colours * n)
        marks_buffers = (self.body_stamp, self.body_taken) if self.batches else ()
        k["reset_batching"].over(max(marks, g), wg, *marks_buffers, self.body_links,
                                 self.group_counts, np.uint32(n), np.uint32(g))
        # gpu: atomic slots in the group lists; cpu: each constraint's group
        outputs = (self.group_counts, self.constraint_slot) if self.batches else \
            (self.constraint_slot,)
        if constraint_capacity > 0:
            if self.mode == "components":
                k["link_bodies"].over(constraint_capacity, wg, constraints, constraint_count,
                                      bodies, self.body_links)
                k["assign_groups"].over(constraint_capacity, wg, constraints, constraint_count,
                                        bodies, self.body_links, *outputs, np.uint32(g))
            else:
                axis = (self._slab_axis(),) if self.mode == "slabs" else \
                    self._column_axes() if self.mode == "columns" else ()
                k["assign_cells"].over(constraint_capacity, wg, constraints, constraint_count,
                                       bodies, self.body_links, *outputs, np.uint32(n),
                                       np.uint32(self.groups_per_colour), *axis,
                                       np.float32(1.0 / self.cell_size))
        if not self.batches:
            k["list_groups"].bind(constraint_count, self.constraint_slot, self.group_counts,
                                  self.group_offsets, self.order, self.group_batches,
                                  self.group_batch_count, np.uint32(constraint_capacity),
                                  np.uint32(g)).launch(1, 1)
            return
        k["scan_groups"].bind(self.group_counts, self.group_offsets, np.uint32(g)).launch(1, 1)
        if constraint_capacity > 0:
            k["scatter_groups"].over(constraint_capacity, wg, constraints, constraint_count,
                                     self.constraint_slot, self.group_offsets, self.group_list,
                                     self.constraint_batch, self.constraint_blocked)
        k["batch_groups"].bind(constraints, bodies, self.group_offsets, self.group_list,
                               self.body_stamp, self.body_taken, self.constraint_batch,
                               self.constraint_blocked, self.order, self.group_batches,
                               self.group_batch_count, np.uint32(n),
                               np.uint32(self.groups_per_colour)).launch(g * wg, wg)

    def _column_axes(self) -> tuple:
        return tuple(_unit4(axis, "column_axes") for axis in self.column_axes)

    def _slab_axis(self) -> np.ndarray:
        return _unit4(self.slab_axis, "slab_axis")

    def read_batches(self):
        """Host copy of the result (tests, statistics): (order, per-group batch offsets, counts).

        Blocking reads; never called by `World.step`.
        """
        read = self.runtime.read
        offsets = read(self.group_batches).reshape(self.group_count, self.max_batches + 1)
        return read(self.order), offsets, read(self.group_batch_count)
