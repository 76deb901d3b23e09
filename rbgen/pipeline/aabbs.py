"""World AABB stage: one box per body from its shape and transform.

The per-body code lives in ``templates/pipeline/world_aabb.cl.mako``, which
calls each shape type's ``<type>_world_aabb`` (its registry entry's
``aabb_template``, see `rbgen.shapes`); a World runs it inside
`prepare.BodyPreparation` (one launch for both), and `WorldAabbs` launches it on
its own for other callers.
"""

from __future__ import annotations

import numpy as np

from ..codegen import KernelTemplate, Param, compile_spec, work_group_size_param
from ..device import DeviceTraits, Runtime
from ..shapes import shape_type_names


def shape_types_param(doc: str, *, empty: bool) -> Param:
    """The ``shape_types`` parameter of templates that include world_aabb.cl.mako: sorted,
    distinct registered shape type names (``empty``: the empty tuple is allowed too)."""
    return Param(
        "shape_types",
        lambda v: (
            isinstance(v, tuple)
            and (empty or len(v) > 0)
            and set(v) <= set(shape_type_names())
            and tuple(sorted(set(v))) == v
        ),
        doc,
        "a sorted tuple of distinct registered shape type names (rbgen.shapes)"
        + (", empty for none" if empty else ", not empty"),
    )


TEMPLATE = KernelTemplate(
    "pipeline/world_aabbs.cl.mako",
    [
        work_group_size_param(
            "bodies per work group; memory-bound, so any size that fills a CU works"
        ),
        shape_types_param(
            "emit a case only for the shape types present, keeping the kernel small", empty=False
        ),
    ],
    doc="World-space AABB of every body.",
    defaults=lambda traits: {
        "work_group_size": default_work_group_size(traits),
        "shape_types": ("box", "hull", "plane", "sphere"),
    },
)


def default_work_group_size(traits: DeviceTraits) -> int:
    """128 on GPUs; 64 on CPUs (PoCL vectorises across work-items)."""
    return min(128 if traits.is_gpu else 64, traits.max_work_group_size)


class WorldAabbs:
    """Launches `compute_world_aabbs` for the shape types of one world."""

    def __init__(self, runtime: Runtime, shape_types, *, work_group_size: int | None = None):
        self.runtime = runtime
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        self.spec = TEMPLATE.spec(
            work_group_size=self.work_group_size, shape_types=tuple(sorted(set(shape_types)))
        )
        self.kernel = runtime.bound(compile_spec(runtime, self.spec).kernel("compute_world_aabbs"))

    def __call__(self, bodies, shapes, hull_vertices, aabbs, body_count: int, margin: float = 0.0):
        if body_count == 0:
            return None
        return self.kernel.over(
            body_count,
            self.work_group_size,
            bodies,
            shapes,
            hull_vertices,
            aabbs,
            np.uint32(body_count),
            np.float32(margin),
        )
