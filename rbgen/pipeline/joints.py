"""The joint stage: a step's joint edges, and the break test.

Joints enter the step through the constraint-edge list that batching colours
(`layouts.CONSTRAINT_EDGE`): edges ``[0, joint_count)`` are the joints' (the contact
setup writes its edges from ``first_contact_edge`` = the joint count on), each naming its
joint by the item ``EDGE_JOINT << EDGE_KIND_SHIFT | index``. A joint's edge keeps the
colour of its previous step's edge (the constraint ring's generation before the step's:
a redone step inherits what its first try did) when that edge was this joint's (the same
index and bodies: decided on the device, so that every step enqueues the same commands
for its place in the ring, as `rbgen.schedule` records), so that global batching starts
from it. The same launch first copies each joint, as the step
found it, into the step slot's backup (a redone step restores the impulses and broken
flags from it, as the bodies from theirs), then breaks the joints whose reaction over
the last step exceeded their break impulse. The joint records live on the device between steps
(`rbgen.joints.JointStore`); this stage only reads and flags them, so a step adds one
launch and no transfer.
"""

from __future__ import annotations

import numpy as np

from ..codegen import KernelTemplate, compile_spec, work_group_size_param
from ..device import DeviceTraits, Runtime

TEMPLATE = KernelTemplate(
    "pipeline/joints.cl.mako",
    [work_group_size_param("joints per work group; memory-bound, any size that fills a CU")],
    doc="The joints' constraint edges of a step, and the break test.",
    roles={"joints": "inout", "backup": "out", "edges": "inout"},
    defaults=lambda traits: {"work_group_size": default_work_group_size(traits)},
)


def default_work_group_size(traits: DeviceTraits) -> int:
    """64 on GPUs, 16 on CPUs (as the constraint setup)."""
    return min(64 if traits.is_gpu else 16, traits.max_work_group_size)


class JointEdges:
    """Launches `prepare_joints` over a World's joints."""

    def __init__(self, runtime: Runtime, work_group_size: int | None = None):
        self.runtime = runtime
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        self.spec = TEMPLATE.spec(work_group_size=self.work_group_size)
        self.kernel = runtime.bound(compile_spec(runtime, self.spec).kernel("prepare_joints"))

    def __call__(
        self,
        joints,
        backup,
        joint_count: int,
        bodies,
        edges,
        previous_edges,
        previous_count: int,
        substeps,
    ):
        """Copy the joints to ``backup`` (as the step found them, for a redo), then write
        edges [0, joint_count) (``previous_edges``: the last step's, holding
        ``previous_count`` joint edges, whose colours the same joints' edges take);
        ``substeps`` scales the last substep's impulse to
        the step's for the break test."""
        if joint_count == 0:
            return None
        return self.kernel.over(
            joint_count,
            self.work_group_size,
            joints,
            backup,
            np.uint32(joint_count),
            bodies,
            edges,
            previous_edges,
            np.uint32(previous_count),
            np.float32(substeps),
        )
