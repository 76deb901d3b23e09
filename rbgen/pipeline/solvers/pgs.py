"""Projected Gauss-Seidel contact solver over a batcher's groups.

Solve forms (template parameter ``solve_form``, the batcher's):

* ``lanes``: a work group per level-1 group walks its level-2 batches with a
  barrier between them, its lanes solving the constraints of a batch at once;
* ``serial``: a work-item per level-1 group solves the group's constraints one
  after another (Gauss-Seidel proper, no barriers): a CPU runs many small groups
  well, and each row sees every earlier row's result.

Contact geometry (``contact_geometry``, the block normal solve in the serial form or a
persistent launch): a `layouts.CONTACT_GEOMETRY` record a constraint (its face block, the
shock sweep's face block of the held bodies, its friction rows), derived by a step's first
launches (``same_geometry`` false; a persistent launch before its warm start) and read by
every sweep of the step: on a CPU core the block solve's matrices cost more to derive than to
load. The plan chooses it (`default_contact_geometry`).

Persistent solve (``persistent``, lanes form, over ``global`` batching): the one group
of all constraints is solved by one work group per compute unit, a batch's
constraints spread over all their lanes, with a device-wide barrier after each batch
(`rbgen.pipeline.device_barrier`): one launch for the whole solve at any size, every
compute unit busy. A batch's constraints go round the work groups first, so that a
small batch is a lane or two on every compute unit, not full warps on a few.

Warm start (``warm_start_mode``): ``batched``, a sweep over the batches that applies
every constraint's old impulses; ``summed`` (persistent solves on devices with 64-bit
atomics), two phases: every constraint's old impulses become velocity changes summed
per body in 64-bit fixed point (order-free integer sums: the same bits every run), then
every body takes its sum. Between the substeps of a persistent launch the contacts' part
of the two phases folds into the launch's other work: the last velocity sweep of a
substep sums each contact's warm start as it solves it (its impulses are final then), and
the bodies take the sums as they move; the first sweep of the next substep refreshes each
contact's targets before its rows. Without joints one device-wide barrier separates two
substeps, and no pass over the constraints runs between them; with joints a pass over the
joints sums their warm start after the bodies move (it measures the poses of the substep
it starts), and the bodies take every sum behind two barriers more.

Sweeps: `solve` runs the warm start, ``iterations`` velocity sweeps and
``position_iterations`` split-impulse sweeps; position sweep k is solved in the same
batch steps as velocity sweep k (its rows touch only push velocities and impulses).
With one launch in the batcher's plan (global batching) every sweep runs in that one
launch; otherwise a sweep is one launch per colour and the warm start a sweep of its
own. Odd velocity sweeps visit each manifold's points backwards. With the block normal
solve, only the last ``release_sweeps`` sweeps solve each manifold's complete block;
the earlier ones take its all-pushing solution where it holds (a cheaper sweep).

Constraint kinds: the batcher's ``order`` lists constraint-edge items
(`layouts.CONSTRAINT_EDGE`); a contact's item is its index in the constraints. With
``joints`` (a World that has joints), a joint's item (kind ``layouts.EDGE_JOINT``) names
its record in the ``joints`` buffer, whose rows (``joint_rows.cl.mako``) are solved in
the same batches, sweeps and launches: the item visits of ``pgs.cl.mako`` (the warm
starts, ``solve_copy``, the serial loops) pick the kind from the item's high bits, a case
emitted only when the plan has joints, so that a World without joints runs the contact
solver unchanged.

Arguments: ``SOLVE_GROUPS`` declares solve_groups' arguments once; the template renders
them and `PgsSolver` binds them by name through it (`rbgen.codegen.Signature`), so the
two cannot disagree. Host cost: each distinct set of trailing scalars of the launch
schedule has its own kernel object (`rbgen.launch.instance`) with those scalars set once;
buffers and ``relaxation`` are bound once per call, only the changed ones reaching the
driver.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pyopencl.array as cl_array

from ... import layouts
from ...codegen import (
    Arg,
    KernelTemplate,
    Param,
    Signature,
    compile_spec,
    power_of_two,
    work_group_size_param,
)
from ...device import INT64_ATOMICS, DeviceTraits, Runtime
from ...errors import RbgenError
from ...launch import instance
from ..batching import SOLVE_FORMS
from ..device_barrier import barrier_buffer, persistent_groups, persistent_launch_validated
from .common import (
    PushVelocities,
    check_sweeps,
    fast_math_options,
    fast_math_param,
    normal_solve_param,
    resolve_fast_math,
    shock_sweep,
)
from .support import SupportBuffers

#: how the warm start reaches the velocities (see the template parameter "warm_start_mode")
WARM_START_MODES = ("batched", "summed")


def _velocity_space(values) -> str:
    """The velocities' address space: other work groups of a persistent launch write them
    between batches, so it reads them through volatile pointers."""
    return "volatile __global" if values["persistent"] else "__global"


def _persistent(values) -> bool:
    return values["persistent"]


def _chained(values) -> bool:
    return values["persistent"] and values["support_chains"]


def _summed(values) -> bool:
    return values["warm_start_mode"] == "summed"


def _serial(values) -> bool:
    return values["solve_form"] == "serial"


def _joints(values) -> bool:
    return values["joints"]


def _geometry_cache(values) -> bool:
    """The block solve keeps each contact's `layouts.CONTACT_GEOMETRY` for the step
    (derived by the launches with GEOMETRY_PASS, read by every sweep): the template
    parameter ``contact_geometry``."""
    return values["contact_geometry"]


#: solve_groups' arguments, in order: the template renders them, `PgsSolver` binds them.
#: The buffers and ``relaxation`` are bound once per solve; the trailing scalars once per
#: kernel object (`rbgen.launch.instance`), one object per distinct set of them.
SOLVE_GROUPS = Signature(
    "solve_groups",
    [
        Arg("__global ContactConstraint*", "constraints"),
        Arg("__global ContactGeometry*", "geometry", when=_geometry_cache),
        Arg("__global JointConstraint*", "joints", when=_joints),
        Arg("__global const uint*", "order"),
        Arg("__global const uint*", "group_batches"),
        Arg("__global const uint*", "group_batch_count"),
        Arg(lambda v: f"{_velocity_space(v)} Body*", "bodies"),
        Arg("__global const BodyInertia*", "inertia"),
        Arg(lambda v: f"{_velocity_space(v)} SplitVelocity*", "split"),
        Arg("volatile __global uint*", "sync", when=_persistent),
        Arg("volatile __global long*", "warm_sums", when=_summed),
        Arg("volatile __global BodyDelta*", "deltas", when=_persistent),
        Arg("const uint", "body_count", when=lambda v: _summed(v) or _persistent(v)),
        Arg("const float", "relaxation"),
        # joints: 1 / the substep, and the fraction of a joint's error pushed out a substep
        Arg("const float", "inv_h", when=_joints),
        Arg("const float", "joint_recovery", when=_joints),
        # a persistent launch runs the step's substeps itself (see the template)
        Arg("const uint", "substeps", when=_persistent),
        Arg("const float", "h", when=_persistent),
        Arg("const float4", "gravity", when=_persistent),
        Arg("__global const float4*", "kicks", when=_persistent),
        Arg("const uint", "kicked", when=_persistent),
        Arg("const float", "linear_damping_factor", when=_persistent),
        Arg("const float", "angular_damping_factor", when=_persistent),
        Arg("const float", "max_angular_step", when=_persistent),
        Arg("const float", "penetration_slop", when=_persistent),
        Arg("const float", "penetration_recovery", when=_persistent),
        # the support chains after each substep's sweeps (`rbgen.pipeline.solvers.support`;
        # support_rounds: its pointer-jumping rounds, `support.ROUNDS`)
        Arg("volatile __global uint*", "supports", when=_chained),
        Arg("volatile __global float4*", "links", when=_chained),
        Arg("const uint", "support_rounds", when=_chained),
        Arg("const uint", "group_offset"),
        Arg("const uint", "group_end", when=_serial),
        Arg("const uint", "passes"),
        Arg("const uint", "velocity_sweeps"),
        Arg("const uint", "position_sweeps"),
        Arg("const uint", "velocity_release_from"),
        Arg("const uint", "position_release_from"),
    ],
)
#: the buffers of a solve and ``relaxation`` (bound once per solve), in SOLVE_GROUPS' order
SOLVE_BUFFERS = (
    "constraints",
    "geometry",
    "joints",
    "order",
    "group_batches",
    "group_batch_count",
    "bodies",
    "inertia",
    "split",
    "sync",
    "warm_sums",
    "deltas",
    "body_count",
    "relaxation",
    "inv_h",
    "joint_recovery",
    "substeps",
    "h",
    "gravity",
    "kicks",
    "kicked",
    "linear_damping_factor",
    "angular_damping_factor",
    "max_angular_step",
    "penetration_slop",
    "penetration_recovery",
    "supports",
    "links",
    "support_rounds",
)
#: one launch's trailing scalars (bound once per kernel object)
LAUNCH_SCALARS = (
    "group_offset",
    "group_end",
    "passes",
    "velocity_sweeps",
    "position_sweeps",
    "velocity_release_from",
    "position_release_from",
)

APPLY_SPLIT_VELOCITIES = Signature(
    "apply_split_velocities",
    [
        Arg("__global Body*", "bodies"),
        Arg("__global SplitVelocity*", "split"),
        Arg("const uint", "body_count"),
        Arg("const float", "dt"),
    ],
)

TEMPLATE = KernelTemplate(
    "pipeline/solvers/pgs.cl.mako",
    [
        work_group_size_param(
            "lanes form: lanes solving one batch at a time (a batch of a "
            "dense pile holds a few hundred constraints); serial form: groups "
            "per work group, each solved by its own work-item"
        ),
        Param(
            "max_batches",
            power_of_two(2, 4096),
            "must equal the batcher's max_batches (the layout of group_batches)",
            "a power of two from 2 to 4096",
        ),
        Param(
            "solve_form",
            SOLVE_FORMS,
            "lanes: a work group per level-1 group, lanes over level-2 batches with barriers; "
            "serial: a work-item per level-1 group, its constraints one after another",
        ),
        normal_solve_param(),
        Param(
            "persistent",
            (False, True),
            "lanes form, one group of all constraints (global batching): every work group "
            "of the launch (one per compute unit) takes part in each batch, with a "
            "device-wide barrier between batches (one launch for the whole solve)",
        ),
        fast_math_param(),
        Param(
            "joints",
            (False, True),
            "visit joint items of the constraint-edge list too (their rows: "
            "joint_rows.cl.mako); off for Worlds without joints, whose solve is the contact "
            "solver alone",
        ),
        Param(
            "fold_substeps",
            (False, True),
            "a persistent launch does each substep's refresh of the contacts' targets, "
            "carry of their impulses and summed warm start in the sweeps as they visit "
            "them (without joints, one device-wide barrier between substeps; a joint's "
            "warm start stays a pass after the bodies move: it measures the poses of the "
            "substep it starts); off, or any other launch: passes of their own, the same "
            "arithmetic",
        ),
        Param(
            "contact_geometry",
            (False, True),
            "block normal solve, serial form or persistent launch: what the rows of a "
            "contact derive from its lever arms, normal and the bodies' inertias alone "
            "(its face block and friction rows; they hold over a step) is derived once a "
            "step into a ContactGeometry record a constraint, which every sweep reads "
            "(loads in place of arithmetic on each visit's chain)",
        ),
        Param(
            "support_chains",
            (False, True),
            "persistent launch: after each substep's sweeps, the support chains' phases "
            "(rbgen.pipeline.solvers.support: a body stops sinking into its support, along "
            "whole chains); off, or any other launch: none in the kernel (other launches "
            "run the chains' own kernels)",
        ),
        Param(
            "warm_start_mode",
            WARM_START_MODES,
            "batched: the warm start is a sweep over the batches (one batch step per "
            "colour); summed (persistent only): every constraint's old impulses are summed "
            "per body in 64-bit fixed point with atomics, then every body takes its sum",
        ),
    ],
    doc="PGS velocity sweeps and split-impulse position sweeps over batched contacts.",
    roles={
        "constraints": "inout",
        "bodies": "inout",
        "split": "inout",
        "sync": "inout",
        "warm_sums": "inout",
        "deltas": "inout",
        "joints": "inout",
        "geometry": "inout",
        "supports": "inout",
        "links": "inout",
    },
    requires=lambda v: _parameter_rules(v),
    build_options=fast_math_options,
    defaults=lambda traits: default_values(traits, persistent=persistent_launch_validated(traits)),
    signatures=[SOLVE_GROUPS, APPLY_SPLIT_VELOCITIES],
)


def default_values(
    traits: DeviceTraits, *, persistent: bool = False, solve_form: str | None = None
) -> dict:
    """The solver's parameters for a device and a batching of this solve form (the
    template's defaults: a default World's plan on that device)."""
    solve_form = solve_form or ("lanes" if traits.is_gpu else "serial")
    values = {
        "work_group_size": default_work_group_size(traits, solve_form, persistent),
        "max_batches": 128,
        "solve_form": solve_form,
        "normal_solve": default_normal_solve(),
        "persistent": persistent,
        "fast_math": resolve_fast_math(traits, None),
        "joints": False,
        "support_chains": False,
        "fold_substeps": default_fold_substeps(persistent),
        "warm_start_mode": "summed"
        if persistent and traits.has_extension(INT64_ATOMICS)
        else "batched",
    }
    values["contact_geometry"] = default_contact_geometry(values)
    return values


def can_keep_contact_geometry(values: dict) -> bool:
    """Whether a solve with these template values (``normal_solve``, ``solve_form``,
    ``persistent``) can keep its contacts' geometry for the step: the block normal solve
    (the geometry is its block's) in the serial form or a persistent launch, whose
    launches derive the records before every sweep that reads them. The template's rules,
    the plan and `rbgen tune` ask this one function."""
    return values["normal_solve"] == "block" and (
        values["solve_form"] == "serial" or bool(values["persistent"])
    )


def default_contact_geometry(values: dict) -> bool:
    """Whether a solve with these template values keeps its contacts' geometry for the
    step (the template parameter "contact_geometry"): the block normal solve's serial
    form, a CPU's, whose core loads a record faster than it derives one. A persistent
    launch can keep it too, but does not by default: on NVIDIA GPUs a visit's chain is
    the block solve itself, not the derivation the record saves, and in large scenes the
    record's loads (a second record a contact, read in every sweep) made it slower. The
    plan chooses (`rbgen.plan`: a tunable, `rbgen tune --what plan` measures both)."""
    return can_keep_contact_geometry(values) and values["solve_form"] == "serial"


def default_fold_substeps(persistent: bool) -> bool:
    """Whether a solve folds its substeps' passes into its sweeps (the template parameter
    "fold_substeps"): wherever it can, a persistent launch. It saves a pass over the
    contacts a substep (their refresh), and without joints two device-wide barriers and
    the warm-start pass too, and does the same arithmetic in the same order (the same
    bits on an exact build)."""
    return bool(persistent)


def _parameter_rules(values: dict) -> str | None:
    """What the solver template's parameters must agree on (None: they do)."""
    if values["persistent"] and values["solve_form"] != "lanes":
        return "persistent needs solve_form='lanes' (the work groups share the batches)"
    if values["contact_geometry"] and not can_keep_contact_geometry(values):
        return (
            "contact_geometry=True needs normal_solve='block' (the geometry is its block's) "
            "in the serial form or a persistent launch (the launches that derive the records "
            "come before every sweep that reads them)"
        )
    if values["support_chains"] and not values["persistent"]:
        return (
            "support_chains=True needs persistent=True (other solves launch the chains' "
            "own kernels after their sweeps: rbgen.pipeline.solvers.support.SupportChains)"
        )
    if values["warm_start_mode"] == "summed" and not values["persistent"]:
        return (
            "warm_start_mode='summed' needs persistent=True (its two phases are "
            "separated by a device-wide barrier)"
        )
    return None


def default_normal_solve() -> str:
    """block on every device: lanes solve a batch's manifolds side by side, so a
    sequential solve's point-order torque is not corrected by rows solved after it and
    columns lean; cells split a column between launches; and a CPU's serial solve over
    slabs, though a sequential sweep is cheaper there, topples a 30-box column with it,
    where the block holds the column and, at the CPU's default substeps, the lattices."""
    return "block"


def default_work_group_size(
    traits: DeviceTraits, solve_form: str | None = None, persistent: bool = False
) -> int:
    """lanes form: 64 (two warps / one wavefront per batch step), 256 for a persistent
    solve (one work group a compute unit does all; the block solve's registers a lane
    allow no more); serial form: 1 (one group per work group, so that PoCL hands groups to
    its threads one at a time)."""
    if (solve_form or ("lanes" if traits.is_gpu else "serial")) == "serial":
        return 1
    return min(256 if persistent else 64, traits.max_work_group_size)


#: bodies per work group of apply_split_velocities: enough to amortise a work group's
#: start on a CPU, two warps on a GPU
APPLY_WORK_GROUP_SIZE = 64

#: bit flags of a `solve_groups` launch's ``passes`` argument (as in the template)
WARM_START_PASS, FIRST_REVERSED, RESTITUTION_PASS, GEOMETRY_PASS, SHOCK_PASS = 1, 2, 4, 8, 16


@dataclasses.dataclass(frozen=True)
class SubstepMotion:
    """What a solver that integrates its substeps needs of the step: the substep count and
    length, gravity, the damping factors (per substep), the rotation clamp (per substep),
    the push rule, and the bodies' `BodyDelta` records."""

    substeps: int
    h: float
    gravity: np.ndarray
    linear_damping_factor: float
    angular_damping_factor: float
    max_angular_step: float
    penetration_slop: float
    penetration_recovery: float
    deltas: object
    #: the prepare kernel's per-substep velocity changes of the step's external forces
    #: (2 float4 a body), None for a step without forces
    kicks: object = None
    #: the support chains' records (`rbgen.pipeline.solvers.support.SupportBuffers`) and
    #: their rounds a substep; None: no support chains
    support: SupportBuffers | None = None
    support_rounds: int = 0

    def arguments(self) -> dict:
        """The kernel arguments by name."""
        return {
            "substeps": np.uint32(self.substeps),
            "h": np.float32(self.h),
            "gravity": np.array([*self.gravity, 0.0], np.float32),
            "linear_damping_factor": np.float32(self.linear_damping_factor),
            "angular_damping_factor": np.float32(self.angular_damping_factor),
            "max_angular_step": np.float32(self.max_angular_step),
            "penetration_slop": np.float32(self.penetration_slop),
            "penetration_recovery": np.float32(self.penetration_recovery),
            "deltas": self.deltas,
            # (without forces the argument is bound to a buffer that is not read)
            "kicks": self.deltas if self.kicks is None else self.kicks,
            "kicked": np.uint32(self.kicks is not None),
            # (a kernel with the support chains' phases: `PgsSolver`, support_chains)
            **(
                {}
                if self.support is None
                else {
                    "supports": self.support.supports,
                    "links": self.support.links,
                    "support_rounds": np.uint32(self.support_rounds),
                }
            ),
        }


def check_release_sweeps(release_sweeps) -> None:
    """Refuse a ``release_sweeps`` that is neither None nor an integer >= 0, naming it."""
    if release_sweeps is not None and (
        isinstance(release_sweeps, bool)
        or not isinstance(release_sweeps, (int, np.integer))
        or release_sweeps < 0
    ):
        raise RbgenError(
            f"release_sweeps must be None (every sweep) or an integer >= 0, got {release_sweeps!r}"
        )


def first_release_sweep(sweeps: int, release_sweeps: int | None) -> int:
    """The first of ``sweeps`` sweeps whose block solve may release points: the last
    ``release_sweeps`` of them (None: all)."""
    return 0 if release_sweeps is None else max(0, sweeps - release_sweeps)


class PgsSolver(PushVelocities):
    """Launches the PGS sweeps over the groups of its batcher (see the module docstring).

    ``batcher``: the `rbgen.pipeline.batching.Batcher` whose arrays each `solve` reads
    (the caller runs the batcher before); its solve form and max_batches are the solver's.
    ``persistent``: one launch over every compute unit (global batching only).
    ``release_sweeps`` (block normal solve): how many of the last velocity sweeps, and of
    the last position sweeps, solve the complete block (None: every sweep).
    """

    def __init__(
        self,
        runtime: Runtime,
        batcher,
        *,
        normal_solve: str | None = None,
        persistent: bool = False,
        fast_math: bool | None = None,
        warm_start_mode: str | None = None,
        work_group_size: int | None = None,
        release_sweeps: int | None = None,
        joints: bool = False,
        contact_geometry: bool | None = None,
        support_chains: bool = False,
    ):
        self.runtime = runtime
        self.batcher = batcher
        traits = runtime.traits
        persistent = bool(persistent)
        if persistent and batcher.group_count != 1:
            raise RbgenError(
                f"a persistent solve needs one group of all constraints (global "
                f"batching), got {batcher.group_count} groups (batching "
                f"{batcher.mode!r})"
            )
        values = default_values(traits, persistent=persistent, solve_form=batcher.solve_form)
        if warm_start_mode == "summed" and not runtime.has_extension(INT64_ATOMICS):
            raise RbgenError(
                f"warm_start_mode='summed' needs the device extension "
                f"{INT64_ATOMICS}, which {traits.device_name} lacks"
            )
        overrides = {
            "normal_solve": normal_solve,
            "warm_start_mode": warm_start_mode,
            "work_group_size": work_group_size,
            "fast_math": None if fast_math is None else resolve_fast_math(traits, fast_math),
        }
        values.update({k: v for k, v in overrides.items() if v is not None})
        values["contact_geometry"] = (
            default_contact_geometry(values) if contact_geometry is None else bool(contact_geometry)
        )
        values["max_batches"] = int(batcher.max_batches)
        values["joints"] = bool(joints)
        values["support_chains"] = bool(support_chains) and persistent
        values["fold_substeps"] = default_fold_substeps(persistent)
        check_release_sweeps(release_sweeps)
        self.release_sweeps = None if release_sweeps is None else int(release_sweeps)
        self.spec = TEMPLATE.spec(**values)
        self.solve_form = values["solve_form"]
        self.work_group_size = values["work_group_size"]
        self.persistent = persistent
        self.max_batches = values["max_batches"]
        #: per-body fixed-point sums of the summed warm start (zero between solves)
        self._warm_sums: cl_array.Array | None = None
        #: the deltas a solve without motion binds (never written)
        self._idle_deltas: cl_array.Array | None = None
        #: the serial block solve's per-constraint geometry (`_geometry_buffer`)
        self.geometry_cache = _geometry_cache(values)
        self._geometry: cl_array.Array | None = None
        #: the device-wide barrier's words over batches other than global's (which brings its own)
        self._sync = barrier_buffer(runtime) if persistent else None
        self._program = program = compile_spec(runtime, self.spec)
        self.apply_kernel = runtime.bound(program.kernel("apply_split_velocities"))
        # the arguments this specialisation has, bound by name at their declared positions
        have = {a.name for a in SOLVE_GROUPS.args(self.spec.values)}
        self._buffer_names = tuple(n for n in SOLVE_BUFFERS if n in have)
        self._scalar_names = tuple(n for n in LAUNCH_SCALARS if n in have)
        self._bind_buffers = SOLVE_GROUPS.binder(self.spec, *self._buffer_names)
        self._bind_scalars = SOLVE_GROUPS.binder(self.spec, *self._scalar_names)
        SOLVE_GROUPS.check_bound(self.spec, self._bind_buffers, self._bind_scalars)
        self._bind_apply = APPLY_SPLIT_VELOCITIES.binder(
            self.spec, "bodies", "split", "body_count", "dt"
        )
        #: trailing scalars -> kernel object with those scalars set
        self._instances: dict = {}
        #: (plan, sweeps, warm start) -> ([(kernel, global size)], distinct kernels)
        self._schedules: dict = {}

    @property
    def normal_solve(self) -> str:
        return self.spec.values["normal_solve"]

    def barrier_state(self):
        """The device-wide barrier words its persistent launch uses (None: it makes none)."""
        if not self.persistent:
            return None
        state = getattr(self.batcher, "state", None)  # (a device array has no truth value)
        return self._sync if state is None else state

    @property
    def integrates(self) -> bool:
        """Whether a solve runs the step's substeps itself and moves the bodies (a
        persistent launch): then `solve` takes the step's `SubstepMotion`."""
        return self.persistent

    def solve(
        self,
        constraints,
        constraint_count,
        constraint_capacity: int,
        bodies,
        inertia,
        body_count: int,
        sweeps,
        motion: SubstepMotion | None = None,
        joints=None,
        h: float | None = None,
        restitution: bool = True,
        same_geometry: bool = False,
    ) -> None:
        """Warm start (every constraint's old impulses, before any sweep),
        ``sweeps.iterations`` velocity sweeps and ``sweeps.position_iterations``
        split-impulse sweeps over the batches of the batcher's last call, launched as the
        module docstring says. ``body_count``: all bodies, static ones too (indexed as in
        ``bodies``); the count arguments are the batcher's (unused here). A solver built
        with joints takes the device `JointConstraint` records (``joints``, the items of
        kind EDGE_JOINT index them), the substep ``h`` and ``sweeps.joint_recovery``. With
        ``same_geometry`` (see `rbgen.pipeline.solvers.Solver.solve`) the serial block
        solve reuses the ContactGeometry its previous call derived. A solver that
        `integrates` runs all ``motion.substeps`` substeps and moves the bodies; without
        ``motion`` it solves once and leaves them where they are. ``restitution``: the
        last velocity sweep applies the contacts' restitution (the step's last substep;
        a solver that `integrates` applies it in its last substep)."""
        iterations, position_iterations = int(sweeps.iterations), int(sweeps.position_iterations)
        shock = shock_sweep(sweeps, self.spec.values["joints"])
        check_sweeps(iterations, position_iterations, sweeps.relaxation, shock)
        # (the sequential normal solve has no block to release: its release scalars are unused)
        release = self.release_sweeps if self.normal_solve == "block" else 0
        batcher = self.batcher
        derive = self.geometry_cache and not same_geometry
        launches, kernels = self._schedule(
            batcher.launch_plan,
            iterations,
            position_iterations,
            bool(sweeps.warm_start),
            release,
            restitution,
            derive,
            shock,
        )
        if not launches:
            return
        given = {
            "constraints": constraints,
            "order": batcher.order,
            "group_batches": batcher.group_batches,
            "group_batch_count": batcher.group_batch_count,
            "bodies": bodies,
            "inertia": inertia,
            "split": self.split_velocities(max(1, int(body_count))),
            "relaxation": np.float32(sweeps.relaxation),
        }
        if self.geometry_cache:
            given["geometry"] = self._geometry_buffer(max(1, int(constraint_capacity)))
        if self.persistent:  # after a global colouring: its buffer (it may have given up)
            given["sync"] = self.barrier_state()
        if self.spec.values["warm_start_mode"] == "summed":
            given["warm_sums"] = self._warm_sum_buffer(max(1, int(body_count)))
        given["body_count"] = np.uint32(body_count)
        if self.spec.values["joints"]:
            if joints is None or h is None or not h > 0:
                raise RbgenError("a solver built with joints needs the joints and h > 0")
            given["joints"] = joints
            given["inv_h"] = np.float32(1.0 / h)
            given["joint_recovery"] = np.float32(sweeps.joint_recovery)
        if self.persistent:  # (substeps 0 unless it runs the step's substeps)
            given.update(
                (
                    motion
                    if self.integrates and motion is not None
                    else self._no_motion(body_count)
                ).arguments()
            )
        shared = [given[name] for name in self._buffer_names]
        for kernel in kernels:
            self._bind_buffers(kernel, *shared)
        wg = self.work_group_size
        for kernel, size in launches:
            kernel.launch(size, wg)

    def _no_motion(self, body_count: int) -> SubstepMotion:
        """A persistent solve's arguments for the warm start and sweeps alone (0 substeps:
        the caller moves the bodies)."""
        if self._idle_deltas is None or len(self._idle_deltas) < body_count:
            self._idle_deltas = cl_array.zeros(
                self.runtime.queue, max(1, body_count), layouts.BODY_DELTA.dtype
            )
        return SubstepMotion(0, 0.0, np.zeros(3), 1.0, 1.0, 0.0, 0.0, 0.0, self._idle_deltas)

    def _geometry_buffer(self, capacity: int):
        """The serial block solve's `layouts.CONTACT_GEOMETRY` records, one a constraint
        slot (grown with the constraints; written by the GEOMETRY_PASS launches)."""
        if self._geometry is None or len(self._geometry) < capacity:
            self._geometry = cl_array.empty(
                self.runtime.queue, capacity, layouts.CONTACT_GEOMETRY.dtype
            )
        return self._geometry

    def _warm_sum_buffer(self, body_capacity: int):
        """The summed warm start's zeroed per-body sums (the kernel leaves them zero; a
        launch whose barrier gave up may leave some behind, and the World then stops
        using this persistent solver)."""
        words = layouts.WARM_SUM_WORDS * body_capacity
        if self._warm_sums is None or len(self._warm_sums) < words:
            self._warm_sums = cl_array.zeros(self.runtime.queue, words, np.int64)
        return self._warm_sums

    def _schedule(
        self,
        plan,
        iterations: int,
        position_iterations: int,
        warm_start: bool,
        release_sweeps: int | None,
        restitution: bool = True,
        derive_geometry: bool = False,
        shock: bool = False,
    ):
        """Every launch of one call (kernel object, global size) and the distinct
        kernel objects, computed once per plan and settings; with `restitution`, the
        launch of the last velocity sweep applies the restitution (with ``shock``, of the
        sweep before it: the last is a shock sweep, SHOCK_PASS); with ``derive_geometry``
        the first launch over each group derives its contacts' geometry (GEOMETRY_PASS)."""
        key = (
            tuple(plan),
            iterations,
            position_iterations,
            warm_start,
            release_sweeps,
            restitution,
            derive_geometry,
            shock,
        )
        schedule = self._schedules.get(key)
        if schedule is not None:
            return schedule
        warm = WARM_START_PASS if warm_start else 0
        bounce = RESTITUTION_PASS if restitution and iterations > 0 else 0
        shocks = SHOCK_PASS if shock and iterations > 1 else 0
        bounce_sweep = iterations - 1 - (1 if shocks else 0)  # (the shock sweep is the last)
        velocity_from = first_release_sweep(iterations, release_sweeps)
        position_from = first_release_sweep(position_iterations, release_sweeps)
        # (passes, velocity sweeps, position sweeps, and the first of each that may release)
        if len(plan) == 1:  # one launch: every sweep in it
            passes = [
                (
                    warm | bounce | shocks,
                    iterations,
                    position_iterations,
                    velocity_from,
                    position_from,
                )
            ]
        else:  # one launch per colour and sweep; the warm start is a sweep of its own
            passes = [(warm, 0, 0, 0, 0)] if warm else []
            passes += [
                (
                    (FIRST_REVERSED if s % 2 else 0)
                    | (bounce if s == bounce_sweep else 0)
                    | (shocks if s == iterations - 1 else 0),
                    int(s < iterations),
                    int(s < position_iterations),
                    int(s < velocity_from),
                    int(s < position_from),
                )
                for s in range(max(iterations, position_iterations))
            ]
        if not self.persistent:  # (a persistent launch also moves the bodies: it always runs)
            passes = [p for p in passes if p[:3] != (0, 0, 0)]
        if derive_geometry and passes:
            passes[0] = (passes[0][0] | GEOMETRY_PASS, *passes[0][1:])
        launches = [self._launch(first, count, *p) for p in passes for first, count in plan]
        kernels = list({id(k): k for k, _ in launches}.values())
        schedule = self._schedules[key] = (launches, kernels)
        return schedule

    def _launch(
        self,
        first: int,
        count: int,
        passes: int,
        velocity_sweeps: int,
        position_sweeps: int,
        velocity_release_from: int,
        position_release_from: int,
    ):
        """(kernel object, global size) of one launch over groups first .. first + count - 1;
        its sweeps from velocity_release_from (position_release_from) on may release points."""
        wg = self.work_group_size
        if self.solve_form == "serial":  # a work-item per group, the last work group partly idle
            size = -(-count // wg) * wg
        elif self.persistent:  # every compute unit, whatever the group count (1)
            size = persistent_groups(self.runtime.traits) * wg
        else:
            size = count * wg
        given = {
            "group_offset": first,
            "group_end": first + count,
            "passes": passes,
            "velocity_sweeps": velocity_sweeps,
            "position_sweeps": position_sweeps,
            "velocity_release_from": velocity_release_from,
            "position_release_from": position_release_from,
        }
        key = tuple(given[name] for name in self._scalar_names)
        kernel = self._instances.get(key)
        if kernel is None:
            kernel = self._instances[key] = instance(self.runtime, self._program, "solve_groups")
            self._bind_scalars(kernel, *(np.uint32(v) for v in key))
        return kernel, size

    def apply_split(self, bodies, body_count: int, dt: float) -> None:
        """Move bodies by their push velocities (after integration) and clear them."""
        if body_count == 0:
            return
        split = self.split_velocities(body_count)
        wg = min(APPLY_WORK_GROUP_SIZE, self.runtime.traits.max_work_group_size)
        self._bind_apply(self.apply_kernel, bodies, split, np.uint32(body_count), np.float32(dt))
        self.apply_kernel.over(body_count, wg)
