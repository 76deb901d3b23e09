"""The narrowphase's kernel templates, their parameters, and the pair kernels each declares.

Kept together because they share the work-group default and the placement
tile; each `KernelTemplate` sits beside its file in
``rbgen/templates/pipeline/narrowphase/``, followed by the `PairKernel`s whose
kernels it holds (the shape-type pairs each handles; see `kinds`). "convex"
in a kind name is a box or a hull (both carry cooked polygons).
"""

from __future__ import annotations

from ...codegen import KernelTemplate, Param, work_group_size_param
from ...device import DeviceTraits
from .kinds import PairKernel, kinds_param_check, pair_kernels, register_pair_kernel


def default_work_group_size(traits: DeviceTraits) -> int:
    """64 on GPUs (pair kernels use many registers: small groups keep occupancy); 16 on CPUs."""
    return min(64 if traits.is_gpu else 16, traits.max_work_group_size)


def default_placement_tile(traits: DeviceTraits, work_group_size: int) -> int:
    """Pairs per placement tile: 256 on GPUs (enough work groups for scatter_manifolds to fill
    the device at a few thousand pairs), 1024 on CPUs (fewer, longer groups); at least one
    pair per work-item."""
    return max(256 if traits.is_gpu else 1024, work_group_size)


def _kinds_param(template_path: str | None) -> Param:
    return Param(
        "kinds",
        kinds_param_check(template_path),
        "emit code only for the pair kernels (kinds) the world needs",
        "a non-empty tuple of distinct names of pair kernels declared "
        + ("for any template" if template_path is None else f"with {template_path}")
        + ", in declaration order",
    )


def _sizes(traits: DeviceTraits) -> dict:
    wg = default_work_group_size(traits)
    return {"work_group_size": wg, "placement_tile": default_placement_tile(traits, wg)}


_WORK_GROUP = work_group_size_param("queue entries per work group")
_DIRECT = Param(
    "direct",
    (True, False),
    "True: the world's only kind reads the pair list itself and clears what classify_pairs "
    "would (one launch less); False: its queue, filled by classify_pairs",
)
_PLACEMENT_TILE = Param(
    "placement_tile",
    lambda v: isinstance(v, int) and 1 <= v <= 1 << 16 and v & (v - 1) == 0,
    "pairs whose manifolds one scatter_manifolds work group places: kernels that store a "
    "manifold count it in its tile, so placement needs no separate prefix-sum launches",
    "a power of two from 1 to 65536, a multiple of work_group_size",
)
#: argument roles of kernels that store manifolds (KernelTemplate ``roles``)
PAIR_ROLES = {"slots": "inout", "contact_flags": "inout", "tile_counts": "inout"}
_SAT_ROLES = {"cache": "inout", "result_count": "inout"}


def pair_kernel_params(template_path: str) -> list[Param]:
    """The parameters of a template whose pair kernels store manifolds themselves:
    ``work_group_size``, ``kinds`` (which of the kernels declared with it to emit) and
    ``placement_tile`` (store_manifold.cl.mako counts manifolds per tile)."""
    return [_WORK_GROUP, _kinds_param(template_path), _PLACEMENT_TILE]


DISPATCH = KernelTemplate(
    "pipeline/narrowphase/dispatch.cl.mako",
    [_WORK_GROUP, _kinds_param(None), _PLACEMENT_TILE],
    doc="Route broadphase pairs to per-kind queues; gather flagged manifold slots.",
    roles={"queue_counts": "inout"},
    defaults=lambda traits: {**_sizes(traits), "kinds": ("convex_plane", "box_box")},
)

PRIMITIVE_PAIRS_PATH = "pipeline/narrowphase/primitive_pairs.cl.mako"
PRIMITIVE_PAIRS = KernelTemplate(
    PRIMITIVE_PAIRS_PATH,
    pair_kernel_params(PRIMITIVE_PAIRS_PATH),
    doc="Contacts of pairs with a sphere, a capsule or a plane (closed forms, one kernel each).",
    roles=PAIR_ROLES,
    defaults=lambda traits: {
        **_sizes(traits),
        "kinds": tuple(k.name for k in pair_kernels() if k.template.path == PRIMITIVE_PAIRS_PATH),
    },
)
for _name, _pairs in (
    ("sphere_sphere", [("sphere", "sphere")]),
    ("sphere_plane", [("sphere", "plane")]),
    ("sphere_convex", [("sphere", "box"), ("sphere", "hull")]),
    ("sphere_capsule", [("sphere", "capsule")]),
    ("capsule_capsule", [("capsule", "capsule")]),
    ("capsule_plane", [("capsule", "plane")]),
    ("convex_plane", [("box", "plane"), ("hull", "plane")]),
):
    register_pair_kernel(PairKernel(_name, tuple(_pairs), PRIMITIVE_PAIRS))

CAPSULE_CONVEX = KernelTemplate(
    "pipeline/narrowphase/capsule_convex.cl.mako",
    [_WORK_GROUP, _PLACEMENT_TILE],
    doc="Capsule against box or hull: segment separating axes, closest points, face clipping.",
    roles=PAIR_ROLES,
    defaults=_sizes,
)
register_pair_kernel(
    PairKernel("capsule_convex", (("capsule", "box"), ("capsule", "hull")), CAPSULE_CONVEX)
)

SAT_BOX_BOX = KernelTemplate(
    "pipeline/narrowphase/sat_box_box.cl.mako",
    [_WORK_GROUP, _DIRECT],
    doc="Separating-axis test of box pairs in closed form (15 axes, no array reads).",
    roles=_SAT_ROLES,
    defaults=lambda traits: {"work_group_size": default_work_group_size(traits), "direct": False},
)
register_pair_kernel(
    PairKernel(
        "box_box",
        (("box", "box"),),
        SAT_BOX_BOX,
        kernel="find_separating_axis",
        separating_axis=True,
    )
)

SAT = KernelTemplate(
    "pipeline/narrowphase/sat.cl.mako",
    [
        _WORK_GROUP,
        _DIRECT,
        Param(
            "first", ("box", "hull"), "box: closed-form projection; hull: loop over the vertices"
        ),
        Param("second", ("box", "hull"), "as first, for the second shape of the kind"),
        Param(
            "edge_axes",
            ("directions", "gauss_map"),
            "directions: every pair of unique edge directions, each measured over the vertices "
            "(cheap for boxes: 3 x 3); gauss_map: only edge pairs whose Gauss-map arcs cross, "
            "measured between the edges (scales to large hulls)",
        ),
    ],
    doc="Separating-axis test of convex pairs with a per-pair best-axis cache.",
    roles=_SAT_ROLES,
    defaults=lambda traits: {
        "work_group_size": default_work_group_size(traits),
        "direct": False,
        "first": "box",
        "second": "hull",
        "edge_axes": "directions",
    },
)
# a box brings its three edge directions; hull pairs prune their edge pairs on the Gauss map
register_pair_kernel(
    PairKernel(
        "box_hull",
        (("box", "hull"),),
        SAT,
        (("first", "box"), ("second", "hull"), ("edge_axes", "directions")),
        kernel="find_separating_axis",
        separating_axis=True,
    )
)
register_pair_kernel(
    PairKernel(
        "hull_hull",
        (("hull", "hull"),),
        SAT,
        (("first", "hull"), ("second", "hull"), ("edge_axes", "gauss_map")),
        kernel="find_separating_axis",
        separating_axis=True,
    )
)

CLIP = KernelTemplate(
    "pipeline/narrowphase/clip.cl.mako",
    [
        _WORK_GROUP,
        _PLACEMENT_TILE,
        Param(
            "max_face_vertices",
            lambda v: isinstance(v, int) and 3 <= v <= 32,
            "sizes the private clipping buffers (2x): the world's largest face",
            "an int from 3 to 32 (rbgen.hull.MAX_FACE_VERTICES)",
        ),
    ],
    doc="Clip incident faces against reference faces; reduce to at most 4 points.",
    roles=PAIR_ROLES,
    defaults=lambda traits: {**_sizes(traits), "max_face_vertices": 4},
)
