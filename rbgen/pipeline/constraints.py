"""Contact constraints from narrowphase manifolds, with warm starting, and their edges.

One `ContactConstraint` per `ContactManifold`: every point gets a normal row, the
manifold a friction pair at the centre of its points and a twist row (a fixed
tangent frame chosen from the normal), the manifold's combined friction and
restitution, a restitution threshold velocity, and split-impulse penetration
recovery (a separate push velocity solved beside the velocity sweeps and thrown away
after moving the bodies: recovery adds no momentum, so nothing bounces from it).

Constraint edges: batching colours a list of `ConstraintEdge` records (two bodies, a
kind-tagged item, an inherited colour, a point), not the constraints themselves, so
that any constraint kind can join the colours. The setup writes contact i's edge at
``first_contact_edge + i`` (the edges before it are reserved for joints, written by a
joint stage at fixed indices; none yet: ``first_contact_edge`` is 0) and the edge count
``first_contact_edge + count`` on the device. A warm-started contact's edge inherits
the previous edge's colour (global batching starts from it).

Warm starting: each step's constraints are recorded in a hash table keyed by
(body a, body b, sub-feature) (`ContactManifold.sub`: one manifold per compound
child or mesh triangle pair); the next step looks its key up first at its own index (the
narrowphase lists pairs in a stable order, so a scene at rest finds them
there, reading the old constraints in order), else in the table, and copies,
point by point, the impulses of the old point with the same feature id, else
of the nearest old point within ``match_distance`` (the narrowphase's feature
ids change when it swaps the reference face of a flat face-face contact,
which happens all the time on stacked boxes). Constraint buffers and tables rotate in a
ring of four, so nothing is copied back to the host and a step redone after
an overflow (the World redoes up to two) still finds the generation it
warm-started from. The setup kernel also clears the table of the generation
after its own (the oldest, which no redo needs), so that a step has no clearing
launch of its own: a generation's table is empty whenever a call starts writing
it (fresh, cleared by the call before, or cleared by `undo`). The first call makes all four
generations (empty), so that every call, a redone one too, enqueues the same commands
for its place in the ring (what `rbgen.schedule` records for a C++ host).
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array

from .. import layouts
from ..codegen import KernelTemplate, Param, compile_spec, work_group_size_param
from ..device import DeviceTraits, Runtime
from ..errors import RbgenError

#: constraint buffers kept in a ring: this step's, the two before it (a redo of up to two
#: steps warm-starts from them) and the next one, whose table this step's setup clears
GENERATIONS = 4

TEMPLATE = KernelTemplate(
    "pipeline/constraints.cl.mako",
    [
        work_group_size_param(
            "manifolds per work group; memory-bound, any size that fills a CU works"
        ),
        Param(
            "warm_start",
            (True, False),
            "emit the previous-step lookup only when warm starting is on",
        ),
        Param(
            "filter_joints",
            (False, True),
            "worlds with joints: a manifold between two joined bodies gets no point",
        ),
    ],
    doc="Contact constraints (a normal row per point, a friction pair and a twist row per "
    "manifold) from contact manifolds.",
    defaults=lambda traits: {
        "work_group_size": default_work_group_size(traits),
        "warm_start": True,
        "filter_joints": False,
    },
)


def default_work_group_size(traits: DeviceTraits) -> int:
    """64 on GPUs (large per-item state); 16 on CPUs."""
    return min(64 if traits.is_gpu else 16, traits.max_work_group_size)


class _Buffers:
    """One generation of constraints, their edges and its pair table."""

    def __init__(self, queue, capacity: int, first_contact_edge: int):
        self.capacity = int(capacity)
        self.constraints = cl_array.zeros(
            queue, max(1, self.capacity), layouts.CONTACT_CONSTRAINT.dtype
        )
        #: the generation's edges: first_contact_edge joint edges, then one a contact
        self.first_contact_edge = int(first_contact_edge)
        self.edges = cl_array.zeros(
            queue, max(1, self.first_contact_edge + self.capacity), layouts.CONSTRAINT_EDGE.dtype
        )
        table_size = 1 << max(4, int(2 * max(1, self.capacity) - 1).bit_length())
        self.table = cl_array.to_device(queue, np.full(table_size, layouts.SOLVER_NONE, np.uint32))
        self.mask = table_size - 1
        #: device uint32 array(1): constraints of this generation
        self.count = cl_array.zeros(queue, 1, np.uint32)


class ContactConstraints:
    """Builds this step's constraints from manifolds; keeps last step's for warm starting.

    ``settings`` (attributes, changeable between steps): ``gravity`` (m/s^2, the
    velocity change the step's preparation gave dynamic bodies: bounces restore the
    approach before it), ``restitution_threshold``
    (m/s; slower impacts do not bounce), ``penetration_slop`` (m of penetration
    left alone), ``penetration_recovery`` (fraction of the penetration removed
    per step), ``warm_start_factor`` (scale of the carried impulses),
    ``match_distance`` (m: an old point this close to a new one, relative to
    body B, passes its impulses on when no feature id matches).
    """

    def __init__(
        self, runtime: Runtime, *, warm_start: bool = True, work_group_size: int | None = None
    ):
        self.runtime = runtime
        self.warm_start = bool(warm_start)
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        #: sorted (lower, higher) body pairs joined by a joint (device uint2 array) and their
        #: count; None: no filter (a World without joints)
        self.joint_pairs = None
        self.joint_pair_count = 0
        self._build(filter_joints=False)
        #: a stand-in for the next generation's table before that generation exists
        self._no_table = cl_array.zeros(runtime.queue, 1, np.uint32)
        #: an empty previous generation (a count of 0 and a table with no entry): what a
        #: call that must not warm-start reads, so that it finds nothing
        self._no_count = cl_array.zeros(runtime.queue, 1, np.uint32)
        self._empty_table = cl_array.to_device(
            runtime.queue, np.full(1, layouts.SOLVER_NONE, np.uint32)
        )
        #: the step's gravity, which prepare_bodies added to the dynamic bodies' velocities
        #: (m/s^2): a bounce restores the approach before it
        self.gravity = (0.0, 0.0, 0.0)
        self.restitution_threshold = 0.5
        self.penetration_slop = 0.005
        self.penetration_recovery = 0.2
        self.warm_start_factor = 1.0
        self.match_distance = 0.02
        #: device uint32 array(1): constraints built by the last call (<= capacity)
        self.count = cl_array.zeros(runtime.queue, 1, np.uint32)
        #: edges before the contacts' (reserved for joints: none yet)
        self.first_contact_edge = 0
        #: device uint32 array(1): edges of the last call (first_contact_edge + count)
        self.edge_count = cl_array.zeros(runtime.queue, 1, np.uint32)
        #: generations in a ring: the current one, and the ones before it that a redone
        #: step (the World redoes up to two) may need again for its warm start
        self._generations: list[_Buffers | None] = [None] * GENERATIONS
        self._current = GENERATIONS - 1

    def _build(self, filter_joints: bool) -> None:
        self.spec = TEMPLATE.spec(
            work_group_size=self.work_group_size,
            warm_start=self.warm_start,
            filter_joints=bool(filter_joints),
        )
        program = compile_spec(self.runtime, self.spec)
        self.setup_kernel = self.runtime.bound(program.kernel("setup_contact_constraints"))

    def set_joint_pairs(self, pairs, count: int) -> None:
        """Contacts between the joined body pairs ``pairs`` (a device uint2 array, sorted,
        lower body first; None: no joints) get no points from the next call on."""
        if (pairs is None) != (self.joint_pairs is None):
            self._build(filter_joints=pairs is not None)
        self.joint_pairs, self.joint_pair_count = pairs, int(count)

    @property
    def generations(self) -> tuple:
        """The ring's generations (None before the first call), for their capacities."""
        return tuple(self._generations)

    @property
    def generation_index(self) -> int:
        """The ring index of this step's generation (valid after a call)."""
        return self._current

    @property
    def constraints(self):
        """Device array of this step's constraints (valid after a call)."""
        return self._generations[self._current].constraints

    @property
    def edges(self):
        """Device array of this step's constraint edges (valid after a call)."""
        return self._generations[self._current].edges

    @property
    def capacity(self) -> int:
        gen = self._generations[self._current]
        return 0 if gen is None else gen.capacity

    @property
    def edge_capacity(self) -> int:
        """Edges this step's array holds (joint edges, then a contact's each)."""
        gen = self._generations[self._current]
        return 0 if gen is None else gen.first_contact_edge + gen.capacity

    def reset(self) -> None:
        """Forget the previous step (e.g. after teleporting bodies)."""
        for gen in self._generations:
            if gen is not None:
                gen.table.fill(np.uint32(layouts.SOLVER_NONE), queue=self.runtime.queue)
                gen.count.fill(np.uint32(0), queue=self.runtime.queue)

    def undo(self, calls: int = 1) -> None:
        """Forget the last ``calls`` calls (their steps are being redone): the generation
        before them is again the one the next call warm-starts from, and the table the
        next call writes (an undone call's) is cleared."""
        if not 0 <= calls < GENERATIONS - 1:
            raise RbgenError(f"can undo at most {GENERATIONS - 2} calls, asked {calls}")
        if calls == 0:
            return
        self._current = (self._current - calls) % GENERATIONS
        self._clear(self._generations[(self._current + 1) % GENERATIONS])

    def _clear(self, gen: _Buffers | None) -> None:
        """Empty one generation's table (a launch: only off the step's normal path)."""
        if gen is not None:
            gen.table.fill(np.uint32(layouts.SOLVER_NONE), queue=self.runtime.queue)

    def __call__(
        self,
        manifolds,
        manifold_count,
        bodies,
        inertia,
        capacity: int,
        dt: float,
        warm_start: bool = True,
    ):
        """Set up min(``manifold_count[0]``, ``capacity``) constraints (count: a device
        uint32 array(1)); that number is written to ``self.count`` on the device.
        ``warm_start=False`` (a World whose warm_start setting is off): this call finds no
        previous constraint, so its impulses start from zero and no colour is inherited,
        as a setup built without warm starting does. ``dt``: the first substep's length."""
        queue, wg = self.runtime.queue, self.work_group_size
        previous = self._generations[self._current]
        first = self.first_contact_edge
        if previous is None:  # the first call makes the whole ring, every generation empty
            whole = [_Buffers(queue, capacity, first) for _ in range(GENERATIONS)]
            self._generations = list(whole)
            previous = whole[self._current]
        self._current = (self._current + 1) % GENERATIONS
        gen = self._generations[self._current]
        if gen is None or gen.capacity < capacity or gen.first_contact_edge != first:
            gen = self._generations[self._current] = _Buffers(queue, capacity, first)
        following = self._generations[(self._current + 1) % GENERATIONS]
        if capacity == 0:
            self.count.fill(np.uint32(0), queue=queue)
            self.edge_count.fill(np.uint32(first), queue=queue)
            self._clear(following)
            return None
        # (the next call's table, which this setup clears; before that generation exists,
        # a one-word stand-in and a size of 0: nothing to clear)
        next_table = self._no_table if following is None else following.table
        args = [
            manifolds,
            manifold_count,
            bodies,
            inertia,
            np.uint32(capacity),
            gen.constraints,
            self.count,
            gen.edges,
            self.edge_count,
            np.uint32(first),
            gen.table,
            np.uint32(gen.mask),
            next_table,
            np.uint32(0 if following is None else following.mask + 1),
        ]
        if self.warm_start:
            found = (
                (previous.count, previous.table, previous.mask)
                if warm_start
                else (self._no_count, self._empty_table, 0)
            )
            args += [
                gen.count,
                previous.constraints,
                previous.edges,
                np.uint32(previous.first_contact_edge),
                found[0],
                found[1],
                np.uint32(found[2]),
                np.float32(self.warm_start_factor),
                np.float32(self.match_distance),
            ]
        if self.joint_pairs is not None:
            args += [self.joint_pairs, np.uint32(self.joint_pair_count)]
        args += [
            np.float32(dt),
            np.array([*self.gravity, 0.0], dtype=np.float32),
            np.float32(self.restitution_threshold),
            np.float32(self.penetration_slop),
            np.float32(self.penetration_recovery),
        ]
        return self.setup_kernel.over(capacity, wg, *args)
