"""Reductions (sum, min, max) of uint32, int32 or float32 arrays to one value.

The result lands in a device array of one element, so a following step can
use it without a round trip. The reduction of no elements is the operation's
identity: 0 for sums, the type's largest value for min (+inf for floats) and
its smallest for max (-inf for floats). Integer sums wrap modulo 2^32.
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..codegen import Param, work_group_size_param
from ..device import DeviceTraits
from ..errors import RbgenError
from ._base import (
    Primitive,
    PrimitiveTemplate,
    ceil_div,
    check_array,
    cl_type,
    default_work_items,
    resolve_count,
)

OPS = ("sum", "min", "max")
_DTYPE = Param("dtype", ("uint", "int", "float"), "element type")
_OP = Param("op", OPS, "the associative operation")

TILED = PrimitiveTemplate(
    "primitives/reduce_tiled.cl.mako",
    [
        _DTYPE,
        _OP,
        work_group_size_param("work-items per tile (tree reduction in local memory)"),
        Param(
            "items_per_thread",
            (1, 2, 4, 8, 16, 32),
            "elements each work-item combines before the tree",
        ),
    ],
    doc="Reduction, GPU shape: tile partials, then one work group.",
    defaults=lambda traits: {
        "dtype": "float",
        "op": "sum",
        "work_group_size": 256,
        "items_per_thread": 16,
    },
)

CHUNKED = PrimitiveTemplate(
    "primitives/reduce_chunked.cl.mako",
    [
        _DTYPE,
        _OP,
        Param(
            "work_items",
            lambda v: isinstance(v, int) and 1 <= v <= 4096,
            "chunks (one work-item each): a small multiple of the compute units",
            "an int from 1 to 4096",
        ),
    ],
    doc="Reduction, CPU shape: chunk partials with private accumulators, then one work-item.",
    defaults=lambda traits: {
        "dtype": "float",
        "op": "sum",
        "work_items": default_work_items(traits),
    },
)


class Reduce(Primitive):
    """``Reduce(runtime, dtype, op="sum"|"min"|"max")(src, out, n=None)``; out: device array(1)."""

    family = "reduce"
    TEMPLATES = {"gpu": TILED, "cpu": CHUNKED}

    def __init__(self, runtime, dtype=np.float32, op: str = "sum", *, params=None):
        if op not in OPS:
            raise RbgenError(f"op must be one of {list(OPS)}, got {op!r}")
        self.dtype = np.dtype(dtype) if dtype is not None else None
        self.type_name = cl_type(dtype, "Reduce dtype")
        self.op = op
        super().__init__(runtime, params)
        self._partials = None

    @property
    def variant(self) -> str:
        return f"{self.op}-{self.type_name}"

    def template_values(self):
        return {"dtype": self.type_name, "op": self.op}

    @classmethod
    def default_params(cls, traits: DeviceTraits, shape: str | None = None):
        """Heuristics: GPU tiles of 256 x 16 (few partials, one tree per 4096
        elements); CPU four chunks per compute unit."""
        if (shape or traits.kind) == "gpu":
            return {
                "shape": "gpu",
                "work_group_size": min(256, traits.max_work_group_size),
                "items_per_thread": 16,
            }
        return {"shape": "cpu", "work_items": default_work_items(traits)}

    def __call__(self, src, out, n=None):
        buf_src = check_array(self.runtime, src, "src", self.dtype)
        buf_out = check_array(self.runtime, out, "out", self.dtype, min_size=1)
        capacity, device_count = resolve_count(self.runtime, n, src.size)
        params, program = self.program(capacity)
        rt, cap = self.runtime, np.uint32(capacity)
        if params["shape"] == "gpu":
            wg = params["work_group_size"]
            groups = max(1, ceil_div(capacity, wg * params["items_per_thread"]))
            global_size, local_size = groups * wg, wg
        else:
            groups = params["work_items"]
            global_size, local_size = groups, 1
        if self._partials is None or self._partials.size < 4 * groups:
            self._partials = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE, 4 * groups)
        k_tiles = program.kernel("reduce_tiles" if params["shape"] == "gpu" else "reduce_chunks")
        k_final = program.kernel("reduce_partials")
        rt.bound(k_tiles).bind(buf_src, cap, device_count, self._partials)
        rt.launch(k_tiles, global_size, local_size)
        if params["shape"] == "gpu":
            rt.bound(k_final).bind(self._partials, cap, device_count, buf_out)
            return rt.launch(k_final, local_size, local_size)
        rt.bound(k_final).bind(self._partials, buf_out)
        return rt.launch(k_final, 1, 1)


def search_space(traits: DeviceTraits) -> list[dict]:
    space = [Reduce.default_params(traits)]
    if traits.is_gpu:
        for wg in (128, 256, 512):
            for ipt in (4, 16, 32):
                if wg <= traits.max_work_group_size:
                    space.append({"shape": "gpu", "work_group_size": wg, "items_per_thread": ipt})
    else:
        cu = max(1, traits.compute_units)
        space += [{"shape": "cpu", "work_items": k * cu} for k in (1, 2, 4, 8, 16)]
    return _unique(space)


def _unique(space):
    out = []
    for p in space:
        if p not in out:
            out.append(p)
    return out
