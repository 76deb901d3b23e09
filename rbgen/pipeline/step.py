"""The step pipeline written as data: the stages of a World step, in order.

    [wake] -> prepare -> broadphase -> [midphase] -> narrowphase -> [children]
           -> constraints -> [joints] -> [batching] -> solve (each substep: sweeps, then
           integrate) -> [sleep]

`StepPipeline.stages` is that list; a step walks it, each stage enqueuing its kernels
(no blocking read). Every stage owns the buffers it writes (the prepare stage the AABBs,
the broadphase the pairs, the narrowphase the manifolds, ...) and reads its inputs from
the stages before it, which it is given at construction. A stage that can fail a step
(a buffer too small, a persistent launch that gave up) declares the words it adds to
the step report (`report_words`, `report`, `problem`) and how to recover (`recover`);
`rbgen.guard.StepGuard` checks them and redoes the step. One convention for every
count a stage hands on: it never exceeds what was stored (the writer clamps it and puts
the capacity it needed in the report), so the next stage reads ``count`` entries as they
are, and an overflowing step is redone before its results are used. A new stage (a midphase
between the broadphase and the narrowphase, a joint stage beside the constraints) is
one class here and one entry in the list `StepPipeline` assembles.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from .. import layouts
from ..bodies import DeviceBodies, bounding_radius
from ..device import Runtime, buffer_of
from ..forces import StepForces
from ..plan import Plan
from ..settings import Settings
from ..shapes import PackedShapes
from .batching import make_batcher
from .broadphase import make_broadphase
from .broadphase.pairs import PairBuffer
from .constraints import ContactConstraints
from .device_barrier import ABANDONED_OFFSET, clear_abandoned
from .integrate import DEFAULT_MAX_ANGULAR_STEP, Integrator
from .joints import JointEdges
from .midphase import STATUS_WORDS, Midphase, needs_midphase
from .narrowphase import Narrowphase
from .prepare import BodyPreparation
from .sleep import Sleeping
from .solvers.jacobi import JacobiSolver
from .solvers.pgs import PgsSolver, SubstepMotion
from .solvers.substeps import ContactRefresh
from .solvers.support import ROUNDS as SUPPORT_ROUNDS
from .solvers.support import SupportBuffers, SupportChains

#: manifolds reserved per body before the first overflow (grown on demand)
MANIFOLDS_PER_BODY = 4


@dataclasses.dataclass
class StepContext:
    """What one enqueued step reads: its dt, its backup slot, the World's step settings,
    the device bodies and shapes, and its external forces (`rbgen.forces`; None: none)."""

    dt: float
    slot: int
    settings: Settings
    bodies: DeviceBodies
    shapes: PackedShapes
    forces: StepForces | None = None
    #: the prepare stage's per-substep velocity changes of the step's forces (2 float4 a
    #: body), set when the step has forces: later substeps add them as they add g h
    kicks: cla.Array | None = None

    @property
    def h(self) -> float:
        """A substep: dt / settings.substeps."""
        return self.dt / self.settings.substeps


def copy_words(queue, report, offset: int, source, byte_count: int, src_offset: int = 0):
    """Enqueue a copy of ``byte_count`` bytes of ``source`` (from byte ``src_offset``) into
    the step report at word ``offset`` (what a stage's `Stage.report` does)."""
    cl.enqueue_copy(
        queue,
        buffer_of(report),
        buffer_of(source),
        byte_count=byte_count,
        src_offset=src_offset,
        dst_offset=4 * offset,
    )


class Stage:
    """A step stage: ``enqueue(step)`` and, for stages that report, the hooks below."""

    name = "stage"
    #: uint32 words this stage adds to the step report
    report_words = 0
    #: whether a kernel of the stage writes its report words itself (given a view of the
    #: report at its offset by `attach_report`); those words come first in the report, so
    #: that the view starts at offset 0 (device arrays with an offset cannot be bound)
    writes_report = False

    def resize(self, body_count: int) -> None:
        """The body count changed (an upload): size per-body buffers."""

    def enqueue(self, step: StepContext) -> None:
        raise NotImplementedError

    def attach_report(self, report, offset: int) -> None:
        """(stages that write their report words themselves) The report and their offset."""

    def report(self, queue, report, offset: int) -> None:
        """Enqueue copies of this stage's status into the report at word ``offset``."""

    def problem(self, words: np.ndarray):
        """What went wrong in a step, from its report words (None: nothing)."""
        return None

    def recover(self, problem) -> None:
        """Make the redo succeed (grow a buffer); the queue is drained."""

    # (for hosts that replay the step without Python: `rbgen.schedule` records these)
    def capacities(self) -> dict[str, int]:
        """This stage's buffer capacities by name: those it grows on overflow (named in
        `report_protocol`) and those that follow one of them lazily."""
        return {}

    def set_capacity(self, name: str, value: int) -> None:
        """Set the capacity ``name`` to exactly ``value``, reallocating its buffers (between
        steps; a schedule is recorded at chosen capacities)."""
        raise KeyError(name)

    def report_protocol(self) -> dict:
        """What this stage's report words mean, as data: ``{"capacities": {name: word}}``
        (the word holds what that capacity must hold: more than it overflowed) and
        ``{"fatal": [{"word", "ok", "message"}]}`` (a word other than ``ok`` stops a host
        that cannot do what `recover` does)."""
        return {}


class PrepareStage(Stage):
    """Gravity, external forces, world inverse inertia, the gyroscopic term, world AABBs
    and the body backup of the step, in one launch (`rbgen.pipeline.prepare`)."""

    name = "prepare"

    def __init__(self, runtime: Runtime, plan: Plan):
        self.runtime = runtime
        self.kernel = BodyPreparation(
            runtime,
            gyroscopic=plan.gyroscopic,
            gravity=True,
            shape_types=plan.shape_types,
            backup=True,
            external_forces=True,
            sleeping=plan.sleeping,
        )
        self.aabbs: cla.Array | None = None
        self.kicks: cla.Array | None = None

    def resize(self, body_count: int) -> None:
        queue, n = self.runtime.queue, max(1, body_count)
        self.aabbs = cla.empty(queue, n, layouts.AABB.dtype)
        self.kicks = cla.empty(queue, 2 * n, cl.cltypes.float4)

    def enqueue(self, step: StepContext) -> None:
        b, substeps = step.bodies, step.settings.substeps
        # (the first substep's gravity: g h = (g / substeps) dt)
        gravity = step.settings.gravity if substeps == 1 else step.settings.gravity / substeps
        self.kernel(
            b.bodies,
            b.inertia,
            b.count,
            step.dt,
            gravity,
            aabbs=(
                step.shapes.shapes,
                step.shapes.vertices,
                self.aabbs,
                step.settings.contact_margin,
            ),
            backup=b.backups[step.slot],
            forces=None if step.forces is None else step.forces.arrays(),
            kicks=self.kicks,
            h=step.h,
        )
        step.kicks = None if step.forces is None else self.kicks


class BroadphaseStage(Stage):
    """Overlapping AABB pairs (`rbgen.pipeline.broadphase`); reports its status."""

    name = "broadphase"
    report_words = layouts.BROADPHASE_STATUS.itemsize // 4

    def __init__(
        self, runtime: Runtime, plan: Plan, prepare: PrepareStage, pair_capacity: int | None
    ):
        self.runtime = runtime
        self.prepare = prepare
        options = {} if pair_capacity is None else {"capacity": int(pair_capacity)}
        self.broadphase = make_broadphase(runtime, plan.broadphase, **options)

    def enqueue(self, step: StepContext) -> None:
        # (the World reads the status through the step report)
        self.broadphase.enqueue(self.prepare.aabbs, step.bodies.static, read_status=False)

    def report(self, queue, report, offset: int) -> None:
        assert self.broadphase.buffer is not None  # (made by the first query)
        status = self.broadphase.buffer.status
        copy_words(queue, report, offset, status, status.nbytes)

    def problem(self, words):
        status = words.view(layouts.BROADPHASE_STATUS.dtype)[0]
        pairs_found = int(status["pairs_found"])
        retry = int(status["retry"]) if "retry" in status.dtype.names else 0
        if (
            status["bad_body"] != layouts.BP_NO_BODY
            or retry
            or pairs_found > self.broadphase.capacity
        ):
            return pairs_found
        return None

    def recover(self, pairs_found) -> None:
        self.broadphase.check()  # raises for a NaN body, grows the pair buffer
        assert self.broadphase.buffer is not None
        self.broadphase.buffer.grow_for(pairs_found)

    def capacities(self) -> dict[str, int]:
        return {"pairs": self.broadphase.capacity}

    def set_capacity(self, name: str, value: int) -> None:
        assert name == "pairs"
        if self.broadphase.buffer is None:  # (before the first query)
            self.broadphase.buffer = PairBuffer(self.runtime, int(value))
        else:
            self.broadphase.buffer.allocate(int(value))

    def report_protocol(self) -> dict:
        word = layouts.BROADPHASE_STATUS.offset
        fatal = [
            {
                "word": word("bad_body") // 4,
                "ok": layouts.BP_NO_BODY,
                "message": "a body's bounding box is NaN or inverted (a NaN state)",
            }
        ]
        if "retry" in [f.name for f in layouts.BROADPHASE_STATUS.fields]:
            fatal.append(
                {
                    "word": word("retry") // 4,
                    "ok": 0,
                    "message": "the broadphase must be redone another way (its host "
                    "side changes its plan)",
                }
            )
        return {"capacities": {"pairs": word("pairs_found") // 4}, "fatal": fatal}


class MidphaseStage(Stage):
    """Sub-feature pairs of the pairs with a compound or a triangle mesh: compound children
    and mesh triangles (`rbgen.pipeline.midphase`); owns their buffers and reports their
    overflow (a word per expansion). Only in worlds with such shapes."""

    name = "midphase"

    def __init__(
        self, runtime: Runtime, shapes, prepare: PrepareStage, broadphase: BroadphaseStage
    ):
        self.midphase = Midphase(runtime, shapes)
        self.prepare, self.broadphase = prepare, broadphase
        self.report_words = int(self.midphase.status.size)

    def enqueue(self, step: StepContext) -> None:
        bp, b = self.broadphase.broadphase, step.bodies
        self.midphase.enqueue(
            b.bodies,
            b.count,
            step.shapes,
            self.prepare.aabbs,
            bp.pairs,
            bp.count,
            step.settings.contact_margin,
            b.shape_indices,
        )

    def report(self, queue, report, offset: int) -> None:
        status = self.midphase.status
        copy_words(queue, report, offset, status, status.nbytes)

    def problem(self, words):
        return self.midphase.problem(words)

    def recover(self, needed) -> None:
        self.midphase.grow(needed)

    def _expansion_names(self) -> list[str]:
        """The expansions of this world (the triangles' is made at the first step)."""
        m = self.midphase
        return [
            n for n, has in (("children", m.has_children), ("triangles", m.has_triangles)) if has
        ]

    def capacities(self) -> dict[str, int]:
        return {f"midphase.{e.name}": e.capacity for e in self.midphase.expansions()}

    def set_capacity(self, name: str, value: int) -> None:
        made = {f"midphase.{e.name}": e for e in self.midphase.expansions()}
        if name in made:
            made[name].capacity = 0  # (exactly: grow never shrinks)
            made[name].grow(value)
        elif name in (f"midphase.{n}" for n in self._expansion_names()):
            self.midphase.capacity = int(value)  # (the first capacity of one not made yet)
        else:
            raise KeyError(name)

    def report_protocol(self) -> dict:
        return {
            "capacities": {
                f"midphase.{name}": STATUS_WORDS[name] for name in self._expansion_names()
            }
        }


class NarrowphaseStage(Stage):
    """Contact manifolds of the pairs (`rbgen.pipeline.narrowphase`): the broadphase's, or
    the midphase's where there is one; owns the manifold buffer, whose overflow the
    narrowphase writes into its report word itself."""

    name = "narrowphase"
    report_words = 1
    writes_report = True

    def __init__(
        self,
        runtime: Runtime,
        shapes,
        broadphase: BroadphaseStage,
        manifold_capacity: int | None,
        midphase: MidphaseStage | None = None,
    ):
        self.runtime = runtime
        self.narrowphase = Narrowphase(runtime, shapes)
        self.broadphase = broadphase
        self.midphase = midphase
        self.initial_capacity = manifold_capacity
        self.capacity = 0
        self.needed_word = None  # the report word the kernel writes (set by the guard)

    def resize(self, body_count: int) -> None:
        self.ensure(self.initial_capacity or MANIFOLDS_PER_BODY * max(body_count, 16))

    def ensure(self, capacity: int) -> None:
        """Grow the manifold buffer to ``capacity`` (never shrinks)."""
        if capacity <= self.capacity:
            return
        queue = self.runtime.queue
        self.capacity = int(capacity)
        self.manifolds = cla.empty(queue, self.capacity, layouts.CONTACT_MANIFOLD.dtype)
        self.count = cla.zeros(queue, 1, np.uint32)

    def attach_report(self, report, offset: int) -> None:
        # a view made once: a pyopencl slice is a new Array, host time every step
        self.needed_word = report[offset : offset + 1]

    def enqueue(self, step: StepContext) -> None:
        source = self.broadphase.broadphase if self.midphase is None else self.midphase.midphase
        bodies = step.bodies.bodies if self.midphase is None else self.midphase.midphase.bodies
        self.narrowphase.enqueue(
            bodies,
            step.shapes,
            source.pairs,
            source.count,
            self.manifolds,
            self.count,
            self.needed_word,
            step.settings.contact_margin,
        )

    def problem(self, words):
        needed = int(words[0])
        return needed or None

    def recover(self, needed) -> None:
        self.ensure(int(needed * 1.25) + 16)

    def capacities(self) -> dict[str, int]:
        return {"manifolds": self.capacity}

    def set_capacity(self, name: str, value: int) -> None:
        assert name == "manifolds"
        self.capacity = 0  # (exactly: ensure never shrinks)
        self.ensure(value)

    def report_protocol(self) -> dict:
        return {"capacities": {"manifolds": 0}}


class ChildrenStage(Stage):
    """Manifolds of compound children back on their compounds, the child named in the
    sub-feature (`rbgen.pipeline.midphase`). Only in worlds with compounds."""

    name = "children"

    def __init__(self, midphase: MidphaseStage, narrowphase: NarrowphaseStage):
        self.midphase, self.narrowphase = midphase, narrowphase

    def enqueue(self, step: StepContext) -> None:
        self.midphase.midphase.resolve(self.narrowphase.manifolds, self.narrowphase.count)


class ConstraintStage(Stage):
    """Contact constraints with warm starting (`rbgen.pipeline.constraints`)."""

    name = "constraints"

    def __init__(self, runtime: Runtime, narrowphase: NarrowphaseStage, warm_start: bool):
        self.constraints = ContactConstraints(runtime, warm_start=warm_start)
        self.narrowphase = narrowphase

    @property
    def capacity(self) -> int:
        return self.narrowphase.capacity

    def capacities(self) -> dict[str, int]:
        # each generation of the ring follows the manifold capacity when it is next written
        return {
            f"constraints.{k}": g.capacity
            for k, g in enumerate(self.constraints.generations)
            if g is not None
        }

    def enqueue(self, step: StepContext) -> None:
        c, s, b = self.constraints, step.settings, step.bodies
        c.gravity = tuple(s.gravity)
        c.restitution_threshold = s.restitution_threshold
        c.penetration_slop = s.penetration_slop
        c.penetration_recovery = s.penetration_recovery
        c(
            self.narrowphase.manifolds,
            self.narrowphase.count,
            b.bodies,
            b.inertia,
            self.capacity,
            step.h,
            warm_start=s.warm_start,
        )  # (the first substep's targets)


class JointStage(Stage):
    """The joints' constraint edges and the break test (`rbgen.pipeline.joints`), after
    the contact setup chose this step's edge generation. Only in worlds with joints."""

    name = "joints"

    def __init__(self, runtime: Runtime, constraints: ConstraintStage, store):
        self.runtime = runtime
        self.constraints = constraints
        #: the World's `rbgen.joints.JointStore`
        self.store = store
        self.edges = JointEdges(runtime)

    def enqueue(self, step: StepContext) -> None:
        store, c = self.store, self.constraints.constraints
        if store.count == 0:
            return
        # the colours are inherited from the ring's generation before this step's (not
        # the last step enqueued: a redone step inherits exactly what its first try did)
        before = c.generations[(c.generation_index - 1) % len(c.generations)]
        self.edges(
            store.device,
            store.backups[step.slot],
            store.count,
            step.bodies.bodies,
            c.edges,
            before.edges,
            before.first_contact_edge,
            step.settings.substeps,
        )
        store.device_newer = True


class BatchingStage(Stage):
    """The PGS solver's colouring of the step's constraint edges (`rbgen.pipeline.batching`)."""

    name = "batching"

    def __init__(self, runtime: Runtime, plan: Plan, constraints: ConstraintStage):
        assert plan.batching is not None  # (a PGS plan)
        options: dict = (
            {"ordered_rounds": plan.ordered_rounds}
            if plan.batching == "global"
            else {"group_count": plan.group_count, "solve_form": plan.solve_form}
        )
        self.batcher = make_batcher(runtime, plan.batching, **options)
        self.constraints = constraints

    def configure(self, bodies, gravity, contact_margin: float) -> None:
        """Scene geometry of spatial batching (from the host copy of the bodies)."""
        radius = max((bounding_radius(s) for s in bodies.dynamic_shapes()), default=0.0)
        slabs, columns = horizontal_axes(bodies.dynamic_positions(), gravity)
        self.batcher.configure(
            cell_size=2.0 * radius + 2.0 * contact_margin + 1e-3,
            slab_axis=slabs,
            column_axis=columns,
        )

    def enqueue(self, step: StepContext) -> None:
        c = self.constraints.constraints
        self.batcher(
            c.edges,
            c.edge_count,
            step.bodies.bodies,
            step.bodies.count,
            c.first_contact_edge + self.constraints.capacity,
        )


def horizontal_axes(positions: np.ndarray, gravity) -> tuple[tuple, tuple]:
    """The two coordinate axes least along gravity, the one on which the dynamic bodies
    spread widest first: the slabs' axis (a pile then spreads over most slabs), then the
    columns' second axis."""
    candidates = list(np.argsort(np.abs(np.asarray(gravity, float)))[:2])
    if len(positions):
        spread = positions.max(axis=0) - positions.min(axis=0)
        candidates.sort(key=lambda axis: -spread[axis])
    return tuple(tuple(float(i == axis) for i in range(3)) for axis in candidates)  # type: ignore[return-value]


class SolveStage(Stage):
    """The contact solver over the step's substeps (`rbgen.pipeline.solvers`): each
    substep its warm start and sweeps, then the bodies integrated over the substep
    (damping, the split-impulse push); from the second substep on, gravity first and the
    contacts' targets refreshed from the bodies' motion (`solvers.substeps`). A persistent
    launch reports whether its device-wide barrier gave up."""

    name = "solve"

    def __init__(
        self,
        runtime: Runtime,
        plan: Plan,
        constraints: ConstraintStage,
        batching: BatchingStage | None,
        joints: JointStage | None = None,
    ):
        self.runtime = runtime
        self.constraints = constraints
        self.joints = joints
        self.solver: PgsSolver | JacobiSolver
        if plan.solver == "pgs":
            assert batching is not None
            self.solver = PgsSolver(
                runtime,
                batching.batcher,
                normal_solve=plan.normal_solve,
                persistent=plan.persistent,
                fast_math=plan.fast_math,
                warm_start_mode=plan.warm_start_mode,
                release_sweeps=plan.release_sweeps,
                joints=plan.joints,
                contact_geometry=plan.contact_geometry,
                support_chains=plan.support_chains,
            )
        else:
            self.solver = JacobiSolver(
                runtime,
                normal_solve=plan.normal_solve,
                persistent=plan.persistent,
                fast_math=plan.fast_math,
            )
        self.integrator = Integrator(runtime, gravity=False, damping=True)
        self._refresh: ContactRefresh | None = None  # (made at the first substepped step)
        # the support chains (the plan's choice; without gravity they hold nothing up and
        # change nothing): a persistent solve's records, which its launch runs, or the
        # chains' own kernels, which the substep loop launches (built here, at set-up)
        self._support: SupportBuffers | None = None
        if plan.support_chains:
            integrates = getattr(self.solver, "integrates", False)
            self._support = SupportBuffers(runtime) if integrates else SupportChains(runtime)
        self.report_words = 1 if self.solver.barrier_state() is not None else 0

    def resize(self, body_count: int) -> None:
        """The bodies were uploaded (added, set or removed): the `BodyDelta` records start
        again from zero. The substeps write a dynamic body's every step but never a static
        body's, which must stay zero: after a removal, a static body can take the index of
        a dynamic body that moved, and its contacts would see the ground move."""
        deltas = None if self._refresh is None else self._refresh.deltas
        if deltas is not None:
            cl.enqueue_fill_buffer(
                self.runtime.queue, buffer_of(deltas), np.uint32(0), 0, deltas.nbytes
            )

    def enqueue(self, step: StepContext) -> None:
        c, b, s = self.constraints, step.bodies, step.settings
        constraints, count = c.constraints.constraints, c.constraints.count
        substeps, h = s.substeps, step.h
        joints = {} if self.joints is None else {"joints": self.joints.store.device, "h": h}
        split = self.solver.split_velocities(b.count) if s.position_iterations > 0 else None
        deltas = None
        if substeps > 1 or getattr(self.solver, "integrates", False):
            if self._refresh is None:
                self._refresh = ContactRefresh(self.runtime)
            deltas = self._refresh.body_deltas(b.count)
        if self._support is not None:
            self._support.grow(b.count)
        if getattr(self.solver, "integrates", False):  # one launch runs every substep
            assert isinstance(self.solver, PgsSolver)
            motion = SubstepMotion(
                substeps,
                h,
                s.gravity,
                (1.0 - s.linear_damping) ** h,
                (1.0 - s.angular_damping) ** h,
                DEFAULT_MAX_ANGULAR_STEP / substeps,
                s.penetration_slop,
                s.penetration_recovery,
                deltas,
                step.kicks,
                self._support,
                SUPPORT_ROUNDS,
            )
            self.solver.solve(
                constraints,
                count,
                c.capacity,
                b.bodies,
                b.inertia,
                b.count,
                s,
                motion=motion,
                **joints,
            )
            return
        chain_launches = self._support if isinstance(self._support, SupportChains) else None
        for k in range(substeps):
            if k > 0:
                assert self._refresh is not None
                self.integrator.apply_gravity(b.bodies, b.count, h, s.gravity, step.kicks)
                self._refresh(
                    constraints,
                    count,
                    c.capacity,
                    b.count,
                    h,
                    s.penetration_slop,
                    s.penetration_recovery,
                )
            self.solver.solve(
                constraints,
                count,
                c.capacity,
                b.bodies,
                b.inertia,
                b.count,
                s,
                restitution=k == substeps - 1,
                same_geometry=k > 0,
                **joints,
            )
            if chain_launches is not None:
                chain_launches.propagate(
                    constraints, count, c.capacity, b.bodies, b.count, s.gravity, h, k
                )
            self.integrator(
                b.bodies,
                b.count,
                h,
                linear_damping=s.linear_damping,
                angular_damping=s.angular_damping,
                max_angular_step=DEFAULT_MAX_ANGULAR_STEP / substeps,
                split=split,
                deltas=deltas,
                first_substep=k == 0,
            )

    def report(self, queue, report, offset: int) -> None:
        copy_words(queue, report, offset, self.solver.barrier_state(), 4, ABANDONED_OFFSET)

    def problem(self, words):
        return bool(words[0]) or None

    def report_protocol(self) -> dict:
        return {
            "fatal": [
                {
                    "word": 0,
                    "ok": 0,
                    "message": "a persistent launch gave up at its device-wide barrier "
                    "(its work groups did not all run at once); export a "
                    "World without persistent launches for this device "
                    "(batching='cells', 'slabs' or 'columns')",
                }
            ]
        }

    def clear_abandoned(self) -> None:
        clear_abandoned(self.runtime, self.solver.barrier_state())


class WakeStage(Stage):
    """The start of a step with sleeping islands (`rbgen.pipeline.sleep`): a force wakes
    its body's island before it acts; after a host change, the bodies agree with their
    sleep records again. No launch on other steps. Only in worlds with sleeping on."""

    name = "wake"

    def __init__(self, sleeping: Sleeping):
        self.sleeping = sleeping

    def enqueue(self, step: StepContext) -> None:
        self.sleeping.begin(step.bodies.bodies, step.bodies.static, step.forces, step.slot)


class SleepStage(Stage):
    """The end of a step with sleeping islands (`rbgen.pipeline.sleep`): rest timers, the
    islands over the step's constraint edges, islands falling asleep or waking."""

    name = "sleep"

    def __init__(self, sleeping: Sleeping, constraints: ConstraintStage):
        self.sleeping = sleeping
        self.constraints = constraints

    def enqueue(self, step: StepContext) -> None:
        c = self.constraints.constraints
        self.sleeping.end(
            step.bodies.bodies,
            step.bodies.static,
            c.edges,
            c.edge_count,
            c.first_contact_edge + self.constraints.capacity,
            step.slot,
            step.settings,
            step.dt,
        )


class StepPipeline:
    """The stages of one plan, in step order (see the module docstring).

    `replan` rebuilds only the stages a new plan changes: a new set of shape types
    rebuilds the collision stages, a new solver choice the batching and solve stages;
    the constraint stage, with its warm-start history, survives both.
    """

    def __init__(
        self,
        runtime: Runtime,
        plan: Plan,
        shapes,
        *,
        pair_capacity=None,
        manifold_capacity=None,
        warm_start: bool = True,
        joint_store=None,
        backups: int = 2,
    ):
        self.runtime, self.shapes = runtime, shapes
        #: the World's `rbgen.joints.JointStore` (None: a pipeline without joints)
        self.joint_store = joint_store
        self.pair_capacity, self.manifold_capacity = pair_capacity, manifold_capacity
        self.plan = plan
        self._build_collision(plan)
        self.constraints = ConstraintStage(runtime, self.narrowphase, warm_start)
        #: the sleep records (None: sleeping off), kept through a replan
        self.sleeping = Sleeping(runtime, backups) if plan.sleeping else None
        self.wake: WakeStage | None = None
        self.sleep: SleepStage | None = None
        if self.sleeping is not None:
            self.wake = WakeStage(self.sleeping)
            self.sleep = SleepStage(self.sleeping, self.constraints)
        self._build_solve(plan)

    def _build_collision(self, plan: Plan) -> None:
        rt = self.runtime
        self.prepare = PrepareStage(rt, plan)
        self.broadphase = BroadphaseStage(rt, plan, self.prepare, self.pair_capacity)
        self.midphase = (
            MidphaseStage(rt, self.shapes, self.prepare, self.broadphase)
            if needs_midphase(plan.shape_types)
            else None
        )
        self.narrowphase = NarrowphaseStage(
            rt, self.shapes, self.broadphase, self.manifold_capacity, self.midphase
        )
        self.children = (
            ChildrenStage(self.midphase, self.narrowphase)
            if self.midphase is not None and self.midphase.midphase.has_children
            else None
        )

    def _build_solve(self, plan: Plan) -> None:
        rt = self.runtime
        self.joints = (
            JointStage(rt, self.constraints, self.joint_store)
            if plan.joints and self.joint_store is not None
            else None
        )
        self.batching = BatchingStage(rt, plan, self.constraints) if plan.solver == "pgs" else None
        self.solve = SolveStage(rt, plan, self.constraints, self.batching, self.joints)
        self._assemble()

    def _assemble(self) -> None:
        self.stages: list[Stage] = [
            s
            for s in (
                self.wake,
                self.prepare,
                self.broadphase,
                self.midphase,
                self.narrowphase,
                self.children,
                self.constraints,
                self.joints,
                self.batching,
                self.solve,
                self.sleep,
            )
            if s is not None
        ]
        self.by_name = {s.name: s for s in self.stages}

    def replan(self, plan: Plan) -> None:
        """Rebuild the stages whose choices differ in ``plan`` (call `resize` after)."""
        old, self.plan = self.plan, plan
        if (old.shape_types, old.broadphase, old.gyroscopic) != (
            plan.shape_types,
            plan.broadphase,
            plan.gyroscopic,
        ):
            self._build_collision(plan)
            self.constraints.narrowphase = self.narrowphase
        solve_choices = (
            "solver",
            "batching",
            "persistent",
            "normal_solve",
            "fast_math",
            "warm_start_mode",
            "release_sweeps",
            "ordered_rounds",
            "group_count",
            "joints",
            "contact_geometry",
        )
        if any(getattr(old, c) != getattr(plan, c) for c in solve_choices):
            self._build_solve(plan)
        self._assemble()

    def __getitem__(self, name: str) -> Stage:
        return self.by_name[name]

    def resize(self, body_count: int) -> None:
        for stage in self.stages:
            stage.resize(body_count)

    def enqueue(self, step: StepContext) -> None:
        for stage in self.stages:
            stage.enqueue(step)
