"""Per-body preparation before the solver: implicit gyroscopic term and world inverse inertia.

The solver needs every body's world inverse inertia tensor; it changes with the
orientation, so a small kernel recomputes it each step from the principal
diagonal kept in `BodyInertia`. The same pass applies the implicit gyroscopic
term (Bullet 2.x's implicit scheme, with the implicit midpoint rule in place
of implicit Euler, which loses momentum): without it an asymmetric box spinning freely keeps its
angular *velocity* instead of its angular *momentum*, which is wrong.
"""
from __future__ import annotations

import numpy as np

from .. import layouts
from ..codegen import compile_spec, KernelTemplate, Param, work_group_size_param
from ..device import DeviceTraits, Runtime
from ..errors import RbgenError

TEMPLATE = KernelTemplate(
    "pipeline/gyroscopic.cl.mako",
    [
        work_group_size_param(
            "bodies per work group; memory-bound, so any size that fills a CU works"),
        Param("gyroscopic", (True, False),
              "emit the implicit gyroscopic update only when the world enables it"),
        Param("gravity", (True, False),
              "add g dt to dynamic bodies here, saving the World a separate gravity launch"),
    ],
    doc="World inverse inertia and the implicit gyroscopic term, one work-item per body.",
    roles={"bodies": "inout", "inertia": "inout"},
    defaults=lambda traits: {"work_group_size": default_work_group_size(traits),
                             "gyroscopic": True, "gravity": False},
)


def default_work_group_size(traits: DeviceTraits) -> int:
    """128 on GPUs; 64 on CPUs (PoCL vectorises across work-items)."""
    return min(128 if traits.is_gpu else 64, traits.max_work_group_size)


def inertia_records(inv_inertia_diag: np.ndarray) -> np.ndarray:
    """`BodyInertia` records from (N, 3) principal inverse inertia (0 rows for static bodies).

    The world tensor is filled by `BodyPreparation` on the device each step.
    """
    diag = np.asarray(inv_inertia_diag, dtype=np.float32).reshape(-1, 3)
    records = layouts.BODY_INERTIA.zeros(len(diag))
    records["inv_inertia_local"][:, :3] = diag
    return records


class BodyPreparation:
    """Launches `prepare_bodies` over `Body` and `BodyInertia` device arrays."""

    def __init__(self, runtime: Runtime, *, gyroscopic: bool = True, gravity: bool = False,
                 work_group_size: int | None = None):
        self.runtime = runtime
        self.gravity = bool(gravity)
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        self.spec = TEMPLATE.spec(work_group_size=self.work_group_size, gyroscopic=bool(gyroscopic),
                                  gravity=self.gravity)
        self.kernel = runtime.bound(compile_spec(runtime, self.spec).kernel("prepare_bodies"))

    def __call__(self, bodies, inertia, body_count: int, dt: float, gravity=None):
        """Prepare ``body_count`` bodies; ``gravity`` (3 numbers) is required exactly
        when built with gravity=True (v += g dt on dynamic bodies)."""
        if (gravity is not None) != self.gravity:
            raise RbgenError("gravity must be given exactly when this BodyPreparation was "
                             f"built with gravity=True (built with gravity={self.gravity})")
        if body_count == 0:
            return None
        args = [bodies, inertia, np.uint32(body_count), np.float32(dt)]
        if self.gravity:
            args.append(np.array([*gravity, 0.0], dtype=np.float32))
        return self.kernel.over(body_count, self.work_group_size, *args)

