"""The user's object: bodies, shapes, settings, and `step()`.

A World owns one `Runtime` and every device buffer of the pipeline. A step is
a fixed sequence of enqueues with no blocking read:

    prepare bodies (world inverse inertia, gyroscopic term, gravity) ->
    world AABBs -> broadphase pairs -> narrowphase manifolds ->
    contact constraints -> batching -> warm start, ``iterations`` PGS sweeps
    and (split impulse) ``position_iterations`` push sweeps (one launch with
    components batching, one per colour and sweep otherwise) -> integrate ->
    (split impulse: apply push velocities)

(With ``solver="jacobi"`` there is no batching, and the sweeps are Jacobi
sweeps with mass splitting, `rbgen.pipeline.jacobi`.)

Counts (pairs, manifolds, constraints, batches) stay on the device. Capacity
overflow: the broadphase and the narrowphase report the size they needed in
small status buffers that are copied to pinned host memory without blocking.
`step()` checks the status of the step before the previous one (done long
ago, so the host does not wait for the device to drain; any read of the state
checks all), and if a buffer was too small it grows it, restores the bodies
saved at the start of that step and redoes it and the step after it, so no
pair or contact is ever dropped.

Bodies: every body, static or dynamic, has an index (returned by `add_static`,
`add_body`, `add_bodies`) into the state arrays (`positions`, ...). A body's
frame is its shape's principal frame (centre of mass): for spheres, boxes and
capsules the shape's own frame, for hulls the cooked (re-centred) frame.

Input checks (errors name the body index and the field): NaN/inf positions,
velocities, orientations; non-positive or non-finite mass of a dynamic body;
friction < 0; restitution outside [0, 1]; a plane as a dynamic body; dt <= 0.
Orientations are normalised; one whose norm is off by more than 1e-3 is
normalised with a warning, a zero one is rejected.
"""
from __future__ import annotations

import warnings

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from . import layouts
from .device import Runtime, coerce_runtime
from .errors import CapacityOverflowError, RbgenError
from .pipeline.batching import MODES as BATCHING_MODES, ConstraintBatcher, default_mode
from .pipeline.constraints import ContactConstraints
from .pipeline.gyroscopic import BodyPreparation, inertia_records
from .pipeline.integrate import Integrator
from .pipeline.grid import ABANDONED_OFFSET, clear_abandoned, grid_validated
from .pipeline.jacobi import JacobiSolver
from .pipeline.solver import (ContactSolver, check_release_sweeps, resident_capacity,
                              resolve_fast_math)
from .shapes import Box, Capsule, ConvexHull, Plane, Shape, ShapeTable, Sphere

#: manifolds reserved per body before the first overflow (grown on demand)
MANIFOLDS_PER_BODY = 4
#: contact solvers (World option ``solver``)
SOLVERS = ("pgs", "jacobi")
#: enqueued steps whose overflow status may be unchecked: a step checks the one
#: before the last, whose status copy is done by then, so the host never drains
#: the queue (the constraint ring keeps the warm-start data of both)
STEPS_IN_FLIGHT = 2
#: redos of one step before giving up (each grows the buffers that overflowed)
MAX_REDOS = 16
#: the step report: the words the host checks after every step, gathered on the device
#: and read with ONE copy (a small copy costs an NVIDIA queue ~8 us, as much as a
#: launch): the manifolds the narrowphase needed beyond the capacity (it writes that
#: word itself), the broadphase status, and the grid barrier's abandoned flag (grid
#: launches only; each of these two a device-to-device copy, ~4 us)
REPORT_NEEDED = 0
REPORT_BROADPHASE = 1
REPORT_ABANDONED = REPORT_BROADPHASE + layouts.BROADPHASE_STATUS.itemsize // 4
REPORT_WORDS = REPORT_ABANDONED + 1
#: the PGS solve's last sweeps (velocity, and position) whose block solve may release
#: points, the earlier ones taking only its all-pushing solution (see the World's
#: release_sweeps and ContactSolver.solve). H200 BoxBox 1,000 / 8,000 / 27,000 / 111,375
#: boxes, global batching, 10 + 4 sweeps (2026-12-04, before the summed warm start and
#: the step report, with a finish per timed block): every sweep complete 0.55 / 0.72
#: / 1.20 / 3.70 ms a step; the last 2: 0.52 / 0.68 / 1.15 / 3.67; the last 1: 0.52 /
#: 0.67 / 1.14 / 3.68. The 8,000-box pile's max speed at step 300: 0.000 / 0.000 / 0.003
#: m/s; the 20-row pyramid's top over 600 steps 1.4 / 1.4 / 1.6 cm. Rows alone in the
#: earlier sweeps were cheaper (0.47 / 0.62 / 1.09 / 3.50) but let a perfectly stacked
#: 10-box column drift 1.8-2.6 cm sideways in 10 s (PoCL, cells / single / global
#: batching), where the all-pushing solution keeps it at 0.00 cm.
DEFAULT_RELEASE_SWEEPS = 2


def _default_normal_solve(batching_mode: str, solver_shape: str) -> str:
    """The normal solve that holds stacks (10 iterations, dt 1/60, manifold friction):
    block, except sequential for the cpu shape with components, columns or slabs batching
    (each keeps a stack whole in one group; with columns and block on PoCL a tipped
    column keeps rocking).

    H200, gpu shape: top motion of a 20-row pyramid in 600 steps / max speed of a dropped
    8,000-box pile at step 300 / sideways drift of a 10-box column in 600 steps:
    cells + block 1.98 cm / 0.0009 m/s / 0.00 cm; cells + sequential 6.99 cm (over the
    5 cm bound) / 0.0052 / 0.96 cm; components + block 1.98 / 0.0005 / 0.00;
    components + sequential 1.81 / 0.0047 / 1.36; slabs + block 2.09 / 0.0005 / 0.00;
    slabs + sequential 3.23 / 0.0049 / 3.89 (over its 2 cm bound). The gpu shape solves a
    batch's manifolds side by side, so a sequential solve's point-order torque is not
    corrected by the rows solved after it, and columns lean; the block solve leaves no
    such torque.
    PoCL, cpu shape (one work-item walks its group in index order, Gauss-Seidel proper):
    components + sequential 1.8-1.9 cm (pyramid), 0 of 28 dropped 4x4x4 grids still
    moving; slabs + sequential 2.8 cm; components + block 1.9-2.9 cm but 2 of 40 grids
    keep a stack top rocking, and block costs 8x the sequential solve there (2x on the
    H200). Cells with the cpu shape needs block: sequential lets the 10-box column drift
    9 cm (the colours split a column between launches)."""
    if solver_shape == "cpu" and batching_mode in ("components", "columns", "slabs"):
        return "sequential"
    return "block"


class World:
    """A rigid-body world on one OpenCL device (see the module docstring).

    Settings (attributes, may change between steps): ``gravity``,
    ``iterations`` (PGS velocity sweeps), ``position_iterations`` (split
    impulse sweeps), ``relaxation`` (successive over-relaxation; 1.0 by default: 1.2
    makes a 10-box column walk sideways and topple within 5 s at 10 iterations),
    ``restitution_threshold`` (m/s),
    ``penetration_slop`` (m; default 1 mm with split impulse, 5 mm with Baumgarte),
    ``penetration_recovery`` (fraction per step),
    ``contact_margin`` (m: contacts are created this far apart),
    ``linear_damping`` and ``angular_damping``.
    Construction options: ``penetration`` ("split", the default, or "baumgarte": split
    impulse keeps recovery out of the velocities (its push rows start from zero
    every step); a 20-row pyramid's top then moves ~2 cm in 10 s and comes to
    rest, while Baumgarte's recovery velocity keeps the same pyramid jittering
    at up to 0.8 m/s),
    ``normal_solve`` ("block": a manifold's normal rows solved together, so
    the order of its points leaves no torque; "sequential": one row after another;
    default: sequential for the cpu shape with components or slabs batching, else
    block — see `_default_normal_solve`), ``release_sweeps`` (with the block: how many
    of the last velocity sweeps, and of the last position sweeps, solve the complete
    block, releasing points where the solution needs it; the earlier ones take its
    all-pushing solution where that holds and solve the other manifolds' rows one after
    another, a cheaper sweep; None, the default: `DEFAULT_RELEASE_SWEEPS` with the PGS
    solver; an integer >= ``iterations``: every sweep complete; the Jacobi solver solves
    the complete block on every sweep and refuses the option),
    ``warm_start``, ``gyroscopic``, ``friction_model`` ("manifold", the default:
    one pair at the centre limited by the total normal impulse, plus twist; "point":
    two friction rows per contact point, each limited by its own point's impulse: a
    1-box-deep 20-row pyramid swaying out of plane loads and unloads its corners, the
    lightly loaded ones slip, and its top creeps 3-5 cm sideways in 10 s, against
    0.3-1.6 cm with "manifold"),
    ``broadphase`` ("grid", "sap", "sap3"),
    ``batching`` (None, the default: "global" on NVIDIA GPUs; on other GPUs
    "single" while every body fits its local memory (1,984 bodies in 48 KiB),
    else "cells"; "slabs" on CPUs; chosen again whenever bodies are added;
    "global": one launch over every compute unit colours all constraints, each
    keeping last step's colour where it still holds, and one launch solves them,
    its work groups passing a barrier across the device after each batch (it
    relies on every work group of a one-per-compute-unit launch running at once,
    which OpenCL does not promise: checked on NVIDIA H100 and H200); "single": one work group
    colours every constraint and one solves them all with the velocities in
    local memory, one launch each a step; "components": one solver launch per
    step, one work group (GPU) or work-item (CPU) per pile; "cells": 9
    launches per sweep, piles spread over the device; "columns": cells that run along
    gravity, 5 launches per sweep, a stack whole in one group; "slabs": 3 launches per
    sweep, piles spread over a few cores in slabs across the widest horizontal
    axis of the bodies when they were last set; a grid launch, global mode's
    or the Jacobi solver's, whose work groups turn out not to run all at once
    gives up its barrier instead of hanging, and the World redoes the step
    without grid launches from then on, with a RuntimeWarning),
    ``solver`` ("pgs", the default: projected Gauss-Seidel over the batching's
    colours; "jacobi": Jacobi sweeps with mass splitting, no batching, see
    `rbgen.pipeline.jacobi`: a sweep is two phases over the whole device
    instead of one per colour, but a push travels one body down a stack per
    sweep, so a 20-row pyramid's top sinks ~22 cm at 10 iterations and holds
    within 2 cm at 80 iterations and 40 position iterations), ``fast_math``
    (the contact solver built with -cl-fast-relaxed-math; None, the default: on GPUs,
    where it shortens each lane's chain of dependent arithmetic, see
    `rbgen.pipeline.solver.default_fast_math`; off on CPUs), ``group_count``
    (solver groups per colour), ``manifold_capacity`` and
    ``pair_capacity`` (initial buffer sizes; grown on overflow).

    Shapes are immutable values (see `rbgen.Shape`): one shape object may be
    added to several Worlds, each keeping its own copy; a shape index (an int
    from some World's table) is refused, naming the index.
    """

    def __init__(self, device=None, gravity=(0.0, -9.81, 0.0), *, iterations: int = 10,
                 position_iterations: int = 4, relaxation: float = 1.0,
                 penetration: str = "split", warm_start: bool = True, gyroscopic: bool = True,
                 friction_model: str = "manifold", normal_solve: str | None = None,
                 broadphase: str = "grid", contact_margin: float = 0.02,
                 restitution_threshold: float = 0.5, penetration_slop: float | None = None,
                 penetration_recovery: float = 0.2, linear_damping: float = 0.0,
                 angular_damping: float = 0.0, batching: str | None = None,
                 group_count: int | None = None, solver: str = "pgs",
                 manifold_capacity: int | None = None, pair_capacity: int | None = None,
                 fast_math: bool | None = None, release_sweeps: int | None = None):
        self.runtime: Runtime = coerce_runtime(device)
        self.gravity = _vector(gravity, 3, "gravity")
        self.iterations, self.position_iterations = int(iterations), int(position_iterations)
        self.contact_margin = float(contact_margin)
        self.linear_damping, self.angular_damping = float(linear_damping), float(angular_damping)
        self.warm_start = bool(warm_start)
        self.broadphase_name = broadphase
        self.shapes = ShapeTable()
        self._host = layouts.BODY.zeros(0)
        self._has_dynamic = False       # any body with inv_mass > 0 (kept by _add)
        self._inv_inertia = np.zeros((0, 3), np.float32)
        self._device_stale = True       # host copy newer than the device
        self._host_stale = False        # device newer than the host copy
        rt = self.runtime
        self._prepare = BodyPreparation(rt, gyroscopic=gyroscopic, gravity=True, backup=True)
        self._integrate = Integrator(rt, gravity=False, damping=True)
        self._constraints = ContactConstraints(rt, penetration=penetration, warm_start=warm_start,
                                               friction=friction_model)
        if batching is not None and batching not in BATCHING_MODES:
            raise RbgenError(f"batching must be one of {BATCHING_MODES} or None (automatic), "
                             f"got {batching!r}")
        if solver not in SOLVERS:
            raise RbgenError(f"solver must be one of {SOLVERS}, got {solver!r}")
        if solver == "jacobi" and batching is not None:
            raise RbgenError(f"batching={batching!r} needs solver='pgs': the Jacobi solver "
                             f"colours nothing")
        self.solver = solver
        self._batching = batching       # None: chosen from the body count at each upload
        self._grid_failed = False       # a grid launch gave up: none from now on
        resolve_fast_math(self.runtime.traits, fast_math)  # a bad value fails here, named
        if release_sweeps is not None and solver == "jacobi":
            raise RbgenError(f"release_sweeps={release_sweeps!r} needs solver='pgs': the "
                             f"Jacobi solver solves the complete block on every sweep")
        check_release_sweeps(release_sweeps)
        #: velocity (and position) sweeps at the end of a step's PGS solve whose block may
        #: release points (None: every sweep; see ContactSolver.solve)
        self.release_sweeps = DEFAULT_RELEASE_SWEEPS \
            if release_sweeps is None and solver == "pgs" else release_sweeps
        self._solver_options = {"split_impulse": penetration == "split",
                                "friction": friction_model, "normal_solve": normal_solve,
                                "group_count": group_count, "fast_math": fast_math}
        #: batching mode -> (ConstraintBatcher, ContactSolver), built when first used
        self._solvers: dict = {}
        if group_count is not None and int(group_count) < 1:
            raise RbgenError(f"group_count must be >= 1, got {group_count!r}")
        # an explicit mode is built now (its errors surface here); automatic at the upload
        self._batcher, self._solver = self._solver_for(batching) if batching else (None, None)
        if solver == "jacobi":
            self._jacobi_options = {"split_impulse": penetration == "split",
                                    "friction": friction_model,
                                    "normal_solve": normal_solve or "block",
                                    "fast_math": fast_math}
            self._solver = JacobiSolver(rt, **self._jacobi_options)
        self.relaxation = float(relaxation)
        self.restitution_threshold = restitution_threshold
        if penetration_slop is None:
            # Baumgarte feeds its push into the warm-started impulse: with a 1 mm slop a
            # 20-row pyramid keeps jittering at up to 0.9 m/s, with 5 mm it comes to rest
            penetration_slop = 0.005 if penetration == "baumgarte" else 0.001
        self.penetration_slop = penetration_slop
        self.penetration_recovery = penetration_recovery
        self._stages_types = None
        self._manifold_capacity = 0
        self._initial_manifolds = manifold_capacity
        self._pair_capacity = pair_capacity
        #: enqueued steps whose overflow status is not checked yet (oldest first)
        self._in_flight: list[_InFlight] = []
        self._serial = 0                # steps enqueued, picks the backup slot
        self._report_pinned: dict = {}  # slot -> (pinned buffer, mapped uint32 words)
        #: the step report on the device (REPORT_*; word REPORT_NEEDED is the
        #: narrowphase's overflow word)
        self._report = cla.zeros(rt.queue, REPORT_WORDS, np.uint32)
        #: its narrowphase overflow word, as the view the narrowphase writes (made once: a
        #: pyopencl slice is a new Array, ~10 us of host time a step)
        self._report_needed = self._report[REPORT_NEEDED:REPORT_NEEDED + 1]
        self.last_step_counters = {"launches": 0, "blocking_reads": 0}
        self.steps = 0
        #: steps redone because a buffer overflowed (each grew the buffer)
        self.overflows = 0

    # ------------------------------------------------------------- settings
    restitution_threshold = property(lambda s: s._constraints.restitution_threshold,
                                     lambda s, v: setattr(s._constraints, "restitution_threshold",
                                                          float(v)))
    penetration_slop = property(lambda s: s._constraints.penetration_slop,
                                lambda s, v: setattr(s._constraints, "penetration_slop", float(v)))
    penetration_recovery = property(lambda s: s._constraints.penetration_recovery,
                                    lambda s, v: setattr(s._constraints, "penetration_recovery",
                                                         float(v)))

    # ------------------------------------------------------------- bodies
    @property
    def body_count(self) -> int:
        return len(self._host)

    def add_static(self, shape: Shape, position=(0.0, 0.0, 0.0), orientation=(0.0, 0.0, 0.0, 1.0),
                   friction: float = 0.6, restitution: float = 0.0) -> int:
        """A body that never moves (planes only this way); returns its index."""
        return int(self._add(shape, np.asarray([position], float), np.asarray([orientation], float),
                             None, friction, restitution, None, None)[0])

    def add_body(self, shape: Shape, mass: float = 1.0, position=(0.0, 0.0, 0.0),
                 orientation=(0.0, 0.0, 0.0, 1.0), linear_velocity=(0.0, 0.0, 0.0),
                 angular_velocity=(0.0, 0.0, 0.0), friction: float = 0.6,
                 restitution: float = 0.0) -> int:
        """One dynamic body; returns its index."""
        return int(self.add_bodies(shape, mass, [position], [orientation], friction, restitution,
                                   [linear_velocity], [angular_velocity])[0])

    def add_bodies(self, shape: Shape, mass=1.0, positions=None, orientations=None,
                   friction=0.6, restitution=0.0, linear_velocities=None,
                   angular_velocities=None) -> np.ndarray:
        """Many dynamic bodies of one shape; ``mass``, ``friction``, ``restitution``
        are scalars or one value per body. Returns their indices."""
        if positions is None:
            raise RbgenError("add_bodies: positions are required (an (N, 3) array)")
        positions = np.asarray(positions, float)
        n = len(positions)
        masses = _per_body(mass, n, "mass")
        if isinstance(shape, Plane):
            raise RbgenError("a Plane can only be static: use add_static")
        return self._add(shape, positions, orientations, masses, friction, restitution,
                         linear_velocities, angular_velocities)

    def _add(self, shape, positions, orientations, masses, friction, restitution,
             linear_velocities, angular_velocities) -> np.ndarray:
        if isinstance(shape, (int, np.integer)):
            # shapes are values, never indices: an index means one World's table
            raise RbgenError(f"shape must be an rbgen shape object (e.g. rbgen.Box(...)), got "
                             f"the index {int(shape)}: shape indices belong to one World's "
                             f"table, while a shape object can be added to any World")
        if not isinstance(shape, Shape):
            raise RbgenError(f"shape must be an rbgen shape, got {type(shape).__name__}")
        if type(shape) not in (Sphere, Box, Capsule, ConvexHull, Plane):
            # the narrowphase has kernels for these pairs only: fail here, not mid-step
            raise RbgenError(f"shape {type(shape).__name__} has no narrowphase kernels; "
                             f"supported: Sphere, Box, Capsule, ConvexHull, Plane")
        n = len(positions)
        first = self.body_count
        positions = _rows(positions, n, 3, "positions", first)
        orientations = _orientations(orientations, n, first)
        lin = _rows(np.zeros((n, 3)) if linear_velocities is None else linear_velocities, n, 3,
                    "linear_velocities", first)
        ang = _rows(np.zeros((n, 3)) if angular_velocities is None else angular_velocities, n, 3,
                    "angular_velocities", first)
        friction = _per_body(friction, n, "friction")
        restitution = _per_body(restitution, n, "restitution")
        for values, name, ok in ((friction, "friction", friction >= 0),
                                 (restitution, "restitution", (restitution >= 0) & (restitution <= 1))):
            bad = np.flatnonzero(~(np.isfinite(values) & ok))
            if len(bad):
                raise RbgenError(f"body {first + bad[0]}: {name}={values[bad[0]]!r} is out of range")
        records = layouts.BODY.zeros(n)
        inv_inertia = np.zeros((n, 3), np.float32)
        if masses is not None:
            bad = np.flatnonzero(~(np.isfinite(masses) & (masses > 0)))
            if len(bad):
                raise RbgenError(f"body {first + bad[0]}: mass must be positive and finite for a "
                                 f"dynamic body, got {masses[bad[0]]!r}")
            unit = shape.mass_properties(mass=1.0)
            records["inv_mass"] = 1.0 / masses
            inv_inertia[:] = 1.0 / (masses[:, None] * np.asarray(unit.inertia)[None, :])
        self._sync_to_host()
        shape_index = self.shapes.add(shape)
        records["position"][:, :3] = positions
        records["orientation"] = orientations
        records["linear_velocity"][:, :3] = lin
        records["angular_velocity"][:, :3] = ang
        records["shape"] = shape_index
        records["friction"], records["restitution"] = friction, restitution
        if masses is None:
            records["linear_velocity"] = 0
            records["angular_velocity"] = 0
        self._host = np.concatenate([self._host, records]).astype(layouts.BODY.dtype)
        self._has_dynamic = bool(np.any(self._host["inv_mass"] > 0))
        self._inv_inertia = np.concatenate([self._inv_inertia, inv_inertia])
        self._device_stale = True
        return np.arange(first, first + n)

    # ------------------------------------------------------------- state
    def _field(self, name, lanes):
        self._sync_to_host()
        return self._host[name][:, :lanes].copy()

    def _set_field(self, name, values, lanes, what):
        self._sync_to_host()
        values = _rows(values, self.body_count, lanes, what, 0)
        if name == "orientation":
            values = _orientations(values, self.body_count, 0)
        dynamic = self._host["inv_mass"] > 0
        if name in ("linear_velocity", "angular_velocity"):
            values = np.where(dynamic[:, None], values, 0.0)
        self._host[name][:, :lanes] = values
        self._device_stale = True
        self._constraints.reset()

    positions = property(lambda s: s._field("position", 3),
                         lambda s, v: s._set_field("position", v, 3, "positions"),
                         doc="(N, 3) float32 centres of mass; setting teleports every body")
    orientations = property(lambda s: s._field("orientation", 4),
                            lambda s, v: s._set_field("orientation", v, 4, "orientations"),
                            doc="(N, 4) float32 unit quaternions (x, y, z, w)")
    linear_velocities = property(lambda s: s._field("linear_velocity", 3),
                                 lambda s, v: s._set_field("linear_velocity", v, 3,
                                                           "linear_velocities"))
    angular_velocities = property(lambda s: s._field("angular_velocity", 3),
                                  lambda s, v: s._set_field("angular_velocity", v, 3,
                                                            "angular_velocities"))

    # ------------------------------------------------------------- device
    def _sync_to_host(self) -> None:
        self._finish_pending()
        if self._host_stale:
            self._host = self.runtime.read(self._bodies)[: self.body_count]
            self._host_stale = False

    def _upload(self) -> None:
        """Send the host bodies (after adds or teleports) and size the buffers."""
        queue, n = self.runtime.queue, self.body_count
        self._bodies = cla.to_device(queue, self._host if n else layouts.BODY.zeros(1))
        self._backups = [cla.empty_like(self._bodies) for _ in range(STEPS_IN_FLIGHT)]
        self._inertia = cla.to_device(queue, inertia_records(self._inv_inertia if n else
                                                             np.zeros((1, 3))))
        self._static = cla.to_device(queue, (self._host["inv_mass"] == 0).astype(np.uint32)
                                     if n else np.zeros(1, np.uint32))
        self._aabbs = cla.empty(queue, max(1, n), layouts.AABB.dtype)
        types = self.shapes.type_names()
        if types != self._stages_types:
            from .pipeline.broadphase import make_broadphase
            from .pipeline.narrowphase import Narrowphase
            # world AABBs are written by the body preparation (one launch for both)
            self._prepare = BodyPreparation(self.runtime, gyroscopic=self._prepare.gyroscopic,
                                            gravity=True, shape_types=types, backup=True)
            self._narrowphase = Narrowphase(self.runtime, self.shapes)
            options = {} if self._pair_capacity is None else {"capacity": int(self._pair_capacity)}
            self._broadphase = make_broadphase(self.runtime, self.broadphase_name, **options)
            self._stages_types = types
        self._packed = self.shapes.pack_all().to_device(queue)
        if self.solver == "pgs":
            mode = self._batching or self._automatic_batching(n)
            if mode == "global" and self._grid_failed:
                mode = self._automatic_batching(n)
            self._use_batching(mode)
        self._ensure_manifolds(self._initial_manifolds or MANIFOLDS_PER_BODY * max(n, 16))
        self._device_stale = False

    def _use_batching(self, mode: str) -> None:
        self._batcher, self._solver = self._solver_for(mode)
        self._batcher.cell_size = self._cell_size()
        self._batcher.slab_axis = self._slab_axis()
        self._batcher.column_axes = self._column_axes()

    def _grid_sync(self):
        """The grid barrier state of this step's grid launches (None: it makes none)."""
        if self._batcher is None:
            return self._solver.sync if self._solver.grid else None
        return self._batcher.state if self._batcher.mode == "global" else None

    def _abandon_grid(self) -> None:
        """A grid launch gave up its barrier (its work groups did not all run at once):
        from now on this World makes no grid launch; the caller redoes the steps."""
        self._grid_failed = True
        clear_abandoned(self.runtime, self._grid_sync())
        self._report[REPORT_ABANDONED:].fill(np.uint32(0))
        if self._batcher is None:
            self._solver = JacobiSolver(self.runtime, grid=False, **self._jacobi_options)
            instead = "the Jacobi solver's launch per phase"
        else:
            mode = self._automatic_batching(self.body_count)
            self._use_batching(mode)
            instead = f"batching mode {mode!r}"
        warnings.warn(f"a grid launch on {self.runtime.traits.device_name} gave up waiting at "
                      f"a barrier across its work groups (they did not all run at once: a GPU "
                      f"shared through MPS?); the step is redone, and this World uses "
                      f"{instead} from now on", RuntimeWarning, stacklevel=3)

    def _automatic_batching(self, body_count: int) -> str:
        """``global`` on NVIDIA GPUs (one colouring and one solver launch a step over every
        compute unit, grid barriers between batches: H200 BoxBox 1,000 / 8,000 / 27,000 /
        111,375 boxes in 0.49 / 0.64 / 1.12 / 3.67 ms a step (2026-12-04), against cells'
        2.86 / 3.52 / 4.28 / 7.51 and single's 1.75 at 1,000 in earlier runs); on other
        GPUs ``single`` while every body fits a resident solve (one colouring and one
        solver launch a step, velocities in local memory), else the device's default
        (cells on GPUs, slabs on CPUs)."""
        traits = self.runtime.traits
        if grid_validated(traits) and not self._grid_failed:
            return "global"
        if traits.is_gpu and body_count <= resident_capacity(traits):
            return "single"
        return default_mode(traits)

    def _solver_for(self, mode: str):
        """The (batcher, solver) pair of a batching mode, built once per World."""
        pair = self._solvers.get(mode)
        if pair is None:
            rt, options = self.runtime, self._solver_options
            if mode == "single":
                capacity = resident_capacity(rt.traits)
                if capacity == 0:
                    raise RbgenError("batching 'single' needs local memory this device lacks")
                batcher = ConstraintBatcher(rt, mode=mode, shape="gpu", max_bodies=capacity)
            elif mode == "global":
                batcher = ConstraintBatcher(rt, mode=mode, shape="gpu")
                capacity = 0
            else:
                batcher = ConstraintBatcher(rt, mode=mode, group_count=options["group_count"])
                capacity = 0
            normal_solve = options["normal_solve"] or _default_normal_solve(mode, batcher.shape)
            solver = ContactSolver(rt, split_impulse=options["split_impulse"],
                                   max_batches=batcher.max_batches, friction=options["friction"],
                                   normal_solve=normal_solve, shape=batcher.shape,
                                   resident_bodies=capacity, grid=mode == "global",
                                   fast_math=options["fast_math"])
            pair = self._solvers[mode] = (batcher, solver)
        return pair

    def _ensure_manifolds(self, capacity: int) -> None:
        if capacity <= self._manifold_capacity:
            return
        queue = self.runtime.queue
        self._manifold_capacity = int(capacity)
        self._manifolds = cla.empty(queue, self._manifold_capacity, layouts.CONTACT_MANIFOLD.dtype)
        self._manifold_count = cla.zeros(queue, 1, np.uint32)

    def _cell_size(self) -> float:
        """Batching cells: the widest dynamic body plus twice the contact margin."""
        radius = 0.0
        for index in np.unique(self._host["shape"][self._host["inv_mass"] > 0]):
            radius = max(radius, bounding_radius(self.shapes.shapes[int(index)]))
        return 2.0 * radius + 2.0 * self.contact_margin + 1e-3

    def _slab_axis(self) -> tuple:
        """Batching slabs: across the coordinate axis, of the two least along gravity, on
        which the dynamic bodies spread widest (a pile then spreads over most slabs)."""
        positions = self._host["position"][self._host["inv_mass"] > 0, :3]
        candidates = np.argsort(np.abs(self.gravity))[:2]
        if len(positions) == 0:
            return tuple(float(i == candidates[0]) for i in range(3))
        spread = positions.max(axis=0) - positions.min(axis=0)
        best = max(candidates, key=lambda axis: spread[axis])
        return tuple(float(i == best) for i in range(3))

    def _column_axes(self) -> tuple:
        """Batching columns: along the coordinate axis most along gravity (when the bodies
        were last set), so the columns' cross-section spans the other two."""
        across = sorted(np.argsort(np.abs(self.gravity))[:2])
        return tuple(tuple(float(i == axis) for i in range(3)) for axis in across)

    # ------------------------------------------------------------- stepping
    def step(self, dt: float, substeps: int = 1) -> None:
        """Advance by ``dt`` seconds in ``substeps`` equal steps (no blocking read)."""
        if not (isinstance(dt, (int, float, np.floating)) and np.isfinite(dt) and dt > 0):
            raise RbgenError(f"dt must be a positive finite number, got {dt!r}")
        if not isinstance(substeps, (int, np.integer)) or substeps < 1:
            raise RbgenError(f"substeps must be a positive integer, got {substeps!r}")
        before = dict(self.runtime.counters)
        for _ in range(int(substeps)):
            self._check_in_flight(keep=STEPS_IN_FLIGHT - 1)
            if not self._has_dynamic and not self._host_stale:
                continue  # nothing can move (empty or static-only world)
            if self._device_stale:
                self._sync_to_host()
                self._upload()
            self._enqueue_step(float(dt) / int(substeps))
        self.steps += 1
        self.last_step_counters = {k: self.runtime.counters[k] - before[k] for k in before}

    def _enqueue_step(self, h: float) -> None:
        rt, n = self.runtime, self.body_count
        self._host_stale = True
        if n == 0:
            return
        slot = self._serial % STEPS_IN_FLIGHT
        self._serial += 1
        margin = self.contact_margin
        # gravity, AABBs and the step's backup (the redo's start) fused in
        self._prepare(self._bodies, self._inertia, n, h, self.gravity,
                      aabbs=(self._packed.shapes, self._packed.vertices, self._aabbs, margin),
                      backup=self._backups[slot])
        self._broadphase.enqueue(self._aabbs, self._static, read_status=False)  # (the report)
        self._narrowphase.enqueue(self._bodies, self._packed, self._broadphase.pairs,
                                  self._broadphase.count, self._manifolds, self._manifold_count,
                                  self._report_needed, margin)
        capacity = self._manifold_capacity
        self._constraints(self._manifolds, self._manifold_count, self._bodies, self._inertia,
                          capacity, h)
        constraints = self._constraints.constraints
        split = self._solver.split_impulse and self.position_iterations > 0
        sweeps = {"iterations": self.iterations,
                  "position_iterations": self.position_iterations if split else 0,
                  "relaxation": self.relaxation, "warm_start": self.warm_start}
        if self._batcher is None:  # Jacobi: no colouring
            self._solver.solve(constraints, self._constraints.count, capacity, self._bodies,
                               self._inertia, n, **sweeps)
        else:
            self._batcher(constraints, self._constraints.count, self._bodies, n, capacity)
            self._solver.solve(constraints, self._batcher, self._bodies, self._inertia, n,
                               release_sweeps=self.release_sweeps, **sweeps)
        self._integrate(self._bodies, n, h, linear_damping=self.linear_damping,  # push fused in
                        angular_damping=self.angular_damping,
                        split=self._solver.split_velocities(n) if split else None)
        self._in_flight.append(_InFlight.start(self, h, slot))

    def _finish_pending(self) -> None:
        """Check every enqueued step (waits for their status copies only)."""
        self._check_in_flight(keep=0)

    def _check_in_flight(self, keep: int) -> None:
        """Check the oldest enqueued steps until at most ``keep`` remain unchecked.

        With ``keep=1`` (every `step`) the step checked is the one before the
        last: its status copy is normally long done, so the host never waits
        for the device to drain. An overflowed step is redone, with every step
        after it, from the bodies saved when it started (buffers grown first).
        """
        redone = 0
        while len(self._in_flight) > keep:
            entry = self._in_flight[0]
            problem = entry.problem(self)
            if problem is None:
                self._in_flight.pop(0)
                continue
            redone += 1
            if redone > MAX_REDOS:
                raise CapacityOverflowError(
                    f"a step still overflowed after {MAX_REDOS} redos with grown buffers "
                    f"(pairs found {problem[0]}, manifolds needed {problem[1]})")
            self.runtime.queue.finish()
            pairs_found, needed, abandoned = problem
            if abandoned:
                self._abandon_grid()
            if not abandoned or pairs_found > self._broadphase.capacity or needed:
                self.overflows += 1
                self._broadphase.check()  # raises for a NaN body, grows the pair buffer
                self._broadphase.buffer.grow_for(pairs_found)
            if needed:
                self._ensure_manifolds(int(needed * 1.25) + 16)
            redo = [e.h for e in self._in_flight]
            cl.enqueue_copy(self.runtime.queue, self._bodies.data,
                            self._backups[entry.slot].data)
            self._constraints.undo(len(redo))
            self._in_flight = []
            for h in redo:
                self._enqueue_step(h)

    # ------------------------------------------------------------- statistics
    def statistics(self) -> dict:
        """Counts of the last step, the batching mode and the normal solve it used (blocking
        reads: call outside the timed loop)."""
        self._finish_pending()
        if self._device_stale or self.body_count == 0:
            return {"bodies": self.body_count, "pairs": 0, "manifolds": 0, "contacts": 0,
                    "batches": 0, "groups_used": 0, "batching": self._batching,
                    "solver": self.solver, "normal_solve": None, **self.last_step_counters}
        read = self.runtime.read
        pairs = int(read(self._broadphase.count)[0])
        manifolds = int(read(self._constraints.count)[0])
        points = read(self._constraints.constraints)[:manifolds]["point_count"]
        batch_counts = (read(self._batcher.group_batch_count) if self._batcher is not None
                        else np.zeros(0, np.uint32))
        return {"bodies": self.body_count, "pairs": pairs, "manifolds": manifolds,
                "contacts": int(points.sum()), "batches": int(batch_counts.max(initial=0)),
                "groups_used": int((batch_counts > 0).sum()),
                "batching": self._batcher.mode if self._batcher is not None else None,
                "solver": self.solver, "normal_solve": self._solver.spec.values["normal_solve"],
                **self.last_step_counters}

    def render(self, path, camera=None, width: int = 960, height: int = 540):
        """Write a picture of the World now to ``path`` (PNG; see `rbgen.render.render_world`:
        ``camera`` a `rbgen.render.Camera`, a dict of its fields, or None to frame the moving
        bodies). One read of the transforms; returns the path written."""
        from .render import render_world

        return render_world(self, path, camera=camera, width=width, height=height)


class _InFlight:
    """One enqueued step: its dt, backup slot, and a pinned copy of its step report.

    The copy's event is kept: pyopencl returns a NannyEvent for a copy into host
    memory, and deleting one waits for its copy (dropping it at once drained the whole
    queue every step)."""

    def __init__(self, h, slot, host, copied):
        self.h, self.slot, self.host, self.copied = h, slot, host, copied

    @classmethod
    def start(cls, world: "World", h: float, slot: int) -> "_InFlight":
        """Gather the step report on the device (the broadphase status and, for a step
        with grid launches, their barrier's abandoned flag, beside the narrowphase's
        overflow word) and enqueue one non-blocking copy of it into pinned host words."""
        queue, report = world.runtime.queue, world._report
        status = world._broadphase.buffer.status
        cl.enqueue_copy(queue, report.data, status.data, byte_count=status.nbytes,
                        dst_offset=4 * REPORT_BROADPHASE)
        grid = world._grid_sync()
        if grid is not None:
            cl.enqueue_copy(queue, report.data, grid.data, byte_count=4,
                            src_offset=ABANDONED_OFFSET, dst_offset=4 * REPORT_ABANDONED)
        pinned = world._report_pinned.get(slot)
        if pinned is None:
            buffer = cl.Buffer(world.runtime.context, cl.mem_flags.ALLOC_HOST_PTR,
                               4 * REPORT_WORDS)
            host, _ = cl.enqueue_map_buffer(queue, buffer, cl.map_flags.READ | cl.map_flags.WRITE,
                                            0, (REPORT_WORDS,), np.uint32)
            pinned = world._report_pinned[slot] = (buffer, host)
        host = pinned[1]
        return cls(h, slot, host, cl.enqueue_copy(queue, host, report.data, is_blocking=False))

    def problem(self, world: "World"):
        """None when the step was complete, else (pairs found, manifolds needed, whether a
        grid launch gave up)."""
        self.copied.wait()
        status = self.host[REPORT_BROADPHASE:REPORT_ABANDONED].view(
            layouts.BROADPHASE_STATUS.dtype)[0]
        pairs_found = int(status["pairs_found"])
        needed = int(self.host[REPORT_NEEDED])
        abandoned = bool(self.host[REPORT_ABANDONED])
        retry = int(status["retry"]) if "retry" in status.dtype.names else 0
        if (status["bad_body"] != layouts.BP_NO_BODY or retry or needed or abandoned
                or pairs_found > world._broadphase.capacity):
            return pairs_found, needed, abandoned
        return None


def bounding_radius(shape: Shape) -> float:
    """Radius of a sphere about the body's origin that holds the shape."""
    if isinstance(shape, Sphere):
        return shape.radius
    if isinstance(shape, Capsule):
        return shape.radius + shape.half_height
    return float(np.linalg.norm(np.asarray(shape.local_vertices()), axis=1).max())


# ----------------------------------------------------------------- validation

def _vector(value, n, what):
    arr = np.asarray(value, float).reshape(-1)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise RbgenError(f"{what} must be {n} finite numbers, got {value!r}")
    return arr


def _per_body(value, n, what):
    arr = np.asarray(value, float)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.shape != (n,):
        raise RbgenError(f"{what} must be a scalar or one value per body ({n}), got shape {arr.shape}")
    return arr.astype(float)


def _rows(values, n, lanes, what, first):
    arr = np.asarray(values, float)
    if arr.shape != (n, lanes):
        raise RbgenError(f"{what} must have shape ({n}, {lanes}), got {arr.shape}")
    bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
    if len(bad):
        raise RbgenError(f"body {first + bad[0]}: {what} has a NaN or infinite value "
                         f"{arr[bad[0]].tolist()}")
    return arr


def _orientations(values, n, first):
    if values is None:
        out = np.zeros((n, 4))
        out[:, 3] = 1.0
        return out
    q = _rows(values, n, 4, "orientations", first)
    norms = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(norms < 1e-6)
    if len(bad):
        raise RbgenError(f"body {first + bad[0]}: orientations has a zero quaternion")
    off = np.flatnonzero(np.abs(norms - 1) > 1e-3)
    if len(off):
        warnings.warn(f"body {first + off[0]}: orientations not unit (norm {norms[off[0]]:.4g}); "
                      f"normalised ({len(off)} bodies)", stacklevel=3)
    return q / norms[:, None]
