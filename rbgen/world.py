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
"""

from __future__ import annotations

import warnings

import numpy as np
import pyopencl as cl

from .bodies import BodyStore, per_body
from .codegen import KernelSpec, SpecLog
from .device import Runtime, coerce_runtime
from .errors import RbgenError
from .guard import STEPS_IN_FLIGHT, Replan, StepGuard
from .pipeline.step import StepContext, StepPipeline
from .plan import Plan, derive_plan
from .settings import STEP, Settings, split_options
from .shapes import Plane, Shape, ShapeTable


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
    (``positions``, ``orientations``, ``linear_velocities``, ``angular_velocities``);
    `rbgen.bodies` lists the checks. Shapes are immutable values: one shape object may be
    added to several Worlds.
    """

    def __init__(self, device=None, gravity=(0.0, -9.81, 0.0), **options):
        step_settings, construction = split_options({"gravity": gravity, **options})
        self.runtime: Runtime = coerce_runtime(device)
        object.__setattr__(self, "settings", Settings(step_settings))
        self.options = construction
        self.shapes = ShapeTable()
        self._bodies = BodyStore(
            self.shapes,
            finish=self._finish_pending,
            read_device=lambda: self.runtime.read(self._device.bodies),
        )
        self._persistent_failed = False
        #: the plan of the current scene (rederived when the shape types change)
        self.plan: Plan = derive_plan(self.runtime.traits, construction)
        self._pipeline: StepPipeline | None = None
        self._device = None
        self._guard = StepGuard(self.runtime)
        #: every kernel specialisation this World compiled (what `rbgen export` writes)
        self._spec_log = SpecLog(self.runtime)
        self.last_step_counters = {"launches": 0, "blocking_reads": 0}
        self.steps = 0

    # ------------------------------------------------------------- settings
    def __getattr__(self, name):
        if name in STEP:
            return getattr(self.settings, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def __setattr__(self, name, value):
        if name in STEP:
            setattr(self.settings, name, value)
        else:
            object.__setattr__(self, name, value)

    @property
    def solver(self) -> str:
        return self.plan.solver

    @property
    def overflows(self) -> int:
        """Steps redone because a buffer overflowed (each grew the buffer)."""
        return self._guard.overflows

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
        return int(
            self._bodies.add(
                shape,
                np.asarray([position], float),
                np.asarray([orientation], float),
                None,
                friction,
                restitution,
                None,
                None,
            )[0]
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
        return int(
            self.add_bodies(
                shape,
                mass,
                [position],
                [orientation],
                friction,
                restitution,
                [linear_velocity],
                [angular_velocity],
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
        are scalars or one value per body. Returns their indices."""
        if positions is None:
            raise RbgenError("add_bodies: positions are required (an (N, 3) array)")
        positions = np.asarray(positions, float)
        if isinstance(shape, Plane):
            raise RbgenError("a Plane can only be static: use add_static")
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

    # ------------------------------------------------------------- state
    def _set_field(self, name, values, lanes, what):
        self._bodies.set_field(name, values, lanes, what)
        if self._pipeline is not None:
            self._steps.constraints.constraints.reset()  # teleports forget the contacts

    positions = property(
        lambda s: s._bodies.field("position", 3),
        lambda s, v: s._set_field("position", v, 3, "positions"),
        doc="(N, 3) float32 centres of mass; setting teleports every body",
    )
    orientations = property(
        lambda s: s._bodies.field("orientation", 4),
        lambda s, v: s._set_field("orientation", v, 4, "orientations"),
        doc="(N, 4) float32 unit quaternions (x, y, z, w)",
    )
    linear_velocities = property(
        lambda s: s._bodies.field("linear_velocity", 3),
        lambda s, v: s._set_field("linear_velocity", v, 3, "linear_velocities"),
    )
    angular_velocities = property(
        lambda s: s._bodies.field("angular_velocity", 3),
        lambda s, v: s._set_field("angular_velocity", v, 3, "angular_velocities"),
    )

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
        )
        if self._pipeline is None:
            self._pipeline = StepPipeline(
                self.runtime,
                plan,
                self.shapes,
                pair_capacity=self.options["pair_capacity"],
                manifold_capacity=self.options["manifold_capacity"],
            )
        elif plan != self.plan:
            self._pipeline.replan(plan)
        self.plan = plan
        self._device = self._bodies.upload(self.runtime.queue, STEPS_IN_FLIGHT)
        self._packed = self.shapes.pack_all().to_device(self.runtime.queue)
        self._size_pipeline(self._pipeline)

    def _size_pipeline(self, pipeline: StepPipeline) -> None:
        """Size the pipeline's buffers for the bodies, set the batching's scene geometry and
        lay out the step report."""
        pipeline.resize(self._bodies.count)
        if pipeline.batching is not None:
            pipeline.batching.configure(
                self._bodies, self.settings.gravity, self.settings.contact_margin
            )
        self._guard.attach(pipeline)

    # ------------------------------------------------------------- stepping
    def step(self, dt: float, substeps: int = 1) -> None:
        """Advance by ``dt`` seconds in ``substeps`` equal steps (no blocking read)."""
        if not (isinstance(dt, (int, float, np.floating)) and np.isfinite(dt) and dt > 0):
            raise RbgenError(f"dt must be a positive finite number, got {dt!r}")
        if not isinstance(substeps, (int, np.integer)) or substeps < 1:
            raise RbgenError(f"substeps must be a positive integer, got {substeps!r}")
        before = dict(self.runtime.counters)
        bodies = self._bodies
        with self._spec_log:
            for _ in range(int(substeps)):
                self._check_in_flight(keep=STEPS_IN_FLIGHT - 1)
                if not bodies.has_dynamic and not bodies.host_stale:
                    continue  # nothing can move (empty or static-only world)
                if bodies.device_stale:
                    self._upload()
                self._enqueue_step(float(dt) / int(substeps))
        self.steps += 1
        self.last_step_counters = {k: self.runtime.counters[k] - before[k] for k in before}

    def _enqueue_step(self, dt: float) -> None:
        self._bodies.host_stale = True
        if self._bodies.count == 0:
            return
        slot = self._guard.next_slot()
        self._steps.enqueue(StepContext(dt, slot, self.settings, self._device, self._packed))
        self._guard.finish_step(dt, slot)

    def _finish_pending(self) -> None:
        """Check every enqueued step (waits for their report copies only)."""
        self._check_in_flight(keep=0)

    def _check_in_flight(self, keep: int) -> None:
        try:
            self._guard.check(keep, self._restore, self._pipeline_rewind, self._enqueue_step)
        except Replan as replan:
            self._abandon_persistent(replan.args[0])

    def _restore(self, slot: int) -> None:
        cl.enqueue_copy(
            self.runtime.queue, self._device.bodies.data, self._device.backups[slot].data
        )

    def _pipeline_rewind(self, steps: int) -> None:
        self._steps.constraints.constraints.undo(steps)

    def _abandon_persistent(self, redo: list) -> None:
        """A persistent launch gave up its device-wide barrier (its work groups did not all
        run at once): this World plans without persistent launches from now on and redoes
        the steps."""
        self._persistent_failed = True
        old = self.plan
        self.plan = derive_plan(
            self.runtime.traits, self.options, self.shapes.type_names(), persistent_failed=True
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
        for dt in redo:
            self._enqueue_step(dt)

    def kernel_specs(self) -> list[tuple[KernelSpec, tuple[str, ...]]]:
        """Every kernel specialisation this World has compiled, with its build options,
        in first-use order: exactly what it runs (after its first step)."""
        return self._spec_log.specs()

    # ------------------------------------------------------------- statistics
    def statistics(self) -> dict:
        """Counts of the last step and the plan's main choices (blocking reads: call
        outside the timed loop)."""
        self._finish_pending()
        plan = self.plan
        summary = {
            "bodies": self.body_count,
            "solver": plan.solver,
            "batching": plan.batching,
            "normal_solve": plan.normal_solve,
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
        points = read(constraints.constraints)[:manifolds]["point_count"]
        batch_counts = (
            read(p.batching.batcher.group_batch_count)
            if p.batching is not None
            else np.zeros(0, np.uint32)
        )
        return {
            **summary,
            "pairs": pairs,
            "manifolds": manifolds,
            "contacts": int(points.sum()),
            "batches": int(batch_counts.max(initial=0)),
            "groups_used": int((batch_counts > 0).sum()),
        }

    def render(self, path, camera=None, width: int = 960, height: int = 540):
        """Write a picture of the World now to ``path`` (PNG; see `rbgen.render.render_world`:
        ``camera`` a `rbgen.render.Camera`, a dict of its fields, or None to frame the moving
        bodies). One read of the transforms; returns the path written."""
        from .render import render_world

        return render_world(self, path, camera=camera, width=width, height=height)
