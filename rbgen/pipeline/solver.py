"""Projected Gauss-Seidel contact solver over a `ConstraintBatcher`'s groups.

Two shapes (template parameter ``shape``, chosen by the device kind):

* ``gpu``: a work group per level-1 group walks its level-2 batches with a
  barrier between them, its lanes solving the constraints of a batch at once;
* ``cpu``: a work-item per level-1 group solves the group's constraints one
  after another (plain Gauss-Seidel, no barriers); its batcher skips the
  level-2 colouring. A CPU runs many small groups well (PoCL schedules work
  groups over its threads), so the cells batching mode keeps every core busy
  even when the scene is one pile.

Resident solve (``resident_bodies`` > 0, gpu shape, over ``single``
batching): one work group keeps every body's velocity in local memory for the
whole solve and sends them home once; a batch step then waits on no global
velocity. A BoxBox step of 1,000 boxes is then 14 launches instead of 116 (the
README has the times).

Grid solve (``grid``, gpu shape, over ``global`` batching, the NVIDIA
default): the one group of all constraints is solved by one work group per
compute unit, a batch's constraints spread over all their lanes, with a
barrier across the device after each batch (`rbgen.pipeline.grid`): ONE
launch for the whole solve at any size, every compute unit busy. Velocities
are read through volatile pointers, since other work groups write them during
the launch. A batch's constraints go round the work groups first (the
template's `lane`), so that a batch of a few hundred manifolds is one or two
lanes on every compute unit, not full warps on the first few: H200 BoxBox
1,000 / 8,000 / 27,000 / 111,375 went from 1.01 / 1.19 / 1.48 / 3.78 to
0.61 / 0.80 / 1.21 / 3.63 ms a step (2026-12-03, the same trajectories).
In batches small enough to leave them idle, the push rows of the split-impulse
sweeps go to a lane a warp further than the velocity rows (the template's
`push_lane`: 0.59 / 0.77 ms at 1,000 / 8,000 with the split in every batch,
but slower at 27,000 / 111,375, hence the size rule, untimed on the GPU).
A batch step (88 a step over BoxBox's 8 colours) then costs ~5 us at 1,000
boxes: ~1.3 us of fence, grid barrier and loop (the launch with the visits
emptied: 0.116 ms for 88 batch steps) and ~3.7 us of one lane's dependent
chain for one manifold, compute rather than memory: reading the velocities
through plain pointers instead of volatile ones (wrong, but timed) saved 2%,
loading the bodies beside the constraint (a visit list written before the
sweeps) nothing, and keeping each face's velocity-independent block geometry
(Q, Q^-1, lever arms) from a pass before the sweeps 2% at 1,000 boxes and
cost 3-13% at 8,000-111,375 (272 bytes a visit more); the rows one by one
instead of the block cut the solve by a third (0.44 -> 0.28 ms) but let the
20-row pyramid's top move 8.9 cm. Batches run from the
highest colour to the lowest (see the template: a ground's contacts, all in
colour 0, come last). Loading each lane's next constraint
while the barrier waits (measured 2026-12-02) made every size 6-10% slower and
was dropped.

Warm start (``warm_start_mode``): ``batched``, a sweep over the batches that
applies every constraint's old impulses; ``summed`` (the grid solve's default
where the device has 64-bit atomics), two phases: every lane turns its
constraints' old impulses into velocity changes and adds them to per-body
sums of 64-bit fixed-point integers with atomics, and after one grid barrier
every body takes its sum. Integer sums do not depend on the order of the
additions, so the result has the same bits every run (float atomics would
not); the grid barrier count drops from one per colour to two (H200 BoxBox
1,000: solve_groups 0.327 -> 0.311 ms).

Launches: `solve` runs the warm start, the ``iterations`` velocity sweeps
and the ``position_iterations`` split-impulse sweeps. With the batcher's
``components`` mode no dynamic body is shared between groups, so ONE launch
of `solve_groups` does them all (each work group loops over the sweeps
itself). With ``cells``, a sweep is one launch per cell colour plus one for
the leftovers, and the warm start is a sweep of its own. Position sweep k is
solved in the same batch steps as velocity sweep k (its rows read and write
only push velocities and push impulses, the velocity rows neither, so each
sees what it would alone): 10 + 4 sweeps cost 10 batch passes, not 14, and
the template loads both velocity sets before solving either, so that the two
chains overlap (H200 BoxBox 1,000 / 8,000 / 27,000 / 111,375: 1.44 / 1.68 /
2.05 / 4.47 -> 1.34 / 1.60 / 1.91 / 4.15 ms a step, the same trajectories).
Odd velocity sweeps visit each manifold's points backwards.
`apply_split_velocities` moves the bodies by their push velocities after
integration.

Relaxation (successive over-relaxation factor, 1 = plain Gauss-Seidel) and
the iteration counts are World settings, passed per call.

Host cost: a launch sets no argument. Each distinct set of trailing scalars
(first group, passes, sweeps) of the launch schedule has its own kernel object
(`rbgen.launch.instance`) with those scalars set once; the buffers and
``relaxation`` are bound once per call through `rbgen.launch.BoundKernel` (the
driver sees only the changed ones: this step's constraint buffer, a grown
buffer, a new relaxation).
"""
from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array

from .. import layouts
from ..codegen import compile_spec, KernelTemplate, Param, power_of_two, work_group_size_param
from ..device import INT64_ATOMICS, DeviceTraits, Runtime
from ..errors import RbgenError
from ..launch import instance
from .batching import SINGLE_MAX_BODIES
from .grid import grid_groups, sync_buffer

#: friction models (see the template parameter "friction")
FRICTION_MODELS = ("point", "manifold")
#: how a manifold's normal rows are solved (see the template parameter "normal_solve")
NORMAL_SOLVES = ("block", "sequential")
#: how the warm start reaches the velocities (see the template parameter "warm_start_mode")
WARM_START_MODES = ("batched", "summed")
#: kernel shapes (see the template parameter "shape")
SHAPES = ("gpu", "cpu")
#: the build options of a fast_math solver. The solver relies on no infinity or NaN (a
#: NaN body is caught by the broadphase, which is built without them), and its rows
#: tolerate a few ulps in a reciprocal or a square root.
FAST_MATH_OPTIONS = ("-cl-fast-relaxed-math",)


def fast_math_param() -> Param:
    """The contact solvers' ``fast_math`` parameter (its build options: `fast_math_options`)."""
    return Param("fast_math", (False, True),
                 "build with -cl-fast-relaxed-math: a lane's constraint is a long chain of "
                 "dependent arithmetic, which IEEE division and square root and unfused, "
                 "unreordered operations lengthen")


def fast_math_options(values: dict) -> tuple[str, ...]:
    """The build options of a solver specialisation (its ``fast_math`` value)."""
    return FAST_MATH_OPTIONS if values["fast_math"] else ()


def default_fast_math(traits: DeviceTraits) -> bool:
    """On GPUs. H200 BoxBox (global batching, 10 + 4 iterations) 1,000 / 8,000 / 27,000 /
    111,375 boxes: 0.59 / 0.76 / 1.24 / 3.78 -> 0.54 / 0.71 / 1.18 / 3.71 ms a step with the
    contact solver alone built so (2026-12-03; the same pairs, nothing sunk; the same flag on
    every other program gained nothing more beyond noise). -cl-unsafe-math-optimizations
    alone gave 0.56 / 0.75 and native reciprocals in the rows 0.58 / 0.75: the gain is the
    compiler's freedom to reorder and fuse more than the divisions. Off on CPUs, where PoCL
    showed no gain beyond its noise (27.0 -> 26.0 ms of solve at 8,000 boxes) and exact
    arithmetic keeps the CPU results the reference."""
    return traits.kind == "gpu"


def resolve_fast_math(traits: DeviceTraits, fast_math: bool | None) -> bool:
    """A solver's ``fast_math`` argument: None is the device's default; else a bool."""
    if fast_math is None:
        return default_fast_math(traits)
    if not isinstance(fast_math, (bool, np.bool_)):
        raise RbgenError(f"fast_math must be True, False or None, got {fast_math!r}")
    return bool(fast_math)

TEMPLATE = KernelTemplate(
    "pipeline/solver.cl.mako",
    [
        work_group_size_param("gpu shape: lanes solving one batch at a time (a batch of a dense "
                              "pile holds a few hundred constraints); cpu shape: groups per "
                              "work group, each solved by its own work-item"),
        Param("max_batches", power_of_two(2, 4096),
              "must equal the batcher's max_batches (the layout of group_batches)",
              "a power of two from 2 to 4096"),
        Param("shape", SHAPES,
              "gpu: a work group per level-1 group, lanes over level-2 batches with barriers; "
              "cpu: a work-item per level-1 group, its constraints one after another"),
        Param("split_impulse", (True, False),
              "emit the position sweeps and the push-velocity kernel"),
        Param("normal_solve", NORMAL_SOLVES,
              "block: a manifold's normal rows solved together (no point-order bias, so "
              "symmetric stacks stay upright); sequential: one row after another (cheaper, "
              "tips columns)"),
        Param("resident_bodies", lambda v: isinstance(v, int) and 0 <= v <= 65536,
              "0: velocities live in global memory; N > 0 (gpu shape, one group of all "
              "constraints): the single work group keeps the velocities of up to N bodies in "
              "local memory (24 bytes a body) for the whole solve",
              "an integer from 0 to 65536"),
        Param("grid", (False, True),
              "gpu shape, one group of all constraints (single or global batching): every "
              "work group of the launch (one per compute unit) takes part in each batch, with "
              "a barrier across the work groups between batches (one launch for the whole "
              "solve, every compute unit busy)"),
        Param("friction", FRICTION_MODELS,
              "point: two tangent rows per contact point; manifold: one tangent pair at the "
              "points' centre plus a twist row (fewer rows, Bullet3's GPU choice)"),
        fast_math_param(),
        Param("warm_start_mode", WARM_START_MODES,
              "batched: the warm start is a sweep over the batches (one batch step per "
              "colour); summed (grid only): every constraint's old impulses are summed per "
              "body in 64-bit fixed point with atomics, then every body takes its sum, two "
              "phases with one grid barrier between them whatever the colours"),
    ],
    doc="PGS velocity sweeps (and split-impulse position sweeps) over batched contacts.",
    roles={"constraints": "inout", "bodies": "inout", "split": "inout", "warm_sums": "inout"},
    requires=lambda v: _parameter_rules(v),
    build_options=fast_math_options,
    defaults=lambda traits: {"friction": "point", "work_group_size": default_work_group_size(traits),
                             "max_batches": 128, "shape": traits.kind, "split_impulse": True,
                             "normal_solve": "block", "resident_bodies": 0, "grid": False,
                             "fast_math": default_fast_math(traits),
                             "warm_start_mode": "batched"},
)


def _parameter_rules(values: dict) -> str | None:
    """What the solver template's parameters must agree on (None: they do)."""
    if values["resident_bodies"] and values["shape"] != "gpu":
        return "resident_bodies needs shape='gpu' (one work group solves everything)"
    if values["grid"] and (values["shape"] != "gpu" or values["resident_bodies"]):
        return "grid needs shape='gpu' and no resident_bodies (the work groups share the " \
               "velocities through global memory)"
    if values["warm_start_mode"] == "summed" and not values["grid"]:
        return "warm_start_mode='summed' needs grid=True (its two phases are separated by " \
               "a grid barrier)"
    return None


def default_work_group_size(traits: DeviceTraits, shape: str | None = None,
                             resident: bool = False) -> int:
    """gpu shape: 64 (two warps / one wavefront per batch step), 256 for a resident or grid
    solve (one work group a compute unit does all, and a batch of 1,000 boxes holds ~300
    manifolds; the block solve's ~180 registers a lane allow no more on 64k-register
    compute units); cpu
    shape: 1 (one group per work group, so that PoCL hands groups to its threads one at a
    time)."""
    if (shape or traits.kind) == "cpu":
        return 1
    return min(256 if resident else 64, traits.max_work_group_size)


#: local memory a resident solve leaves for the compiler's own use (bytes)
RESIDENT_RESERVE = 1024
#: local bytes per resident body: linear and angular velocity, 6 floats
RESIDENT_BYTES_PER_BODY = 24


def resident_capacity(traits: DeviceTraits) -> int:
    """Bodies a resident solve can hold in this device's local memory (a multiple of 64):
    1,984 with 48 KiB; at most the single-mode batching's limit."""
    usable = traits.local_mem_size - RESIDENT_RESERVE
    return max(0, min(SINGLE_MAX_BODIES, usable // RESIDENT_BYTES_PER_BODY // 64 * 64))


#: bodies per work group of apply_split_velocities: enough to amortise a work group's
#: start on a CPU, two warps on a GPU
APPLY_WORK_GROUP_SIZE = 64

#: bit flags of a `solve_groups` launch's ``passes`` argument (as in the template)
WARM_START_PASS, FIRST_REVERSED = 1, 2


def default_warm_start_mode(runtime: Runtime, grid: bool) -> str:
    """summed for a grid solve on a device with 64-bit atomics (two phases instead of a
    batch step per colour), else batched."""
    return "summed" if grid and runtime.has_extension(INT64_ATOMICS) else "batched"


def check_release_sweeps(release_sweeps) -> None:
    """Refuse a ``release_sweeps`` that is neither None nor an integer >= 0, naming it."""
    if release_sweeps is not None and (isinstance(release_sweeps, bool)
                                       or not isinstance(release_sweeps, (int, np.integer))
                                       or release_sweeps < 0):
        raise RbgenError(f"release_sweeps must be None (every sweep) or an integer >= 0, "
                         f"got {release_sweeps!r}")


def first_release_sweep(sweeps: int, release_sweeps: int | None) -> int:
    """The first of ``sweeps`` sweeps whose block solve may release points: the last
    ``release_sweeps`` of them (None: all)."""
    return 0 if release_sweeps is None else max(0, sweeps - release_sweeps)


def check_sweeps(iterations: int, position_iterations: int, relaxation: float,
                 split_impulse: bool, solver: str) -> None:
    """Refuse sweep settings no solver can run, naming them."""
    if iterations < 0 or position_iterations < 0 or not 0.0 < relaxation < 2.0:
        raise RbgenError(f"need iterations >= 0, position_iterations >= 0 and "
                         f"0 < relaxation < 2, got iterations={iterations!r}, "
                         f"position_iterations={position_iterations!r}, "
                         f"relaxation={relaxation!r}")
    if position_iterations and not split_impulse:
        raise RbgenError(f"position_iterations need a {solver} built with split_impulse=True")


class PushVelocities:
    """A solver's push velocities (split impulse): zero between steps, grown on demand."""

    _split = None

    def split_velocities(self, body_capacity: int):
        """The zeroed push-velocity array (grown to ``body_capacity``)."""
        if self._split is None or len(self._split) < body_capacity:
            self._split = cl_array.zeros(self.runtime.queue, max(1, int(body_capacity)),
                                         layouts.SPLIT_VELOCITY.dtype)
        return self._split


class ContactSolver(PushVelocities):
    """Launches the PGS sweeps over a `ConstraintBatcher`'s groups."""

    def __init__(self, runtime: Runtime, *, split_impulse: bool = True, max_batches: int = 128,
                 friction: str = "point", work_group_size: int | None = None,
                 normal_solve: str = "block", shape: str | None = None,
                 resident_bodies: int = 0, grid: bool = False, fast_math: bool | None = None,
                 warm_start_mode: str | None = None):
        self.runtime = runtime
        self.split_impulse = bool(split_impulse)
        self.shape = shape or runtime.traits.kind
        if self.shape not in SHAPES:
            raise RbgenError(f"shape must be one of {SHAPES}, got {shape!r}")
        self.resident_bodies = int(resident_bodies)
        if self.resident_bodies:  # (the gpu shape is the template's rule)
            capacity = resident_capacity(runtime.traits)
            if not 0 < self.resident_bodies <= capacity:
                raise RbgenError(f"resident_bodies={self.resident_bodies} does not fit this "
                                 f"device's local memory ({capacity} bodies at most)")
        self.work_group_size = work_group_size or default_work_group_size(
            runtime.traits, self.shape, resident=bool(self.resident_bodies or grid))
        if friction not in FRICTION_MODELS:
            raise RbgenError(f"friction must be one of {FRICTION_MODELS}, got {friction!r}")
        if normal_solve not in NORMAL_SOLVES:
            raise RbgenError(f"normal_solve must be one of {NORMAL_SOLVES}, got {normal_solve!r}")
        if warm_start_mode is None:
            warm_start_mode = default_warm_start_mode(runtime, bool(grid))
        elif warm_start_mode == "summed" and not runtime.has_extension(INT64_ATOMICS):
            raise RbgenError(f"warm_start_mode='summed' needs the device extension "
                             f"{INT64_ATOMICS}, which {runtime.traits.device_name} lacks")
        self.spec = TEMPLATE.spec(work_group_size=self.work_group_size, max_batches=int(max_batches),
                                  shape=self.shape, split_impulse=self.split_impulse,
                                  friction=friction, normal_solve=normal_solve,
                                  resident_bodies=self.resident_bodies, grid=bool(grid),
                                  fast_math=resolve_fast_math(runtime.traits, fast_math),
                                  warm_start_mode=warm_start_mode)
        #: per-body fixed-point sums of the summed warm start (6 int64 words a body,
        #: zero between solves; grown on demand)
        self._warm_sums = None
        self.grid = bool(grid)
        #: the grid barrier's words over batches other than global's (which brings its own)
        self._sync = sync_buffer(runtime) if self.grid else None
        self._program = program = compile_spec(runtime, self.spec)
        if self.split_impulse:
            self.apply_kernel = runtime.bound(program.kernel("apply_split_velocities"))
        self.max_batches = int(max_batches)
        #: trailing scalars -> kernel object with those scalars set
        self._instances: dict = {}
        #: (plan, sweeps, warm start) -> ([(kernel, global size)], distinct kernels)
        self._schedules: dict = {}

    def _check(self, batcher):
        if batcher.max_batches != self.max_batches:
            raise RbgenError(f"batcher max_batches={batcher.max_batches} differs from the "
                             f"solver's {self.max_batches}")
        if self.shape == "gpu" and not batcher.batches:
            raise RbgenError("the gpu-shaped solver needs level-2 batches: build the "
                             "ConstraintBatcher with shape='gpu'")
        if (self.resident_bodies or self.grid) and batcher.group_count != 1:
            raise RbgenError(f"a {'resident' if self.resident_bodies else 'grid'} solve needs "
                             f"one group of all constraints (batching mode 'single' or "
                             f"'global'), got {batcher.group_count} groups "
                             f"(mode {batcher.mode!r})")

    def solve(self, constraints, batcher, bodies, inertia, body_capacity: int = 0, *,
              iterations: int, position_iterations: int = 0, relaxation: float = 1.0,
              warm_start: bool = True, release_sweeps: int | None = None) -> None:
        """Warm start (every constraint's old impulses, before any sweep), ``iterations``
        velocity sweeps and ``position_iterations`` split-impulse sweeps (needs
        split_impulse=True and ``body_capacity``), launched as the module docstring says.
        A resident solver needs ``body_capacity``: the number of bodies (all of them,
        static ones too: they are indexed as in ``bodies``).

        Odd sweeps visit each manifold's points backwards (symmetric Gauss-Seidel):
        a 5-box column then comes to rest at 10 iterations instead of wobbling for
        ever; the price is slower convergence of redundant contacts between free
        bodies (their residual halves more slowly).

        ``release_sweeps`` (normal_solve "block"): only the last ``release_sweeps``
        velocity sweeps and the last ``release_sweeps`` position sweeps solve each
        manifold's complete block, releasing points where its solution needs that (None:
        every sweep). The earlier ones take the block's all-pushing solution where it
        holds (a face resting on a face: exact and order-free, so symmetric stacks stay
        symmetric) and solve the other manifolds' rows one after another: a cheaper
        sweep, because on a GPU the lanes of a batch wait for the slowest and the
        releasing cases are the block's long chain. The last sweeps remove the rows'
        point-order residual (the World's default: 2; `rbgen.world.DEFAULT_RELEASE_SWEEPS`
        has the figures)."""
        self._check(batcher)
        if self.resident_bodies and not 0 < body_capacity <= self.resident_bodies:
            raise RbgenError(f"{body_capacity} bodies do not fit a resident solve built for "
                             f"{self.resident_bodies}")
        check_sweeps(iterations, position_iterations, relaxation, self.split_impulse,
                     "ContactSolver")
        check_release_sweeps(release_sweeps)
        if self.spec.values["normal_solve"] != "block":
            release_sweeps = 0  # (the rows only: the kernel takes no release scalars)
        launches, kernels = self._schedule(batcher.launch_plan, int(iterations),
                                           int(position_iterations), bool(warm_start),
                                           None if release_sweeps is None else int(release_sweeps))
        if not launches:
            return
        shared = [constraints, batcher.order, batcher.group_batches, batcher.group_batch_count,
                  bodies, inertia]
        if self.split_impulse:
            shared.append(self.split_velocities(max(1, int(body_capacity))))
        if self.grid:  # after a global colouring: its buffer (it may have given up)
            shared.append(batcher.state if batcher.mode == "global" else self._sync)
        if self.spec.values["warm_start_mode"] == "summed":
            if body_capacity <= 0:
                raise RbgenError("a summed warm start needs body_capacity (the number of "
                                 "bodies)")
            shared += [self._warm_sum_buffer(int(body_capacity)), np.uint32(body_capacity)]
        shared.append(np.float32(relaxation))
        if self.resident_bodies:
            shared.append(np.uint32(body_capacity))
        for kernel in kernels:
            kernel.bind_first(*shared)
        wg = self.work_group_size
        for kernel, size in launches:
            kernel.launch(size, wg)

    def _warm_sum_buffer(self, body_capacity: int):
        """The summed warm start's zeroed per-body sums (the kernel leaves them zero; a
        launch whose grid barrier gave up may leave some behind, and the World then
        stops using this grid solver)."""
        words = layouts.WARM_SUM_WORDS * body_capacity
        if self._warm_sums is None or len(self._warm_sums) < words:
            self._warm_sums = cl_array.zeros(self.runtime.queue, words, np.int64)
        return self._warm_sums

    def solve_velocities(self, constraints, batcher, bodies, inertia, body_capacity: int = 0, *,
                         iterations: int, relaxation: float = 1.0, warm_start: bool = True,
                         release_sweeps: int | None = None) -> None:
        """Warm start and ``iterations`` velocity sweeps (see `solve`)."""
        self.solve(constraints, batcher, bodies, inertia, body_capacity, iterations=iterations,
                   relaxation=relaxation, warm_start=warm_start, release_sweeps=release_sweeps)

    def solve_positions(self, constraints, batcher, bodies, inertia, body_capacity: int, *,
                        iterations: int, relaxation: float = 1.0,
                        release_sweeps: int | None = None) -> None:
        """Split-impulse sweeps on push velocities only (needs split_impulse=True)."""
        if not self.split_impulse:
            raise RbgenError("this ContactSolver was built with split_impulse=False")
        self.solve(constraints, batcher, bodies, inertia, body_capacity, iterations=0,
                   position_iterations=iterations, relaxation=relaxation, warm_start=False,
                   release_sweeps=release_sweeps)

    def _schedule(self, plan, iterations: int, position_iterations: int, warm_start: bool,
                  release_sweeps: int | None):
        """Every launch of one call (kernel object, global size) and the distinct
        kernel objects, computed once per plan and settings."""
        key = (tuple(plan), iterations, position_iterations, warm_start, release_sweeps)
        schedule = self._schedules.get(key)
        if schedule is not None:
            return schedule
        warm = WARM_START_PASS if warm_start else 0
        velocity_from = first_release_sweep(iterations, release_sweeps)
        position_from = first_release_sweep(position_iterations, release_sweeps)
        # (passes, velocity sweeps, position sweeps, and the first of each that may release)
        if len(plan) == 1:  # groups share no body: every sweep in one launch
            passes = [(warm, iterations, position_iterations, velocity_from, position_from)]
        else:  # one launch per colour and sweep; the warm start is a sweep of its own
            passes = [(warm, 0, 0, 0, 0)] if warm else []
            passes += [(FIRST_REVERSED if s % 2 else 0, int(s < iterations),
                        int(s < position_iterations), int(s < velocity_from),
                        int(s < position_from))
                       for s in range(max(iterations, position_iterations))]
        passes = [p for p in passes if p[:3] != (0, 0, 0)]
        launches = [self._launch(first, count, *p) for p in passes for first, count in plan]
        kernels = list({id(k): k for k, _ in launches}.values())
        schedule = self._schedules[key] = (launches, kernels)
        return schedule

    def _launch(self, first: int, count: int, passes: int, velocity_sweeps: int,
                position_sweeps: int, velocity_release_from: int, position_release_from: int):
        """(kernel object, global size) of one launch over groups first .. first + count - 1;
        its sweeps from velocity_release_from (position_release_from) on may release points."""
        wg = self.work_group_size
        scalars = [first]
        if self.shape == "cpu":  # a work-item per group, the last work group partly idle
            scalars.append(first + count)
            size = -(-count // wg) * wg
        elif self.grid:  # every compute unit, whatever the group count (1)
            size = grid_groups(self.runtime.traits) * wg
        else:
            size = count * wg
        scalars += [passes, velocity_sweeps]
        if self.split_impulse:
            scalars.append(position_sweeps)
        if self.spec.values["normal_solve"] == "block":
            scalars.append(velocity_release_from)
            if self.split_impulse:
                scalars.append(position_release_from)
        key = tuple(scalars)
        kernel = self._instances.get(key)
        if kernel is None:
            kernel = self._instances[key] = instance(self.runtime, self._program, "solve_groups")
            kernel.bind_last(*(np.uint32(v) for v in scalars))
        return kernel, size

    def apply_split(self, bodies, body_count: int, dt: float) -> None:
        """Move bodies by their push velocities (after integration) and clear them."""
        if body_count == 0:
            return
        split = self.split_velocities(body_count)
        wg = min(APPLY_WORK_GROUP_SIZE, self.runtime.traits.max_work_group_size)
        self.apply_kernel.over(body_count, wg, bodies, split, np.uint32(body_count),
                               np.float32(dt))
