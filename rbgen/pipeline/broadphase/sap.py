"""One-axis sweep and prune: sort by the lower bound, sweep forward.

Why: unlike the grid it needs no cell size, so mixed sizes and clustered
scenes cost it nothing extra as long as the sweep axis separates the bodies;
the axis of largest centre variance is chosen on the device every query.

Step by step (all on the device, no blocking read):

1. ``measure_bodies`` + Reduce: validation and the geometric mean size;
   bodies more than ``large_factor`` times that are large (ground slabs) and
   are tested through a list (Compact), not swept: one of them would
   otherwise sweep over everything.
2. ``measure_centres`` + six Reduce sums: the centre variance per axis;
   ``sweep_keys`` picks the axis and writes sortable lower bounds.
3. RadixSort of (key, body); ``gather_sorted`` copies the sorted boxes.
4. ``count_sweep_pairs`` / Scan / ``write_sweep_pairs``: the sweep, in the GPU
   shape (tiles in local memory, barriers) or the CPU shape (one work-item
   per body, no barriers), then the pair buffer orders the pairs.
"""

from __future__ import annotations

import numpy as np

from ... import layouts
from ...codegen import KernelTemplate, Param, compile_spec, work_group_size_param
from .base import Broadphase, check_size_factor, default_work_group_size

TEMPLATE = KernelTemplate(
    "pipeline/broadphase/sap.cl.mako",
    [
        work_group_size_param(
            "bodies per work group, and the tile of sorted boxes staged in the GPU shape"
        ),
        Param(
            "shape",
            ("gpu", "cpu"),
            "gpu: a group sweeps together over tiles in local memory; cpu: independent "
            "sweeps through the cache, no barriers",
        ),
    ],
    doc="Sweep and prune on the axis of largest variance.",
    defaults=lambda traits: {
        "work_group_size": default_work_group_size(traits),
        "shape": traits.kind,
    },
)

#: A body more than this many times the geometric mean size is swept as
#: large (tested through the list): ground slabs, walls.
DEFAULT_LARGE_FACTOR = 8.0


class SapBroadphase(Broadphase):
    """``SapBroadphase(runtime, shape=None, large_factor=8.0, capacity=None)``."""

    name = "sap"

    def __init__(
        self,
        runtime,
        *,
        shape: str | None = None,
        large_factor: float = DEFAULT_LARGE_FACTOR,
        capacity=None,
        work_group_size=None,
    ):
        super().__init__(runtime, capacity=capacity, work_group_size=work_group_size)
        self.large_factor = check_size_factor(large_factor)
        self.shape = shape or runtime.traits.kind
        self.program = compile_spec(
            runtime, TEMPLATE.spec(work_group_size=self.work_group_size, shape=self.shape)
        )

    def _enqueue_query(self, aabbs, static, n):
        from ...primitives import Compact, RadixSort, Reduce, Scan

        runtime, program = self.runtime, self.program
        large_flags = self.exact("large_flags", n)
        moments = [self.exact(f"moment{k}", n, np.float32) for k in range(6)]
        self.launch(
            program.kernel("measure_centres"),
            n,
            aabbs.base_data,
            np.uint32(n),
            self.log_size_sum.base_data,
            np.float32(self.large_factor),
            *(m.base_data for m in moments),
            large_flags.base_data,
        )
        large_bodies = self.exact("large_bodies", n)
        large_count = self.exact("large_count", 1)
        self.primitive("compact", lambda: Compact(runtime))(
            large_flags, large_bodies, large_count, n=n
        )
        reduce = self.primitive("sum", lambda: Reduce(runtime, np.float32, op="sum"))
        sums = [self.exact(f"moment_sum{k}", 1, np.float32) for k in range(6)]
        for moment, total in zip(moments, sums):
            reduce(moment, total, n=n)

        keys, bodies = self.exact("keys", n), self.exact("bodies", n)
        axis = self.exact("sweep_axis", 1)
        self.launch(
            program.kernel("sweep_keys"),
            n,
            aabbs.base_data,
            np.uint32(n),
            large_flags.base_data,
            large_count.base_data,
            *(s.base_data for s in sums),
            axis.base_data,
            keys.base_data,
            bodies.base_data,
        )
        self.primitive("sort", lambda: RadixSort(runtime, key_bits=32, with_values=True))(
            keys, bodies, n=n
        )
        sorted_boxes = self.exact("sorted_boxes", n, layouts.AABB.dtype)
        self.launch(
            program.kernel("gather_sorted"),
            n,
            aabbs.base_data,
            np.uint32(n),
            axis.base_data,
            bodies.base_data,
            sorted_boxes.base_data,
        )

        sweep = (
            aabbs.base_data,
            static.base_data,
            np.uint32(n),
            sorted_boxes.base_data,
            large_bodies.base_data,
            large_count.base_data,
        )
        counts, offsets = self.exact("pair_counts", n), self.exact("pair_offsets", n)
        found = self.exact("pairs_found", 1)
        self.launch(program.kernel("count_sweep_pairs"), n, *sweep, counts.base_data)
        self.primitive("scan", lambda: Scan(runtime, np.uint32, inclusive=False))(
            counts, offsets, n=n, total=found
        )
        buffer = self.buffer
        self.launch(
            program.kernel("write_sweep_pairs"),
            n,
            *sweep,
            offsets.base_data,
            found.base_data,
            np.uint32(buffer.capacity),
            buffer.pairs_a.base_data,
            buffer.pairs_b.base_data,
            buffer.status.base_data,
        )
        buffer.sort(n)
