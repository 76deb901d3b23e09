"""Fill the first n elements of a uint32, int32 or float32 array with a value.

A host count uses the driver's ``enqueue_fill_buffer`` (on PoCL 5x faster than
any kernel we measured). A device count needs a kernel that stops at the
count: one template serves both shapes, only the defaults differ.
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..codegen import Param, work_group_size_param
from ..device import DeviceTraits
from ._base import Primitive, PrimitiveTemplate, ceil_div, check_array, cl_type, resolve_count

TEMPLATE = PrimitiveTemplate(
    "primitives/fill.cl.mako",
    [
        Param("dtype", ("uint", "int", "float"), "element type"),
        work_group_size_param("work-items per tile"),
        Param("items_per_thread", (1, 4, 16, 64, 256), "elements each work-item writes"),
    ],
    doc="Fill an array (or its first n elements) with one value.",
    defaults=lambda traits: {"dtype": "uint", **_strip(Fill.default_params(traits))},
)


def _strip(params):
    return {k: v for k, v in params.items() if k != "shape"}


class Fill(Primitive):
    """``Fill(runtime, dtype)(array, value, n=None)``."""

    family = "fill"
    TEMPLATES = {"gpu": TEMPLATE, "cpu": TEMPLATE}

    def __init__(self, runtime, dtype=np.uint32, *, params=None):
        self.dtype = np.dtype(dtype) if dtype is not None else None
        self.type_name = cl_type(dtype, "Fill dtype")
        super().__init__(runtime, params)

    @property
    def variant(self) -> str:
        return self.type_name

    def template_values(self):
        return {"dtype": self.type_name}

    @classmethod
    def default_params(cls, traits: DeviceTraits, shape: str | None = None):
        """Heuristics (device counts only): GPU 256 x 4 coalesced stores; CPU 64 x 256
        (PoCL vectorises across the 64 work-items, each group fills 64 KiB)."""
        if (shape or traits.kind) == "gpu":
            return {
                "shape": "gpu",
                "work_group_size": min(256, traits.max_work_group_size),
                "items_per_thread": 4,
            }
        return {
            "shape": "cpu",
            "work_group_size": min(64, traits.max_work_group_size),
            "items_per_thread": 256,
        }

    def __call__(self, array, value, n=None):
        buf = check_array(self.runtime, array, "array", self.dtype)
        capacity, device_count = resolve_count(self.runtime, n, array.size)
        if capacity == 0:
            return None
        if device_count is None:
            # the count is known here: the driver's own fill is the fastest kernel there is
            pattern = self.dtype.type(value)
            return cl.enqueue_fill_buffer(
                self.runtime.queue, buf, pattern, 0, capacity * self.dtype.itemsize
            )
        params, program = self.program(capacity)
        wg = params["work_group_size"]
        groups = ceil_div(capacity, wg * params["items_per_thread"])
        kernel = program.kernel("fill")
        self.runtime.bound(kernel).bind(
            buf, self.dtype.type(value), np.uint32(capacity), device_count
        )
        return self.runtime.launch(kernel, groups * wg, wg)


def search_space(traits: DeviceTraits) -> list[dict]:
    space = [Fill.default_params(traits)]
    shape = traits.kind
    shapes = ((64, 256), (64, 16), (64, 1)) if shape == "cpu" else ((256, 1), (256, 4), (256, 16))
    for wg, ipt in shapes:
        p = {
            "shape": shape,
            "work_group_size": min(wg, traits.max_work_group_size),
            "items_per_thread": ipt,
        }
        if p not in space:
            space.append(p)
    return space
