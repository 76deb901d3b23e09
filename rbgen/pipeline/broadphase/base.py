"""What every broadphase shares: arguments, body sizes, the query protocol.

A broadphase object is built once per world and queried every step:

``enqueue(aabbs, static, read_status=True)``
    enqueues the whole query (no blocking read): validation and sizes of the
    bodies, the algorithm's kernels, the ordering of the pairs, and a
    non-blocking read of the status into pinned memory (``read_status=False``:
    none, for a caller that copies ``buffer.status`` with its own reads: a
    small copy costs a GPU's queue as much as a launch; `check` then reads);
``check()``
    waits for that status copy only; raises `RbgenError` naming the first
    body with a NaN or inverted AABB; returns False, after adapting, when the
    pair buffer overflowed (it is grown to fit) or the status asks for a
    retry (status.retry: the grid's owner emission met more large bodies than
    it has rows; sap3: a degenerate step) -- the caller then redoes the query,
    or the whole step; True when ``pairs[:count]`` holds every pair;
``find_pairs(aabbs, static)``
    both, repeated until complete: the simple call for tests and benchmarks.
"""

from __future__ import annotations

import math

import numpy as np
import pyopencl.array as cla

from ... import layouts
from ...codegen import KernelTemplate, compile_spec, power_of_two, work_group_size_param
from ...device import DeviceTraits, Runtime
from ...errors import RbgenError
from .pairs import PairBuffer, check_capacity

BODIES_TEMPLATE = KernelTemplate(
    "pipeline/broadphase/bodies.cl.mako",
    [
        work_group_size_param(
            "bodies per work group; memory-bound, so any size that fills a CU works"
        )
    ],
    doc="Validation of world AABBs and their log2 sizes for the size statistics.",
    defaults=lambda traits: {"work_group_size": default_work_group_size(traits)},
)

#: Pairs per body reserved by default before the first query (grown on demand).
DEFAULT_PAIRS_PER_BODY = 8


def default_work_group_size(traits: DeviceTraits) -> int:
    """128 on GPUs; 64 on CPUs (PoCL vectorises across work-items)."""
    return min(128 if traits.is_gpu else 64, traits.max_work_group_size)


def check_size_factor(value, name: str = "large_factor") -> float:
    """A multiple of the typical size that sorts bodies by size: above ``large_factor``
    a body is tested apart from the others (grid, sap), above ``fine_factor`` it is in the
    grid's coarse level. It must be a positive finite number (the error names ``name``)."""
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise RbgenError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


def round_up(count: int, multiple: int) -> int:
    return max(1, -(-count // multiple)) * multiple


class Broadphase:
    """Base class: subclasses implement `_enqueue_query` (see module docstring)."""

    name = ""

    def __init__(
        self, runtime: Runtime, *, capacity: int | None = None, work_group_size: int | None = None
    ):
        if not isinstance(runtime, Runtime):
            raise RbgenError(f"runtime must be an rbgen.Runtime, got {type(runtime).__name__}")
        self.runtime = runtime
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        if not power_of_two(1, runtime.traits.max_work_group_size)(self.work_group_size):
            raise RbgenError(
                f"work_group_size={self.work_group_size!r} must be a power of two "
                f"no larger than {runtime.traits.max_work_group_size}"
            )
        self.buffer = None if capacity is None else PairBuffer(runtime, check_capacity(capacity))
        self._bodies = compile_spec(
            runtime, BODIES_TEMPLATE.spec(work_group_size=self.work_group_size)
        )
        self._scratch: dict[str, cla.Array] = {}
        self._views: dict[str, cla.Array] = {}
        self._primitives: dict = {}
        self._no_static = None
        self._aabbs: cla.Array | np.ndarray | None = None
        self.body_count = 0
        self.last_count = 0

    # ------------------------------------------------------------------ API
    @property
    def pairs(self) -> cla.Array:
        """Device `Pair` array; the first ``count`` entries are valid after a query."""
        assert self.buffer is not None  # made by the first query at the latest
        return self.buffer.pairs

    @property
    def count(self) -> cla.Array:
        """Device uint32 array of one element: the number of pairs stored."""
        assert self.buffer is not None  # made by the first query at the latest
        return self.buffer.count

    @property
    def capacity(self) -> int:
        return 0 if self.buffer is None else self.buffer.capacity

    @property
    def fallback(self) -> str | None:
        """Why this broadphase left the algorithm it was made with for the rest of its
        queries (None: it did not; the grid's owner emission gives way to slot emission)."""
        return None

    def describe(self) -> str:
        """The algorithm its queries run now, in a few words (benchmark records)."""
        return self.name

    def enqueue(self, aabbs, static=None, read_status: bool = True) -> None:
        """Enqueue one query (no blocking read); `check` tells whether it is complete."""
        aabbs, static, n = self._arguments(aabbs, static)
        if self.buffer is None:
            self.buffer = PairBuffer(self.runtime, max(1024, DEFAULT_PAIRS_PER_BODY * n))
        self.buffer.new_query()
        self._aabbs, self.body_count = aabbs, n
        if n >= 2:
            self._start_query(aabbs, n)
            self._enqueue_query(aabbs, static, n)
        else:
            self.buffer.reset_status()
            if n == 1:
                self._measure(aabbs, n, sizes=False)  # still validates the single box
        if read_status:
            self.buffer.start_status_read()

    def check(self) -> bool:
        """True when the last query stored every pair; False after growing the buffer."""
        assert self.buffer is not None  # made by the query (enqueue) that check follows
        status = self.buffer.read_status()
        if status["bad_body"] != layouts.BP_NO_BODY:
            self._raise_bad_body(int(status["bad_body"]))
        if status["retry"]:
            self._prepare_retry(int(status["retry"]))
            return False
        found = int(status["pairs_found"])
        if found > self.buffer.capacity:
            self.buffer.grow_for(found)
            return False
        self.last_count = found
        return True

    def find_pairs(self, aabbs, static=None) -> int:
        """Run queries until every pair is stored; returns the pair count."""
        while True:
            self.enqueue(aabbs, static)
            if self.check():
                return self.last_count

    def host_pairs(self) -> np.ndarray:
        """The pairs of the last complete query as an (m, 2) uint32 numpy array."""
        assert self.buffer is not None  # made by the first query at the latest
        return self.buffer.host_pairs(self.last_count)

    # ---------------------------------------------------------- subclasses
    def _enqueue_query(self, aabbs: cla.Array, static: cla.Array, n: int) -> None:
        """Enqueue the algorithm for n >= 2 bodies, ending with ordered ``pairs``."""
        raise NotImplementedError

    def _start_query(self, aabbs: cla.Array, n: int) -> None:
        """Enqueue what precedes the algorithm for n >= 2 bodies: the status reset,
        validation and the size statistics (overridden where the algorithm's first
        kernel does these itself)."""
        assert self.buffer is not None  # enqueue made it before the query
        self.buffer.reset_status()
        self._measure(aabbs, n)

    def _prepare_retry(self, reason: int) -> None:
        """Adapt after a query that asked to be redone another way (status.retry)."""
        raise RbgenError(f"{type(self).__name__}: unexpected retry request {reason}")

    def primitive(self, key, make):
        """A primitive built once by ``make()`` and kept under ``key``."""
        if key not in self._primitives:
            self._primitives[key] = make()
        return self._primitives[key]

    def scratch(self, name: str, size: int, dtype=np.uint32) -> cla.Array:
        """A device array of at least ``size`` elements kept between queries.

        Primitives take host counts, so callers pass ``n=`` explicitly.
        """
        array = self._scratch.get(name)
        if array is None or array.size < size or array.dtype != np.dtype(dtype):
            array = self._scratch[name] = cla.empty(self.runtime.queue, max(1, size), dtype)
        return array

    def exact(self, name: str, size: int, dtype=np.uint32) -> cla.Array:
        """A scratch array of exactly ``size`` elements (a view from its start, kept
        while the scratch array and the size stay the same)."""
        array = self.scratch(name, size, dtype)
        view = self._views.get(name)
        if view is None or view.size != size or view.base_data is not array.base_data:
            view = self._views[name] = array[:size]
        return view

    def launch(self, kernel, count: int, *args) -> None:
        """``kernel`` over ``count`` items; arguments set only when changed (`rbgen.launch`)."""
        self.runtime.bound(kernel).over(count, self.work_group_size, *args)

    # -------------------------------------------------------------- helpers
    def _arguments(self, aabbs, static):
        queue = self.runtime.queue
        if isinstance(aabbs, np.ndarray):
            if aabbs.dtype != layouts.AABB.dtype:
                raise RbgenError(f"aabbs must have the Aabb layout dtype, got {aabbs.dtype}")
            aabbs = cla.to_device(queue, aabbs) if len(aabbs) else aabbs
        if isinstance(aabbs, np.ndarray):  # empty
            n = 0
        elif isinstance(aabbs, cla.Array) and aabbs.dtype == layouts.AABB.dtype:
            n = aabbs.size
        else:
            raise RbgenError(
                f"aabbs must be a pyopencl or numpy array of the Aabb layout, "
                f"got {type(aabbs).__name__}"
            )
        if static is None:
            if self._no_static is None or self._no_static.size < max(n, 1):
                self._no_static = cla.zeros(queue, max(n, 1), np.uint32)
            static = self._no_static
        else:
            if isinstance(static, np.ndarray):
                static = (
                    cla.to_device(queue, np.ascontiguousarray(static, np.uint32))
                    if len(static)
                    else cla.zeros(queue, 1, np.uint32)
                )
            if not isinstance(static, cla.Array) or static.dtype != np.uint32:
                raise RbgenError("static must be None or a uint32 array of flags (1 = static)")
            if n and static.size < n:
                raise RbgenError(f"static has {static.size} flags for {n} bodies")
        return aabbs, static, n

    def _measure(self, aabbs: cla.Array, n: int, sizes: bool = True) -> None:
        """Validation, plus (``sizes``) the sum of log2 sizes in ``self.log_size_sum``."""
        from ...primitives import Reduce

        log_sizes = self.exact("log_sizes", n, np.float32)
        assert self.buffer is not None  # enqueue made it before the query
        self.launch(
            self._bodies.kernel("measure_bodies"),
            n,
            aabbs.base_data,
            np.uint32(n),
            log_sizes.base_data,
            self.buffer.status.base_data,
        )
        if sizes:
            self.log_size_sum = self.exact("log_size_sum", 1, np.float32)
            self.primitive("sum", lambda: Reduce(self.runtime, np.float32, op="sum"))(
                log_sizes, self.log_size_sum, n=n
            )

    def _raise_bad_body(self, body: int) -> None:
        assert self._aabbs is not None  # set by the query whose status named the body
        record = self.runtime.read(self._aabbs[body : body + 1])[0]
        lower, upper = record["lower"][:3], record["upper"][:3]
        raise RbgenError(
            f"body {body} has an invalid AABB (NaN or lower > upper): "
            f"lower={lower.tolist()}, upper={upper.tolist()}"
        )
