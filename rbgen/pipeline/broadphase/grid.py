"""Uniform-grid broadphase: cell hash, bucket lists or sorted buckets, neighbour cells.

Why a grid: for bodies of similar size (stacks, piles, granular scenes) each
body meets only the few bodies of the cells around its own, so the work is
linear in the body count, with no sweep.

Both emissions measure the same things: validation, the geometric mean
size, bodies larger than ``large_factor`` times it flagged large (the
ground, big boxes: kept out of the grid and tested as a list), and the
largest small body, which sets the cell side. Then (all on the device, no
blocking read):

``emission="owner"`` (the default; grid_owner.cl.mako): the whole query in
   six launches, because on a GPU the launch count sets the time of a query
   of up to ~10^5 bodies. Partial sums per work group replace the
   reductions; each small body joins the linked list of its bucket
   (``bucketing="list"``, one atomic exchange: no sort, no scan); each pair
   is written by its lower body (its owner) into the owner's slice, so the
   list comes out sorted without a global sort: a small owner visits the
   cells that can hold an overlapping body's lower corner (from one below
   its lower corner's cell to its upper corner's: 8 to 27), a large owner
   (at most LARGE_ROWS, else the query asks to be redone with slot
   emission) ranks its partners by prefix counts.
   Slice offsets are scanned per work group and the group totals by one
   work group.

   The small bodies form two grid levels: those within ``fine_factor`` (2)
   times the geometric mean size are fine, the rest coarse, and each level's
   cell is set by its largest body. Why: one cell for all makes every body
   visit cells sized for the largest small one (ragdoll parts falling on a
   pile of boxes more than twice their size would search cells sized for the
   boxes), while the bodies that differ most from the typical one are few. A
   fine owner visits fine cells for fine partners and coarse cells for coarse
   ones; a coarse owner visits coarse cells, where fine bodies are filed a
   second time (the template header's contract: every pair found once, by its
   owner). A coarse body thus meets no more candidates than in a one-level
   grid, and a fine body far fewer. The threshold follows the geometric mean,
   known on the device before any body is filed (no quantile, no extra pass);
   2x keeps a size spread of 2 (most scenes of one kind of body, and equal
   sizes) in one level, which is then the one-level grid with no coarse list
   filled or read.
``emission="slot"`` (grid.cl.mako): ``measure_bodies`` +
   Reduce, ``classify_sizes`` + Reduce max; the boxes in bucket order and
   the bucket starts (large bodies get a key past every bucket and end the
   list): ``bucketing="sort"`` (CPU default) is ``bucket_bodies``, RadixSort
   of (bucket, body), ``gather_sorted``, BoundSearch of every bucket id;
   ``bucketing="count"`` is ``count_bucket_bodies`` (atomic bucket sizes),
   Scan, ``scatter_bucket_bodies`` (atomic cursors). Then
   ``count_grid_pairs`` / Scan / ``write_grid_pairs``: each body visits its
   own cell, the 13 forward neighbour cells and the large-body list, and the
   pair buffer sorts the pairs by (a, b).

Atomics make the order inside a bucket vary between runs; the pair list does
not (it is ordered by construction or afterwards).

Exactness: overlapping small bodies must land in adjacent cells; with the
1% slack on the cell side this holds while coordinates stay within about
80,000 cell sides of the origin (float32 rounding of lower / cell), e.g.
160 km for 2 m cells; with two levels, the fine cell's sides (40 km for
0.5 m fine cells).

The cell is as small as the small bodies allow (a cell holds about one
body in a dense packing), so ``large_factor`` only decides which bodies are
too big for the grid: a larger factor keeps more bodies in the grid at the
price of larger cells.
"""

from __future__ import annotations

import math

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ... import layouts
from ...codegen import (
    Compiled,
    KernelTemplate,
    Param,
    compile_spec,
    power_of_two,
    work_group_size_param,
)
from ...errors import RbgenError
from .base import Broadphase, check_size_factor, default_work_group_size
from .pairs import key_bits

TEMPLATE = KernelTemplate(
    "pipeline/broadphase/grid.cl.mako",
    [
        work_group_size_param(
            "bodies per work group; the visit is latency-bound, so any size that fills a CU works"
        ),
        Param(
            "bucketing",
            ("sort", "count"),
            "sort: radix sort of (bucket, body) and bound search of the bucket starts "
            "(deterministic order inside buckets); count: counting sort with atomics, "
            "a fifth of the launches",
        ),
    ],
    doc="Uniform grid, slot emission: bucket keys per body, pair counting and writing over "
    "neighbour cells, then a global sort of the pairs.",
    defaults=lambda traits: {
        "work_group_size": default_work_group_size(traits),
        "bucketing": default_bucketing(traits, "slot"),
    },
)

OWNER_TEMPLATE = KernelTemplate(
    "pipeline/broadphase/grid_owner.cl.mako",
    [
        work_group_size_param(
            "bodies per work group; the visit is latency-bound, and the pair offsets are "
            "scanned per group (one work group scans the group totals)"
        ),
        Param(
            "large_rows",
            power_of_two(1, 32),
            "most large bodies handled (one bit of a body's row mask each)",
            "a power of two from 1 to 32",
        ),
    ],
    doc="Uniform grid, owner emission: the whole query in six launches, bucket lists, "
    "pairs written sorted by their lower body.",
    defaults=lambda traits: {
        "work_group_size": default_work_group_size(traits),
        "large_rows": LARGE_ROWS,
    },
)

#: Bodies larger than this many times the geometric mean size are large (kept
#: out of the grid). 4 keeps ordinary size spreads in the grid.
DEFAULT_LARGE_FACTOR = 4.0
#: Owner emission: grid bodies up to this many times the geometric mean size are
#: fine (the others coarse). 2 keeps the fine cell within 2x the typical body
#: (8x its volume) while bodies of one size, or of a spread within 2x, all stay fine.
DEFAULT_FINE_FACTOR = 2.0
#: Bucket tables of owner emission: fine, coarse, fine bodies by coarse cell.
OWNER_TABLES = 3
#: Owner emission handles at most this many large bodies (ground slabs, walls);
#: with more, a query is redone with slot emission.
LARGE_ROWS = 8
#: Buckets per body: sparse enough that distinct cells rarely share a bucket.
BUCKETS_PER_BODY = 2
#: Most work groups of ``measure_grid_bodies``: every work group of the
#: classification sums all their partial sums, so they are few; 512 still
#: give each compute unit of a large GPU several groups.
MEASURE_GROUPS = 512
#: Bucketings each emission can use.
BUCKETINGS = {"owner": ("list",), "slot": ("sort", "count")}


def default_emission(traits) -> str:
    """Owner emission everywhere: on GPUs six launches and no global pair sort; on CPUs
    too it beats slot emission, which visits half the cells but counts and writes in two
    passes, then sorts (benchmarks/broadphase.py compares them)."""
    return "owner"


def default_bucketing(traits, emission: str) -> str:
    """Owner emission: bucket lists. Slot emission: counting sort on GPUs (launch
    count matters most), radix sort on CPUs (deterministic buckets, cheap there)."""
    if emission == "owner":
        return "list"
    return "count" if traits.is_gpu else "sort"


def grid_dim_for(body_count: int) -> int:
    """Buckets per axis: the cube root of BUCKETS_PER_BODY * n, at least 3.

    At least 3 so that the 27 buckets around any cell are distinct.
    """
    return max(3, math.ceil((BUCKETS_PER_BODY * max(body_count, 1)) ** (1.0 / 3.0)))


class GridBroadphase(Broadphase):
    """``GridBroadphase(runtime, large_factor=4.0, fine_factor=2.0, emission=None,
    bucketing=None, capacity=None, work_group_size=None)``; see `Broadphase` and the
    module docstring (``fine_factor`` >= ``large_factor``: one grid level)."""

    name = "grid"

    def __init__(
        self,
        runtime,
        *,
        large_factor: float = DEFAULT_LARGE_FACTOR,
        fine_factor: float = DEFAULT_FINE_FACTOR,
        emission: str | None = None,
        bucketing: str | None = None,
        capacity=None,
        work_group_size=None,
    ):
        super().__init__(runtime, capacity=capacity, work_group_size=work_group_size)
        self.large_factor = check_size_factor(large_factor)
        self.fine_factor = check_size_factor(fine_factor, "fine_factor")
        self.emission = emission or default_emission(runtime.traits)
        if self.emission not in BUCKETINGS:
            raise RbgenError(f"emission must be one of {list(BUCKETINGS)}, got {emission!r}")
        self.bucketing = bucketing or default_bucketing(runtime.traits, self.emission)
        if self.bucketing not in BUCKETINGS[self.emission]:
            raise RbgenError(
                f"bucketing={bucketing!r} does not go with emission="
                f"{self.emission!r}; choose one of {list(BUCKETINGS[self.emission])}"
            )
        self._programs: dict[tuple[str, str], Compiled] = {}
        self._program()  # builds the kernels now
        self._bucket_ids: cla.Array | None = None
        self._fallback: str | None = None

    def _program(self):
        """The program of the current emission (and bucketing)."""
        key = (self.emission, self.bucketing)
        if key not in self._programs:
            if self.emission == "owner":
                spec = OWNER_TEMPLATE.spec(
                    work_group_size=self.work_group_size, large_rows=LARGE_ROWS
                )
            else:
                spec = TEMPLATE.spec(work_group_size=self.work_group_size, bucketing=self.bucketing)
            self._programs[key] = compile_spec(self.runtime, spec)
        return self._programs[key]

    @property
    def fallback(self) -> str | None:
        return self._fallback

    def describe(self) -> str:
        """``grid, owner emission`` or ``grid, slot emission (count bucketing)``, and why
        the owner emission was given up if it was (`fallback`)."""
        text = f"grid, {self.emission} emission"
        if self.emission == "slot":
            text += f" ({self.bucketing} bucketing)"
        return text + (f" since {self._fallback}" if self._fallback else "")

    def _prepare_retry(self, reason: int) -> None:
        """More large bodies than owner rows: use slot emission from now on."""
        if reason != layouts.BP_RETRY_LARGE:
            super()._prepare_retry(reason)
        if self.emission == "owner":
            self._fallback = (
                f"a query met more than {LARGE_ROWS} large bodies (larger than "
                f"{self.large_factor:g} x the bodies' geometric mean size)"
            )
        self.emission = "slot"
        self.bucketing = default_bucketing(self.runtime.traits, "slot")

    def _start_query(self, aabbs, n):
        """Owner emission resets the status, validates and measures in its own kernels."""
        if self.emission != "owner":
            super()._start_query(aabbs, n)

    def _enqueue_query(self, aabbs, static, n):
        if self.emission == "owner":
            self._owner_query(aabbs, static, n)
        else:
            self._slot_query(aabbs, static, n)

    # ------------------------------------------------------- owner emission
    def _owner_query(self, aabbs, static, n):
        """The six launches of grid_owner.cl.mako."""
        program, buffer, wg = self._program(), self.buffer, self.work_group_size
        dim = grid_dim_for(n)
        bucket_count, groups = OWNER_TABLES * dim**3, -(-n // wg)
        measure_groups = min(groups, MEASURE_GROUPS)
        partials = self.exact("log_size_partials", measure_groups, np.float32)
        heads, next_body = self.exact("bucket_heads", bucket_count), self.exact("next_body", n)
        next_split = self.exact("next_split", n)
        levels = self.exact("body_levels", n)
        large_count, large_bodies = (
            self.exact("large_count", 1),
            self.exact("large_bodies", LARGE_ROWS),
        )
        sizes = self.exact("grid_sizes", 2)
        status = buffer.status.base_data
        self.launch(
            program.kernel("measure_grid_bodies"),
            measure_groups * wg,
            aabbs.base_data,
            np.uint32(n),
            np.uint32(bucket_count),
            partials.base_data,
            heads.base_data,
            large_count.base_data,
            sizes.base_data,
            status,
        )
        self.launch(
            program.kernel("classify_grid_bodies"),
            n,
            aabbs.base_data,
            static.base_data,
            np.uint32(n),
            partials.base_data,
            np.uint32(measure_groups),
            np.float32(self.fine_factor),
            np.float32(self.large_factor),
            levels.base_data,
            large_count.base_data,
            large_bodies.base_data,
            sizes.base_data,
            status,
        )
        self.launch(
            program.kernel("link_bucket_bodies"),
            n,
            aabbs.base_data,
            static.base_data,
            np.uint32(n),
            np.int32(dim),
            levels.base_data,
            sizes.base_data,
            heads.base_data,
            next_body.base_data,
            next_split.base_data,
        )

        visit = (
            aabbs.base_data,
            static.base_data,
            np.uint32(n),
            np.int32(dim),
            levels.base_data,
            sizes.base_data,
            heads.base_data,
            next_body.base_data,
            next_split.base_data,
            large_count.base_data,
            large_bodies.base_data,
        )
        in_group = self.exact("in_group_offsets", n)
        group_pairs, group_rows = (
            self.exact("group_pairs", groups),
            self.exact("group_rows", LARGE_ROWS * groups),
        )
        owner_starts, owner_counts = (
            self.exact("owner_starts", LARGE_ROWS),
            self.exact("owner_counts", LARGE_ROWS),
        )
        capacity = np.uint32(buffer.capacity)
        self.launch(
            program.kernel("count_owned_pairs"),
            n,
            *visit,
            in_group.base_data,
            group_pairs.base_data,
            group_rows.base_data,
        )
        self.launch(
            program.kernel("place_owner_slices"),
            wg,
            np.uint32(groups),
            large_count.base_data,
            large_bodies.base_data,
            in_group.base_data,
            group_pairs.base_data,
            group_rows.base_data,
            owner_starts.base_data,
            owner_counts.base_data,
            capacity,
            status,
        )
        self.launch(
            program.kernel("write_owned_pairs"),
            n,
            *visit,
            in_group.base_data,
            group_pairs.base_data,
            group_rows.base_data,
            owner_starts.base_data,
            owner_counts.base_data,
            capacity,
            buffer.pairs.base_data,
        )

    # -------------------------------------------------------- slot emission
    def _bucket_id_queries(self, bucket_count: int) -> cla.Array:
        """0, 1, ..., bucket_count: the BoundSearch queries of the bucket starts."""
        if self._bucket_ids is None or self._bucket_ids.size != bucket_count + 1:
            self._bucket_ids = cla.to_device(
                self.runtime.queue, np.arange(bucket_count + 1, dtype=np.uint32)
            )
        return self._bucket_ids

    def _slot_query(self, aabbs, static, n):
        from ...primitives import Reduce

        runtime, program = self.runtime, self._program()
        dim = grid_dim_for(n)
        bucket_count = dim**3

        small_sizes = self.exact("small_sizes", n, np.float32)
        large_flags = self.exact("large_flags", n)
        self.launch(
            program.kernel("classify_sizes"),
            n,
            aabbs.base_data,
            np.uint32(n),
            self.log_size_sum.base_data,
            np.float32(self.large_factor),
            small_sizes.base_data,
            large_flags.base_data,
        )
        largest = self.exact("largest_small_size", 1, np.float32)
        self.primitive("max", lambda: Reduce(runtime, np.float32, op="max"))(
            small_sizes, largest, n=n
        )

        sorted_boxes = self.exact("sorted_boxes", n, layouts.AABB.dtype)
        starts = self.exact("bucket_starts", bucket_count + 1)
        bucket = (
            aabbs.base_data,
            np.uint32(n),
            large_flags.base_data,
            largest.base_data,
            np.int32(dim),
        )
        if self.bucketing == "sort":
            keys = self._sort_buckets(program, bucket, aabbs, n, bucket_count, sorted_boxes, starts)
        else:
            keys = self._count_buckets(
                program, bucket, aabbs, n, bucket_count, sorted_boxes, starts
            )
        visit = (
            aabbs.base_data,
            static.base_data,
            np.uint32(n),
            largest.base_data,
            np.int32(dim),
            keys.base_data,
            sorted_boxes.base_data,
            starts.base_data,
        )
        self._slot_pairs(program, visit, n)

    def _sort_buckets(self, program, bucket, aabbs, n, bucket_count, sorted_boxes, starts):
        """Radix sort of (bucket, body), gather, bound search: the sorted keys."""
        from ...primitives import BoundSearch, RadixSort

        runtime = self.runtime
        keys, bodies = self.exact("keys", n), self.exact("bodies", n)
        self.launch(program.kernel("bucket_bodies"), n, *bucket, keys.base_data, bodies.base_data)
        bits = key_bits(bucket_count)
        self.primitive(("sort", bits), lambda: RadixSort(runtime, key_bits=bits, with_values=True))(
            keys, bodies, n=n
        )
        self.launch(
            program.kernel("gather_sorted"),
            n,
            aabbs.base_data,
            np.uint32(n),
            bodies.base_data,
            sorted_boxes.base_data,
        )
        self.primitive("lower_bound", lambda: BoundSearch(runtime, side="lower"))(
            keys,
            self._bucket_id_queries(bucket_count),
            starts,
            n_keys=n,
            n_queries=bucket_count + 1,
        )
        return keys

    def _count_buckets(self, program, bucket, aabbs, n, bucket_count, sorted_boxes, starts):
        """Counting sort: bucket sizes, their scan (the starts), scatter: the sorted keys."""
        queue = self.runtime.queue
        keys, sizes = self.exact("keys", n), self.exact("bucket_sizes", bucket_count + 1)
        cl.enqueue_fill_buffer(queue, sizes.base_data, np.uint32(0), 0, 4 * (bucket_count + 1))
        self.launch(
            program.kernel("count_bucket_bodies"), n, *bucket, keys.base_data, sizes.base_data
        )
        self._scan(sizes, starts, bucket_count + 1, None)
        cursors = self.exact("bucket_cursors", bucket_count + 1)
        cl.enqueue_copy(
            queue, cursors.base_data, starts.base_data, byte_count=4 * (bucket_count + 1)
        )
        sorted_keys = self.exact("sorted_keys", n)
        self.launch(
            program.kernel("scatter_bucket_bodies"),
            n,
            aabbs.base_data,
            np.uint32(n),
            keys.base_data,
            cursors.base_data,
            sorted_keys.base_data,
            sorted_boxes.base_data,
        )
        return sorted_keys

    def _slot_pairs(self, program, visit, n):
        counts, offsets = self.exact("pair_counts", n), self.exact("pair_offsets", n)
        found = self.exact("pairs_found", 1)
        self.launch(program.kernel("count_grid_pairs"), n, *visit, counts.base_data)
        self._scan(counts, offsets, n, found)
        buffer = self.buffer
        self.launch(
            program.kernel("write_grid_pairs"),
            n,
            *visit,
            offsets.base_data,
            found.base_data,
            np.uint32(buffer.capacity),
            buffer.pairs_a.base_data,
            buffer.pairs_b.base_data,
            buffer.status.base_data,
        )
        buffer.sort(n)

    def _scan(self, src, dst, n, total):
        from ...primitives import Scan

        self.primitive("scan", lambda: Scan(self.runtime, np.uint32, inclusive=False))(
            src, dst, n=n, total=total
        )
