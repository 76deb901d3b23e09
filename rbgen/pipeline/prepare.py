"""Per-body preparation before the solver: implicit gyroscopic term and world inverse inertia.

The solver needs every body's world inverse inertia tensor; it changes with the
orientation, so a small kernel recomputes it each step from the principal
diagonal kept in `BodyInertia`. The same pass applies the implicit gyroscopic
term (Bullet 2.x's implicit scheme, with the implicit midpoint rule in place
of implicit Euler, which loses momentum): without it an asymmetric box spinning freely keeps its
angular *velocity* instead of its angular *momentum*, which is wrong.

Built with ``shape_types``, the pass also writes every body's world AABB
(the World's broadphase input, see `aabbs`): the step's poses are the same
before and after this kernel, so a World saves the separate AABB launch. It
also gives each body its speculative distance for this step (continuous
collision): a body whose travel |v| dt exceeds `FAST_FRACTION` of its inner
radius gets that travel, in ``Body.linear_velocity.w``, and its AABB swept along
it; the narrowphase keeps a pair's points up to the contact margin plus its
bodies' speculative distances, and the solver lets such a gap close and no more
(speculative contacts, as PhysX's speculative CCD: no extra launch, dynamic and
static pairs alike). Every other body gets 0, so a scene without fast bodies has
the pairs and contacts it had without it.
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from .. import layouts
from ..codegen import KernelTemplate, Param, compile_spec, work_group_size_param
from ..device import DeviceTraits, Runtime
from ..errors import RbgenError
from .aabbs import shape_types_param

#: a body is fast when one step's travel exceeds this fraction of its inner radius
#: (Box2D v3's safety factor): a slower body's centre cannot cross a surface in one step,
#: so the contact found at the overlap pushes it back the way it came
FAST_FRACTION = 0.5

TEMPLATE = KernelTemplate(
    "pipeline/prepare.cl.mako",
    [
        work_group_size_param(
            "bodies per work group; memory-bound, so any size that fills a CU works"
        ),
        Param(
            "gyroscopic",
            (True, False),
            "emit the implicit gyroscopic update only when the world enables it",
        ),
        Param(
            "gravity",
            (True, False),
            "add g dt to dynamic bodies here, saving the World a separate gravity launch",
        ),
        shape_types_param(
            "write world AABBs here for these shape types, saving the World "
            "the AABB launch; () writes none",
            empty=True,
        ),
        Param(
            "backup",
            (False, True),
            "copy every body to a backup array first, saving the World a copy command",
        ),
        Param(
            "external_forces",
            (False, True),
            "apply the step's forces and torques from Python (rbgen.forces) here",
        ),
        Param(
            "sleeping",
            (False, True),
            "a body without inverse mass (a sleeping one: rbgen.pipeline.sleep) gets no "
            "world inverse inertia either, so the solver sees it as static",
        ),
    ],
    doc="World inverse inertia and the implicit gyroscopic term, one work-item per body.",
    roles={
        "bodies": "inout",
        "inertia": "inout",
        "backup": "out",
        "forces": "in",
        "lever_forces": "in",
        "moments": "in",
        "kicks": "out",
    },
    defaults=lambda traits: {
        "work_group_size": default_work_group_size(traits),
        "gyroscopic": True,
        "gravity": False,
        "shape_types": (),
        "backup": False,
        "external_forces": False,
        "sleeping": False,
    },
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
    """Launches `prepare_bodies` over `Body` and `BodyInertia` device arrays.

    ``shape_types`` (the world's shape type names): also write world AABBs,
    whose inputs are then given to each call as ``aabbs``. ``backup``: first copy
    every body, as it is, into the ``backup`` array given to each call.
    """

    def __init__(
        self,
        runtime: Runtime,
        *,
        gyroscopic: bool = True,
        gravity: bool = False,
        shape_types=(),
        backup: bool = False,
        external_forces: bool = False,
        sleeping: bool = False,
        work_group_size: int | None = None,
    ):
        self.runtime = runtime
        self.gyroscopic = bool(gyroscopic)
        self.gravity = bool(gravity)
        self.shape_types = tuple(sorted(set(shape_types)))
        self.backup = bool(backup)
        self.external_forces = bool(external_forces)
        self.sleeping = bool(sleeping)
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        self.spec = TEMPLATE.spec(
            work_group_size=self.work_group_size,
            gyroscopic=self.gyroscopic,
            gravity=self.gravity,
            shape_types=self.shape_types,
            backup=self.backup,
            external_forces=self.external_forces,
            sleeping=self.sleeping,
        )
        self.kernel = runtime.bound(compile_spec(runtime, self.spec).kernel("prepare_bodies"))
        self._kicks: cla.Array | None = None

    def _scratch_kicks(self, body_count: int):
        """A kicks buffer of at least ``body_count`` bodies, for callers that do not keep
        the per-substep changes."""
        kicks = self._kicks
        if kicks is None or len(kicks) < 2 * body_count:
            kicks = self._kicks = cla.empty(
                self.runtime.queue, 2 * max(1, body_count), cl.cltypes.float4
            )
        return kicks

    def __call__(
        self,
        bodies,
        inertia,
        body_count: int,
        dt: float,
        gravity=None,
        aabbs=None,
        backup=None,
        forces=None,
        kicks=None,
        h: float | None = None,
    ):
        """Prepare ``body_count`` bodies; ``gravity`` (3 numbers) is required exactly
        when built with gravity=True (v += g dt on dynamic bodies); ``aabbs``, a tuple
        (shapes, hull_vertices, aabbs, margin) as `WorldAabbs` takes them, exactly
        when built with shape types; ``backup`` (a Body array of at least
        ``body_count``) exactly when built with backup=True. ``forces`` (built with
        external_forces=True): None for a step without forces, else three float4 device
        arrays of at least ``body_count``, or None each (force, lever force, moment:
        `rbgen.forces`; None is zero), with ``kicks`` (2 float4 a body: the velocity
        changes each substep of ``h`` (default ``dt``) adds; written only when a force
        array is given; None: a buffer of this BodyPreparation's own)."""
        if (gravity is not None) != self.gravity:
            raise RbgenError(
                "gravity must be given exactly when this BodyPreparation was "
                f"built with gravity=True (built with gravity={self.gravity})"
            )
        if (aabbs is not None) != bool(self.shape_types):
            raise RbgenError(
                "aabbs must be given exactly when this BodyPreparation was built "
                f"with shape types (built with shape_types={self.shape_types})"
            )
        if (backup is not None) != self.backup:
            raise RbgenError(
                "backup must be given exactly when this BodyPreparation was "
                f"built with backup=True (built with backup={self.backup})"
            )
        if body_count == 0:
            return None
        args = [bodies, inertia, np.uint32(body_count)]
        if self.backup:
            args.append(backup)
        if self.gravity:
            args.append(np.array([*gravity, 0.0], dtype=np.float32))
        if self.external_forces:
            arrays = [None] * 3 if forces is None else list(forces)
            args += [bodies if a is None else a for a in arrays]
            args.append(np.uint32(sum(1 << k for k, a in enumerate(arrays) if a is not None)))
            if kicks is None and forces is not None:  # (written: a buffer of its own)
                kicks = self._scratch_kicks(body_count)
            args += [bodies if kicks is None else kicks, np.float32(dt if h is None else h)]
        if aabbs is not None:
            shapes, hull_vertices, boxes, margin = aabbs
            args += [shapes, hull_vertices, boxes, np.float32(margin)]
        args.append(np.float32(dt))
        return self.kernel.over(body_count, self.work_group_size, *args)
