"""The narrowphase stage: contact manifolds for the broadphase pairs.

A step enqueues a fixed sequence of launches with no blocking read:

1. ``classify_pairs`` routes every pair to the queue of its shape-type pair
   ("kind", see `templates.ALL_KINDS`) and clears its contact flag (a world
   whose only kind is a convex one, e.g. boxes only, skips it: that kind's
   separating-axis kernel reads the pair list directly);
2. one kernel per primitive kind (sphere-sphere, sphere-plane, sphere-convex,
   sphere-capsule, capsule-capsule, capsule-plane, capsule-convex,
   convex-plane) writes the pair's manifold slot;
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

Counts stay on the device: the pair count, the queue lengths, the manifold
count (the clipping queue's length of the last call stays in
``sat_count[1]``). Non-blocking contract for a step: the manifold buffer has a
capacity; when more manifolds exist, ``overflow[0]`` receives the number
needed (else 0, so nobody clears it) and ``manifold_count[0]`` the true count
(consumers use min(count, capacity)).
The host reads ``overflow`` without stalling (e.g. a non-blocking copy
checked at the start of the next step), then grows the buffer and redoes the
step; nothing is dropped silently. `find_contacts` does this synchronously.

Separating-axis cache: one `SatCacheEntry` per pair-list index, keyed by the
pair's bodies (a, b). When the broadphase's sorted pair list keeps a pair at
the same index (the common case at rest), last step's best axis is tried
first and usually ends the test for separated pairs; a mismatched key only
costs the full test. The cache survives between calls and is cleared when
the pair capacity grows.

Margin: points with separation up to ``+margin`` are reported (resting
contacts persist between steps).
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ... import layouts
from ...codegen import compile_spec
from ...device import Runtime
from ...errors import RbgenError
from ...shapes import PackedShapes, ShapeTable
from .templates import (ALL_KINDS, CAPSULE_CONVEX, CAPSULE_CONVEX_KIND, CLIP, CONVEX_KINDS,
                        DISPATCH, PRIMITIVE_KINDS, PRIMITIVE_PAIRS, SAT, SAT_BOX_BOX)
from .templates import default_placement_tile, default_work_group_size

SUPPORTED_TYPES = ("box", "capsule", "hull", "plane", "sphere")


def kinds_for(shape_types) -> tuple[str, ...]:
    """The kinds (kernel shape-type pairs) needed by a world with these shape types."""
    types = set(shape_types)
    unsupported = sorted(types - set(SUPPORTED_TYPES))
    if unsupported:
        raise RbgenError(f"narrowphase: shape type(s) {unsupported} are not supported "
                         f"(supported: {list(SUPPORTED_TYPES)})")
    convex = types & {"box", "hull"}
    wanted = set()
    if "capsule" in types:
        wanted.add("capsule_capsule")
        if convex:
            wanted.add(CAPSULE_CONVEX_KIND)
        if "sphere" in types:
            wanted.add("sphere_capsule")
        if "plane" in types:
            wanted.add("capsule_plane")
    if "sphere" in types:
        wanted.add("sphere_sphere")
        if "plane" in types:
            wanted.add("sphere_plane")
        if convex:
            wanted.add("sphere_convex")
    if convex and "plane" in types:
        wanted.add("convex_plane")
    if "box" in types:
        wanted.add("box_box")
        if "hull" in types:
            wanted.add("box_hull")
    if "hull" in types:
        wanted.add("hull_hull")
    return tuple(k for k in ALL_KINDS if k in wanted)


def _data(a):
    return a.data if hasattr(a, "data") else a


class Narrowphase:
    """Contact manifolds for pairs of bodies with the shape types of one world.

    ``shapes`` is the world's `ShapeTable` (or a tuple of shape type names,
    then give ``max_face_vertices``). A shape pair without a kernel raises here,
    at construction, never during a step. Box pairs run through a closed-form
    15-axis kernel; the edge-edge axes of the other convex tests are the
    unique edge directions when a box is involved (three of them) and the
    Gauss-map edge pairs for hull pairs (which scale to large hulls). A world
    whose shapes cannot touch each other (only planes) gets a narrowphase
    that reports no contacts. ``work_group_size`` and ``placement_tile`` (pairs
    per scatter work group, a multiple of the work-group size; default per
    device) choose kernel shapes; results are the same.
    """

    def __init__(self, runtime: Runtime, shapes, *, max_face_vertices: int | None = None,
                 work_group_size: int | None = None, placement_tile: int | None = None):
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
        #: one convex kind (same shape type on both sides): its separating-axis kernel
        #: reads the pair list itself and no classify_pairs runs
        self.direct = len(self.kinds) == 1 and self.kinds[0] in CONVEX_KINDS
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        wg = self.work_group_size
        self.placement_tile = tile = placement_tile or default_placement_tile(runtime.traits, wg)
        if tile % wg:
            raise RbgenError(f"placement_tile ({tile}) must be a multiple of work_group_size ({wg})")
        self.max_face_vertices = max(3, int(max_face_vertices or 4))
        self.k_classify = self.k_scatter = None
        if self.kinds:
            dispatch = compile_spec(runtime, DISPATCH.spec(work_group_size=wg, kinds=self.kinds,
                                                           placement_tile=tile))
            self.k_classify = runtime.bound(dispatch.kernel("classify_pairs"))
            self.k_scatter = runtime.bound(dispatch.kernel("scatter_manifolds"))
        primitive = tuple(k for k in self.kinds if k in PRIMITIVE_KINDS)
        self.primitive_kernels = {}
        if primitive:
            prog = compile_spec(runtime, PRIMITIVE_PAIRS.spec(work_group_size=wg, kinds=primitive,
                                                               placement_tile=tile))
            self.primitive_kernels = {k: runtime.bound(prog.kernel(k)) for k in primitive}
        if CAPSULE_CONVEX_KIND in self.kinds:
            prog = compile_spec(runtime, CAPSULE_CONVEX.spec(work_group_size=wg, placement_tile=tile))
            capsule_convex = runtime.bound(prog.kernel("capsule_convex"))
            self.primitive_kernels[CAPSULE_CONVEX_KIND] = capsule_convex
        self.sat_kernels, self.sat_edge_axes = {}, {}
        for kind in (k for k in self.kinds if k in CONVEX_KINDS):
            if kind == "box_box":
                prog = compile_spec(runtime, SAT_BOX_BOX.spec(work_group_size=wg,
                                                              direct=self.direct))
                self.sat_kernels[kind] = runtime.bound(prog.kernel("find_separating_axis"))
                self.sat_edge_axes[kind] = "closed_form"
                continue
            first, second = kind.split("_")
            # unique directions win when a box is involved (3 of them); hull pairs prune
            # their edge pairs on the Gauss map instead
            edge_axes = "gauss_map" if (first, second) == ("hull", "hull") else "directions"
            prog = compile_spec(runtime, SAT.spec(work_group_size=wg, first=first, second=second,
                                                  edge_axes=edge_axes, direct=self.direct))
            self.sat_kernels[kind] = runtime.bound(prog.kernel("find_separating_axis"))
            self.sat_edge_axes[kind] = edge_axes
        self.k_clip = None
        self._build_clip()
        self.capacity = 0
        self._counters_clear = True  # queue counters hold zeros (see enqueue)

    def _build_clip(self) -> None:
        if not self.sat_kernels:
            return
        clip = compile_spec(self.runtime, CLIP.spec(work_group_size=self.work_group_size,
                                                    placement_tile=self.placement_tile,
                                                    max_face_vertices=self.max_face_vertices))
        self.k_clip = self.runtime.bound(clip.kernel("clip_incident_face"))

    def _follow_table(self) -> None:
        """Rebuild for faces larger than the clipping buffers (shapes added since)."""
        if self.table is None or len(self.table.shapes) == self._table_size:
            return
        self._table_size = len(self.table.shapes)
        kinds = kinds_for(self.table.type_names())
        if not set(kinds) <= set(self.kinds):
            raise RbgenError(f"narrowphase: the shape table now needs kinds {list(kinds)} but this "
                             f"Narrowphase was built for {list(self.kinds)}; build a new one")
        needed = self.table.max_face_vertices()
        if needed > self.max_face_vertices:
            self.max_face_vertices = needed
            self._build_clip()

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
        self.sat_results = cla.zeros(q, cap if self.sat_kernels else 1, layouts.SAT_RESULT.dtype)
        self.capacity = cap

    # ------------------------------------------------------------------ step
    def enqueue(self, bodies, shapes: PackedShapes, pairs, pair_count, manifolds, manifold_count,
                overflow, margin: float = 0.0) -> dict:
        """Enqueue the whole stage; returns its events by stage name (no blocking read).

        ``bodies``, ``pairs`` (Pair records), ``pair_count`` (uint32 array(1)),
        ``manifolds`` (ContactManifold records, its size is the capacity),
        ``manifold_count`` (uint32 array(1), written) and ``overflow`` (uint32
        array(1), set to the needed capacity when it is exceeded, else to 0)
        are pyopencl arrays; ``shapes`` are `PackedShapes` on the device.
        """
        if not (np.isfinite(margin) and margin >= 0):
            raise RbgenError(f"margin must be a non-negative finite number, got {margin!r}")
        self._follow_table()
        rt, wg = self.runtime, self.work_group_size
        if not self.kinds:  # nothing can touch: no manifolds, no overflow
            cl.enqueue_fill_buffer(rt.queue, _data(overflow), np.uint32(0), 0, 4)
            return {"clear": cl.enqueue_fill_buffer(rt.queue, _data(manifold_count), np.uint32(0),
                                                     0, 4)}
        pair_capacity = int(pairs.size)
        self._ensure(max(1, pair_capacity))
        cap = np.uint32(self.capacity)
        size = max(1, pair_capacity)
        margin = np.float32(margin)
        events = {}
        if not self._counters_clear:  # a call that stopped before its scatter_manifolds
            for counters in (self.queue_counts, self.sat_count):
                cl.enqueue_fill_buffer(rt.queue, counters.data, np.uint32(0), 0, counters.nbytes)
        self._counters_clear = False
        common = (pairs, bodies, shapes.shapes)
        tiles = (self.tile_counts, np.uint32(self.tile_count))
        if self.direct:  # the separating-axis kernel reads the pairs and clears for classify
            queue_args = (pair_count, self.contact_flags, *tiles)
        else:
            events["classify"] = self.k_classify.over(
                size, wg, pairs, pair_count, bodies, shapes.shapes, self.contact_flags,
                self.queues, self.queue_counts, cap, *tiles)
            queue_args = (self.queues, self.queue_counts, cap)
        out_args = (self.slots, self.contact_flags, self.tile_counts, margin)
        for kind, kernel in self.primitive_kernels.items():
            args = [*common, self.queues, self.queue_counts, cap, np.uint32(self.kind_index[kind]),
                    *out_args]
            if kind == "sphere_convex":
                args += [shapes.vertices, shapes.faces, shapes.face_indices]
            elif kind == CAPSULE_CONVEX_KIND:
                args += [shapes.vertices, shapes.faces, shapes.face_indices, shapes.edges]
            elif kind == "convex_plane":
                args += [shapes.vertices]
            events[kind] = kernel.over(size, wg, *args)
        if self.sat_kernels:
            result_count = self.sat_count
            for kind, kernel in self.sat_kernels.items():
                edge_axes = self.sat_edge_axes[kind]
                hull_args = []
                if edge_axes != "closed_form":
                    edges = shapes.edges if edge_axes == "directions" else shapes.adjacency
                    hull_args = [shapes.vertices, shapes.faces, edges]
                kind_arg = () if self.direct else (np.uint32(self.kind_index[kind]),)
                events["sat_" + kind] = kernel.over(
                    size, wg, *common, *hull_args, *queue_args, *kind_arg,
                    self.sat_cache, self.sat_results, result_count, margin)
            hulls = (shapes.vertices, shapes.faces, shapes.face_indices, shapes.edges,
                     shapes.adjacency)
            out = (self.slots, self.contact_flags, self.tile_counts)
            events["clip"] = self.k_clip.over(
                size, wg, *common, *hulls, self.sat_results, result_count, *out, margin)
        events["scatter"] = self.k_scatter.over(
            self.tile_count * wg, wg, self.slots, self.contact_flags, self.tile_counts, pair_count,
            np.uint32(pair_capacity), bodies, manifolds, np.uint32(manifolds.size), manifold_count,
            overflow, self.queue_counts, self.sat_count)
        self._counters_clear = True
        return events

    # ------------------------------------------------------------------ convenience
    def find_contacts(self, bodies, shapes: PackedShapes, pairs, pair_count, margin: float = 0.0,
                      capacity: int | None = None) -> np.ndarray:
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


def find_contacts(runtime: Runtime, table: ShapeTable, bodies: np.ndarray, pairs,
                  margin: float = 0.0, **options) -> np.ndarray:
    """One-shot host convenience: `Body` records, a `ShapeTable` and pairs (an (n, 2)
    array of body indices with a < b, or Pair records) to `ContactManifold` records."""
    q = runtime.queue
    pairs = np.asarray(pairs)
    if pairs.dtype != layouts.PAIR.dtype:
        idx = np.asarray(pairs, np.int64).reshape(-1, 2)
        if len(idx) and (np.any(idx[:, 0] >= idx[:, 1]) or np.any(idx < 0)
                         or np.any(idx >= len(bodies))):
            raise RbgenError("find_contacts: pairs must be body indices (a, b) with a < b")
        records = layouts.PAIR.zeros(len(idx))
        records["a"], records["b"] = idx[:, 0], idx[:, 1]
        pairs = records
    n = len(pairs)
    padded = layouts.PAIR.zeros(max(1, n))
    padded[:n] = pairs
    narrowphase = Narrowphase(runtime, table, **options)
    packed = table.pack_all().to_device(q)
    return narrowphase.find_contacts(cla.to_device(q, np.ascontiguousarray(bodies)), packed,
                                     cla.to_device(q, padded), n, margin)
