"""The user's object: bodies, shapes, settings, and `step()`.

A World is a thin façade over four parts, each in its own module:

* `rbgen.bodies.BodyStore`: the host mirror of every body, input checks, device arrays;
* `rbgen.plan.Plan`: every choice for this device and these options (solver, batching,
  kernels), derived once and rederived only when the scene's shape types change;
* `rbgen.pipeline.step.StepPipeline`: the stages of a step, in order, each owning its
  buffers;
* `rbgen.guard.StepGuard`: the step report, the overflow check and the redo.

A step is a fixed sequence of enqueues with no blocking read; counts stay on the device;
an overflowed buffer is grown and the step redone, so no pair or contact is dropped.
Every check (input, memory: `rbgen.memory`) happens at construction, adds, sets, removals
and growth, never on a step's path; a refused request leaves the World as it was.
"""

from __future__ import annotations

import warnings

import numpy as np
import pyopencl as cl

from . import history, layouts
from .bodies import STATE_FIELDS, BodyStore, body_ids, bounding_radius, floats, one_row, per_body
from .codegen import KernelSpec, SpecLog
from .device import Runtime, coerce_runtime
from .errors import RbgenError
from .forces import KEEP_STEPS, ExternalForces
from .guard import STEPS_IN_FLIGHT, Replan, StepGuard
from .joints import JointStore, joint_fields, joint_reactions, pack_joints
from .memory import WorldMemory
from .pipeline import sleep
from .pipeline.step import StepContext, StepPipeline
from .plan import Plan, derive_plan
from .settings import STEP, Settings, split_options
from .shapes import Plane, Shape, ShapeTable
from .snapshot import PendingFrame, SnapshotCopies


def _state_property(what: str, doc: str) -> property:
    """A World state field: reading gives the read-only snapshot, assigning sets it all."""
    return property(lambda w: w._field(what), lambda w, v: w._set_field(what, v), doc=doc)


class World:
    """A rigid-body world on one OpenCL device.

    ``World(device=None, gravity=(0, -9.81, 0), **options)``: ``device`` is a Runtime, a
    device choice (index or name) or None (the default device). Every option, its
    default and what it allows is in `rbgen.settings` (the README has the table): step
    settings (``iterations``, ``position_iterations``, ``relaxation``, ``warm_start``,
    ``contact_margin``, ``restitution_threshold``, ``penetration_slop``,
    ``penetration_recovery``, damping) are attributes changeable between steps;
    construction options (``solver``, ``batching``, ``normal_solve``, ``broadphase``,
    ``fast_math``, ``gyroscopic``, capacities, ``plan`` overrides) decide the kernels and
    are fixed. A bad value raises `RbgenError` naming the option and what it allows.

    Bodies: every body, static or dynamic, has an index into the state arrays
    (``positions``, ``orientations``, ``linear_velocities``, ``angular_velocities``:
    read-only snapshots; `set_state` and whole-array assignment change the state);
    `rbgen.bodies` lists the checks. `remove_bodies` renumbers the bodies after the
    removed ones and returns the mapping. Shapes are immutable values: one shape object
    may be added to several Worlds.

    Memory: a World that would not fit (at construction, on an add of bodies or joints,
    or when a buffer grows after an overflow) raises `rbgen.errors.MemoryLimitError`
    naming the need and the limit before allocating (`rbgen.memory`).
    """

    def __init__(self, device=None, gravity=(0.0, -9.81, 0.0), **options):
        split_options({"gravity": gravity, **options})  # refuses bad options before a device
        self.runtime: Runtime = coerce_runtime(device)
        step_settings, construction = split_options(
            {"gravity": gravity, **options}, self.runtime.traits.is_gpu
        )
        object.__setattr__(self, "settings", Settings(step_settings))
        self.options = construction
        self.shapes = ShapeTable()
        self._bodies = BodyStore(
            self.shapes,
            finish=self._finish_pending,
            read_device=lambda: self.runtime.read(self._device.bodies),
        )
        self._persistent_failed = False
        #: the bodies whose shapes and spread size the batching's cells and slabs (None:
        #: this World's own; a WorldBatch gives one environment's, so that its colouring
        #: does not depend on the number of environments)
        self._batching_scene: BodyStore | None = None
        self._joints = JointStore(self.runtime)
        #: (old joint count,) int64: what the last `remove_bodies` or `remove_joints` did
        #: to the joint ids (new id, -1 removed); empty before either
        self.last_joint_mapping = np.zeros(0, np.int64)
        #: the plan of the current scene (rederived when the shape types change)
        self.plan: Plan = derive_plan(self.runtime.traits, construction)
        self._pipeline: StepPipeline | None = None
        self._device = None
        self._guard = StepGuard(self.runtime)
        self._forces = ExternalForces(self.runtime)
        #: non-blocking reads of the transforms (`snapshot_frame`)
        self._snapshots = SnapshotCopies(self.runtime)
        #: step number -> the settings it ran with (a redo replays them, not the settings
        #: changed since); the steps a redo can reach (`rbgen.forces.KEEP_STEPS`)
        self._step_settings: dict[int, Settings] = {}
        #: every kernel specialisation this World compiled (what `rbgen export` writes)
        self._spec_log = SpecLog(self.runtime)
        self.last_step_counters = {"launches": 0, "blocking_reads": 0}
        self.steps = 0
        self._memory = WorldMemory(self, self.runtime, construction)
        given = [
            f"{k}={construction[k]}"
            for k in ("pair_capacity", "manifold_capacity")
            if construction[k] is not None
        ]
        self._memory.check(f"a World with {', '.join(given) or 'no bodies'}", self._memory.sizes(0))

    # ------------------------------------------------------------- settings
    def __getattr__(self, name):
        if name in STEP:
            return getattr(self.settings, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def __setattr__(self, name, value):
        if name in STEP:
            before = np.array(self.settings.gravity) if name == "gravity" else None
            setattr(self.settings, name, value)
            if before is not None and np.any(before != self.settings.gravity):
                self._wake_islands(np.ones(self._bodies.count, bool))  # (all fall anew)
        else:
            object.__setattr__(self, name, value)

    @property
    def solver(self) -> str:
        return self.plan.solver

    @property
    def overflows(self) -> int:
        """Steps redone because a buffer overflowed (each grew the buffer) or the
        broadphase asked to be redone another way (`overflows_by_stage` tells which)."""
        return self._guard.overflows

    @property
    def fallbacks(self) -> list[str]:
        """The choices this World gave up while it ran, sorted: a plan choice whose source
        is "fallback" (`rbgen.plan.Plan.sources`: a persistent launch that gave up at its
        device-wide barrier), and "broadphase" once the broadphase left its algorithm for
        another (`rbgen.pipeline.broadphase.Broadphase.fallback`: the grid's owner emission,
        six launches a query, for slot emission, tens of them). Either makes a step take
        more launches than the plan's."""
        given_up = [name for name, source in self.plan.sources.items() if source == "fallback"]
        if self._pipeline is not None and self._pipeline.broadphase.broadphase.fallback:
            given_up.append("broadphase")
        return sorted(given_up)

    @property
    def overflows_by_stage(self) -> dict[str, int]:
        """`overflows` by the step stage that asked for the redo (e.g. ``{"broadphase":
        1}``; a redo that two stages asked for counts for both)."""
        return dict(self._guard.overflows_by_stage)

    @property
    def release_sweeps(self) -> int | None:
        """The PGS solve's last sweeps that solve each manifold's complete block (see
        `rbgen.plan`; 0 when the normal solve is sequential)."""
        return self.plan.release_sweeps if self.plan.normal_solve == "block" else 0

    # ------------------------------------------------------------- bodies
    @property
    def body_count(self) -> int:
        return self._bodies.count

    def add_static(
        self,
        shape: Shape,
        position=(0.0, 0.0, 0.0),
        orientation=(0.0, 0.0, 0.0, 1.0),
        friction: float = 0.6,
        restitution: float = 0.0,
    ) -> int:
        """A body that never moves (planes only this way); returns its index."""
        body = self._bodies.count
        position = one_row(position, 3, "position", body)
        orientation = one_row(orientation, 4, "orientation", body)
        self._afford_add(1, shape)
        return int(
            self._bodies.add(shape, position, orientation, None, friction, restitution, None, None)[
                0
            ]
        )

    def add_body(
        self,
        shape: Shape,
        mass: float = 1.0,
        position=(0.0, 0.0, 0.0),
        orientation=(0.0, 0.0, 0.0, 1.0),
        linear_velocity=(0.0, 0.0, 0.0),
        angular_velocity=(0.0, 0.0, 0.0),
        friction: float = 0.6,
        restitution: float = 0.0,
    ) -> int:
        """One dynamic body; returns its index."""
        body = self._bodies.count
        return int(
            self.add_bodies(
                shape,
                mass,
                one_row(position, 3, "position", body),
                one_row(orientation, 4, "orientation", body),
                friction,
                restitution,
                one_row(linear_velocity, 3, "linear_velocity", body),
                one_row(angular_velocity, 3, "angular_velocity", body),
            )[0]
        )

    def add_bodies(
        self,
        shape: Shape,
        mass=1.0,
        positions=None,
        orientations=None,
        friction=0.6,
        restitution=0.0,
        linear_velocities=None,
        angular_velocities=None,
    ) -> np.ndarray:
        """Many dynamic bodies of one shape; ``mass``, ``friction``, ``restitution``
        are scalars or one value per body. Returns their indices. Too many bodies for
        the host or the device raise `MemoryLimitError` before anything is allocated."""
        if positions is None:
            raise RbgenError("add_bodies: positions are required (an (N, 3) array)")
        try:
            shape_of = np.shape(positions)
        except ValueError:  # a ragged sequence
            shape_of = None
        if shape_of is None or len(shape_of) != 2 or shape_of[1] != 3:
            raise RbgenError(
                f"positions must be an (N, 3) array, got "
                f"{'a ragged sequence' if shape_of is None else shape_of}"
            )
        self._afford_add(shape_of[0], shape)
        try:
            positions = floats(positions)
        except (TypeError, ValueError):
            raise RbgenError(
                f"positions must be numbers of shape (N, 3), got {type(positions).__name__}"
            ) from None
        if isinstance(shape, Plane):
            raise RbgenError("shape: a Plane can only be static (use add_static)")
        return self._bodies.add(
            shape,
            positions,
            orientations,
            per_body(mass, len(positions), "mass"),
            friction,
            restitution,
            linear_velocities,
            angular_velocities,
        )

    def _afford_add(self, count: int, shape) -> None:
        self._memory.check_add(self._bodies, count, shape, self._pipeline)

    def remove_bodies(self, ids) -> np.ndarray:
        """Remove the bodies ``ids`` (an index or a sequence; repeats allowed) between steps.

        The bodies after a removed one move down to close the gap, keeping their order
        (the step runs over dense arrays: holes would cost every kernel every step).
        Returns ``mapping``, an int64 array over the old indices: ``mapping[old]`` is the
        new index, -1 for a removed body; update kept indices with ``ids =
        mapping[ids]``. The survivors' contacts keep their warm start (renumbered);
        nothing of a removed body is carried onto another. Buffers keep their capacity
        (adding bodies again reuses it).

        Joints: a joint with a removed body at either end is removed with it (a joint to
        the world goes with its body); the other joints follow their renumbered bodies,
        keeping their order, impulses and broken flags, and move down to close the gaps.
        `last_joint_mapping` then reports it: old joint id -> new id, -1 removed."""
        count = self._bodies.count
        mapping = self._bodies.remove(ids)
        joints = np.arange(self._joints.count, dtype=np.int64)
        if len(mapping) != count or np.any(mapping < 0):
            history.renumber_bodies(self.runtime, self._pipeline, mapping)
            sleeping = self._sleep_records()
            if sleeping is not None:  # (bodies added since the last step have no record yet)
                records = sleeping.read()
                sleeping.adopt(sleep.renumber(records, mapping[: len(records)]))
            self._forces.resize(count)
            self._forces.renumber(mapping)
            joints = self._joints.renumber_bodies(mapping)
        self.last_joint_mapping = joints
        return mapping

    # ------------------------------------------------------------- forces
    def apply_forces(self, ids, forces, torques=None, points=None) -> None:
        """Forces (N) on the bodies ``ids`` during the next step only (`rbgen.forces`).

        ``forces``: one (3,) row per id, or one row for them all; ``torques`` (N m,
        world frame) likewise; ``points`` (world coordinates): each force acts there,
        adding the torque (point - centre of mass) x force. Calls before a step add up;
        a static body's forces are ignored. No blocking read: the sums go to the device
        with the step. Bad ids, shapes or NaN/inf values raise `RbgenError` naming the
        argument (and the body), and nothing is added. The first forces a World is given
        bring their upload buffers (`rbgen.memory.FORCE_UPLOADS` a body): when they do not
        fit, `MemoryLimitError` says so and nothing is added."""
        self._forces.resize(self._bodies.count)
        checked = self._forces.checked(ids, forces, torques, points)
        self._give_forces()
        self._forces.accumulate(*checked)

    def _give_forces(self) -> None:
        """Before the first forces are added: check that their uploads fit (raises
        `MemoryLimitError`), then count them in the World's memory account."""
        if not self._forces.given:
            self._memory.check_forces(self._bodies, self._pipeline)
            self._forces.given = True
            self._memory.record(self._bodies, self.shapes.type_names(), self._pipeline)

    # ------------------------------------------------------------- joints
    @property
    def joint_count(self) -> int:
        return self._joints.count

    def add_joint(self, joint) -> int:
        """Add one joint (`rbgen.BallJoint`, `FixedJoint`, `HingeJoint`, `SliderJoint`,
        `DistanceJoint`; anchors and axes in world coordinates now); returns its id."""
        kind, fields = joint_fields(joint)
        return int(self.add_joints(kind, **fields)[0])

    def add_joints(self, kind, **fields) -> np.ndarray:
        """Many joints of one ``kind`` (a joint class) at once: each field (``a``, ``b``,
        ``break_impulse`` and the kind's own, as its class names them) is one value for
        all or one per joint (``b``: None or -1 for the world). Returns their ids. A bad
        value raises `RbgenError` naming the joint and the field; nothing is added."""
        if self.plan.solver != "pgs":
            raise RbgenError(
                f"joints need solver='pgs' (this World's solver is {self.plan.solver!r}, "
                f"which has no joint rows)"
            )
        self._bodies.sync_to_host()
        if "a" in fields:  # (else pack_joints names the missing field)
            added = len(np.atleast_1d(np.asarray(fields["a"], dtype=object)))
            self._memory.check_joints(self._bodies, added, self._pipeline)
        host = self._bodies.host
        records = pack_joints(
            kind,
            fields,
            self._joints.count,
            host["position"][:, :3],
            host["orientation"],
            host["inv_mass"] > 0,
        )
        ids = self._joints.add(records)
        self._wake_islands(np.concatenate([records["body_a"], records["body_b"]]))
        return ids

    def remove_joints(self, ids) -> np.ndarray:
        """Remove the joints ``ids`` between steps; the later joints move down to close
        the gap. Returns ``mapping`` over the old ids (new id, -1 removed)."""
        self._finish_pending()  # (a step redone after this must find the joints it ran)
        self._joints.sync_to_host()
        old = self._joints.host
        self.last_joint_mapping = mapping = self._joints.remove(ids)
        gone = old[mapping < 0]
        self._wake_islands(np.concatenate([gone["body_a"], gone["body_b"]]))
        return mapping

    @property
    def joint_impulses(self) -> np.ndarray:
        """(J, 6) float32: the reaction of each joint on body b over the last step, world
        frame: linear impulse (N s) then angular impulse (N m s); the last substep's
        impulses times the substeps it ran with (a broken joint's are zero). Blocking
        reads."""
        self._finish_pending()
        self._joints.sync_to_host()
        self._bodies.sync_to_host()
        host = self._joints.host
        linear, angular = joint_reactions(
            host, self._bodies.host["position"][:, :3], self._bodies.host["orientation"]
        )
        out = np.zeros((len(host), 6), np.float32)
        out[:, :3], out[:, 3:] = linear, angular
        ran = self._step_settings.get(self.steps - 1, self.settings)
        return out * np.float32(ran.substeps)

    @property
    def joints_broken(self) -> np.ndarray:
        """(J,) bool: the joints that broke (exceeded their break_impulse). A blocking read."""
        self._finish_pending()
        self._joints.sync_to_host()
        return (self._joints.host["flags"] & layouts.JOINT_BROKEN) != 0

    # ------------------------------------------------------------- state
    def set_state(
        self,
        ids,
        positions=None,
        orientations=None,
        linear_velocities=None,
        angular_velocities=None,
    ) -> None:
        """Set the state of the bodies ``ids`` (an index or a sequence of distinct
        indices): each field given is one row per id, or one row for them all (None:
        unchanged). Orientations are normalised; static bodies may be moved but their
        velocities stay zero. Every value is checked before any is written: a bad one
        raises `RbgenError` naming the body and the field, and the World is unchanged.
        The contacts of the bodies set lose their warm start (the old impulses belong to
        a configuration the bodies have left)."""
        ids = self._bodies.set_rows(
            ids,
            {
                "positions": positions,
                "orientations": orientations,
                "linear_velocities": linear_velocities,
                "angular_velocities": angular_velocities,
            },
        )
        if any(
            v is not None for v in (positions, orientations, linear_velocities, angular_velocities)
        ):
            affected = np.zeros(self._bodies.count, bool)
            affected[ids] = True
            history.forget_bodies(self.runtime, self._pipeline, affected)
            self._joints.forget_bodies(affected)
            self._wake_islands(affected)

    def _field(self, what):
        name, lanes = STATE_FIELDS[what]
        return self._bodies.field(
            name,
            lanes,
            f"world.set_state(ids, {what}=...) or assign the whole array (world.{what} = values)",
        )

    def _set_field(self, what, values):
        name, lanes = STATE_FIELDS[what]
        changed = self._bodies.set_field(name, values, lanes, what)
        history.forget_bodies(self.runtime, self._pipeline, changed)
        self._wake_islands(changed)

    positions = _state_property(
        "positions",
        "(N, 3) float32 centres of mass: a read-only snapshot. Assigning an (N, 3) "
        "array teleports every body; `set_state` sets some.",
    )
    orientations = _state_property(
        "orientations",
        "(N, 4) float32 unit quaternions (x, y, z, w): a read-only snapshot; assign "
        "the whole array or use `set_state`.",
    )
    linear_velocities = _state_property(
        "linear_velocities",
        "(N, 3) float32 m/s: a read-only snapshot; assign the whole array (static "
        "bodies' rows are ignored: they stay at rest) or use `set_state`.",
    )
    angular_velocities = _state_property(
        "angular_velocities",
        "(N, 3) float32 rad/s (world frame): a read-only snapshot; assign the whole "
        "array (static bodies' rows are ignored) or use `set_state`.",
    )

    def snapshot_frame(self) -> PendingFrame:
        """The bodies' transforms now, without draining the queue: enqueues one
        non-blocking copy of the body records into pinned host memory and returns a
        `rbgen.snapshot.PendingFrame`, whose ``result()`` (or ``wait()``) waits for that
        copy only and gives the `rbgen.render.Frame` that a blocking read now
        (`rbgen.render.frame_of`) would give, bit for bit.

        The contract: steps run after the snapshot do not change it (the copy is enqueued
        before them on the World's in-order queue, so it reads the records first); a step
        before it that overflows is redone and the snapshot copied again after the redone
        step; bodies added or removed after it change nothing in it (it keeps its own host
        memory and its body count, ``count``). When nothing was stepped since the state was
        last read or set, the host copy is the state and the frame is ready at once."""
        return self._snapshots.take(self)

    @property
    def _steps(self) -> StepPipeline:
        """The step pipeline (built at the first step, when the scene's shapes are known)."""
        if self._pipeline is None:
            raise RbgenError("the World has no step pipeline before its first step")
        return self._pipeline

    # ------------------------------------------------------------- device
    def _upload(self) -> None:
        """Send the host bodies (after adds or sets), replan if the shape types changed,
        and size the buffers."""
        self._bodies.sync_to_host()
        plan = derive_plan(
            self.runtime.traits,
            self.options,
            self.shapes.type_names(),
            persistent_failed=self._persistent_failed,
            joints=self._joints.count > 0,
        )
        if self._pipeline is None:
            self._pipeline = StepPipeline(
                self.runtime,
                plan,
                self.shapes,
                pair_capacity=self.options["pair_capacity"],
                manifold_capacity=self.options["manifold_capacity"],
                joint_store=self._joints,
                backups=STEPS_IN_FLIGHT,
            )
        elif plan != self.plan:
            self._pipeline.replan(plan)
        self.plan = plan
        self._device = self._bodies.upload(self.runtime.queue, STEPS_IN_FLIGHT, self._device)
        self._packed = self.shapes.pack_all().to_device(self.runtime.queue)
        self._size_pipeline(self._pipeline)
        self._upload_joints()
        self._upload_sleep()

    # ------------------------------------------------------------- sleeping
    def _sleep_records(self):
        """The pipeline's `rbgen.pipeline.sleep.Sleeping` once it holds records (None:
        sleeping off, or no step yet)."""
        p = self._pipeline
        if p is None or p.sleeping is None or p.sleeping.records is None:
            return None
        return p.sleeping

    def _upload_sleep(self) -> None:
        """After an upload: bodies added since the last step get awake records, and every
        body on the device is made to agree with its record again at the next step."""
        p = self._pipeline
        if p is None or p.sleeping is None:
            return
        sleeping, host = p.sleeping, self._bodies.host
        if sleeping.records is not None and sleeping.count == len(host):
            sleeping.bodies_uploaded()
            return
        extents = np.zeros(len(host), np.float32)
        dynamic = host["inv_mass"] > 0
        for k in np.unique(host["shape"][dynamic]):
            extents[dynamic & (host["shape"] == k)] = bounding_radius(self.shapes.shapes[int(k)])
        records = sleep.fresh_records(host["inv_mass"], extents)
        if sleeping.records is not None and sleeping.count:
            kept = sleeping.read()
            records[: len(kept)] = kept  # (removals renumbered them already: only adds)
        sleeping.adopt(records)

    def _wake_islands(self, ids) -> None:
        """Wake the sleeping islands of the bodies ``ids`` (indices or a bool mask), between
        steps (a blocking read of the records when sleeping is on)."""
        sleeping = self._sleep_records()
        ids = np.asarray(ids)
        ids = np.flatnonzero(ids) if ids.dtype == bool else ids.astype(np.int64)
        if sleeping is None or len(ids) == 0:
            return
        self._finish_pending()
        records = sleeping.read()
        # (bodies added since the last step have no record yet: they are awake)
        if sleep.wake_islands(records, ids[ids < len(records)]):
            sleeping.adopt(records)

    def wake(self, ids=None) -> None:
        """Wake the sleeping islands that hold the bodies ``ids`` (None: every body), between
        steps. Bodies wake by themselves when touched, pushed or set; this is for a change
        the World cannot see. Does nothing with sleeping off."""
        count = self._bodies.count
        self._wake_islands(np.arange(count) if ids is None else body_ids(ids, count, "ids"))

    @property
    def asleep(self) -> np.ndarray:
        """(N,) bool: the bodies asleep now (all False with sleeping off or before the first
        step). A blocking read."""
        self._finish_pending()
        sleeping = self._sleep_records()
        out = np.zeros(self._bodies.count, bool)
        if sleeping is not None:
            records = sleeping.read()
            n = min(len(records), len(out))
            out[:n] = records["asleep"][:n] == layouts.SLEEP_ASLEEP
        return out

    def _upload_joints(self) -> None:
        """Send the joint records after a change; the contacts' edges follow the joints'."""
        self._joints.upload()
        if self._pipeline is not None:
            contacts = self._pipeline.constraints.constraints
            contacts.first_contact_edge = self._joints.count
            has = self._joints.count > 0
            contacts.set_joint_pairs(
                self._joints.pairs if has else None, self._joints.pair_count if has else 0
            )

    def _size_pipeline(self, pipeline: StepPipeline) -> None:
        """Size the pipeline's buffers for the bodies, set the batching's scene geometry and
        lay out the step report."""
        pipeline.resize(self._bodies.count)
        if pipeline.batching is not None:
            pipeline.batching.configure(
                self._batching_scene or self._bodies,
                self.settings.gravity,
                self.settings.contact_margin,
            )
        self._guard.attach(pipeline)
        self._memory.record(self._bodies, self.shapes.type_names(), pipeline)

    # ------------------------------------------------------------- stepping
    def step(self, dt: float, substeps: int = 1) -> None:
        """Advance by ``dt`` seconds in ``substeps`` equal steps (no blocking read)."""
        if isinstance(dt, (bool, np.bool_)) or not (
            isinstance(dt, (int, float, np.integer, np.floating)) and np.isfinite(dt) and dt > 0
        ):
            raise RbgenError(f"dt must be a positive finite number (seconds), got {dt!r}")
        if (
            isinstance(substeps, (bool, np.bool_))
            or not isinstance(substeps, (int, np.integer))
            or substeps < 1
        ):
            raise RbgenError(f"substeps must be a positive integer, got {substeps!r}")
        self.plan.check_settings(self.settings)
        before = dict(self.runtime.counters)
        bodies = self._bodies
        with self._spec_log:
            for _ in range(int(substeps)):
                self._check_in_flight(keep=STEPS_IN_FLIGHT - 1)
                if not bodies.has_dynamic and not bodies.host_stale:
                    continue  # nothing can move (empty or static-only world)
                if bodies.device_stale or (
                    self._joints.dirty and (self._joints.count > 0) != self.plan.joints
                ):
                    self._upload()
                elif self._joints.dirty:
                    self._upload_joints()
                self._enqueue_step(float(dt) / int(substeps))
        self.steps += 1
        self.last_step_counters = {k: self.runtime.counters[k] - before[k] for k in before}

    def _enqueue_step(self, dt: float, tag: int | None = None) -> None:
        self._bodies.host_stale = True
        if self._bodies.count == 0:
            return
        slot = self._guard.next_slot()
        tag = self.steps if tag is None else tag
        settings = self._settings_of(tag)
        self._forces.resize(self._bodies.count)
        forces = self._forces.for_step(tag)
        self._steps.enqueue(StepContext(dt, slot, settings, self._device, self._packed, forces))
        self._guard.finish_step(dt, slot, tag)

    def _settings_of(self, tag: int) -> Settings:
        """The settings step ``tag`` runs with: a copy of the World's made at its first
        enqueue, which its substeps and any redo read again (settings changed after the
        step, before it was checked, are the next step's)."""
        settings = self._step_settings.get(tag)
        if settings is None:
            for old in [t for t in self._step_settings if t < tag - KEEP_STEPS]:
                del self._step_settings[old]
            values = self.settings.as_dict()
            values["gravity"] = np.array(values["gravity"], copy=True)
            settings = self._step_settings[tag] = Settings(values)
        return settings

    def _finish_pending(self) -> None:
        """Check every enqueued step (waits for their report copies only)."""
        self._check_in_flight(keep=0)

    def _check_in_flight(self, keep: int) -> None:
        try:
            self._guard.check(
                keep,
                self._restore,
                self._pipeline_rewind,
                self._redo_step,
                self._afford_growth,
                self._forget_steps,
            )
        except Replan as replan:
            self._abandon_persistent(replan.args[0])
        self._snapshots.copy_stale(self)  # (snapshots after the last redone step)

    def _redo_step(self, dt: float, tag: int) -> None:
        """Enqueue a step again (a redo after `_restore`): the snapshots taken after the
        failed step are copied again where they were taken, before the first later step."""
        self._snapshots.copy_before(self, tag)
        self._enqueue_step(dt, tag)

    def _afford_growth(self, problems: dict) -> None:
        self._memory.check_growth(self._bodies, self.shapes.type_names(), self._pipeline, problems)

    def _forget_steps(self, tag: int) -> None:
        """The steps from step number ``tag`` on were undone (a redo could not be made):
        the bodies are as they were before it, so the count goes back too (and their
        forces are dropped)."""
        self.steps = min(self.steps, tag)
        self._snapshots.forget(tag)
        self._forces.forget(tag)
        for old in [t for t in self._step_settings if t >= tag]:
            del self._step_settings[old]

    def _restore(self, slot: int, failed_tag: int | None = None) -> None:
        """The bodies and the joint records as the step of backup ``slot`` found them; for
        a redo of the step tagged ``failed_tag``, the snapshots taken after it read a state
        the redo replaces (`SnapshotCopies.invalidate`)."""
        cl.enqueue_copy(
            self.runtime.queue, self._device.bodies.data, self._device.backups[slot].data
        )
        if self._pipeline is not None and self._pipeline.joints is not None:
            self._joints.restore(slot)
        sleeping = self._sleep_records()
        if sleeping is not None:
            sleeping.restore(slot, self._device.bodies, self._device.static)
        if failed_tag is not None:
            self._snapshots.invalidate(failed_tag)

    def _pipeline_rewind(self, steps: int) -> None:
        self._steps.constraints.constraints.undo(steps)

    def _abandon_persistent(self, redo: list) -> None:
        """A persistent launch gave up its device-wide barrier (its work groups did not all
        run at once): this World plans without persistent launches from now on and redoes
        the steps."""
        self._persistent_failed = True
        old = self.plan
        self.plan = derive_plan(
            self.runtime.traits,
            self.options,
            self.shapes.type_names(),
            persistent_failed=True,
            joints=self._joints.count > 0,
        )
        self._steps.replan(self.plan)
        self._size_pipeline(self._steps)
        warnings.warn(
            f"a persistent launch on {self.runtime.traits.device_name} gave up waiting "
            f"at a device-wide barrier (its work groups did not all run at once: a "
            f"GPU shared through MPS?); the step is redone, and this World plans "
            f"without persistent launches from now on ({old.describe()} -> "
            f"{self.plan.describe()})",
            RuntimeWarning,
            stacklevel=4,
        )
        for dt, tag in redo:
            self._redo_step(dt, tag)

    def kernel_specs(self) -> list[tuple[KernelSpec, tuple[str, ...]]]:
        """Every kernel specialisation this World has compiled, with its build options,
        in first-use order: exactly what it runs (after its first step)."""
        return self._spec_log.specs()

    # ------------------------------------------------------------- statistics
    def statistics(self, contacts: bool = True) -> dict:
        """Counts of the last step and the plan's main choices (blocking reads: call
        outside the timed loop; ``contacts=False``: without the contact points, whose count
        reads every manifold, so that only a few words are read; "contacts" is then None);
        ``broadphase``: the algorithm the broadphase runs now
        (`rbgen.pipeline.broadphase.Broadphase.describe`: the grid leaves its owner emission,
        six launches, for slot emission, tens of them, once a query meets too many large
        bodies)."""
        self._finish_pending()
        plan = self.plan
        summary = {
            "bodies": self.body_count,
            "solver": plan.solver,
            "batching": plan.batching,
            "normal_solve": plan.normal_solve,
            "broadphase": (
                plan.broadphase
                if self._pipeline is None
                else self._pipeline.broadphase.broadphase.describe()
            ),
            **self.last_step_counters,
        }
        if self._bodies.device_stale or self.body_count == 0 or self._pipeline is None:
            return {
                **summary,
                "pairs": 0,
                "manifolds": 0,
                "contacts": 0,
                "batches": 0,
                "groups_used": 0,
            }
        read, p = self.runtime.read, self._steps
        pairs = int(read(p.broadphase.broadphase.count)[0])
        constraints = p.constraints.constraints
        manifolds = int(read(constraints.count)[0])
        points = read(constraints.constraints)[:manifolds]["point_count"] if contacts else None
        batch_counts = (
            read(p.batching.batcher.group_batch_count)
            if p.batching is not None
            else np.zeros(0, np.uint32)
        )
        if plan.sleeping:
            summary["asleep"] = int(self.asleep.sum())
        return {
            **summary,
            "pairs": pairs,
            "manifolds": manifolds,
            "contacts": None if points is None else int(points.sum()),
            "batches": int(batch_counts.max(initial=0)),
            "groups_used": int((batch_counts > 0).sum()),
        }

    def render(self, path, camera=None, width: int = 960, height: int = 540):
        """Write a picture of the World now to ``path`` (PNG; see `rbgen.render.render_world`:
        ``camera`` a `rbgen.render.Camera`, a dict of its fields, or None to frame the moving
        bodies). One read of the transforms; returns the path written."""
        from .render import render_world

        return render_world(self, path, camera=camera, width=width, height=height)
