"""Substeps: the solver runs several times a step on the step's contacts.

A step finds its contacts once; the solve stage then runs ``substeps`` substeps of
h = dt / substeps, each: gravity (the first substep's comes with the body
preparation), the contacts' targets refreshed from how far their bodies moved so far
(`ContactRefresh`, from the second substep on; the first substep's targets are the
setup's), the solver's warm start and sweeps, and the bodies integrated over h. Stiffness
comes from the substep rate rather than from sweeps: a stack's weight reaches its base
through warm-started impulses each substep, and positions follow each substep, so tall
stacks stop sinking while a substep costs no collision pass.
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array

from ... import layouts
from ...codegen import KernelTemplate, compile_spec, work_group_size_param
from ...device import DeviceTraits, Runtime

TEMPLATE = KernelTemplate(
    "pipeline/solvers/substeps.cl.mako",
    [work_group_size_param("constraints per work group; memory-bound")],
    doc="Contact targets of a substep from the bodies' motion since the step began.",
    roles={"constraints": "inout"},
    defaults=lambda traits: {"work_group_size": default_work_group_size(traits)},
)


def default_work_group_size(traits: DeviceTraits) -> int:
    """64 on GPUs, 16 on CPUs (as the constraint setup)."""
    return min(64 if traits.is_gpu else 16, traits.max_work_group_size)


class ContactRefresh:
    """Launches `refresh_contact_targets`; owns the bodies' `BodyDelta` records (zero for
    static bodies, which never move)."""

    def __init__(self, runtime: Runtime, work_group_size: int | None = None):
        self.runtime = runtime
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        self.spec = TEMPLATE.spec(work_group_size=self.work_group_size)
        program = compile_spec(runtime, self.spec)
        self.kernel = runtime.bound(program.kernel("refresh_contact_targets"))
        self.deltas: cl_array.Array | None = None

    def body_deltas(self, body_count: int):
        """The `BodyDelta` records (grown to ``body_count``, zero when made)."""
        if self.deltas is None or len(self.deltas) < body_count:
            self.deltas = cl_array.zeros(
                self.runtime.queue, max(1, int(body_count)), layouts.BODY_DELTA.dtype
            )
        return self.deltas

    def __call__(
        self,
        constraints,
        constraint_count,
        capacity: int,
        body_count: int,
        h: float,
        penetration_slop: float,
        penetration_recovery: float,
    ) -> None:
        """Refresh min(``constraint_count[0]``, ``capacity``) constraints' targets for a
        substep of ``h`` seconds."""
        if capacity <= 0:
            return
        self.kernel.over(
            capacity,
            self.work_group_size,
            constraints,
            constraint_count,
            np.uint32(capacity),
            self.body_deltas(body_count),
            np.float32(h),
            np.float32(penetration_slop),
            np.float32(penetration_recovery),
        )
