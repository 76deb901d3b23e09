"""The pair kernels of a body against one triangle of a static mesh (`rbgen.mesh`).

The midphase (`rbgen.pipeline.midphase`) turns a (mesh, body) pair into (body, mesh,
1 + triangle) pairs; these kernels, declared for the (type, "mesh") pairs, find each
one's contacts, with the triangle as a two-sided polygon and the face normal on its
inactive edges (``templates/pipeline/narrowphase/triangles.cl.mako``). A box or hull
clips polygons itself, so its kernel's buffers follow the world's largest face
(``max_face_vertices``, which the narrowphase passes to every template that declares it).
"""

from __future__ import annotations

from ... import mesh as _mesh  # noqa: F401 - registers the "mesh" shape type first
from ...codegen import KernelTemplate, Param
from .kinds import PairKernel, register_pair_kernel
from .templates import (
    PAIR_ROLES,
    default_placement_tile,
    default_work_group_size,
    pair_kernel_params,
)

PATH = "pipeline/narrowphase/triangles.cl.mako"


def _convex_matches_kinds(values) -> str | None:
    convex = {"box_triangle": "box", "hull_triangle": "hull"}
    wanted = {convex[k] for k in values["kinds"] if k in convex} or {"none"}
    if wanted != {values["convex"]}:
        return (
            f"convex={values['convex']!r} does not match kinds {values['kinds']} (one "
            f"program holds the box or the hull kernel, named for the kinds)"
        )
    return None


TRIANGLE_PAIRS = KernelTemplate(
    PATH,
    pair_kernel_params(PATH)
    + [
        Param(
            "max_face_vertices",
            lambda v: isinstance(v, int) and 3 <= v <= 32,
            "sizes the private clipping buffers (faces + 3): the world's largest face",
            "an int from 3 to 32 (rbgen.hull.MAX_FACE_VERTICES)",
        ),
        Param(
            "convex",
            ("none", "box", "hull"),
            "the shape of the program's convex_triangle kernel: a box (closed-form "
            "extents, three edge directions) or a hull (its vertices); none: no such kernel",
        ),
    ],
    doc="Contacts of a sphere, capsule, box or hull with one mesh triangle (two-sided, "
    "active edges).",
    roles=PAIR_ROLES,
    requires=_convex_matches_kinds,
    defaults=lambda traits: {
        "work_group_size": default_work_group_size(traits),
        "placement_tile": default_placement_tile(traits, default_work_group_size(traits)),
        "kinds": ("sphere_triangle", "capsule_triangle", "hull_triangle"),
        "max_face_vertices": 4,
        "convex": "hull",
    },
)
register_pair_kernel(
    PairKernel("sphere_triangle", (("sphere", "mesh"),), TRIANGLE_PAIRS, (("convex", "none"),))
)
register_pair_kernel(
    PairKernel("capsule_triangle", (("capsule", "mesh"),), TRIANGLE_PAIRS, (("convex", "none"),))
)
# a box and a hull each in a program of their own: a work group holds one kind of shape
register_pair_kernel(
    PairKernel(
        "box_triangle",
        (("box", "mesh"),),
        TRIANGLE_PAIRS,
        (("convex", "box"),),
        kernel="convex_triangle",
    )
)
register_pair_kernel(
    PairKernel(
        "hull_triangle",
        (("hull", "mesh"),),
        TRIANGLE_PAIRS,
        (("convex", "hull"),),
        kernel="convex_triangle",
    )
)
