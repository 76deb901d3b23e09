"""Memory: what a World needs, what the machine has, and a refusal when it does not fit.

A World checks before it allocates: at construction (its initial capacities), on every
add (the host mirror with its temporaries, and the device buffers its next step
allocates) and before a buffer grows on overflow (`rbgen.guard`). A need above a limit
raises `MemoryLimitError` naming both, and nothing is allocated: a process that
exhausts host memory is killed by the operating system without a word, and a failed
device allocation surfaces mid-step.

**Estimates** are sums over the World's buffers, each an element count times an item
size from `rbgen.layouts` (a few uint32 scratch arrays count words). The counts follow
the pipeline's own sizing: bodies; the pair capacity (`DEFAULT_PAIRS_PER_BODY` a body,
or the ``pair_capacity`` option, or what growth reached); the manifold capacity
(`MANIFOLDS_PER_BODY` a body, or ``manifold_capacity``, or grown), which also sizes each
of the constraint ring's `GENERATIONS`; the joints (their records with a backup per step
in flight, their joined pairs, and an edge each in every generation of the ring and in
the batching's lists); the substep motion records; once the World was given forces,
their uploads (`FORCE_UPLOADS` float4 arrays a body, each with a pinned host array:
``pinned``, host memory). Every buffer that grows with the scene has a term: tests hold
the growth of the named bytes within 1 KiB (and 5 % above) of the growth of the bytes
a World really holds, for every broadphase and solver, with and without forces,
substeps, sleeping and joints. Only fixed-size tables (shapes, status words, reports)
are left to `FIXED_BYTES`; `SCRATCH_ALLOWANCE` is a margin on top.

**Limits**: host: ``MemAvailable`` of ``/proc/meminfo`` and the headroom of this
process's cgroup (the smaller); device: its global memory (less what the other live
Worlds on it estimate, or the ``memory_limit`` option), and its largest single
allocation. A CPU device (PoCL) allocates from host memory, so there its buffers count
against the host limit too. OpenCL cannot say how much device memory other processes
hold: ``memory_limit`` is the lever for a shared GPU.
"""

from __future__ import annotations

import dataclasses
import os
import weakref

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from . import layouts
from .errors import MemoryLimitError
from .forces import FIELDS as FORCE_FIELDS
from .forces import KEEP_STEPS as FORCE_KEEP_STEPS
from .guard import STEPS_IN_FLIGHT
from .pipeline.broadphase.base import DEFAULT_PAIRS_PER_BODY
from .pipeline.broadphase.grid import OWNER_TABLES, grid_dim_for
from .pipeline.broadphase.pairs import MAX_FOLDED_BODIES
from .pipeline.broadphase.sap3 import CHANGES_PER_BODY
from .pipeline.constraints import GENERATIONS
from .pipeline.midphase import PAIRS_PER_PAIR
from .pipeline.step import MANIFOLDS_PER_BODY

WORD = 4  # bytes of a uint32 / float scratch element
FLOAT64 = 8
#: the grid's first pair buffer holds at least this many pairs (rbgen.pipeline.broadphase)
MIN_PAIRS = 1024
#: manifolds reserved for a small scene (`NarrowphaseStage.resize`: 4 x max(bodies, 16))
MIN_MANIFOLD_BODIES = 16
#: scratch that no term below names (sort tables, views, counters), as a fraction
SCRATCH_ALLOWANCE = 0.10
#: shapes, status words, the step report, primitives' small tables
FIXED_BYTES = 1 << 20

#: float64 arrays of one body that `BodyStore.add` holds while it checks and builds
#: the records (identity orientations and their normalised copy, two velocities, the
#: positions converted to float, mass, friction, restitution, and the checks' masks)
ADD_TEMPORARY_FLOAT64 = 4 + 4 + 3 + 3 + 3 + 3 + 4
#: the host mirror of one body: its record and its inverse inertia diagonal (float32)
HOST_BYTES_PER_BODY = layouts.BODY.itemsize + 3 * WORD
#: the force uploads a World holds once it was given forces (`rbgen.forces`): one float4
#: array a body per field, for each step a redo can reach and the step being enqueued,
#: each with a pinned host array of the same size that it is copied from
FORCE_UPLOADS = len(FORCE_FIELDS) * (FORCE_KEEP_STEPS + 1)
FORCE_UPLOAD_BYTES = 4 * WORD  # (a float4 a body)
#: float64 arrays of one joint that `rbgen.joints.pack_joints` holds while it checks and
#: packs the records (the bodies' poses at both ends, anchors, axes, limits, masks)
ADD_JOINT_TEMPORARY_FLOAT64 = 2 * (3 + 4) + 3 * 3 + 2 * 3 + 8


# ----------------------------------------------------------------- sizes


@dataclasses.dataclass(frozen=True)
class Sizes:
    """The element counts that size a World's buffers. ``expanded``: the output capacity of
    each midphase expansion in order (children, then triangles; none without compounds or
    meshes); ``proxies``: compound children placed as bodies of their own."""

    bodies: int
    pairs: int  # pair capacity
    manifolds: int  # manifold (and constraint) capacity
    expanded: tuple = ()
    proxies: int = 0
    joints: int = 0

    @property
    def narrow_pairs(self) -> int:
        """The pairs the narrowphase sees: the last expansion's, else the broadphase's."""
        return self.expanded[-1] if self.expanded else self.pairs


def default_pairs(bodies: int, option: int | None) -> int:
    """The first pair buffer's capacity (`rbgen.pipeline.broadphase.base`)."""
    return int(option) if option is not None else max(MIN_PAIRS, DEFAULT_PAIRS_PER_BODY * bodies)


def default_manifolds(bodies: int, option: int | None) -> int:
    """The first manifold buffer's capacity (`rbgen.pipeline.step.NarrowphaseStage`)."""
    return (
        int(option) if option is not None else MANIFOLDS_PER_BODY * max(bodies, MIN_MANIFOLD_BODIES)
    )


def grown_pairs(capacity: int, needed: int) -> int:
    """The pair capacity after an overflow that needed ``needed`` pairs
    (`rbgen.pipeline.broadphase.pairs.PairBuffer.grow_for`)."""
    return max(needed + needed // 4, 2 * capacity) if needed > capacity else capacity


def grown_manifolds(capacity: int, needed: int) -> int:
    """The manifold capacity after an overflow that needed ``needed`` manifolds
    (`rbgen.pipeline.step.NarrowphaseStage.recover`)."""
    return max(capacity, int(needed * 1.25) + 16)


def expanded_pairs(input_size: int, current: int) -> int:
    """A midphase expansion's output capacity for ``input_size`` input pairs
    (`rbgen.pipeline.midphase.Expansion.ensure`), or what it already holds."""
    return max(current, PAIRS_PER_PAIR * input_size + MIN_PAIRS)


def grown_expansion(capacity: int, needed: int) -> int:
    """A midphase expansion's capacity after an overflow (`Midphase.grow`)."""
    return max(capacity, int(needed * 1.25) + 16)


def table_words(capacity: int) -> int:
    """Slots of one generation's warm-start table (`rbgen.pipeline.constraints`)."""
    return 1 << max(4, int(2 * max(1, capacity) - 1).bit_length())


# ----------------------------------------------------------------- estimate


@dataclasses.dataclass(frozen=True)
class Estimate:
    """Device bytes of a World's buffers by name (``buffers``), with the largest single
    buffer (``largest``: name, bytes) and the total with the allowances; ``pinned``: the
    pinned host buffers it copies through, by name (host memory on a GPU: they count
    against the host limit, not the device's)."""

    sizes: Sizes
    buffers: dict
    largest: tuple
    pinned: dict = dataclasses.field(default_factory=dict)

    @property
    def total(self) -> int:
        """Device bytes with the allowances (`SCRATCH_ALLOWANCE`, `FIXED_BYTES`)."""
        return int(sum(self.buffers.values()) * (1 + SCRATCH_ALLOWANCE)) + FIXED_BYTES

    @property
    def pinned_total(self) -> int:
        """Bytes of the pinned host buffers."""
        return int(sum(self.pinned.values()))

    @property
    def named(self) -> int:
        """Every buffer a term names, device and pinned, without the allowances: what
        `device_bytes` measures of the World, less the small fixed tables (shapes, status
        words, reports) that `FIXED_BYTES` stands for."""
        return int(sum(self.buffers.values())) + self.pinned_total


def estimate(
    sizes: Sizes,
    *,
    broadphase: str = "grid",
    solver: str = "pgs",
    kinds: int = 1,
    sleeping: bool = False,
    contact_geometry: bool = False,
    forces: bool = False,
    support_chains: bool = False,
) -> Estimate:
    """The device buffers of a World of ``sizes`` (``kinds``: the narrowphase's shape-type
    pair queues; ``sleeping``: the World option; ``contact_geometry``: the PGS solve keeps a
    `layouts.CONTACT_GEOMETRY` a constraint (the block solve's serial form and persistent
    launch); ``forces``: the World was given external forces, so it holds `FORCE_UPLOADS`
    uploads, each a device array and a pinned host array; ``support_chains``: the World
    option). Each entry is (bytes of one
    buffer, how many such buffers).

    Contract: every buffer that grows with the bodies, pairs, manifolds or joints has a
    term here, for the broadphases, solvers and options a World takes (a test holds the
    named bytes, `Estimate.named`, within a few per cent and a few KiB of what a World
    really holds); only tables of a fixed size are left to `FIXED_BYTES`, and
    `SCRATCH_ALLOWANCE` is a margin on top, not a place for buffers the terms forget.
    Buffers made by a later step setting (solver substeps > 1 makes the substep motion
    records) are counted from the start: a setting changes without a memory check."""
    n, p, m, j = sizes.bodies, sizes.pairs, sizes.manifolds, sizes.joints
    q = sizes.narrow_pairs
    slots = 2 if broadphase == "sap3" else 1  # sap3 double-buffers its pairs and boxes
    one = {
        # bodies and what the step keeps per body
        "bodies": (layouts.BODY.itemsize * n, 1 + STEPS_IN_FLIGHT),  # + the redo backups
        "inertia": (layouts.BODY_INERTIA.itemsize * n, 1),
        "static flags": (WORD * n, 1),
        "aabbs": (layouts.AABB.itemsize * n, 1),
        "split velocities": (layouts.SPLIT_VELOCITY.itemsize * n, 1),
        # the step's external forces as per-substep velocity changes (linear, angular)
        "force kicks": (2 * 4 * WORD * n, 1),
        # the bodies' motion since the step began, for the substeps' contact targets
        # (made at the first step with solver substeps > 1, or by a persistent solve)
        "substep motion records": (layouts.BODY_DELTA.itemsize * n, 1),
        # pairs and the narrowphase's per-pair arrays
        "pairs": (layouts.PAIR.itemsize * p, slots),
        "pair halves": (2 * WORD * p, slots),
        "narrowphase slots": (layouts.CONTACT_MANIFOLD.itemsize * q, 1),
        "contact flags and queues": ((1 + kinds) * WORD * q, 1),
        "separating-axis cache": (layouts.SAT_CACHE_ENTRY.itemsize * q, 1),
        "separating-axis results": (layouts.SAT_RESULT.itemsize * q, 1),
        # manifolds, the constraint ring and the batching / solver lists
        "manifolds": (layouts.CONTACT_MANIFOLD.itemsize * m, 1),
        "constraints": (layouts.CONTACT_CONSTRAINT.itemsize * max(1, m), GENERATIONS),
        # (a joint's edge each, then a contact's)
        "constraint edges": (layouts.CONSTRAINT_EDGE.itemsize * max(1, m + j), GENERATIONS),
        "warm-start tables": (WORD * table_words(m), GENERATIONS),
    }
    if solver == "pgs" and support_chains:
        # the support chains' keys and links (made at the first step that runs them:
        # rbgen.pipeline.solvers.support)
        one["support chains"] = ((WORD + 2 * 4 * WORD) * n, 1)
    if sleeping:  # the sleep records, their redo backups, union-find nodes and marks
        one["sleep records"] = (layouts.BODY_SLEEP.itemsize * n, 1 + STEPS_IN_FLIGHT)
        one["sleep islands"] = (2 * WORD * n, 1)
    inputs = (p, *sizes.expanded[:-1])
    for k, (inputs_k, outputs_k) in enumerate(zip(inputs, sizes.expanded)):
        # each expansion's counts and offsets per input pair, and its output pairs
        one[f"midphase expansion {k + 1}"] = (
            2 * WORD * inputs_k + layouts.PAIR.itemsize * outputs_k,
            1,
        )
    if sizes.proxies:
        # compound children placed after the bodies (records and boxes), their proxies
        placed = n + sizes.proxies
        one["placed children"] = (
            (layouts.BODY.itemsize + layouts.AABB.itemsize) * placed
            + layouts.CHILD_PROXY.itemsize * sizes.proxies
            + WORD * n,
            1,
        )
    if broadphase == "sap":
        # the sweep's centre moments (6), log sizes, large flags and list, sort keys and
        # bodies, pair counts and offsets; the radix sort's keys and values; sorted boxes
        one["broadphase scratch"] = ((13 + 2) * WORD * n + layouts.AABB.itemsize * n, 1)
        # the pairs sorted into (a, b) order: folded keys (values too past
        # MAX_FOLDED_BODIES) and the digit table (at most a word a pair)
        one["pair sort"] = ((2 + (n > MAX_FOLDED_BODIES)) * WORD * p, 1)
    else:
        # grid (sap3's full query too): body links (two levels), levels, group offsets,
        # and the bucket heads (`grid_dim_for` cubed, a table per OWNER_TABLES)
        one["broadphase scratch"] = (WORD * (4 * n + OWNER_TABLES * grid_dim_for(n) ** 3), 1)
    if broadphase == "sap3":
        # per slot: boxes, ranks (6 endpoints), sorted endpoints (3 axes x 2); endpoint
        # keys (3 axes x 2) and the radix sort's keys and values (2 x 2)
        one["sweep endpoints"] = ((layouts.AABB.itemsize + 12 * WORD) * n, slots)
        one["sweep keys"] = (10 * WORD * n, 1)
        # the incremental update: rank moves (6 a body); per change slot the two halves,
        # flags, index, ranks and keep flags, the sort's keys and values and the unique
        # pair; per old pair its keep flag and rank
        changes = CHANGES_PER_BODY * n + 1024  # (`IncrementalSapBroadphase._update_pairs`)
        one["incremental update"] = (
            6 * WORD * n + (8 * WORD + layouts.PAIR.itemsize) * changes + 2 * WORD * p,
            1,
        )
    if solver == "jacobi":
        # two sides a constraint: slots, lists, and two float4 velocity changes each
        one["solver lists"] = ((2 * 2 * WORD + 2 * 2 * 4 * WORD) * m, 1)
        one["body contact lists"] = (2 * WORD * n, 1)
    else:
        # the most any batching allocates: cells for lanes mark a body per colour twice
        # (9 colours) and own it per cell colour (8); global batching's bids and colour
        # masks are fewer. Per constraint: order, slot, batch, blocked flag, group list.
        one["batching per body"] = ((2 * 9 + 8) * WORD * n, 1)
        one["batching per constraint"] = (5 * WORD * (m + j), 1)
        if contact_geometry:  # the block solve's, a contact constraint (solvers/pgs.py)
            one["contact geometry"] = (layouts.CONTACT_GEOMETRY.itemsize * max(1, m), 1)
        # the summed warm start's 64-bit sums (persistent PGS on GPUs)
        one["warm-start sums"] = (layouts.WARM_SUM_WORDS * 8 * n, 1)
    if j:
        # the records, and a backup per step in flight (`rbgen.joints.JointStore`)
        one["joints"] = (layouts.JOINT_CONSTRAINT.itemsize * j, 1 + STEPS_IN_FLIGHT)
        one["joined pairs"] = (2 * WORD * j, 1)
    pinned = {}
    if forces:
        one["force uploads"] = (FORCE_UPLOAD_BYTES * n, FORCE_UPLOADS)
        pinned["force upload staging"] = FORCE_UPLOAD_BYTES * n * FORCE_UPLOADS
    buffers = {name: size * count for name, (size, count) in one.items()}
    largest = max(((name, size) for name, (size, _) in one.items()), key=lambda t: t[1])
    return Estimate(sizes, buffers, largest, pinned)


# ----------------------------------------------------------------- limits


def _read_int(path: str) -> int | None:
    try:
        with open(path) as f:
            text = f.read().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _cgroup_headroom() -> tuple[int, str] | None:
    """Bytes left under this process's cgroup memory limit (v2, else v1), or None."""
    try:
        with open("/proc/self/cgroup") as f:
            lines = f.read().splitlines()
    except OSError:
        return None
    for line in lines:
        _, controllers, path = line.split(":", 2)
        if controllers == "":  # v2
            bases = [f"/sys/fs/cgroup{path}", "/sys/fs/cgroup"]
            files = ("memory.max", "memory.current")
        elif "memory" in controllers.split(","):
            bases = [f"/sys/fs/cgroup/memory{path}", "/sys/fs/cgroup/memory"]
            files = ("memory.limit_in_bytes", "memory.usage_in_bytes")
        else:
            continue
        for base in bases:
            limit = _read_int(os.path.join(base, files[0]))
            used = _read_int(os.path.join(base, files[1]))
            if limit is not None and used is not None and limit < 1 << 60:
                return max(0, limit - used), f"cgroup limit {format_bytes(limit)}"
    return None


def host_available() -> tuple[int | None, str]:
    """Bytes this process may still allocate on the host, and where that figure comes
    from (None: unknown, so nothing is refused on the host's account)."""
    found = []
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    found.append((int(line.split()[1]) * 1024, "MemAvailable"))
                    break
    except OSError:
        pass
    headroom = _cgroup_headroom()
    if headroom is not None:
        found.append(headroom)
    if not found:
        return None, "unknown"
    return min(found)


def rss_bytes() -> int:
    """Resident host memory of this process (for the soak; 0 where unknown)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


@dataclasses.dataclass(frozen=True)
class DeviceMemory:
    """A device's memory as OpenCL reports it; ``shares_host``: its buffers are host
    memory (a CPU device)."""

    name: str
    global_bytes: int
    max_alloc_bytes: int
    shares_host: bool

    @classmethod
    def of(cls, runtime) -> DeviceMemory:
        device = runtime.device
        return cls(
            device.name.strip(),
            int(device.global_mem_size),
            int(device.max_mem_alloc_size),
            runtime.traits.is_cpu,
        )


def format_bytes(count: float) -> str:
    """``count`` bytes in the largest binary unit that keeps it at 1 or more."""
    units = ("bytes", "KiB", "MiB", "GiB", "TiB")
    power = 0
    while abs(count) >= 1024 and power < len(units) - 1:
        count, power = count / 1024, power + 1
    return f"{count:,.0f} bytes" if power == 0 else f"{count:,.1f} {units[power]}"


# ----------------------------------------------------------------- one World

#: every live World's device estimate, by World (weakly held): Worlds on one device share it
_LEDGER: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


class WorldMemory:
    """The memory account of one World: its estimate now, and the checks of adds and
    growth against the limits (see the module docstring).

    ``options``: the World's construction options (``broadphase``, ``solver``,
    ``pair_capacity``, ``manifold_capacity``, ``memory_limit``)."""

    def __init__(self, owner, runtime, options: dict):
        self.runtime = runtime
        self.options = options
        self.device = DeviceMemory.of(runtime)
        self._owner = weakref.ref(owner)
        self.held = estimate(Sizes(0, 0, 0), **self._config(()))  # nothing allocated yet
        _LEDGER[owner] = (runtime.device.int_ptr, self.held.total)

    def _config(self, shape_types, forces: bool | None = None) -> dict:
        """The `estimate` options of this World (``forces``: whether it holds force
        uploads; None: whether it was given forces so far)."""
        from .errors import RbgenError
        from .pipeline.narrowphase.kinds import kinds_for, pair_kernels

        try:
            kinds = len(kinds_for(shape_types))
        except RbgenError:  # (a shape the World refuses anyway: its own check says why)
            kinds = len(pair_kernels())
        return {
            "broadphase": self.options["broadphase"],
            "solver": self.options["solver"],
            "kinds": max(1, kinds),
            "sleeping": bool(self.options.get("sleeping", False)),
            "contact_geometry": self._keeps_contact_geometry(),
            "forces": self._forces_given() if forces is None else bool(forces),
            "support_chains": bool(self.options.get("support_chains", False)),
        }

    def _keeps_contact_geometry(self) -> bool:
        """Whether the World's current plan solves with a ContactGeometry record a
        constraint (`rbgen.plan.Plan.contact_geometry`)."""
        plan = getattr(self._owner(), "plan", None)
        return bool(plan is not None and plan.contact_geometry)

    def _forces_given(self) -> bool:
        owner = self._owner()
        forces = getattr(owner, "_forces", None)
        return bool(getattr(forces, "given", False))

    def sizes(self, bodies: int, pipeline=None, store=None, joints: int | None = None) -> Sizes:
        """The sizes a World of ``bodies`` runs with: the defaults for that many bodies,
        or what its buffers already reached (they never shrink). ``store`` (the World's
        `rbgen.bodies.BodyStore`) gives the compound children and the expansions;
        ``joints``: the joint count (None: the World's now)."""
        if joints is None:
            joints = int(getattr(self._owner(), "joint_count", 0))
        pairs = default_pairs(bodies, self.options["pair_capacity"])
        manifolds = default_manifolds(bodies, self.options["manifold_capacity"])
        current: list[int] = []
        if pipeline is not None:
            pairs = max(pairs, current_pair_capacity(pipeline))
            manifolds = max(manifolds, pipeline.narrowphase.capacity)
            if pipeline.midphase is not None:
                current = [e.capacity for e in pipeline.midphase.midphase.expansions()]
        expansions, proxies = midphase_of(store)
        expanded: list[int] = []
        for k in range(max(expansions, len(current))):
            size = expanded[-1] if expanded else pairs
            expanded.append(expanded_pairs(size, current[k] if k < len(current) else 0))
        return Sizes(bodies, pairs, manifolds, tuple(expanded), proxies, joints)

    def need(self, bodies: int, shape_types, pipeline=None, store=None) -> Estimate:
        """The estimate of a World of ``bodies`` with ``shape_types`` (and ``pipeline``'s
        buffers as they are; ``store``: its bodies, for compounds and meshes)."""
        return estimate(self.sizes(bodies, pipeline, store), **self._config(shape_types))

    def record(self, store, shape_types, pipeline) -> None:
        """The World now holds the buffers of ``store``'s bodies (after an upload)."""
        self.held = self.need(store.count, shape_types, pipeline, store)
        owner = self._owner()
        if owner is not None:
            _LEDGER[owner] = (self.runtime.device.int_ptr, self.held.total)

    def check(
        self,
        what: str,
        sizes: Sizes,
        shape_types=(),
        host_bytes: int = 0,
        forces: bool | None = None,
    ) -> Estimate:
        """Raise `MemoryLimitError` when a World of ``sizes`` (and ``host_bytes`` more on
        the host, besides the growth of its pinned buffers) does not fit; ``what`` names
        the request in the message; ``forces``: as `_config`. Returns the estimate that
        fits."""
        need = estimate(sizes, **self._config(shape_types, forces))
        device = self.device
        counts = f"{sizes.bodies:,} bodies, {sizes.pairs:,} pairs, {sizes.manifolds:,} manifolds"
        if sizes.joints:
            counts += f", {sizes.joints:,} joints"
        name, largest = need.largest
        if largest > device.max_alloc_bytes:
            raise MemoryLimitError(
                f"{what} needs a {name} buffer of {format_bytes(largest)} "
                f"({counts}; about {format_bytes(need.total)} in all); {device.name} "
                f"allocates at most {format_bytes(device.max_alloc_bytes)} in one buffer"
            )
        limit, source = self._device_limit()
        if need.total > limit:
            raise MemoryLimitError(
                f"{what} needs about {format_bytes(need.total)} of device memory "
                f"({counts}); the limit is {format_bytes(limit)} ({source})"
            )
        pinned = max(0, need.pinned_total - self.held.pinned_total)
        buffers = max(0, need.total - self.held.total) if device.shares_host else 0
        more = host_bytes + pinned + buffers
        available, source = host_available()
        if available is not None and more > available:
            shared = (
                f", {format_bytes(buffers)} device buffers: "
                f"{device.name} allocates from host memory"
                if device.shares_host
                else ""
            )
            staged = f", {format_bytes(pinned)} pinned upload buffers" if pinned else ""
            raise MemoryLimitError(
                f"{what} needs about {format_bytes(more)} more host memory "
                f"({format_bytes(host_bytes)} for the bodies' host copy and temporaries"
                f"{staged}{shared}); {format_bytes(available)} is available ({source})"
            )
        return need

    def _device_limit(self) -> tuple[int, str]:
        option = self.options.get("memory_limit")
        if option is not None:
            return int(option), "the World's memory_limit"
        device_id = self.runtime.device.int_ptr
        owner = self._owner()
        others = sum(
            total
            for world, (dev, total) in list(_LEDGER.items())
            if dev == device_id and world is not owner
        )
        source = f"{self.device.name}'s global memory"
        if others:
            source += f", less {format_bytes(others)} estimated for other Worlds on it"
        return self.device.global_bytes - others, source

    # ------------------------------------------------------------- requests
    def check_add(self, store, added: int, shape, pipeline) -> None:
        """Before ``added`` bodies of ``shape`` join ``store`` (a `rbgen.bodies.BodyStore`)."""
        count = store.count + added
        host = (
            HOST_BYTES_PER_BODY * count  # the new mirror
            + (layouts.BODY.itemsize + FLOAT64 * ADD_TEMPORARY_FLOAT64) * added
            + (layouts.BODY_INERTIA.itemsize + WORD) * count
        )  # upload temporaries
        sizes = self.sizes(count, pipeline, store)
        composite = getattr(type(shape), "composite", False)
        mesh = getattr(type(shape), "type_name", "") == "mesh"
        types = {type(s).type_name for s in store.shapes.shapes}
        expansions = len(sizes.expanded)
        if (
            composite and not any(getattr(type(s), "composite", False) for s in store.shapes.shapes)
        ) or (mesh and "mesh" not in types):
            expansions += 1  # the shape brings a midphase expansion of its own
        expanded = list(sizes.expanded)
        while len(expanded) < expansions:
            expanded.append(expanded_pairs(expanded[-1] if expanded else sizes.pairs, 0))
        sizes = dataclasses.replace(
            sizes,
            expanded=tuple(expanded),
            proxies=sizes.proxies + (added * len(shape.children) if composite else 0),
        )
        shape_types = (*store.shapes.type_names(), getattr(type(shape), "type_name", ""))
        self.check(
            f"adding {added:,} bodies (to {store.count:,})",
            sizes,
            tuple(t for t in shape_types if t),
            host,
        )

    def check_joints(self, store, added: int, pipeline) -> None:
        """Before ``added`` joints join the World's (whose bodies are ``store``'s)."""
        count = int(getattr(self._owner(), "joint_count", 0))
        host = (
            layouts.JOINT_CONSTRAINT.itemsize * (2 * (count + added) + added)  # old, new, packed
            + FLOAT64 * ADD_JOINT_TEMPORARY_FLOAT64 * added
        )
        self.check(
            f"adding {added:,} joints (to {count:,})",
            self.sizes(store.count, pipeline, store, joints=count + added),
            store.shapes.type_names(),
            host,
        )

    def check_forces(self, store, pipeline) -> None:
        """Before a World's first external forces (`World.apply_forces`): the uploads
        they bring (`FORCE_UPLOADS` device arrays of a float4 a body, each with a pinned
        host array) must fit; raises `MemoryLimitError` naming them otherwise. The World
        marks its forces given afterwards (`rbgen.forces.ExternalForces.given`), and from
        then on its estimates count them."""
        self.check(
            f"applying forces to {store.count:,} bodies (their uploads: "
            f"{format_bytes(2 * FORCE_UPLOADS * FORCE_UPLOAD_BYTES * max(1, store.count))})",
            self.sizes(store.count, pipeline, store),
            store.shapes.type_names(),
            forces=True,
        )

    def check_growth(self, store, shape_types, pipeline, problems: dict) -> None:
        """Before the stages in ``problems`` (stage -> what it reported) recover by growing
        their buffers (`rbgen.guard`)."""
        sizes = self.sizes(store.count, pipeline, store)
        grown = []
        for stage, problem in problems.items():
            if stage.name == "broadphase":
                pairs = grown_pairs(current_pair_capacity(pipeline), int(problem))
                grown.append(f"pairs {sizes.pairs:,} -> {pairs:,}")
                sizes = dataclasses.replace(sizes, pairs=max(sizes.pairs, pairs))
            elif stage.name == "midphase":
                expansions = pipeline.midphase.midphase.expansions()
                expanded = list(sizes.expanded)
                for k, e in enumerate(expansions):
                    if e.name in problem:
                        expanded[k] = max(
                            expanded[k], grown_expansion(e.capacity, int(problem[e.name]))
                        )
                        grown.append(f"{e.name} pairs {e.capacity:,} -> {expanded[k]:,}")
                sizes = dataclasses.replace(sizes, expanded=tuple(expanded))
            elif stage.name == "narrowphase":
                manifolds = grown_manifolds(pipeline.narrowphase.capacity, int(problem))
                grown.append(f"manifolds {sizes.manifolds:,} -> {manifolds:,}")
                sizes = dataclasses.replace(sizes, manifolds=max(sizes.manifolds, manifolds))
        if grown:
            self.held = self.check(
                f"growing the buffers after an overflow ({', '.join(grown)})", sizes, shape_types
            )
            owner = self._owner()
            if owner is not None:
                _LEDGER[owner] = (self.runtime.device.int_ptr, self.held.total)


def midphase_of(store) -> tuple[int, int]:
    """(midphase expansions, compound children placed as bodies) of a body store's scene:
    an expansion for compounds (their children) and one for meshes (their triangles)."""
    if store is None or store.count == 0:
        return 0, 0
    shapes = store.shapes.shapes
    children = [len(s.children) if getattr(type(s), "composite", False) else 0 for s in shapes]
    proxies = int(np.asarray(children, np.int64)[store.host["shape"]].sum())
    types = {type(s).type_name for s in shapes}
    has_children = any(getattr(type(s), "composite", False) for s in shapes)
    return int(has_children) + int("mesh" in types), proxies


def current_pair_capacity(pipeline) -> int:
    """The pair buffer's capacity now (0 before the first query)."""
    return int(pipeline.broadphase.broadphase.capacity)


# ----------------------------------------------------------------- measurement


def device_buffers(root) -> dict[str, int]:
    """Every distinct device buffer reachable from ``root`` (a World) through rbgen
    objects, containers and pyopencl arrays, as {path: bytes}; the shared Runtime and the
    kernels' argument caches are not followed (they are not the World's). For tests and
    the soak: the bytes a World really holds."""
    found: dict[int, tuple[str, int]] = {}
    seen: set[int] = set()
    stack = [(root, "world")]
    skip = {"Runtime", "BoundKernel", "SpecLog"}
    while stack:
        obj, path = stack.pop()
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        if isinstance(obj, cla.Array):
            buffer = obj.base_data
            if isinstance(buffer, cl.Buffer):
                found.setdefault(buffer.int_ptr, (path, buffer.size))
        elif isinstance(obj, cl.Buffer):
            found.setdefault(obj.int_ptr, (path, obj.size))
        elif isinstance(obj, dict):
            stack.extend((v, f"{path}[{k!r}]") for k, v in obj.items())
        elif isinstance(obj, (list, tuple)):
            stack.extend((v, f"{path}[{i}]") for i, v in enumerate(obj))
        elif type(obj).__module__.startswith("rbgen") and type(obj).__name__ not in skip:
            names = list(getattr(obj, "__dict__", {}))
            for cls in type(obj).__mro__:
                names += [s for s in getattr(cls, "__slots__", ()) if isinstance(s, str)]
            for name in names:
                if hasattr(obj, name):
                    stack.append((getattr(obj, name), f"{path}.{name}"))
    return {path: size for path, size in found.values()}


def device_bytes(root) -> int:
    """The total of `device_buffers`."""
    return sum(device_buffers(root).values())
