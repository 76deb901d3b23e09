"""Lower or upper bound of query keys in an ascending uint32 key array.

``BoundSearch(runtime, side)(sorted_keys, queries, out, n_keys=None,
n_queries=None)`` writes for each query the first index i < n_keys with
``keys[i] >= query`` (lower) or ``keys[i] > query`` (upper), n_keys if none:
numpy's ``searchsorted(keys, queries, side)``. One binary search per work-item
in both shapes; only the work-group size is tuned.
"""

from __future__ import annotations

import numpy as np

from ..codegen import Param, work_group_size_param
from ..device import DeviceTraits
from ..errors import RbgenError
from ._base import Primitive, PrimitiveTemplate, ceil_div, check_array, resolve_count

SIDES = ("lower", "upper")

TEMPLATE = PrimitiveTemplate(
    "primitives/bound_search.cl.mako",
    [
        Param("side", SIDES, "first key >= query (lower) or > query (upper)"),
        work_group_size_param("queries per work group"),
    ],
    doc="Binary search of many queries in sorted keys.",
    defaults=lambda traits: {"side": "lower", "work_group_size": 64},
)


class BoundSearch(Primitive):
    """``BoundSearch(runtime, side="lower"|"upper")(sorted_keys, queries, out, ...)``."""

    family = "bound_search"
    TEMPLATES = {"gpu": TEMPLATE, "cpu": TEMPLATE}

    def __init__(self, runtime, side: str = "lower", *, params=None):
        if side not in SIDES:
            raise RbgenError(f"side must be one of {list(SIDES)}, got {side!r}")
        self.side = side
        super().__init__(runtime, params)

    @property
    def variant(self) -> str:
        return self.side

    def template_values(self):
        return {"side": self.side}

    @classmethod
    def default_params(cls, traits: DeviceTraits, shape: str | None = None):
        """Heuristics: 128 queries per group on GPUs (4 warps hide the dependent
        loads), 64 on CPUs."""
        shape = shape or traits.kind
        return {
            "shape": shape,
            "work_group_size": min(128 if shape == "gpu" else 64, traits.max_work_group_size),
        }

    def __call__(self, sorted_keys, queries, out, n_keys=None, n_queries=None):
        rt = self.runtime
        buf_keys = check_array(rt, sorted_keys, "sorted_keys", np.uint32)
        buf_queries = check_array(rt, queries, "queries", np.uint32)
        key_capacity, device_keys = resolve_count(rt, n_keys, sorted_keys.size, "n_keys")
        query_capacity, device_queries = resolve_count(rt, n_queries, queries.size, "n_queries")
        buf_out = check_array(rt, out, "out", np.uint32, min_size=query_capacity)
        if query_capacity == 0:
            return None
        params, program = self.program(query_capacity)
        wg = params["work_group_size"]
        kernel = program.kernel("bound_search")
        rt.bound(kernel).bind(
            buf_keys,
            np.uint32(key_capacity),
            device_keys,
            buf_queries,
            np.uint32(query_capacity),
            device_queries,
            buf_out,
        )
        return rt.launch(kernel, ceil_div(query_capacity, wg) * wg, wg)


def search_space(traits: DeviceTraits) -> list[dict]:
    shape = traits.kind
    space = [BoundSearch.default_params(traits)]
    for wg in (32, 64, 128, 256):
        p = {"shape": shape, "work_group_size": wg}
        if wg <= traits.max_work_group_size and p not in space:
            space.append(p)
    return space
