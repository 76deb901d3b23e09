"""The midphase: sub-feature pairs of compounds and triangle meshes, between the
broadphase and the narrowphase.

The broadphase pairs whole bodies. For a pair with a compound or a triangle mesh the
narrowphase needs the parts that may touch, and the midphase expands every such pair
into them, in up to two expansions (each only when the world has the shape type):

1. children (compounds, `rbgen.compound`): ``place_children`` gives every child of a
   compound body a body of its own after the world's bodies (a proxy: the compound's
   body where the child is, with the child's shape and world AABB), then a pair with a
   compound becomes the pairs of its children whose boxes overlap the other side's;
2. triangles (meshes, `rbgen.mesh`): a pair of a mesh and a body (or a child) becomes
   the (body, triangle) pairs whose boxes overlap, found by walking the mesh's BVH
   (`rbgen.bvh`), with sub-feature 1 + the triangle.

Every other pair is copied. Each expansion counts its output per input pair, scans the
counts and writes each pair's output at its place, in input order and, within a pair,
in child or triangle order: deterministic, and no atomics. The narrowphase then runs on
the expanded list (over the placed bodies when there are compounds) with the pair
kernels of the parts' types; ``resolve_child_manifolds`` afterwards turns a proxy back
into its compound and names the child in the manifold's sub-feature
(`layouts.SUB_CHILD_SHIFT`), so warm starting keys each child and triangle apart.

Counts stay on the device. An expansion's output buffer has a capacity; when more pairs
exist its status word receives the size needed (nothing is written past the capacity, and
its count is then the capacity: the pairs stored, as the broadphase's count is),
the World's step guard sees it in the step report, grows the buffer (`grow`) and redoes
the step: no candidate is ever dropped. `find_pairs` does the same synchronously.

Traversal, a tunable shape of the triangle kernels (`TRIANGLES`): "global" walks each
pair's tree in global memory, one work-item per pair (Bullet3's way); "local" stages
subtrees of ``subtree_nodes`` nodes in local memory, shared by the pairs of a work group
that reach them. The tuner chooses per device (family "midphase", `register_family`);
untuned devices get `default_params`.
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cla

from .. import layouts, tuning
from ..codegen import Arg, KernelTemplate, Param, Signature, compile_spec, work_group_size_param
from ..compound import Compound
from ..device import DeviceTraits, Runtime
from ..errors import RbgenError
from ..launch import bound
from ..primitives import Scan
from ..primitives._base import size_bucket
from ..shapes import Box, PackedShapes, ShapeTable, shape_type
from .aabbs import shape_types_param

#: output pairs reserved per input pair before the first overflow (grown on demand)
PAIRS_PER_PAIR = 4
#: the status words: one per expansion (the output size needed, 0 when it fit)
STATUS_WORDS = {"children": 0, "triangles": 1}

_PAIR_INPUT = (
    Arg("__global const Pair*", "pairs"),
    Arg("__global const uint*", "pair_count"),
    Arg("const uint", "pair_capacity"),
)
_PAIR_OUTPUT = (
    Arg("__global const uint*", "offsets"),
    Arg("__global Pair*", "out_pairs"),
    Arg("const uint", "out_capacity"),
    Arg("__global uint*", "out_count"),  # (clamped to the capacity by the writer)
    Arg("__global uint*", "status"),
    Arg("const uint", "status_word"),
)
_MESH_ARRAYS = (
    Arg("__global const Body*", "bodies"),
    Arg("__global const Shape*", "shapes"),
    Arg("__global const float4*", "hull_vertices"),
    Arg("__global const Aabb*", "aabbs"),
    Arg("__global const BvhNode*", "bvh_nodes"),
    Arg("__global const MeshTriangle*", "mesh_triangles"),
    Arg("__global const float4*", "mesh_vertices"),
)
_CHILD_ARRAYS = (
    Arg("__global const Body*", "placed_bodies"),
    Arg("__global const Shape*", "shapes"),
    Arg("__global const Aabb*", "placed_aabbs"),
    Arg("__global const uint*", "first_proxy"),
)

TRAVERSALS = ("global", "local")


def _subtree_nodes_allowed(value) -> bool:
    return isinstance(value, int) and (
        value == 0 or (16 <= value <= 4096 and value & (value - 1) == 0)
    )


def _traversal_rule(values) -> str | None:
    if values["traversal"] == "local" and values["subtree_nodes"] == 0:
        return "traversal='local' needs subtree_nodes > 0 (the nodes staged in local memory)"
    if values["traversal"] == "global" and values["subtree_nodes"] != 0:
        return "traversal='global' stages nothing: subtree_nodes must be 0"
    return None


TRIANGLES = KernelTemplate(
    "pipeline/midphase/triangles.cl.mako",
    [
        work_group_size_param("input pairs per work group (one work-item each)"),
        Param(
            "traversal",
            TRAVERSALS,
            "global: each work-item walks its tree in global memory (Bullet3's way); "
            "local: a work group stages the subtrees its pairs reach in local memory, "
            "each read once for the group",
        ),
        Param(
            "subtree_nodes",
            _subtree_nodes_allowed,
            "local traversal: nodes of the largest subtree staged (16 bytes each); global: 0",
            "0, or a power of two from 16 to 4096",
        ),
    ],
    doc="Midphase: the (body, triangle) pairs of (mesh, body) pairs, by BVH walks.",
    requires=_traversal_rule,
    defaults=lambda traits: default_params(traits),
    signatures=(
        Signature(
            "count_triangle_pairs", _PAIR_INPUT + _MESH_ARRAYS + (Arg("__global uint*", "counts"),)
        ),
        Signature("write_triangle_pairs", _PAIR_INPUT + _MESH_ARRAYS + _PAIR_OUTPUT),
    ),
)

CHILDREN = KernelTemplate(
    "pipeline/midphase/children.cl.mako",
    [
        work_group_size_param("bodies, pairs or manifolds per work group (one work-item each)"),
        shape_types_param("the children's shape types (their world AABB cases)", empty=False),
    ],
    doc="Midphase: compound children as bodies of their own, their pairs, their manifolds.",
    roles={"manifolds": "inout"},
    defaults=lambda traits: {
        "work_group_size": default_work_group_size(traits),
        "shape_types": ("box", "hull", "sphere"),
    },
    signatures=(
        Signature(
            "place_children",
            (
                Arg("__global const Body*", "bodies"),
                Arg("__global const Aabb*", "aabbs"),
                Arg("const uint", "body_count"),
                Arg("__global const Shape*", "shapes"),
                Arg("__global const float4*", "hull_vertices"),
                Arg("__global const CompoundChild*", "compound_children"),
                Arg("__global const ChildProxy*", "proxies"),
                Arg("const uint", "proxy_count"),
                Arg("const float", "margin"),
                Arg("__global Body*", "placed_bodies"),
                Arg("__global Aabb*", "placed_aabbs"),
            ),
        ),
        Signature(
            "count_child_pairs", _PAIR_INPUT + _CHILD_ARRAYS + (Arg("__global uint*", "counts"),)
        ),
        Signature("write_child_pairs", _PAIR_INPUT + _CHILD_ARRAYS + _PAIR_OUTPUT),
        Signature(
            "resolve_child_manifolds",
            (
                Arg("__global ContactManifold*", "manifolds"),
                Arg("__global const uint*", "manifold_count"),
                Arg("const uint", "manifold_capacity"),
                Arg("__global const ChildProxy*", "proxies"),
                Arg("const uint", "body_count"),
            ),
        ),
    ),
)


def default_work_group_size(traits: DeviceTraits) -> int:
    """64 on GPUs, 16 on CPUs: a walk is long and divergent, so small groups keep the
    work-items of a group at the same pace (and, staged, few pairs wait for each subtree)."""
    return min(64 if traits.is_gpu else 16, traits.max_work_group_size)


def default_params(traits: DeviceTraits) -> dict:
    """The heuristic triangle-walk parameters: the global traversal on every device. On
    CPUs local memory is ordinary cached memory and barriers cost; on GPUs the nodes a
    group's walks share stay in the L1/L2 caches anyway, while staging a subtree in local
    memory (Bullet3's scheme) costs a barrier and reads nodes no walk visits
    (`benchmarks/midphase.py` compares both). The tuner (`search_space`) still tries the
    local traversal on each device."""
    return {
        "work_group_size": default_work_group_size(traits),
        "traversal": "global",
        "subtree_nodes": 0,
    }


def search_space(traits: DeviceTraits) -> list[dict]:
    """The tuner's candidates (the heuristic default first): both traversals, subtree
    sizes from 64 to 512 nodes, two work-group sizes."""
    space = [default_params(traits)]
    for wg in (16, 32, 64, 128):
        if wg > traits.max_work_group_size:
            continue
        space.append({"work_group_size": wg, "traversal": "global", "subtree_nodes": 0})
        for nodes in (64, 128, 256, 512):
            if 16 * nodes + 64 <= traits.local_mem_size:
                space.append({"work_group_size": wg, "traversal": "local", "subtree_nodes": nodes})
    unique = []
    for params in space:
        if params not in unique:
            unique.append(params)
    return unique


def needs_midphase(shape_types) -> bool:
    """Whether a world with these shape types has pairs to expand."""
    return any(shape_type(t).composite or t == "mesh" for t in shape_types)


class _Launch:
    """One kernel of a spec, its arguments bound by name from a dict of values."""

    def __init__(self, runtime: Runtime, spec, name: str, work_group_size: int):
        self.kernel = bound(runtime, compile_spec(runtime, spec).kernel(name))
        signature = spec.template.signatures[name]
        self.names = tuple(a.name for a in signature.args(spec.values))
        self.binder = signature.binder(spec, *self.names)
        self.work_group_size = work_group_size

    def __call__(self, count: int, values: dict):
        self.binder(self.kernel, *(_data(values[n]) for n in self.names))
        return self.kernel.launch(
            max(1, -(-int(count) // self.work_group_size)) * self.work_group_size,
            self.work_group_size,
        )


def _data(value):
    return value.data if isinstance(value, cla.Array) else value


class Expansion:
    """Count, scan, write: one expansion's output (see the module docstring)."""

    def __init__(
        self,
        runtime: Runtime,
        name: str,
        spec,
        count: str,
        write: str,
        work_group_size: int,
        capacity: int | None = None,
    ):
        self.runtime = runtime
        self.name = name
        self._count = _Launch(runtime, spec, count, work_group_size)
        self._write = _Launch(runtime, spec, write, work_group_size)
        self.scan = Scan(runtime, np.uint32, inclusive=False)
        self.status_word = STATUS_WORDS[name]
        self.capacity = 0
        self.requested = capacity
        self.input_size = 0
        self.count = cla.zeros(runtime.queue, 1, np.uint32)

    def ensure(self, input_size: int) -> None:
        """Size the per-input arrays for an input list of ``input_size`` entries and the
        output for the expansion's first use."""
        q = self.runtime.queue
        if input_size > self.input_size:
            self.input_size = int(input_size)
            self.counts = cla.empty(q, self.input_size, np.uint32)
            self.offsets = cla.empty(q, self.input_size, np.uint32)
        if self.capacity == 0:
            self.grow(self.requested or PAIRS_PER_PAIR * self.input_size + 1024)

    def grow(self, capacity: int) -> None:
        """Hold at least ``capacity`` output pairs (never shrinks)."""
        if capacity <= self.capacity:
            return
        self.capacity = int(capacity)
        self.pairs = cla.empty(self.runtime.queue, self.capacity, layouts.PAIR.dtype)

    def enqueue(self, pairs, pair_count, values: dict, status) -> None:
        size = max(1, int(pairs.size))
        self.ensure(size)
        values = {
            **values,
            "pairs": pairs,
            "pair_count": pair_count,
            "pair_capacity": np.uint32(pairs.size),
            "counts": self.counts,
            "offsets": self.offsets,
            "out_pairs": self.pairs,
            "out_capacity": np.uint32(self.capacity),
            "out_count": self.count,
            "status": status,
            "status_word": np.uint32(self.status_word),
        }
        self._count(size, values)
        self.scan(self.counts, self.offsets, n=pair_count, total=self.count)
        self._write(size, values)


class Midphase:
    """The midphase of a world with the shape types of ``table`` (a `ShapeTable`; see
    the module docstring).

    ``params``: the triangle walk's parameters (``work_group_size``, ``traversal``,
    ``subtree_nodes``), else the tuned ones, else `default_params`; ``capacity``: each
    expansion's first output capacity (default: `PAIRS_PER_PAIR` per input pair).
    After `enqueue`, ``pairs``, ``count`` and ``bodies`` are what the narrowphase
    reads, and ``status`` holds a word per expansion (`STATUS_WORDS`).
    """

    def __init__(
        self,
        runtime: Runtime,
        table: ShapeTable,
        *,
        params: dict | None = None,
        capacity: int | None = None,
    ):
        self.runtime = runtime
        self.table = table
        types = set(table.type_names())
        self.has_children = any(shape_type(t).composite for t in types)
        self.has_triangles = "mesh" in types
        self.params_override = dict(params) if params is not None else None
        if self.params_override is not None:
            TRIANGLES.spec(**self.params_override)  # checked now, not at the first step
        self.capacity = capacity
        self.children: Expansion | None = None
        self.triangles: Expansion | None = None
        self._triangle_bucket: int | None = None
        self.status = cla.zeros(runtime.queue, len(STATUS_WORDS), np.uint32)
        self._configured: np.ndarray | None = None
        self.pairs = self.count = self.bodies = None
        if self.has_children:
            child_types = tuple(
                sorted(
                    {
                        type(c).type_name
                        for s in table.shapes
                        if isinstance(s, Compound)
                        for c in s.children
                    }
                )
            )
            wg = default_work_group_size(runtime.traits)
            spec = CHILDREN.spec(work_group_size=wg, shape_types=child_types or ("sphere",))
            self._place = _Launch(runtime, spec, "place_children", wg)
            self._resolve = _Launch(runtime, spec, "resolve_child_manifolds", wg)
            self.children = Expansion(
                runtime, "children", spec, "count_child_pairs", "write_child_pairs", wg, capacity
            )

    # ------------------------------------------------------------------ parameters
    def params_for(self, input_size: int) -> dict:
        """Explicit params, else the tuned winner for this size, else the heuristic."""
        if self.params_override is not None:
            return dict(self.params_override)
        tuned = tuning.lookup(self.runtime.traits, FAMILY, "triangles", size_bucket(input_size))
        if tuned is not None:
            tuned = dict(tuned)
            tuned.pop("shape", None)
            try:
                TRIANGLES.spec(**tuned)
                return tuned
            except RbgenError:
                pass  # an entry from another version of the parameters: the heuristic
        return default_params(self.runtime.traits)

    def _triangle_expansion(self, input_size: int) -> Expansion:
        bucket = size_bucket(input_size)
        if self.triangles is None or (
            self.params_override is None and bucket != self._triangle_bucket
        ):
            params = self.params_for(input_size)
            spec = TRIANGLES.spec(**params)
            old = self.triangles
            self.triangles = Expansion(
                self.runtime,
                "triangles",
                spec,
                "count_triangle_pairs",
                "write_triangle_pairs",
                params["work_group_size"],
                old.capacity if old is not None else self.capacity,
            )
            self._triangle_bucket = bucket
            self.triangle_params = params
        return self.triangles

    # ------------------------------------------------------------------ compounds
    def _configure(self, shape_indices: np.ndarray) -> None:
        """The child proxies of the bodies with these shape indices (host tables, made
        once per upload)."""
        q = self.runtime.queue
        n = len(shape_indices)
        children = np.array(
            [len(s.children) if isinstance(s, Compound) else 0 for s in self.table.shapes], np.int64
        )
        per_body = children[shape_indices] if n else np.zeros(0, np.int64)
        first = n + np.concatenate([[0], np.cumsum(per_body)[:-1]]) if n else per_body
        total = int(per_body.sum())
        proxies = layouts.CHILD_PROXY.zeros(max(1, total))
        owners = np.repeat(np.arange(n), per_body)
        proxies["body"][:total] = owners
        proxies["child"][:total] = np.arange(total) - (first[owners] - n)
        self.body_count, self.proxy_count = n, total
        self.first_proxy = cla.to_device(
            q, np.maximum(first, 0).astype(np.uint32) if n else np.zeros(1, np.uint32)
        )
        self.proxies = cla.to_device(q, proxies)
        self.placed_bodies = cla.empty(q, max(1, n + total), layouts.BODY.dtype)
        self.placed_aabbs = cla.empty(q, max(1, n + total), layouts.AABB.dtype)

    # ------------------------------------------------------------------ step
    def enqueue(
        self,
        bodies,
        body_count: int,
        shapes: PackedShapes,
        aabbs,
        pairs,
        pair_count,
        margin: float = 0.0,
        shape_indices: np.ndarray | None = None,
    ) -> None:
        """Enqueue the expansions (no blocking read). ``bodies`` (Body records),
        ``aabbs`` (their world AABBs), ``pairs`` and ``pair_count`` (the broadphase's)
        are device arrays; ``shape_indices``: each body's shape index on the host (needed
        with compounds; the proxies are rebuilt when it is a new array)."""
        values = {
            **shapes.kernel_arguments(),
            "bodies": bodies,
            "aabbs": aabbs,
            "body_count": np.uint32(body_count),
            "margin": np.float32(margin),
        }
        if self.has_children:
            if shape_indices is None:
                raise RbgenError("midphase: a world with compounds needs the bodies' shape indices")
            if self._configured is not shape_indices:
                self._configure(shape_indices)
                self._configured = shape_indices
            values.update(
                proxies=self.proxies,
                proxy_count=np.uint32(self.proxy_count),
                first_proxy=self.first_proxy,
                placed_bodies=self.placed_bodies,
                placed_aabbs=self.placed_aabbs,
            )
            self._place(body_count + self.proxy_count, values)
            assert self.children is not None  # (made with the stage when it has compounds)
            self.children.enqueue(pairs, pair_count, values, self.status)
            pairs, pair_count = self.children.pairs, self.children.count
            values.update(bodies=self.placed_bodies, aabbs=self.placed_aabbs)
        if self.has_triangles:
            triangles = self._triangle_expansion(int(pairs.size))
            triangles.enqueue(pairs, pair_count, values, self.status)
            pairs, pair_count = triangles.pairs, triangles.count
        self.pairs, self.count, self.bodies = pairs, pair_count, values["bodies"]

    def resolve(self, manifolds, manifold_count) -> None:
        """Turn proxies in the narrowphase's manifolds back into their compounds, naming
        the child in the sub-feature (worlds with compounds; after the narrowphase)."""
        if not self.has_children:
            return
        self._resolve(
            manifolds.size,
            {
                "manifolds": manifolds,
                "manifold_count": manifold_count,
                "manifold_capacity": np.uint32(manifolds.size),
                "proxies": self.proxies,
                "body_count": np.uint32(self.body_count),
            },
        )

    # ------------------------------------------------------------------ overflow
    def expansions(self) -> list[Expansion]:
        return [e for e in (self.children, self.triangles) if e is not None]

    def problem(self, words: np.ndarray) -> dict | None:
        """The expansions whose output overflowed and the size each needs, from the status
        words (None: every output fit)."""
        found = {
            e.name: int(words[e.status_word])
            for e in self.expansions()
            if int(words[e.status_word]) > e.capacity
        }
        return found or None

    def grow(self, needed: dict) -> None:
        """Grow the outputs that overflowed (a quarter more than needed)."""
        for e in self.expansions():
            if e.name in needed:
                e.grow(int(needed[e.name] * 1.25) + 16)

    def find_pairs(
        self,
        bodies,
        body_count: int,
        shapes: PackedShapes,
        aabbs,
        pairs,
        pair_count,
        margin: float = 0.0,
        shape_indices=None,
    ) -> np.ndarray:
        """The expanded pairs as host `Pair` records, growing the outputs until they fit
        (blocking; for tests, tools and benchmarks). ``pair_count`` may be a host int."""
        q = self.runtime.queue
        if not isinstance(pair_count, cla.Array):
            pair_count = cla.to_device(q, np.array([int(pair_count)], np.uint32))
        while True:
            self.enqueue(
                bodies, body_count, shapes, aabbs, pairs, pair_count, margin, shape_indices
            )
            needed = self.problem(self.runtime.read(self.status))
            if needed is None:
                n = int(self.runtime.read(self.count)[0])
                return self.runtime.read(self.pairs)[:n]
            self.grow(needed)


# ---------------------------------------------------------------------- tuning
FAMILY = "midphase"


def _bench_build(runtime: Runtime, variant: str, params: dict):
    """A candidate: its template values (the bench builds its Midphase on its own scene)."""
    values = dict(params)
    values.pop("shape")
    return values


def _bench(runtime: Runtime, values: dict, n: int, rng):
    """A terrain of 2 x 128 x 128 triangles and min(n, 16384) boxes above it, every box
    paired with the terrain; checked against brute force."""
    from ..mesh import TriangleMesh
    from . import midphase_reference as reference
    from .aabbs import WorldAabbs

    bodies_n = int(min(max(n, 16), 1 << 14))
    vertices, triangles = reference.terrain(128, 1.0, rng)
    mesh = TriangleMesh(vertices, triangles, name="tuning terrain")
    table = ShapeTable()
    table.add(mesh)
    box = table.add(Box((0.4, 0.4, 0.4)))
    host = reference.bodies_above(bodies_n, mesh, box, rng)
    q = runtime.queue
    packed = table.pack_all().to_device(q)
    d_bodies = cla.to_device(q, host)
    aabbs = cla.empty(q, len(host), layouts.AABB.dtype)
    WorldAabbs(runtime, table.type_names())(
        d_bodies, packed.shapes, packed.vertices, aabbs, len(host)
    )
    pairs = layouts.PAIR.zeros(bodies_n)
    pairs["a"], pairs["b"] = 0, np.arange(1, bodies_n + 1)
    d_pairs = cla.to_device(q, pairs)
    count = cla.to_device(q, np.array([bodies_n], np.uint32))
    midphase = Midphase(runtime, table, params=values, capacity=64 * bodies_n)
    expected = reference.brute_force(mesh, host, aabbs.get(), pairs)

    def run():
        midphase.enqueue(d_bodies, len(host), packed, aabbs, d_pairs, count)

    def check():
        n_out = int(midphase.count.get()[0])
        return n_out <= midphase.triangles.capacity and np.array_equal(
            midphase.pairs.get()[:n_out], expected
        )

    return run, check


def register_family() -> None:
    """Declare the triangle walk to the tuner (`rbgen tune` times both traversals)."""
    if FAMILY in tuning.FAMILIES:
        return
    tuning.register(
        tuning.Family(
            name=FAMILY,
            variants=("triangles",),
            space=lambda traits: [{"shape": p["traversal"], **p} for p in search_space(traits)],
            build=_bench_build,
            bench=_bench,
            templates=lambda: {t: TRIANGLES for t in TRAVERSALS},
        )
    )


register_family()
