"""Incremental three-axis sweep and prune (Bullet3's third-generation broadphase).

Why: in a simulation most bodies move a little per step, so the sorted
endpoint arrays change little; the pairs that start or stop overlapping are
found from the endpoints that changed rank, without a full query.

Each step (all enqueued, no blocking read):

1. validation (``measure_bodies``); the 2n endpoints of each axis are sorted
   (RadixSort, stable from a canonical order) and their ranks taken;
2. ``rank_moves`` + Reduce: how far endpoints moved in rank. Above the budget
   (``max_moves_per_body`` * n) the step is degenerate (teleports, a first
   step): nothing is scanned and the status says so;
3. ``find_changes``: each moved endpoint scans the previous and current sorted
   arrays between its old and new rank and records the pairs whose overlap
   differs between the old and new boxes (see sap3.cl.mako for why this finds
   every change);
4. the changes are sorted (two stable key-value sorts) and made distinct
   (``mark_unique_changes`` + Compact); the new set is the symmetric
   difference of the old set and the changes, merged in (a, b) order
   (``mark_*_pairs`` binary-search each list in the other, Scan ranks the
   kept entries, ``place_*_pairs`` write them): the old set is never
   re-sorted, so a quiet step costs little more than the endpoint sorts.

State is double-buffered: a step writes the slot the last complete step did
not, and `check` commits it. A degenerate step makes `check` return False and
the next `enqueue` runs a full query (``full``: "grid" or "sap") into the same
pair buffer, then keeps the sorted endpoints as history; so the protocol is
that of every broadphase (base.py): redo the query, or the step, when `check`
says it is incomplete. The first query, a new body count and `reset()` are
full queries directly. Static flags must stay the same between steps (call
`reset` after changing them).
"""

from __future__ import annotations

import math

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ... import layouts
from ...codegen import KernelTemplate, compile_spec, work_group_size_param
from ...device import buffer_of
from ...errors import RbgenError
from .base import Broadphase, default_work_group_size
from .pairs import PairBuffer, check_capacity, key_bits

TEMPLATE = KernelTemplate(
    "pipeline/broadphase/sap3.cl.mako",
    [
        work_group_size_param(
            "endpoints or records per work group; memory-bound kernels, any size that fills a CU"
        )
    ],
    doc="Incremental 3-axis SAP: endpoint ranks, changed pairs, merge with the previous set.",
    defaults=lambda traits: {"work_group_size": default_work_group_size(traits)},
)

#: Rank moves per body (summed over its 6 endpoints) above which a step is
#: degenerate: scanning would cost more than a full query.
DEFAULT_MAX_MOVES_PER_BODY = 16.0
#: Room for pair changes per body; more changes make the step degenerate.
CHANGES_PER_BODY = 4
#: status.crossings of a step that must be redone in full (see sap3.cl.mako).
INCREMENTAL_FAILED = 0xFFFFFFFF


class _Slot:
    """One step's state: sorted endpoints, their ranks, the boxes, the pairs."""

    def __init__(self, runtime, n: int, capacity: int):
        queue = runtime.queue
        self.sorted = [cla.empty(queue, 2 * n, np.uint32) for _ in range(3)]
        self.ranks = cla.empty(queue, 6 * n, np.uint32)
        self.boxes = cla.empty(queue, n, layouts.AABB.dtype)
        self.pairs = PairBuffer(runtime, capacity)


class IncrementalSapBroadphase(Broadphase):
    """``IncrementalSapBroadphase(runtime, full="grid", full_options=None,
    max_moves_per_body=16, capacity=None)``; ``full_options`` go to the full-query broadphase."""

    name = "sap3"

    def __init__(
        self,
        runtime,
        *,
        full: str = "grid",
        full_options: dict | None = None,
        max_moves_per_body: float = DEFAULT_MAX_MOVES_PER_BODY,
        capacity=None,
        work_group_size=None,
    ):
        super().__init__(runtime, capacity=None, work_group_size=work_group_size)
        from . import make_broadphase

        if full not in ("grid", "sap"):
            raise RbgenError(
                f"full must be 'grid' or 'sap' (the full-query broadphase), got {full!r}"
            )
        if not (
            isinstance(max_moves_per_body, (int, float))
            and math.isfinite(max_moves_per_body)
            and max_moves_per_body >= 0
        ):
            raise RbgenError(
                f"max_moves_per_body must be a non-negative number, got {max_moves_per_body!r}"
            )
        self._initial_capacity = None if capacity is None else check_capacity(capacity)
        self.full = make_broadphase(
            runtime,
            full,
            capacity=capacity,
            work_group_size=work_group_size,
            **(full_options or {}),
        )
        self.max_moves_per_body = float(max_moves_per_body)
        self.program = compile_spec(runtime, TEMPLATE.spec(work_group_size=self.work_group_size))
        self.reset()

    def reset(self) -> None:
        """Forget the history: the next query is a full one."""
        self._slots: list[_Slot | None] = [None, None]
        self._current: int | None = None  # slot of the last complete step
        self._target: int | None = None  # slot the pending step writes
        self._pending_full = True
        self._force_full = False  # set by check() after a degenerate step
        self._slot_bodies = -1

    @property
    def fallback(self) -> str | None:
        return self.full.fallback

    def describe(self) -> str:
        return f"sap3 (full queries: {self.full.describe()})"

    @property
    def incremental(self) -> bool:
        """Whether the last enqueued query was incremental (not a full one)."""
        return not self._pending_full

    # ------------------------------------------------------------ protocol
    def enqueue(self, aabbs, static=None, read_status: bool = True) -> None:
        aabbs, static, n = self._arguments(aabbs, static)
        if n != self._slot_bodies:
            capacity = self._initial_capacity or max(1024, 8 * n)
            self._slots = [_Slot(self.runtime, max(n, 1), capacity) for _ in (0, 1)]
            self._slot_bodies, self._current = n, None
        full = self._current is None or self._force_full
        self._force_full = False
        self._target = 0 if self._current is None else 1 - self._current
        slot = self._slots[self._target]
        assert slot is not None  # a new body count (every count after reset) made both slots
        self.buffer = slot.pairs
        slot.pairs.new_query()
        self._aabbs, self.body_count, self._pending_full = aabbs, n, full
        if full:
            self.full.buffer = slot.pairs
            self.full.enqueue(aabbs, static, read_status=False)
        else:
            slot.pairs.reset_status()
            self._measure(aabbs, n, sizes=False)
        if n >= 1:
            self._sort_endpoints(aabbs, n, slot)
            cl.enqueue_copy(
                self.runtime.queue,
                buffer_of(slot.boxes),
                aabbs.base_data,
                byte_count=n * layouts.AABB.itemsize,
            )
        if not full and n >= 2:
            assert self._current is not None  # a step that is not full has a last one
            old = self._slots[self._current]
            assert old is not None  # made with slot
            self._update_pairs(aabbs, static, n, old, slot)
        if read_status:
            slot.pairs.start_status_read()

    def check(self) -> bool:
        assert self.buffer is not None  # the query (enqueue) that check follows set it
        status = self.buffer.read_status()
        if status["bad_body"] != layouts.BP_NO_BODY:
            self._raise_bad_body(int(status["bad_body"]))
        if self._pending_full and status["retry"]:
            self.full._prepare_retry(int(status["retry"]))
            return False
        if not self._pending_full and int(status["crossings"]) == INCREMENTAL_FAILED:
            self._force_full = True
            return False
        found = int(status["pairs_found"])
        if found > self.buffer.capacity:
            self.buffer.grow_for(found)
            return False
        self._current, self.last_count = self._target, found
        return True

    # ---------------------------------------------------------------- steps
    def _sort_endpoints(self, aabbs, n: int, slot: _Slot) -> None:
        from ...primitives import RadixSort

        keys = [self.exact(f"keys{k}", 2 * n) for k in range(3)]
        self.launch(
            self.program.kernel("endpoint_keys"),
            2 * n,
            aabbs.base_data,
            np.uint32(n),
            *(k.base_data for k in keys),
            *(s.base_data for s in slot.sorted),
        )
        sort = self.primitive(
            "sort32", lambda: RadixSort(self.runtime, key_bits=32, with_values=True)
        )
        for key, ends in zip(keys, slot.sorted):
            sort(key, ends, n=2 * n)
        self.launch(
            self.program.kernel("endpoint_ranks"),
            2 * n,
            np.uint32(n),
            *(s.base_data for s in slot.sorted),
            slot.ranks.base_data,
        )

    def _update_pairs(self, aabbs, static, n: int, old: _Slot, new: _Slot) -> None:
        from ...primitives import Compact, RadixSort, Reduce, Scan

        runtime, program = self.runtime, self.program
        moves = self.exact("moves", 6 * n, np.float32)
        total_moves = self.exact("total_moves", 1, np.float32)
        self.launch(
            program.kernel("rank_moves"),
            6 * n,
            np.uint32(n),
            old.ranks.base_data,
            new.ranks.base_data,
            moves.base_data,
        )
        self.primitive("sum", lambda: Reduce(runtime, np.float32, op="sum"))(
            moves, total_moves, n=6 * n
        )

        budget = self.max_moves_per_body * n
        change_capacity = CHANGES_PER_BODY * n + 1024
        changes_a = self.exact("changes_a", change_capacity)
        changes_b = self.exact("changes_b", change_capacity)
        change_count = self.exact("change_count", 1)
        cl.enqueue_fill_buffer(runtime.queue, buffer_of(change_count), np.uint32(0), 0, 4)
        self.launch(
            program.kernel("find_changes"),
            6 * n,
            aabbs.base_data,
            old.boxes.base_data,
            static.base_data,
            np.uint32(n),
            old.ranks.base_data,
            new.ranks.base_data,
            *(s.base_data for s in old.sorted),
            *(s.base_data for s in new.sorted),
            total_moves.base_data,
            np.float32(budget),
            change_count.base_data,
            np.uint32(change_capacity),
            changes_a.base_data,
            changes_b.base_data,
            new.pairs.status.base_data,
        )

        # the distinct changes, sorted by (a, b)
        bits = key_bits(n - 1)
        sort = self.primitive(
            ("sort", bits), lambda: RadixSort(runtime, key_bits=bits, with_values=True)
        )
        sort(changes_b, changes_a, n=change_count)
        sort(changes_a, changes_b, n=change_count)
        first = self.exact("first_flags", change_capacity)
        self.launch(
            program.kernel("mark_unique_changes"),
            change_capacity,
            changes_a.base_data,
            changes_b.base_data,
            change_count.base_data,
            np.uint32(change_capacity),
            first.base_data,
            new.pairs.status.base_data,
        )
        compact = self.primitive("compact", lambda: Compact(runtime))
        unique_index = self.exact("unique_index", change_capacity)
        unique_count = self.exact("unique_count", 1)
        compact(first, unique_index, unique_count, n=change_count)
        unique = self.exact("unique_changes", change_capacity, layouts.PAIR.dtype)
        self.launch(
            program.kernel("gather_unique_changes"),
            change_capacity,
            changes_a.base_data,
            changes_b.base_data,
            unique_index.base_data,
            unique_count.base_data,
            unique.base_data,
        )

        # new set = old set XOR changes, merged in (a, b) order
        old_capacity = old.pairs.capacity
        keep_old = self.exact("keep_old", old_capacity)
        keep_change = self.exact("keep_change", change_capacity)
        lists = (
            old.pairs.pairs.base_data,
            old.pairs.status.base_data,
            unique.base_data,
            unique_count.base_data,
        )
        self.launch(program.kernel("mark_old_pairs"), old_capacity, *lists, keep_old.base_data)
        self.launch(
            program.kernel("mark_new_pairs"), change_capacity, *lists, keep_change.base_data
        )
        scan = self.primitive("scan", lambda: Scan(runtime, np.uint32, inclusive=False))
        old_ranks, kept_total = self.exact("old_ranks", old_capacity), self.exact("kept", 1)
        change_ranks = self.exact("change_ranks", change_capacity)
        added_total = self.exact("added", 1)
        scan(keep_old, old_ranks, n=old.pairs.count, total=kept_total)
        scan(keep_change, change_ranks, n=unique_count, total=added_total)
        capacity = np.uint32(new.pairs.capacity)
        self.launch(
            program.kernel("place_old_pairs"),
            old_capacity,
            old.pairs.pairs.base_data,
            old.pairs.status.base_data,
            keep_old.base_data,
            old_ranks.base_data,
            unique.base_data,
            unique_count.base_data,
            change_ranks.base_data,
            added_total.base_data,
            capacity,
            new.pairs.pairs.base_data,
        )
        self.launch(
            program.kernel("place_new_pairs"),
            change_capacity,
            old.pairs.pairs.base_data,
            old.pairs.status.base_data,
            old_ranks.base_data,
            kept_total.base_data,
            unique.base_data,
            unique_count.base_data,
            keep_change.base_data,
            change_ranks.base_data,
            added_total.base_data,
            capacity,
            new.pairs.pairs.base_data,
            new.pairs.status.base_data,
        )
