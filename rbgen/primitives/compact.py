"""Stream compaction: indices (or values) of the flagged elements, in order.

``Compact(runtime)(flags, out, out_count, n=None, values=None)`` writes to
``out`` the indices i < n with ``flags[i] != 0`` in increasing order (or
``values[i]`` for those i when ``values`` is given) and leaves their number in
``out_count[0]`` on the device: nothing is read back. ``out`` must hold n
elements (the most that can be kept). Count, scan the counts, scatter: the
same reduce-then-scan structure as `Scan`, in a GPU and a CPU shape.
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..codegen import Param, power_of_two
from ..device import DeviceTraits
from ..errors import RbgenError
from ._base import (
    Primitive,
    PrimitiveTemplate,
    ceil_div,
    check_array,
    clamp_wavefront,
    default_work_items,
    resolve_count,
    tiled_or_chunked_space,
)

_GATHER = Param(
    "gather_values", (True, False), "write values[i] of kept elements instead of their index i"
)

TILED = PrimitiveTemplate(
    "primitives/compact_tiled.cl.mako",
    [
        _GATHER,
        Param(
            "work_group_size",
            power_of_two(32, 1024),
            "work-items per tile",
            "a power of two from 32 to 1024, at least the wavefront",
        ),
        Param("items_per_thread", (1, 2, 4, 8, 16), "consecutive flags per work-item"),
        Param("wavefront", (32, 64), "segment width of the work-group scan"),
    ],
    doc="Stream compaction, GPU shape: count tiles, scan counts, scatter tiles.",
    defaults=lambda traits: {
        "gather_values": False,
        **_strip(Compact.default_params(traits, "gpu")),
    },
)

CHUNKED = PrimitiveTemplate(
    "primitives/compact_chunked.cl.mako",
    [
        _GATHER,
        Param(
            "work_items",
            lambda v: isinstance(v, int) and 1 <= v <= 4096,
            "chunks (one work-item each): a small multiple of the compute units",
            "an int from 1 to 4096",
        ),
    ],
    doc="Stream compaction, CPU shape: one long chunk per work-item.",
    defaults=lambda traits: {
        "gather_values": False,
        **_strip(Compact.default_params(traits, "cpu")),
    },
)


def _strip(params):
    return {k: v for k, v in params.items() if k != "shape"}


class Compact(Primitive):
    """``Compact(runtime)(flags, out, out_count, n=None, values=None)``."""

    family = "compact"
    TEMPLATES = {"gpu": TILED, "cpu": CHUNKED}

    def __init__(self, runtime, *, params=None):
        self._gathering = False  # set per call: values given or not
        super().__init__(runtime, params)
        self._counts = None

    @property
    def variant(self) -> str:
        return "indices"

    def template_values(self):
        return {"gather_values": self._gathering}

    @classmethod
    def default_params(cls, traits: DeviceTraits, shape: str | None = None):
        """Heuristics as for `Scan`: GPU tiles of 256 x 8 flags, CPU four chunks per CU."""
        if (shape or traits.kind) == "gpu":
            wf = clamp_wavefront(traits)
            return {
                "shape": "gpu",
                "work_group_size": max(wf, min(256, traits.max_work_group_size)),
                "items_per_thread": 8,
                "wavefront": wf,
            }
        return {"shape": "cpu", "work_items": default_work_items(traits)}

    def __call__(self, flags, out, out_count, n=None, values=None):
        rt = self.runtime
        buf_flags = check_array(rt, flags, "flags", np.uint32)
        capacity, device_count = resolve_count(rt, n, flags.size)
        buf_out = check_array(rt, out, "out", np.uint32, min_size=capacity)
        buf_count = check_array(rt, out_count, "out_count", np.uint32, min_size=1)
        buf_values = None
        if values is not None:
            buf_values = check_array(rt, values, "values", np.uint32)
            if values.size < capacity:
                raise RbgenError(
                    f"values holds {values.size} elements, shorter than flags ({capacity})"
                )
        self._gathering = values is not None
        params, program = self.program(capacity)
        cap = np.uint32(capacity)
        if params["shape"] == "gpu":
            wg = params["work_group_size"]
            groups = max(1, ceil_div(capacity, wg * params["items_per_thread"]))
            global_size, local_size = groups * wg, wg
            names = ("count_tiles", "scan_tile_counts", "scatter_tiles")
        else:
            groups = params["work_items"]
            global_size, local_size = groups, 1
            names = ("count_chunks", "scan_chunk_counts", "scatter_chunks")
        if self._counts is None or self._counts.size < 4 * groups:
            self._counts = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE, 4 * groups)
        k_count, k_scan, k_scatter = (program.kernel(k) for k in names)
        rt.bound(k_count).bind(buf_flags, cap, device_count, self._counts)
        rt.launch(k_count, global_size, local_size)
        if params["shape"] == "gpu":
            rt.bound(k_scan).bind(self._counts, cap, device_count, buf_count)
            rt.launch(k_scan, local_size, local_size)
        else:
            rt.bound(k_scan).bind(self._counts, buf_count)
            rt.launch(k_scan, 1, 1)
        gathered = (buf_values,) if values is not None else ()
        extra = (buf_count,) if params["shape"] == "cpu" else ()
        rt.bound(k_scatter).bind(
            buf_flags, *gathered, buf_out, cap, device_count, self._counts, *extra
        )
        return rt.launch(k_scatter, global_size, local_size)


def search_space(traits: DeviceTraits) -> list[dict]:
    """Candidate parameters the tuner tries on a device (heuristic default first)."""
    return tiled_or_chunked_space(Compact.default_params(traits), traits)
