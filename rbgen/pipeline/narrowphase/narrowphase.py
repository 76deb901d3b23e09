"""The narrowphase stage: contact manifolds for the broadphase pairs.

A step enqueues a fixed sequence of launches with no blocking read:

1. ``classify_pairs`` routes every pair to the queue of its pair kernel
   ("kind", a `kinds.PairKernel`: the kernel declared for its two shape types)
   and clears its contact flag (a world whose only kind is a separating-axis
   one, e.g. boxes only, skips it: that kernel reads the pair list directly);
2. each kind that finds its contacts in one kernel (sphere and capsule pairs,
   convex-plane, capsule-convex) writes the manifold slots of its pairs;
3. convex pairs (box-box, box-hull, hull-hull) go through two kernels
   instead of one large one (which would diverge on GPUs: most pairs stop
   at a separating axis): ``find_separating_axis`` (one launch per convex
   kind) appends the touching pairs to a clipping queue;
   ``clip_incident_face`` runs over that queue and reduces each pair's
   points to at most four;
4. ``scatter_manifolds`` writes the manifolds in pair order (deterministic):
   every kernel that stores a manifold also counts it in its placement tile
   (a fixed run of pairs, one atomic increment), so each work group of the
   scatter finds its tile's start by summing the counts before it, with no
   prefix-sum launches of its own.

The kinds a world needs, and the programs built for them, follow from the shape
types present (`kinds.kinds_for`). Kernel arguments are bound by name: each
kernel's C signature names what it takes from `ARGUMENTS`, so a new pair kernel
reads whichever shape arrays it declares and needs no launch code of its own.

Counts stay on the device: the pair count, the queue lengths, the manifold
count (the clipping queue's length of the last call stays in
``sat_count[1]``). Non-blocking contract for a step: the manifold buffer has a
capacity; when more manifolds exist, ``overflow[0]`` receives the number
needed (else 0, so nobody clears it) and ``manifold_count[0]`` the true count
(consumers use min(count, capacity)).
The host reads ``overflow`` without stalling (e.g. a non-blocking copy
checked at the start of the next step), then grows the buffer and redoes the
step; nothing is dropped silently. `find_contacts` does this synchronously.

Sub-features: a pair's key is (a, b, sub) (`Pair`); every manifold carries its
pair's ``sub``, so one body pair may have several manifolds (compound children,
mesh triangles), each warm-started on its own.

Separating-axis cache: one `SatCacheEntry` per pair-list index, keyed by the
pair (a, b, sub). When the broadphase's sorted pair list keeps a pair at the
same index (the common case at rest), last step's best axis is tried first and
usually ends the test for separated pairs; a mismatched key only costs the
full test. The cache survives between calls and is cleared when the pair
capacity grows.

Margin: points with separation up to ``+margin`` are reported (resting
contacts persist between steps).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ... import layouts
from ...codegen import compile_spec, kernel_signatures
from ...device import Runtime, buffer_of
from ...errors import RbgenError
from ...shapes import KERNEL_ARGUMENTS, PackedShapes, ShapeTable, table_arguments
from .kinds import kinds_for, pair_kernel
from .templates import CLIP, DISPATCH, default_placement_tile, default_work_group_size

#: every argument the stage gives its kernels, by name (what it is)
ARGUMENTS = {
    **{name: f"PackedShapes.{field}" for field, name in KERNEL_ARGUMENTS.items()},
    "bodies": "Body records",
    "pairs": "Pair records of the call",
    "pair_count": "device uint: pairs in the list",
    "pair_list_size": "uint: the pair list's size (no count reaches past it)",
    "pair_capacity": "uint: entries per queue (the stage's pair capacity)",
    "queues": "one queue per kind: pair indices | RB_PAIR_SWAPPED",
    "queue_counts": "device uint per kind: its queue's length",
    "kind": "uint: the launched kernel's queue",
    "contact_flags": "device uint per pair: 1 when its slot holds a manifold",
    "slots": "ContactManifold per pair index",
    "tile_counts": "device uint per placement tile: manifolds stored in it",
    "tile_count": "uint: placement tiles",
    "cache": "SatCacheEntry per pair index",
    "results": "SatResult queue of clip_incident_face",
    "result_count": "device uint[2]: its length (running, last call's)",
    "sat_count": "the same array as result_count",
    "margin": "float: largest separation reported",
    "manifolds": "ContactManifold output",
    "manifold_capacity": "uint: its size",
    "manifold_count": "device uint: manifolds found",
    "overflow": "device uint: the capacity needed, 0 when they fit",
}


def _data(a):
    return a.data if hasattr(a, "data") else a


class _Launch:
    """A bound kernel with the names of its arguments, in order."""

    __slots__ = ("kernel", "names", "work_group_size")

    def __init__(self, kernel, names: tuple[str, ...], work_group_size: int):
        self.kernel, self.names, self.work_group_size = kernel, names, work_group_size

    def __call__(self, count: int, values: dict):
        return self.kernel.over(count, self.work_group_size, *[values[n] for n in self.names])


class Narrowphase:
    """Contact manifolds for pairs of bodies with the shape types of one world.

    ``shapes`` is the world's `ShapeTable` (or a tuple of shape type names,
    then give ``max_face_vertices``). A shape pair without a kernel raises here,
    at construction, never during a step. Each pair kernel's choices are fixed
    by its declaration (`templates`): box pairs run through a closed-form
    15-axis kernel; the edge-edge axes of the other convex tests are the unique
    edge directions when a box is involved (three of them) and the Gauss-map
    edge pairs for hull pairs (which scale to large hulls). A world whose
    shapes cannot touch each other (only planes) gets a narrowphase that
    reports no contacts. ``work_group_size`` and ``placement_tile`` (pairs per
    scatter work group, a multiple of the work-group size; default per device)
    choose kernel shapes; results are the same.
    """

    def __init__(
        self,
        runtime: Runtime,
        shapes,
        *,
        max_face_vertices: int | None = None,
        work_group_size: int | None = None,
        placement_tile: int | None = None,
    ):
        #: a table given here is watched: when shapes with larger faces are added later,
        #: the clipping kernel is rebuilt for them before the next launch
        self.table = shapes if isinstance(shapes, ShapeTable) else None
        self._table_size = 0
        if self.table is not None:
            types = shapes.type_names()
            max_face_vertices = max_face_vertices or shapes.max_face_vertices()
            self._table_size = len(shapes.shapes)
        else:
            types = tuple(shapes)
        self.runtime = runtime
        self.kinds = kinds_for(types)
        self.kind_index = {k: i for i, k in enumerate(self.kinds)}
        declared = [pair_kernel(k) for k in self.kinds]
        #: one separating-axis kind with one shape type on both sides: its kernel reads the
        #: pair list itself and no classify_pairs runs
        only = declared[0] if len(declared) == 1 else None
        self.direct = (
            only is not None
            and "direct" in only.template.params
            and all(first == second for first, second in only.handles(types))
        )
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        wg = self.work_group_size
        self.placement_tile = tile = placement_tile or default_placement_tile(runtime.traits, wg)
        if tile % wg:
            raise RbgenError(
                f"placement_tile ({tile}) must be a multiple of work_group_size ({wg})"
            )
        self.max_face_vertices = max(3, int(max_face_vertices or 4))
        self._classify: _Launch | None = None
        self._scatter: _Launch | None = None
        self._clip: _Launch | None = None
        if self.kinds:
            dispatch = DISPATCH.spec(work_group_size=wg, kinds=self.kinds, placement_tile=tile)
            self._classify = self._launch(dispatch, "classify_pairs")
            self._scatter = self._launch(dispatch, "scatter_manifolds")
        launches = self._build_pair_kernels(declared)
        #: (kind, launch) of the kinds that store their manifolds, then of the
        #: separating-axis kinds (whose results clip_incident_face turns into manifolds)
        self._contact = [(k.name, launches[k.name]) for k in declared if not k.separating_axis]
        self._separating = [(k.name, launches[k.name]) for k in declared if k.separating_axis]
        self._build_clip()
        self.capacity = 0
        self._counters_clear = True  # queue counters hold zeros (see enqueue)

    def _launch(self, spec, kernel_name: str) -> _Launch:
        """Build ``spec`` (programs are cached) and bind one of its kernels by argument name."""
        program = compile_spec(self.runtime, spec)
        names = tuple(a["name"] for a in kernel_signatures(spec.source)[kernel_name])
        unknown = [n for n in names if n not in ARGUMENTS and n not in table_arguments()]
        if unknown:
            raise RbgenError(
                f"narrowphase: kernel {kernel_name} of {spec.path} takes {unknown}, "
                f"which the stage does not provide (it provides {list(ARGUMENTS)})"
            )
        return _Launch(self.runtime.bound(program.kernel(kernel_name)), names, self.work_group_size)

    def _build_pair_kernels(self, declared) -> dict:
        """One program per template and parameter set (a template with a ``kinds``
        parameter holds several kernels); the launch of each kind."""
        shared = {
            "work_group_size": self.work_group_size,
            "placement_tile": self.placement_tile,
            "direct": self.direct,
            "max_face_vertices": self.max_face_vertices,
        }
        programs: dict[tuple, list] = {}
        for kind in declared:
            programs.setdefault((kind.template.path, kind.params), []).append(kind)
        launches = {}
        for group in programs.values():
            template = group[0].template
            values: dict[str, Any] = {k: v for k, v in shared.items() if k in template.params}
            values.update(group[0].params)
            if "kinds" in template.params:
                values["kinds"] = tuple(kind.name for kind in group)
            spec = template.spec(**values)
            for kind in group:
                launches[kind.name] = self._launch(spec, kind.kernel)
        return launches

    def _build_clip(self) -> None:
        if not self._separating:
            return
        self._clip = self._launch(
            CLIP.spec(
                work_group_size=self.work_group_size,
                placement_tile=self.placement_tile,
                max_face_vertices=self.max_face_vertices,
            ),
            "clip_incident_face",
        )

    def _follow_table(self) -> None:
        """Rebuild for faces larger than the clipping buffers (shapes added since)."""
        if self.table is None or len(self.table.shapes) == self._table_size:
            return
        self._table_size = len(self.table.shapes)
        kinds = kinds_for(self.table.type_names())
        if not set(kinds) <= set(self.kinds):
            raise RbgenError(
                f"narrowphase: the shape table now needs kinds {list(kinds)} but this "
                f"Narrowphase was built for {list(self.kinds)}; build a new one"
            )
        needed = self.table.max_face_vertices()
        if needed > self.max_face_vertices:
            self.max_face_vertices = needed
            self._build_clip()
            if any("max_face_vertices" in pair_kernel(k).template.params for k in self.kinds):
                # pair kernels that clip polygons themselves size their buffers alike
                launches = self._build_pair_kernels([pair_kernel(k) for k in self.kinds])
                self._contact = [(k, launches[k]) for k, _ in self._contact]
                self._separating = [(k, launches[k]) for k, _ in self._separating]

    # ------------------------------------------------------------------ buffers
    def _ensure(self, pair_capacity: int) -> None:
        if pair_capacity <= self.capacity:
            return
        q = self.runtime.queue
        cap = int(pair_capacity)
        self._counters_clear = True  # fresh zeros (scatter_manifolds clears them after use)
        self.contact_flags = cla.zeros(q, cap, np.uint32)
        self.tile_count = -(-cap // self.placement_tile)
        self.tile_counts = cla.zeros(q, self.tile_count, np.uint32)
        self.slots = cla.zeros(q, cap, layouts.CONTACT_MANIFOLD.dtype)
        self.queues = cla.zeros(q, cap * len(self.kinds), np.uint32)
        self.queue_counts = cla.zeros(q, len(self.kinds), np.uint32)
        self.sat_count = cla.zeros(q, 2, np.uint32)  # [running count, last call's count]
        self.sat_cache = cla.zeros(q, cap, layouts.SAT_CACHE_ENTRY.dtype)
        self.sat_results = cla.zeros(q, cap if self._separating else 1, layouts.SAT_RESULT.dtype)
        self.capacity = cap

    # ------------------------------------------------------------------ step
    def enqueue(
        self,
        bodies,
        shapes: PackedShapes,
        pairs,
        pair_count,
        manifolds,
        manifold_count,
        overflow,
        margin: float = 0.0,
    ) -> dict:
        """Enqueue the whole stage; returns its events by stage name (no blocking read).

        ``bodies``, ``pairs`` (Pair records), ``pair_count`` (uint32 array(1)),
        ``manifolds`` (ContactManifold records, its size is the capacity),
        ``manifold_count`` (uint32 array(1), written) and ``overflow`` (uint32
        array(1), set to the needed capacity when it is exceeded, else to 0)
        are pyopencl arrays; ``shapes`` are `PackedShapes` on the device.
        Events: "classify", each kind by name (separating-axis kinds as
        "sat_<kind>"), "clip", "scatter".
        """
        if not (np.isfinite(margin) and margin >= 0):
            raise RbgenError(f"margin must be a non-negative finite number, got {margin!r}")
        self._follow_table()
        rt = self.runtime
        if not self.kinds:  # nothing can touch: no manifolds, no overflow
            cl.enqueue_fill_buffer(rt.queue, _data(overflow), np.uint32(0), 0, 4)
            return {
                "clear": cl.enqueue_fill_buffer(rt.queue, _data(manifold_count), np.uint32(0), 0, 4)
            }
        pair_list_size = int(pairs.size)
        self._ensure(max(1, pair_list_size))
        size = max(1, pair_list_size)
        if not self._counters_clear:  # a call that stopped before its scatter_manifolds
            for counters in (self.queue_counts, self.sat_count):
                cl.enqueue_fill_buffer(
                    rt.queue, buffer_of(counters), np.uint32(0), 0, counters.nbytes
                )
        self._counters_clear = False
        values = {
            **shapes.kernel_arguments(),
            "bodies": bodies,
            "pairs": pairs,
            "pair_count": pair_count,
            "pair_list_size": np.uint32(pair_list_size),
            "pair_capacity": np.uint32(self.capacity),
            "queues": self.queues,
            "queue_counts": self.queue_counts,
            "kind": np.uint32(0),
            "contact_flags": self.contact_flags,
            "slots": self.slots,
            "tile_counts": self.tile_counts,
            "tile_count": np.uint32(self.tile_count),
            "cache": self.sat_cache,
            "results": self.sat_results,
            "result_count": self.sat_count,
            "sat_count": self.sat_count,
            "margin": np.float32(margin),
            "manifolds": manifolds,
            "manifold_capacity": np.uint32(manifolds.size),
            "manifold_count": manifold_count,
            "overflow": overflow,
        }
        # built with the kinds, which are not empty here
        assert self._classify is not None and self._scatter is not None
        events = {}
        if not self.direct:  # (else the separating-axis kernel reads the pairs and clears)
            events["classify"] = self._classify(size, values)
        for kind, launch in self._contact:
            values["kind"] = np.uint32(self.kind_index[kind])
            events[kind] = launch(size, values)
        for kind, launch in self._separating:
            values["kind"] = np.uint32(self.kind_index[kind])
            events["sat_" + kind] = launch(size, values)
        if self._separating:
            assert self._clip is not None  # _build_clip builds it for separating-axis kinds
            events["clip"] = self._clip(size, values)
        events["scatter"] = self._scatter(self.tile_count * self.work_group_size, values)
        self._counters_clear = True
        return events

    # ------------------------------------------------------------------ convenience
    def find_contacts(
        self,
        bodies,
        shapes: PackedShapes,
        pairs,
        pair_count,
        margin: float = 0.0,
        capacity: int | None = None,
    ) -> np.ndarray:
        """All manifolds as host `ContactManifold` records, growing the output as needed.

        Blocking (reads the count); for tests, tools and benchmarks. Arguments
        as in `enqueue`; ``pair_count`` may also be a host int.
        """
        q = self.runtime.queue
        if not isinstance(pair_count, cla.Array):
            pair_count = cla.to_device(q, np.array([int(pair_count)], np.uint32))
        capacity = max(1, int(capacity if capacity is not None else max(1, pairs.size // 2)))
        count = cla.zeros(q, 1, np.uint32)
        overflow = cla.zeros(q, 1, np.uint32)
        while True:
            manifolds = cla.empty(q, capacity, layouts.CONTACT_MANIFOLD.dtype)
            self.enqueue(bodies, shapes, pairs, pair_count, manifolds, count, overflow, margin)
            needed = int(self.runtime.read(overflow)[0])
            if needed == 0:
                n = int(self.runtime.read(count)[0])
                return self.runtime.read(manifolds)[:n]
            capacity = needed


def find_contacts(
    runtime: Runtime, table: ShapeTable, bodies: np.ndarray, pairs, margin: float = 0.0, **options
) -> np.ndarray:
    """One-shot host convenience: `Body` records, a `ShapeTable` and pairs (an (n, 2)
    array of body indices with a < b, or Pair records) to `ContactManifold` records."""
    q = runtime.queue
    pairs = np.asarray(pairs)
    if pairs.dtype != layouts.PAIR.dtype:
        idx = np.asarray(pairs, np.int64).reshape(-1, 2)
        if len(idx) and (
            np.any(idx[:, 0] >= idx[:, 1]) or np.any(idx < 0) or np.any(idx >= len(bodies))
        ):
            raise RbgenError("find_contacts: pairs must be body indices (a, b) with a < b")
        records = layouts.PAIR.zeros(len(idx))
        records["a"], records["b"] = idx[:, 0], idx[:, 1]
        pairs = records
    n = len(pairs)
    padded = layouts.PAIR.zeros(max(1, n))
    padded[:n] = pairs
    narrowphase = Narrowphase(runtime, table, **options)
    packed = table.pack_all().to_device(q)
    return narrowphase.find_contacts(
        cla.to_device(q, np.ascontiguousarray(bodies)), packed, cla.to_device(q, padded), n, margin
    )
