"""Projected Gauss-Seidel contact solver: one launch per iteration.

Each work group owns one level-1 group of `ConstraintBatcher` (no dynamic
body shared with any other group of the same launch) and walks its batches
with a barrier between them, so an iteration needs no synchronisation between
work groups and no host round trip: with the batcher's ``components`` mode,
ONE launch of `solve_contacts` per iteration (the warm start fused into the
first); with ``cells``, one per cell colour plus one for the leftovers (and
one warm-start sweep before the iterations). Split impulse adds
``position_iterations`` sweeps of `solve_penetration` and one
`apply_split_velocities` after integration.

Relaxation (successive over-relaxation factor, 1 = plain Gauss-Seidel) and
the iteration counts are World settings, passed per call.

Host cost: a launch sets no argument. Each distinct (first group, passes)
of the launch plan has its own kernel object (`rbgen.launch.instance`) with
those scalars set once; the buffers and ``relaxation`` are bound once per
call through `rbgen.launch.BoundKernel` (the driver sees only the changed
ones: this step's constraint buffer, a grown buffer, a new relaxation).
"""
from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array

from .. import layouts
from ..codegen import compile_spec, KernelTemplate, Param, power_of_two, work_group_size_param
from ..device import DeviceTraits, Runtime
from ..errors import RbgenError
from ..launch import instance

#: friction models (see the template parameter "friction")
FRICTION_MODELS = ("point", "manifold")
#: how a manifold's normal rows are solved (see the template parameter "normal_solve")
NORMAL_SOLVES = ("block", "sequential")

TEMPLATE = KernelTemplate(
    "pipeline/solver.cl.mako",
    [
        work_group_size_param("lanes solving one batch at a time; a batch of a dense pile holds "
                              "a few hundred constraints"),
        Param("max_batches", power_of_two(2, 4096),
              "must equal the batcher's max_batches (the layout of group_batches)",
              "a power of two from 2 to 4096"),
        Param("split_impulse", (True, False),
              "emit the position pass and the push-velocity kernels"),
        Param("normal_solve", NORMAL_SOLVES,
              "block: a manifold's normal rows solved together (no point-order bias, so "
              "symmetric stacks stay upright); sequential: one row after another (cheaper, "
              "tips columns)"),
        Param("friction", FRICTION_MODELS,
              "point: two tangent rows per contact point; manifold: one tangent pair at the "
              "points' centre plus a twist row (fewer rows, Bullet3's GPU choice)"),
    ],
    doc="PGS velocity iterations (and split-impulse position iterations) over batched contacts.",
    roles={"constraints": "inout", "bodies": "inout", "split": "inout"},
    defaults=lambda traits: {"friction": "point", "work_group_size": default_work_group_size(traits),
                             "max_batches": 128, "split_impulse": True,
                             "normal_solve": "block"},
)


def default_work_group_size(traits: DeviceTraits) -> int:
    """64 on GPUs (two warps / one wavefront per batch step); 8 on CPUs."""
    return min(64 if traits.is_gpu else 8, traits.max_work_group_size)


#: bit flags of one `solve_contacts` launch (as in the template)
WARM_START_PASS, SOLVE_PASS, REVERSE_PASS = 1, 2, 4


class ContactSolver:
    """Launches the PGS iterations over a `ConstraintBatcher`'s batches."""

    def __init__(self, runtime: Runtime, *, split_impulse: bool = True, max_batches: int = 128,
                 friction: str = "point", work_group_size: int | None = None,
                 normal_solve: str = "block"):
        self.runtime = runtime
        self.split_impulse = bool(split_impulse)
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        if friction not in FRICTION_MODELS:
            raise RbgenError(f"friction must be one of {FRICTION_MODELS}, got {friction!r}")
        if normal_solve not in NORMAL_SOLVES:
            raise RbgenError(f"normal_solve must be one of {NORMAL_SOLVES}, got {normal_solve!r}")
        self.spec = TEMPLATE.spec(work_group_size=self.work_group_size, max_batches=int(max_batches),
                                  split_impulse=self.split_impulse, friction=friction,
                                  normal_solve=normal_solve)
        self._program = program = compile_spec(runtime, self.spec)
        if self.split_impulse:
            self.apply_kernel = runtime.bound(program.kernel("apply_split_velocities"))
        self.max_batches = int(max_batches)
        self._split = None
        #: (kernel name, first group, passes) -> kernel object with those scalars set
        self._instances: dict = {}
        #: (kernel name, plan, iterations, warm start) -> ([(kernel, global size)], kernels)
        self._schedules: dict = {}

    def split_velocities(self, body_capacity: int):
        """The zeroed push-velocity array (grown to ``body_capacity``)."""
        if self._split is None or len(self._split) < body_capacity:
            self._split = cl_array.zeros(self.runtime.queue, max(1, int(body_capacity)),
                                         layouts.SPLIT_VELOCITY.dtype)
        return self._split

    def _check(self, batcher):
        if batcher.max_batches != self.max_batches:
            raise RbgenError(f"batcher max_batches={batcher.max_batches} differs from the "
                             f"solver's {self.max_batches}")

    def solve_velocities(self, constraints, batcher, bodies, inertia, *, iterations: int,
                         relaxation: float = 1.0, warm_start: bool = True) -> None:
        """Warm start (every constraint's old impulses, before any sweep), then
        ``iterations`` PGS sweeps; one launch per entry of the batcher's launch plan.

        Odd sweeps visit each manifold's points backwards (symmetric Gauss-Seidel):
        a 5-box column then comes to rest at 10 iterations instead of wobbling for
        ever; the price is slower convergence of redundant contacts between free
        bodies (their residual halves more slowly)."""
        self._check(batcher)
        if iterations < 0 or not 0.0 < relaxation < 2.0:
            raise RbgenError(f"need iterations >= 0 and 0 < relaxation < 2, got "
                             f"iterations={iterations!r}, relaxation={relaxation!r}")
        launches, kernels = self._schedule("solve_contacts", batcher.launch_plan, int(iterations),
                                           bool(warm_start))
        shared = (constraints, batcher.order, batcher.group_batches,
                  batcher.group_batch_count, bodies, inertia, np.float32(relaxation))
        for kernel in kernels:
            kernel.bind_first(*shared)
        wg = self.work_group_size
        for kernel, size in launches:
            kernel.launch(size, wg)

    def _schedule(self, name: str, plan, iterations: int, warm_start: bool = False):
        """Every launch of one call (kernel object, global size) and the distinct
        kernel objects, computed once per plan and settings."""
        key = (name, tuple(plan), iterations, warm_start)
        schedule = self._schedules.get(key)
        if schedule is not None:
            return schedule
        if name == "solve_contacts":
            passes = []
            if warm_start and len(plan) > 1:
                passes.append(WARM_START_PASS)
            elif warm_start and iterations > 0:
                passes.append(WARM_START_PASS | SOLVE_PASS)  # fused into the first sweep
                iterations -= 1
            elif warm_start:
                passes.append(WARM_START_PASS)
            passes += [SOLVE_PASS] * iterations
            passes = [(flags | (REVERSE_PASS if i % 2 else 0),) for i, flags in enumerate(passes)]
        else:
            passes = [()] * iterations  # solve_penetration has no pass flags
        wg = self.work_group_size
        launches = [(self._instance(name, first, flags), count * wg)
                    for flags in passes for first, count in plan]
        kernels = list({id(k): k for k, _ in launches}.values())
        schedule = self._schedules[key] = (launches, kernels)
        return schedule

    def _instance(self, name: str, first: int, flags: tuple):
        """The kernel object of ``name`` whose trailing scalars are (first group, *flags)."""
        key = (name, first, flags)
        kernel = self._instances.get(key)
        if kernel is None:
            kernel = self._instances[key] = instance(self.runtime, self._program, name)
            kernel.bind_last(np.uint32(first), *(np.uint32(f) for f in flags))
        return kernel

    def solve_positions(self, constraints, batcher, bodies, inertia, body_capacity: int, *,
                        iterations: int, relaxation: float = 1.0) -> None:
        """Split-impulse sweeps on push velocities (needs split_impulse=True)."""
        if not self.split_impulse:
            raise RbgenError("this ContactSolver was built with split_impulse=False")
        self._check(batcher)
        split = self.split_velocities(body_capacity)
        launches, kernels = self._schedule("solve_penetration", batcher.launch_plan,
                                           int(iterations))
        shared = (constraints, batcher.order, batcher.group_batches,
                  batcher.group_batch_count, split, bodies, inertia,
                  np.float32(relaxation))
        for kernel in kernels:
            kernel.bind_first(*shared)
        wg = self.work_group_size
        for kernel, size in launches:
            kernel.launch(size, wg)

    def apply_split(self, bodies, body_count: int, dt: float) -> None:
        """Move bodies by their push velocities (after integration) and clear them."""
        if body_count == 0:
            return
        split = self.split_velocities(body_count)
        wg = self.work_group_size
        self.apply_kernel.over(body_count, wg, bodies, split, np.uint32(body_count),
                               np.float32(dt))

