"""Uniform-grid broadphase: cell hash, radix sort, bucket starts, neighbour cells.

Why a grid: for bodies of similar size (stacks, piles, granular scenes) each
body meets only the few bodies of its 27 neighbour cells, so the work is
linear in the body count with two sorts and no sweep.

Step by step (all on the device, no blocking read):

1. ``measure_bodies``: validation and log2 sizes; Reduce sums them.
2. ``bucket_bodies``: the cell side is ``cell_factor`` times the geometric
   mean body size; bodies larger than the cell (the ground, big boxes) are
   flagged large and get a key past every bucket; the others get the bucket
   of their lower corner's cell.
3. RadixSort of (bucket, body); BoundSearch of every bucket id gives the
   start of each bucket in the sorted list; Compact lists the large bodies.
4. ``count_grid_pairs`` / Scan / ``write_grid_pairs``: each body visits the 27
   buckets around its cell and the large-body list (see grid.cl.mako).
5. The pair buffer orders the pairs by (a, b) (pairs.py).
"""
from __future__ import annotations

import math

import numpy as np
import pyopencl.array as cla

from ...codegen import KernelTemplate, Param, compile_spec, power_of_two
from ...errors import RbgenError
from .base import Broadphase, default_work_group_size
from .pairs import key_bits

TEMPLATE = KernelTemplate(
    "pipeline/broadphase/grid.cl.mako",
    [Param("work_group_size", power_of_two(1, 1024),
           "bodies per work group; the visit is latency-bound, so any size that fills a CU works",
           "a power of two from 1 to 1024")],
    doc="Uniform grid: bucket keys per body, pair counting and writing over 27 neighbour cells.",
    defaults=lambda traits: {"work_group_size": default_work_group_size(traits)},
)

#: Cell side over the geometric mean body size. 2 keeps typical bodies small
#: (in the grid) while a cell holds few of them; tunable per scene.
DEFAULT_CELL_FACTOR = 2.0
#: Buckets per body: sparse enough that distinct cells rarely share a bucket.
BUCKETS_PER_BODY = 2


def grid_dim_for(body_count: int) -> int:
    """Buckets per axis: the cube root of BUCKETS_PER_BODY * n, at least 3.

    At least 3 so that the 27 buckets around any cell are distinct.
    """
    return max(3, math.ceil((BUCKETS_PER_BODY * max(body_count, 1)) ** (1.0 / 3.0)))


class GridBroadphase(Broadphase):
    """``GridBroadphase(runtime, cell_factor=2.0, capacity=None)``; see `Broadphase`."""

    name = "grid"

    def __init__(self, runtime, *, cell_factor: float = DEFAULT_CELL_FACTOR, capacity=None,
                 work_group_size=None):
        super().__init__(runtime, capacity=capacity, work_group_size=work_group_size)
        if not (isinstance(cell_factor, (int, float)) and math.isfinite(cell_factor)
                and cell_factor > 0):
            raise RbgenError(f"cell_factor must be a positive finite number, got {cell_factor!r}")
        self.cell_factor = float(cell_factor)
        self.program = compile_spec(runtime, TEMPLATE.spec(work_group_size=self.work_group_size))
        self._bucket_ids = None

    def _bucket_id_queries(self, bucket_count: int) -> cla.Array:
        """0, 1, ..., bucket_count: the BoundSearch queries of the bucket starts."""
        if self._bucket_ids is None or self._bucket_ids.size != bucket_count + 1:
            self._bucket_ids = cla.to_device(self.runtime.queue,
                                             np.arange(bucket_count + 1, dtype=np.uint32))
        return self._bucket_ids

    def _enqueue_query(self, aabbs, static, n):
        from ...primitives import BoundSearch, Compact, RadixSort, Scan
        runtime, program = self.runtime, self.program
        dim = grid_dim_for(n)
        bucket_count = dim ** 3
        keys = self.exact("keys", n)
        bodies = self.exact("bodies", n)
        large_flags = self.exact("large_flags", n)
        self.launch(program.kernel("bucket_bodies"), n, aabbs.base_data, np.uint32(n),
                    self.log_size_sum.base_data, np.float32(self.cell_factor), np.int32(dim),
                    keys.base_data, bodies.base_data, large_flags.base_data)

        large_bodies = self.exact("large_bodies", n)
        large_count = self.exact("large_count", 1)
        self.primitive("compact", lambda: Compact(runtime))(large_flags, large_bodies,
                                                             large_count, n=n)
        bits = key_bits(bucket_count)
        self.primitive(("sort", bits), lambda: RadixSort(runtime, key_bits=bits,
                                                          with_values=True))(keys, bodies, n=n)
        starts = self.exact("bucket_starts", bucket_count + 1)
        self.primitive("lower_bound", lambda: BoundSearch(runtime, side="lower"))(
            keys, self._bucket_id_queries(bucket_count), starts, n_keys=n,
            n_queries=bucket_count + 1)

        visit = (aabbs.base_data, static.base_data, np.uint32(n), self.log_size_sum.base_data,
                 np.float32(self.cell_factor), np.int32(dim), keys.base_data, bodies.base_data,
                 starts.base_data, large_bodies.base_data, large_count.base_data)
        counts = self.exact("pair_counts", n)
        offsets = self.exact("pair_offsets", n)
        found = self.exact("pairs_found", 1)
        self.launch(program.kernel("count_grid_pairs"), n, *visit, counts.base_data)
        self.primitive("scan", lambda: Scan(runtime, np.uint32, inclusive=False))(
            counts, offsets, n=n, total=found)
        buffer = self.buffer
        self.launch(program.kernel("write_grid_pairs"), n, *visit, offsets.base_data,
                    found.base_data, np.uint32(buffer.capacity), buffer.pairs_a.base_data,
                    buffer.pairs_b.base_data, buffer.status.base_data)
