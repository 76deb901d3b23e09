"""Jacobi contact solver with mass splitting: the alternative to batched Gauss-Seidel.

Every constraint of a sweep is solved at once against the velocities the
sweep started from, a body with k contacts split into k copies of 1/k its
mass (Tonge, Benevolenski and Voroshilov, "Mass splitting for jitter-free
parallel rigid body simulation", 2012), and each body then takes the mean of
its copies' velocities (`templates/pipeline/solvers/jacobi.cl.mako` has the phases).
The rows, the block normal solve and the friction are the
Gauss-Seidel solver's own (`templates/pipeline/solvers/contact_rows.cl.mako`).

Why: a Gauss-Seidel sweep is a chain of batches (12 colours in a pile) with a
barrier across the device after each, even when
a batch is a few hundred constraints; a Jacobi sweep is two phases over all
constraints and bodies. It needs no colouring at all. The price is slower
convergence per sweep: what a contact does reaches the next body one sweep
later instead of within the sweep, so a tall stack needs more sweeps (or more
steps, through warm starting) to carry its weight down.

Launches (``persistent``): on devices where
`rbgen.pipeline.device_barrier.persistent_launch_validated` holds ONE launch a step runs
every phase, its work groups passing a device-wide barrier between phases; elsewhere one
launch per phase: 6 to build the bodies' contact lists, then 2 per sweep.

The constraint count stays on the device: the kernels read it and handle
min(count, capacity) constraints, striding over them.

The Jacobi solver reads the contact constraints directly, not the constraint-edge list
that batching colours (`rbgen.pipeline.constraints`): it colours nothing, and a joint
kind would join it as a constraint phase of its own.
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array
import pyopencl.cltypes as cltypes

from ...codegen import Arg, KernelTemplate, Param, Signature, compile_spec, work_group_size_param
from ...device import DeviceTraits, Runtime
from ...errors import RbgenError
from ...launch import instance
from ..device_barrier import barrier_buffer, persistent_groups, persistent_launch_validated
from .common import (
    PushVelocities,
    check_sweeps,
    fast_math_options,
    fast_math_param,
    normal_solve_param,
    resolve_fast_math,
)


def _shared_space(values) -> str:
    """The address space of what lanes of other work groups write during a persistent
    launch (read through volatile pointers)."""
    return "volatile __global" if values["persistent"] else "__global"


#: the arguments every Jacobi kernel starts with (bound once per solve), in order
SHARED_ARGS = (
    Arg("__global ContactConstraint*", "constraints"),
    Arg("__global const uint*", "constraint_count"),
    Arg("const uint", "capacity"),
    Arg(lambda v: f"{_shared_space(v)} Body*", "bodies"),
    Arg("__global const BodyInertia*", "inertia"),
    Arg(lambda v: f"{_shared_space(v)} SplitVelocity*", "split"),
    Arg("volatile __global uint*", "body_contacts"),
    Arg(lambda v: f"{_shared_space(v)} uint*", "body_first"),
    Arg(lambda v: f"{_shared_space(v)} uint*", "chunk_sums"),
    Arg("__global uint*", "side_slots"),
    Arg(lambda v: f"{_shared_space(v)} uint*", "lists"),
    Arg(lambda v: f"{_shared_space(v)} float4*", "changes"),
    Arg("volatile __global uint*", "sync", when=lambda v: v["persistent"]),
    Arg("const float", "relaxation"),
    Arg("const uint", "body_count"),
)
SHARED_NAMES = tuple(a.name for a in SHARED_ARGS)
#: the phases that build the bodies' contact lists, in order (phase launches)
LIST_PHASES = ("clear", "count", "chunk_sums", "scan", "link", "order")
#: every kernel's trailing scalars (bound once per kernel object)
SCALARS = {
    "solve_jacobi": ("passes", "velocity_sweeps", "position_sweeps"),
    **{
        f"jacobi_{phase}": ("reverse",)
        for phase in LIST_PHASES + ("warm_start", "sweep", "average", "push", "average_push")
    },
}
#: each kernel's arguments, declared once: the template renders them, JacobiSolver binds them
SIGNATURES = {
    name: Signature(name, SHARED_ARGS + tuple(Arg("const uint", s) for s in scalars))
    for name, scalars in SCALARS.items()
}

TEMPLATE = KernelTemplate(
    "pipeline/solvers/jacobi.cl.mako",
    [
        work_group_size_param(
            "lanes of a work group; each lane handles constraints and bodies "
            "at its index plus multiples of the launch's size"
        ),
        normal_solve_param(),
        Param(
            "persistent",
            (False, True),
            "True: one launch runs every phase with a device-wide barrier between phases "
            "(the work groups must all run at once); False: one launch per phase",
        ),
        fast_math_param(),
    ],
    doc="Jacobi sweeps with mass splitting over contact constraints.",
    roles={"constraints": "inout", "bodies": "inout", "split": "inout", "sync": "inout"},
    build_options=fast_math_options,
    defaults=lambda traits: {
        "work_group_size": default_work_group_size(traits),
        "normal_solve": "block",
        "persistent": persistent_launch_validated(traits),
        "fast_math": resolve_fast_math(traits, None),
    },
    signatures=SIGNATURES.values(),
)

#: the persistent kernel's ``passes`` flag for the warm start (as in the template)
WARM_START_PASS = 1
#: and for the restitution in its last velocity sweep
RESTITUTION_PASS = 4
#: a ``jacobi_sweep`` launch's ``reverse`` bits: the points backwards, the restitution
SWEEP_REVERSED, SWEEP_RESTITUTION = 1, 2
#: work groups of a phase launch per compute unit (a CPU balances the chunks better)
PHASE_GROUPS_PER_UNIT = 4


def default_work_group_size(traits: DeviceTraits) -> int:
    """256 on GPUs (one group a compute unit for the persistent launch: the rows' registers
    a lane allow no more), 16 on CPUs."""
    return min(256 if traits.is_gpu else 16, traits.max_work_group_size)


class JacobiSolver(PushVelocities):
    """Launches the Jacobi sweeps with mass splitting (see the module docstring)."""

    def __init__(
        self,
        runtime: Runtime,
        *,
        normal_solve: str = "block",
        persistent: bool | None = None,
        work_group_size: int | None = None,
        fast_math: bool | None = None,
    ):
        self.runtime = runtime
        traits = runtime.traits
        self.persistent = (
            persistent_launch_validated(traits) if persistent is None else bool(persistent)
        )
        self.work_group_size = int(work_group_size or default_work_group_size(traits))
        self.spec = TEMPLATE.spec(
            work_group_size=self.work_group_size,
            normal_solve=normal_solve,
            persistent=self.persistent,
            fast_math=resolve_fast_math(traits, fast_math),
        )
        self._program = compile_spec(runtime, self.spec)
        #: work groups of every launch (the scan's chunks depend on it)
        self.groups = persistent_groups(traits) * (1 if self.persistent else PHASE_GROUPS_PER_UNIT)
        q = runtime.queue
        #: the device-wide barrier's words (persistent launch; the World reads its flag)
        self.sync = barrier_buffer(runtime) if self.persistent else None
        self._chunk_sums = cl_array.zeros(q, self.groups, np.uint32)
        self._body_capacity = self._side_capacity = 0
        #: trailing scalars -> kernel object with those scalars set
        self._instances: dict = {}
        #: kernel name -> (binder of the shared arguments, binder of its scalars)
        self._binders: dict = {}

    @property
    def normal_solve(self) -> str:
        return self.spec.values["normal_solve"]

    def barrier_state(self):
        """The device-wide barrier words of its persistent launch (None: it makes none)."""
        return self.sync

    # ------------------------------------------------------------- buffers
    def _ensure(self, body_count: int, capacity: int) -> None:
        q = self.runtime.queue
        if body_count > self._body_capacity:
            self._body_capacity = max(1, int(body_count))
            self._body_contacts = cl_array.zeros(q, self._body_capacity, np.uint32)
            self._body_first = cl_array.zeros(q, self._body_capacity, np.uint32)
        if 2 * capacity > self._side_capacity:
            self._side_capacity = max(2, 2 * int(capacity))
            self._side_slots = cl_array.zeros(q, self._side_capacity, np.uint32)
            self._lists = cl_array.zeros(q, self._side_capacity, np.uint32)
            self._changes = cl_array.zeros(q, 2 * self._side_capacity, cltypes.float4)

    def _binders_of(self, name: str):
        """The binders of kernel ``name``'s shared arguments and of its scalars."""
        binders = self._binders.get(name)
        if binders is None:
            signature = SIGNATURES[name]
            have = {a.name for a in signature.args(self.spec.values)}
            shared = signature.binder(self.spec, *(n for n in SHARED_NAMES if n in have))
            scalars = signature.binder(self.spec, *SCALARS[name])
            signature.check_bound(self.spec, shared, scalars)
            binders = self._binders[name] = (shared, scalars)
        return binders

    def _kernel(self, name: str, *scalars):
        key = (name, *scalars)
        kernel = self._instances.get(key)
        if kernel is None:
            kernel = self._instances[key] = instance(self.runtime, self._program, name)
            self._binders_of(name)[1](kernel, *(np.uint32(v) for v in scalars))
        return kernel

    # ------------------------------------------------------------- solving
    def solve(
        self,
        constraints,
        constraint_count,
        capacity: int,
        bodies,
        inertia,
        body_count: int,
        sweeps,
        restitution: bool = True,
        same_geometry: bool = False,
    ) -> None:
        """Warm start, ``sweeps.iterations`` velocity sweeps and
        ``sweeps.position_iterations`` push sweeps over min(``constraint_count[0]``,
        ``capacity``) constraints (``constraint_count``: a device uint32 array(1)) between
        the first ``body_count`` bodies (with ``restitution``, the last velocity sweep applies
        the contacts' restitution: the step's last substep). Rewrites the constraints' row
        masses for the split bodies and their impulses; leaves the push velocities in
        `split_velocities`. (``same_geometry``: see `Solver.solve`; this solver derives its
        rows every sweep.)"""
        iterations, position_iterations = int(sweeps.iterations), int(sweeps.position_iterations)
        relaxation, warm_start = sweeps.relaxation, bool(sweeps.warm_start)
        check_sweeps(iterations, position_iterations, relaxation)
        if getattr(sweeps, "shock_propagation", False) is True:
            raise RbgenError(
                "shock_propagation=True is a sweep of solver 'pgs' (Gauss-Seidel order); "
                "solver 'jacobi' has none: set shock_propagation=False or solver='pgs'"
            )
        if (
            capacity <= 0
            or body_count <= 0
            or not (warm_start or iterations or position_iterations)
        ):
            return
        self._ensure(body_count, capacity)
        shared = [
            constraints,
            constraint_count,
            np.uint32(capacity),
            bodies,
            inertia,
            self.split_velocities(body_count),
        ]
        shared += [
            self._body_contacts,
            self._body_first,
            self._chunk_sums,
            self._side_slots,
            self._lists,
            self._changes,
        ]
        if self.persistent:
            shared.append(self.sync)
        shared += [np.float32(relaxation), np.uint32(body_count)]
        size = self.groups * self.work_group_size
        for name, kernel in self._schedule(
            int(iterations), int(position_iterations), bool(warm_start), restitution
        ):
            self._binders_of(name)[0](kernel, *shared)
            kernel.launch(size, self.work_group_size)

    def _schedule(
        self, iterations: int, position_iterations: int, warm_start: bool, restitution: bool
    ) -> list:
        """The (kernel name, kernel object) of one call's launches, in launch order."""
        calls: list[tuple[str, tuple[int, ...]]]
        if self.persistent:
            passes = (WARM_START_PASS if warm_start else 0) | (
                RESTITUTION_PASS if restitution else 0
            )
            calls = [("solve_jacobi", (passes, iterations, position_iterations))]
        else:
            calls = [(f"jacobi_{phase}", (0,)) for phase in LIST_PHASES]
            if warm_start:
                calls += [("jacobi_warm_start", (0,)), ("jacobi_average", (0,))]
            for sweep in range(iterations):
                flags = (SWEEP_REVERSED if sweep % 2 else 0) | (
                    SWEEP_RESTITUTION if restitution and sweep == iterations - 1 else 0
                )
                calls += [("jacobi_sweep", (flags,)), ("jacobi_average", (0,))]
            for _ in range(position_iterations):
                calls += [("jacobi_push", (0,)), ("jacobi_average_push", (0,))]
        return [(name, self._kernel(name, *scalars)) for name, scalars in calls]
