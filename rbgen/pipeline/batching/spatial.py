"""Spatial batching (Harada's two-level solver): constraint edges grouped by the cell of a point.

Level 1: an edge belongs to the cell of its point (`layouts.CONSTRAINT_EDGE`; a
contact's first point). ``cells``: cubes of at least the largest dynamic body's size, 8
colours by the parity of their coordinates; ``slabs``: slabs across one horizontal axis
(``slab_axis``), 2 colours; ``columns``: columns along gravity, square across the two
horizontal axes (``slab_axis``, ``column_axis``), 4 colours. Cells of one colour are a
whole cell apart, so their edges share no body and a colour is one solver launch over many
groups; an edge whose body another group of its colour has claimed (a body wider than a
cell) goes to a leftover group solved alone, so correctness never depends on sizes. A
sweep is one launch per colour plus one for the leftovers. Slabs hold whole stacks, which a
serial solve then walks in index order (from the ground up for piles built bottom-up);
columns hold whole stacks too, and a lattice 20 stacks wide has 10 slabs a colour (at most
10 busy cores) but 100 columns a colour (default_spatial_mode).

Level 2 (solve form ``lanes``): each group is coloured into batches by one work group
(maximal independent sets grown by rounds of lowest-priority-wins); the last batch slot
takes any remainder and is solved by a single lane. With ``serial`` a group is one batch,
listed in index order by a single work-item (deterministic).
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array

from ...codegen import KernelTemplate, Param, compile_spec, power_of_two, work_group_size_param
from ...device import DeviceTraits, Runtime
from ...errors import RbgenError
from . import SOLVE_FORMS, default_solve_form, read_batches

#: the spatial algorithms and their colours (parity of 3 cell coordinates, or of the slab)
COLOURS = {"cells": 8, "slabs": 2, "columns": 4}

TEMPLATE = KernelTemplate(
    "pipeline/batching/spatial.cl.mako",
    [
        work_group_size_param(
            "lanes of the batching work group (and of the per-item kernels); "
            "more lanes colour a large group faster"
        ),
        Param(
            "max_batches",
            power_of_two(2, 4096),
            "batch slots per group; the last slot holds the remainder, solved serially, "
            "so this bounds local memory, not correctness",
            "a power of two from 2 to 4096",
        ),
        Param(
            "mode",
            tuple(COLOURS),
            "cells (8 colour launches + leftovers per sweep, piles spread over the device), "
            "slabs (2 colour launches + leftovers per sweep, a stack whole in a group) or "
            "columns (4 colour launches + leftovers per sweep, a stack whole in a group, "
            "many groups a colour)",
        ),
        Param(
            "solve_form",
            SOLVE_FORMS,
            "lanes: level-2 batches for a work group's lanes; serial: none (a group is "
            "solved by one work-item), groups listed by a single work-item",
        ),
    ],
    doc="Level-1 groups (coloured cells or slabs); level-2 batches per work group.",
    roles={"body_owner": "inout", "group_counts": "inout"},
    defaults=lambda traits: {
        "work_group_size": default_work_group_size(traits),
        "max_batches": 128,
        "mode": default_spatial_mode(traits),
        "solve_form": default_solve_form(traits),
    },
)


#: CPUs with more cores than this batch over columns rather than slabs
COLUMNS_FROM_CORES = 8


def default_spatial_mode(traits: DeviceTraits) -> str:
    """The spatial batching a device runs when it has no persistent launch: cells on GPUs
    (any pile spread over the compute units); on CPUs, whose serial solve wants whole
    stacks in a group, slabs up to COLUMNS_FROM_CORES cores and columns beyond. Slabs cost
    2 launches a sweep and give a lattice 20 stacks wide 10 groups a colour, which keep 8
    cores busy but not 16; columns cost 4 and give it 100, so they pay only where the
    cores outnumber a scene's slabs (benchmarks/holds.py: candidate shock_columns)."""
    if traits.is_gpu:
        return "cells"
    return "columns" if traits.compute_units > COLUMNS_FROM_CORES else "slabs"


def default_work_group_size(traits: DeviceTraits) -> int:
    """128 on GPUs (enough lanes per batch of a pile); 16 on CPUs (few cores, cheap barriers)."""
    return min(128 if traits.is_gpu else 16, traits.max_work_group_size)


def default_group_count(traits: DeviceTraits) -> int:
    """Groups per colour: two per compute unit on GPUs; eight per core on CPUs, whose groups
    are single work-items of uneven size that PoCL's threads take in turn."""
    return max(1, min(1024, (2 if traits.is_gpu else 8) * traits.compute_units))


def unit4(vector, name: str) -> np.ndarray:
    """A direction as the float4 kernel argument (unit length, w = 0); a zero or
    non-finite one is refused, naming the setting."""
    axis = np.zeros(4, np.float32)
    axis[:3] = vector
    norm = float(np.linalg.norm(axis))
    if not np.isfinite(norm) or norm == 0.0:
        raise RbgenError(f"{name} must be a non-zero finite vector, got {vector!r}")
    return axis / norm


class SpatialBatcher:
    """Cells or slabs (see the module docstring and `rbgen.pipeline.batching.Batcher`).

    ``cell_size`` must be at least the largest dynamic body's diameter plus the contact
    margin (smaller only costs leftovers); slabs lie across ``slab_axis`` (a unit
    vector), columns across it and ``column_axis``. They are set with `configure` before
    a call.
    """

    def __init__(
        self,
        runtime: Runtime,
        *,
        mode: str = "cells",
        group_count: int | None = None,
        cell_size: float | None = None,
        max_batches: int = 128,
        work_group_size: int | None = None,
        solve_form: str | None = None,
    ):
        self.runtime = runtime
        traits = runtime.traits
        if mode not in COLOURS:
            raise RbgenError(f"spatial batching mode must be one of {tuple(COLOURS)}, got {mode!r}")
        self.mode = mode
        self.solve_form = solve_form or default_solve_form(traits)
        if self.solve_form not in SOLVE_FORMS:
            raise RbgenError(f"solve_form must be one of {SOLVE_FORMS}, got {solve_form!r}")
        self.batches = self.solve_form == "lanes"
        self.max_batches = int(max_batches)
        self.cell_size = None if cell_size is None else float(cell_size)
        self.slab_axis: tuple[float, ...] = (1.0, 0.0, 0.0)
        self.column_axis: tuple[float, ...] = (0.0, 0.0, 1.0)
        self.cell_colours = COLOURS[mode]
        self.work_group_size = work_group_size or default_work_group_size(traits)
        per_colour = int(group_count or default_group_count(traits))
        if per_colour < 1:
            raise RbgenError(f"group_count must be >= 1, got {group_count!r}")
        colours = self.cell_colours
        self.groups_per_colour = per_colour
        self.group_count = colours * per_colour + 1
        self.colours = colours + 1
        self.launch_plan = [(c * per_colour, per_colour) for c in range(colours)]
        self.launch_plan.append((colours * per_colour, 1))
        self.spec = TEMPLATE.spec(
            work_group_size=self.work_group_size,
            max_batches=self.max_batches,
            mode=self.mode,
            solve_form=self.solve_form,
        )
        names = ["reset_batching", "assign_cells"]
        names += (
            ["scan_groups", "scatter_groups", "batch_groups"] if self.batches else ["list_groups"]
        )
        program = compile_spec(runtime, self.spec)
        self._kernels = {name: runtime.bound(program.kernel(name)) for name in names}
        self.body_capacity = self.edge_capacity = 0
        queue, g = runtime.queue, self.group_count
        self.group_counts = cl_array.zeros(queue, g, np.uint32)
        self.group_offsets = cl_array.zeros(queue, g + 1, np.uint32)
        self.group_batches = cl_array.zeros(queue, g * (self.max_batches + 1), np.uint32)
        self.group_batch_count = cl_array.zeros(queue, g, np.uint32)

    def configure(self, *, cell_size: float, slab_axis, column_axis=None) -> None:
        """The cell side (m), the slabs' axis of the scene and the columns' second axis
        (None: keep the last; both horizontal, at right angles)."""
        self.cell_size = float(cell_size)
        self.slab_axis = tuple(float(v) for v in slab_axis)
        if column_axis is not None:
            self.column_axis = tuple(float(v) for v in column_axis)

    def ensure_capacity(self, body_capacity: int, edge_capacity: int) -> None:
        """Grow the per-body and per-edge scratch (never shrinks)."""
        queue = self.runtime.queue
        if body_capacity > self.body_capacity:
            self.body_capacity = int(body_capacity)
            n = max(1, self.body_capacity)
            if self.batches:  # level-2 marks, one set per colour
                self.body_stamp = cl_array.empty(queue, self.colours * n, np.uint32)
                self.body_taken = cl_array.empty(queue, self.colours * n, np.uint32)
            self.body_owner = cl_array.empty(queue, self.cell_colours * n, np.uint32)
        if edge_capacity > self.edge_capacity:
            self.edge_capacity = int(edge_capacity)
            n = max(1, self.edge_capacity)
            self.order = cl_array.empty(queue, n, np.uint32)
            #: per edge: its level-1 group
            self.edge_group = cl_array.empty(queue, n, np.uint32)
            if self.batches:  # per edge: its slot in its group's list, batch, blocked mark
                (self.edge_slot, self.edge_batch, self.edge_blocked, self.group_list) = (
                    cl_array.empty(queue, n, np.uint32) for _ in range(4)
                )

    def __call__(self, edges, edge_count, bodies, body_count: int, edge_capacity: int) -> None:
        """Batch the first ``edge_count[0]`` constraint edges (a device uint32 array(1));
        ``edge_capacity`` bounds the count and sizes the launches."""
        if not self.cell_size:
            raise RbgenError(f"batching mode {self.mode!r} needs a positive cell_size")
        self.ensure_capacity(body_count, edge_capacity)
        k, wg = self._kernels, self.work_group_size
        g, n = self.group_count, self.body_capacity
        marks = max(self.cell_colours * n, self.colours * n if self.batches else 0)
        marks_buffers = (self.body_stamp, self.body_taken) if self.batches else ()
        k["reset_batching"].over(
            max(marks, g),
            wg,
            *marks_buffers,
            self.body_owner,
            self.group_counts,
            np.uint32(n),
            np.uint32(g),
        )
        # lanes: also the atomic slots in the group lists
        slots = (self.group_counts, self.edge_slot) if self.batches else ()
        if edge_capacity > 0:
            axis = {
                "slabs": (unit4(self.slab_axis, "slab_axis"),),
                "columns": (
                    unit4(self.slab_axis, "slab_axis"),
                    unit4(self.column_axis, "column_axis"),
                ),
            }.get(self.mode, ())
            k["assign_cells"].over(
                edge_capacity,
                wg,
                edges,
                edge_count,
                bodies,
                self.body_owner,
                *slots,
                self.edge_group,
                np.uint32(n),
                np.uint32(self.groups_per_colour),
                *axis,
                np.float32(1.0 / self.cell_size),
            )
        if not self.batches:
            k["list_groups"].bind(
                edges,
                edge_count,
                self.edge_group,
                self.group_counts,
                self.group_offsets,
                self.order,
                self.group_batches,
                self.group_batch_count,
                np.uint32(edge_capacity),
                np.uint32(g),
            ).launch(1, 1)
            return
        k["scan_groups"].bind(self.group_counts, self.group_offsets, np.uint32(g)).launch(1, 1)
        if edge_capacity > 0:
            k["scatter_groups"].over(
                edge_capacity,
                wg,
                edge_count,
                self.edge_group,
                self.edge_slot,
                self.group_offsets,
                self.group_list,
                self.edge_batch,
                self.edge_blocked,
            )
        k["batch_groups"].bind(
            edges,
            bodies,
            self.group_offsets,
            self.group_list,
            self.body_stamp,
            self.body_taken,
            self.edge_batch,
            self.edge_blocked,
            self.order,
            self.group_batches,
            self.group_batch_count,
            np.uint32(n),
            np.uint32(self.groups_per_colour),
        ).launch(g * wg, wg)

    def read_batches(self):
        return read_batches(self)
