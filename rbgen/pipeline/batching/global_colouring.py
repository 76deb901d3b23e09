"""Global batching: one persistent launch over every compute unit colours all edges.

All constraint edges form one group whose batches (colours) the PGS solver's persistent
launch solves one after another on every compute unit
(``templates/pipeline/batching/global_colouring.cl.mako`` has the algorithm: the
previous step's colour of each edge where it still holds, then Jones-Plassmann rounds
with global body marks, the first ``ordered_rounds`` of a step first-fit in index
order). One colouring launch and one solver launch a step at any size: the choice where
the device runs a persistent launch (`rbgen.pipeline.device_barrier`).
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array

from ...codegen import KernelTemplate, Param, compile_spec, power_of_two, work_group_size_param
from ...device import DeviceTraits, Runtime
from ...errors import RbgenError
from ..device_barrier import barrier_buffer, persistent_groups
from . import read_batches

TEMPLATE = KernelTemplate(
    "pipeline/batching/global_colouring.cl.mako",
    [
        work_group_size_param("lanes of each of the launch's work groups (one per compute unit)"),
        Param(
            "max_batches",
            power_of_two(2, 4096),
            "batch slots (the solver's layout of group_batches); the last is the serial remainder",
            "a power of two from 2 to 4096",
        ),
    ],
    doc="Global batching: one launch over the whole device colours all constraint edges (the "
    "previous step's colours where they still hold, Jones-Plassmann rounds for the rest, "
    "global body marks and a device-wide barrier between phases).",
    roles={
        "edges": "inout",
        "edge_colour": "inout",
        "pairs": "inout",
        "bids": "inout",
        "used": "inout",
        "state": "inout",
    },
    defaults=lambda traits: {
        "work_group_size": default_work_group_size(traits),
        "max_batches": 128,
    },
)

#: Jones-Plassmann rounds a step that bid constraint indices (first-fit in index order,
#: the fewest colours) before the rest bid hashes and are provisionally coloured; a
#: static contact graph reaches the index-order colouring over a few steps
ORDERED_ROUNDS = 64


def default_work_group_size(traits: DeviceTraits) -> int:
    """256 on GPUs (one group per compute unit: the lanes are the device's parallelism);
    64 on CPUs."""
    return min(256 if traits.is_gpu else 64, traits.max_work_group_size)


class GlobalBatcher:
    """One group of all constraint edges, coloured by one persistent launch (see the
    module docstring and `rbgen.pipeline.batching.Batcher`)."""

    mode = "global"
    solve_form = "lanes"
    group_count = 1
    launch_plan = [(0, 1)]

    def __init__(
        self,
        runtime: Runtime,
        *,
        max_batches: int = 128,
        work_group_size: int | None = None,
        ordered_rounds: int = ORDERED_ROUNDS,
    ):
        self.runtime = runtime
        self.max_batches = int(max_batches)
        if not isinstance(ordered_rounds, (int, np.integer)) or not 0 <= ordered_rounds < 2**32:
            raise RbgenError(
                f"ordered_rounds must be a non-negative integer, got {ordered_rounds!r}"
            )
        self.ordered_rounds = int(ordered_rounds)
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        self.spec = TEMPLATE.spec(
            work_group_size=self.work_group_size, max_batches=self.max_batches
        )
        #: the device barrier's words, 2 lost flags, the highest colour, the batch counters
        #: (the layout of colour_global's STATE_*); the PGS solver's launch shares it
        self.state = barrier_buffer(runtime, 3 + self.max_batches + 1)
        program = compile_spec(runtime, self.spec)
        self._kernel = runtime.bound(program.kernel("colour_global"))
        self.body_capacity = self.edge_capacity = 0
        queue = runtime.queue
        self.group_batches = cl_array.zeros(queue, self.max_batches + 1, np.uint32)
        self.group_batch_count = cl_array.zeros(queue, 1, np.uint32)

    def configure(self, *, cell_size: float, slab_axis, column_axis=None) -> None:
        """(no scene geometry: the colouring is topological)"""

    def ensure_capacity(self, body_capacity: int, edge_capacity: int) -> None:
        """Grow the per-body and per-edge scratch (never shrinks)."""
        queue = self.runtime.queue
        if body_capacity > self.body_capacity:
            self.body_capacity = int(body_capacity)
            n = max(1, self.body_capacity)
            self.body_bids = cl_array.empty(queue, 2 * n, np.uint32)  # two rounds' bids
            self.body_colours = cl_array.empty(queue, 4 * n, np.uint32)  # 2 64-bit masks
        if edge_capacity > self.edge_capacity:
            self.edge_capacity = int(edge_capacity)
            n = max(1, self.edge_capacity)
            self.order = cl_array.empty(queue, n, np.uint32)
            #: every edge's colour (its batch) in the last call
            self.edge_batch = cl_array.empty(queue, n, np.uint32)
            self.edge_pairs = cl_array.empty(queue, 2 * n, np.uint32)

    def __call__(self, edges, edge_count, bodies, body_count: int, edge_capacity: int) -> None:
        """Colour the first ``edge_count[0]`` constraint edges (a device uint32 array(1));
        ``edge_capacity`` bounds the count."""
        self.ensure_capacity(body_count, edge_capacity)
        wg = self.work_group_size
        self._kernel.bind(
            edges,
            edge_count,
            bodies,
            self.edge_batch,
            self.order,
            self.group_batches,
            self.group_batch_count,
            self.edge_pairs,
            self.body_bids,
            self.body_colours,
            self.state,
            np.uint32(body_count),
            np.uint32(self.ordered_rounds),
        ).launch(persistent_groups(self.runtime.traits) * wg, wg)

    def read_batches(self):
        return read_batches(self)
