"""The pair buffer every broadphase fills, its ordering, and its status.

Contract (all broadphases):

* ``pairs`` is a device array of `Pair` (a < b) with room for ``capacity``
  pairs; after a query its first ``pair_count`` entries are the overlapping
  pairs sorted by (a, b), so the same input gives the same list on every
  device.
* ``status`` is one `BroadphaseStatus` on the device; ``count`` is a view of
  its first word (``pair_count``), a 1-element uint32 array that later stages
  pass to kernels as a device count.
* A query never drops a pair silently: ``pairs_found`` counts every pair even
  when it exceeds the capacity, and only ``min(pairs_found, capacity)`` are
  stored. The host sees the overflow when it checks the status, grows the
  buffer to fit and runs the query again.
* Checking without a stall: `start_status_read` enqueues a non-blocking copy
  of the status into pinned host memory right after the query; `read_status`
  waits for that copy only (a query whose read was not started, because its
  caller copies the status with its own, gets one then). In a simulation loop
  the host starts the read at the end of step k and checks it at the start of
  step k + 1 (by then the copy is long done); on overflow it grows the buffer and redoes step k.
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ... import layouts
from ...codegen import KernelTemplate, compile_spec, work_group_size_param
from ...device import DeviceTraits, Runtime, buffer_of
from ...errors import RbgenError

TEMPLATE = KernelTemplate(
    "pipeline/broadphase/pairs.cl.mako",
    [
        work_group_size_param(
            "pairs per work group; memory-bound, so any size that fills a CU works"
        )
    ],
    doc="Folding pairs into sort keys and packing sorted halves into Pair records.",
    defaults=lambda traits: {"work_group_size": default_work_group_size(traits)},
)

#: status-read events kept alive (more than the steps a World keeps in flight)
KEPT_READ_EVENTS = 4

#: Largest body count whose pairs fold into one 32-bit key a * n + b.
MAX_FOLDED_BODIES = 1 << 16


def default_work_group_size(traits: DeviceTraits) -> int:
    """128 on GPUs; 64 on CPUs (PoCL vectorises across work-items)."""
    return min(128 if traits.is_gpu else 64, traits.max_work_group_size)


def key_bits(largest: int) -> int:
    """Bits a radix sort needs for keys up to ``largest``."""
    return max(1, int(largest).bit_length())


def check_capacity(capacity) -> int:
    if (
        isinstance(capacity, (bool, np.bool_))
        or not isinstance(capacity, (int, np.integer))
        or capacity < 1
    ):
        raise RbgenError(f"pair capacity must be a positive integer, got {capacity!r}")
    return int(capacity)


class PairBuffer:
    """Device storage of one broadphase's pairs and status (see module docstring)."""

    def __init__(self, runtime: Runtime, capacity: int):
        self.runtime = runtime
        queue = runtime.queue
        words = layouts.BROADPHASE_STATUS.itemsize // 4
        self.status = cla.zeros(queue, words, np.uint32)
        #: ``pair_count`` on the device (a view of the status' first word)
        self.count = self.status[0:1]
        self._initial = np.zeros(1, layouts.BROADPHASE_STATUS.dtype).view(np.uint32).copy()
        self._initial.view(layouts.BROADPHASE_STATUS.dtype)["bad_body"] = layouts.BP_NO_BODY
        self._pinned_buffer = cl.Buffer(runtime.context, cl.mem_flags.ALLOC_HOST_PTR, 4 * words)
        self._pinned, _ = cl.enqueue_map_buffer(
            queue, self._pinned_buffer, cl.map_flags.READ, 0, (words,), np.dtype(np.uint32)
        )
        self._pinned[:] = self._initial
        #: the initial status on the device: the reset is a device copy (a copy from
        #: host memory returns a pyopencl NannyEvent, whose deletion waits for it)
        self._initial_device = cla.to_device(queue, self._initial)
        #: events of the last status reads; a NannyEvent waits for its copy when it is
        #: deleted, so the few last ones are kept (steps in flight) and only older,
        #: long-finished ones are dropped
        self._read_events: list = []
        #: whether the last query's status read was started (see `new_query`)
        self._read_started = False
        self.program = compile_spec(runtime, TEMPLATE.default_spec(runtime.traits))
        self.work_group_size = self.program.spec.values["work_group_size"]
        self._sorts: dict[tuple[int, bool], object] = {}
        self.capacity = 0
        self.allocate(check_capacity(capacity))

    def allocate(self, capacity: int) -> None:
        """(Re)allocate the pair arrays for ``capacity`` pairs (contents are lost)."""
        queue = self.runtime.queue
        self.capacity = int(capacity)
        self.pairs = cla.empty(queue, self.capacity, layouts.PAIR.dtype)
        self.pairs_a = cla.empty(queue, self.capacity, np.uint32)
        self.pairs_b = cla.empty(queue, self.capacity, np.uint32)

    def grow_for(self, needed: int) -> None:
        """Make room for ``needed`` pairs with headroom, so growth is rare."""
        if needed > self.capacity:
            self.allocate(max(needed + needed // 4, 2 * self.capacity))

    def reset_status(self) -> None:
        """Enqueue the status reset that starts every query (no launch, no wait)."""
        cl.enqueue_copy(self.runtime.queue, buffer_of(self.status), buffer_of(self._initial_device))

    def _sorter(self, bits: int, with_values: bool):
        from ...primitives import RadixSort

        key = (bits, with_values)
        if key not in self._sorts:
            self._sorts[key] = RadixSort(self.runtime, key_bits=bits, with_values=with_values)
        return self._sorts[key]

    def sort(self, body_count: int) -> None:
        """Enqueue the ordering of the stored pairs by (a, b) into ``pairs``."""
        if body_count < 2:
            return
        if body_count <= MAX_FOLDED_BODIES:
            self._launch(
                "combine_pair_keys", self.pairs_a, self.pairs_b, self.status, np.uint32(body_count)
            )
            self._sorter(key_bits(body_count * body_count - 1), False)(self.pairs_a, n=self.count)
            self._launch(
                "split_pair_keys", self.pairs_a, self.status, np.uint32(body_count), self.pairs
            )
        else:
            sort = self._sorter(key_bits(body_count - 1), True)
            sort(self.pairs_b, self.pairs_a, n=self.count)
            sort(self.pairs_a, self.pairs_b, n=self.count)
            self.pack()

    def pack(self) -> None:
        """Enqueue the packing of pair halves already in (a, b) order into ``pairs``."""
        self._launch("interleave_pairs", self.pairs_a, self.pairs_b, self.status, self.pairs)

    def _launch(self, name: str, *args) -> None:
        """One kernel of this buffer's program over the whole capacity."""
        self.runtime.bound(self.program.kernel(name)).over(
            self.capacity, self.work_group_size, *args
        )

    def new_query(self) -> None:
        """A query is being enqueued: its status read is not started yet."""
        self._read_started = False

    def start_status_read(self) -> None:
        """Enqueue a non-blocking copy of the status into pinned host memory."""
        event = cl.enqueue_copy(
            self.runtime.queue, self._pinned, buffer_of(self.status), is_blocking=False
        )
        self._read_events = [*self._read_events[-(KEPT_READ_EVENTS - 1) :], event]
        self._read_started = True

    def read_status(self) -> np.void:
        """The status of the last query (waits for its read, started now if it was not)."""
        if not self._read_started:
            self.start_status_read()
        self._read_events[-1].wait()
        return self._pinned.view(layouts.BROADPHASE_STATUS.dtype)[0].copy()

    def host_pairs(self, count: int) -> np.ndarray:
        """The first ``count`` pairs as an (m, 2) uint32 array (a blocking read)."""
        if count == 0:
            return np.zeros((0, 2), np.uint32)
        records = self.runtime.read(self.pairs[:count])
        return np.stack([records["a"], records["b"]], axis=1).astype(np.uint32)
