"""Prefix sums (inclusive or exclusive) of uint32, int32 or float32 arrays.

Two algorithms:

* reduce-then-scan, always available and the heuristic default: three
  launches, in either shape (see `_base`): a GPU shape over tiles of
  ``work_group_size * items_per_thread`` elements and a CPU shape over a few
  long chunks. It reads the input twice (3n words moved).
* the chained scan (``scan_chained.cl.mako``): ONE launch for any n, input
  read once (2n words). It relies on forward progress between work groups
  (and, with ``order="group"``, on groups starting in id order), so it runs
  only where its guard (`chained_scan_works`) passed, and only
  when asked for (``chained=True``) or chosen by the tuner (its candidates
  are part of the ``scan`` family's space). Its state persists between calls
  with a new epoch per call instead of being zeroed. A tile looks back over
  up to ``lookback`` predecessors per step (one per work-item, GPU shape).

The optional total (sum of the first n elements) is written to a device array
so that a following step can use it without a round trip. Integer sums wrap
modulo 2^32 like C.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ..codegen import Param, power_of_two
from ..device import INT64_ATOMICS, DeviceTraits
from ..errors import RbgenError
from ._base import (
    Primitive,
    PrimitiveTemplate,
    ceil_div,
    check_array,
    cl_type,
    clamp_wavefront,
    default_work_items,
    device_check,
    resolve_count,
    tiled_or_chunked_space,
    unique_params,
)

DTYPES = ("uint", "int", "float")

_DTYPE = Param("dtype", DTYPES, "element type; sums wrap (integers) or round (float) like C")
_INCLUSIVE = Param("inclusive", (True, False), "whether element i counts itself")

TILED = PrimitiveTemplate(
    "primitives/scan_tiled.cl.mako",
    [
        _DTYPE,
        _INCLUSIVE,
        Param(
            "work_group_size",
            power_of_two(32, 1024),
            "work-items per tile; larger tiles mean fewer tile sums but more barriers",
            "a power of two from 32 to 1024, at least the wavefront",
        ),
        Param(
            "items_per_thread",
            (1, 2, 4, 8, 16),
            "elements each work-item scans serially: amortises the work-group scan",
        ),
        Param(
            "wavefront",
            (32, 64),
            "segment width of the two-level work-group scan (32 NVIDIA, 64 AMD)",
        ),
    ],
    doc="Prefix sum, GPU shape: reduce tiles, scan tile sums, scan tiles.",
    defaults=lambda traits: {
        "dtype": "uint",
        "inclusive": False,
        **Scan.default_params(traits, shape="gpu", strip=True),
    },
)

CHUNKED = PrimitiveTemplate(
    "primitives/scan_chunked.cl.mako",
    [
        _DTYPE,
        _INCLUSIVE,
        Param(
            "work_items",
            lambda v: isinstance(v, int) and 1 <= v <= 4096,
            "chunks (one work-item each): a small multiple of the compute units",
            "an int from 1 to 4096",
        ),
    ],
    doc="Prefix sum, CPU shape: one long chunk per work-item, private running sums.",
    defaults=lambda traits: {
        "dtype": "uint",
        "inclusive": False,
        **Scan.default_params(traits, shape="cpu", strip=True),
    },
)


CHAINED = PrimitiveTemplate(
    "primitives/scan_chained.cl.mako",
    [
        _DTYPE,
        _INCLUSIVE,
        Param(
            "work_group_size",
            power_of_two(1, 1024),
            "work-items per tile (1 on CPUs: one work-item walks a whole tile)",
            "a power of two from 1 to 1024, at least the wavefront",
        ),
        Param(
            "items_per_thread",
            power_of_two(4, 1 << 16),
            "elements per work-item, loaded as vectors of 4 and kept in registers "
            "(GPU shape: 16-64 hide memory latency; CPU shape: a cache-sized tile)",
            "a power of two from 4 to 65536",
        ),
        Param(
            "wavefront", (1, 32, 64), "segment width of the work-group scan (1: serial, CPU shape)"
        ),
        Param(
            "order",
            ("ticket", "group"),
            "how a work group finds its tile: ticket (atomic counter, start order: safe "
            "in any dispatch order) or group id (no atomic or barrier before the loads; "
            "relies on groups starting in id order, as GPUs do)",
        ),
        Param(
            "lookback",
            power_of_two(1, 1024),
            "predecessors one look-back step polls, one per work-item: a wider window "
            "reaches a tile that knows its prefix in fewer steps (1: serial, CPU shape)",
            "a power of two from 1 to 1024",
        ),
    ],
    doc="Prefix sum in one launch (chained scan, decoupled look-back); opt-in with a guard.",
    # zeroed once at allocation, then carried from call to call (with a new epoch each)
    roles={"state": "inout"},
    defaults=lambda traits: {
        "dtype": "uint",
        "inclusive": False,
        **Scan.default_params(traits, shape="chained", strip=True),
    },
)

#: GPU-shape chained tiles keep every element in registers: at most this many per work-item
CHAINED_MAX_ITEMS = 64
#: the chained scan's epochs run 1 .. EPOCHS - 1 (30 bits beside the 2-bit status)
EPOCHS = 1 << 30


class Scan(Primitive):
    """``Scan(runtime, dtype, inclusive)(src, dst, n=None, total=None)``.

    ``src`` and ``dst`` are pyopencl arrays of ``dtype`` (may be the same);
    ``n`` is None (all of src), a host int or a device uint32 count; ``total``
    an optional device array that receives the sum of the n elements.

    Which algorithm runs: explicit ``params``, else the tuned winner of family
    ``scan`` (which may be the chained scan where its guard passed), else the
    reduce-then-scan heuristic. ``chained=True`` opts in to the single-pass
    chained scan: tuned as family ``scan_chained``, else its heuristic. Any
    chained choice is checked once per device by `chained_scan_works` and falls
    back to reduce-then-scan when that check fails. Calls of one Scan share
    the chained scan's state, so they must run in order (one in-order queue).
    """

    TEMPLATES = {"gpu": TILED, "cpu": CHUNKED, "chained": CHAINED}

    def __init__(
        self,
        runtime,
        dtype=np.uint32,
        inclusive: bool = False,
        *,
        chained: bool = False,
        params=None,
    ):
        self.dtype = np.dtype(dtype) if dtype is not None else None
        self.type_name = cl_type(dtype, "Scan dtype")
        self.inclusive = bool(inclusive)
        #: opt-in single-pass scan; see scan_chained.cl.mako for its guard
        self.chained = bool(chained)
        if params is not None and self.chained and params.get("shape") != "chained":
            raise RbgenError(f"chained=True contradicts params['shape']={params.get('shape')!r}")
        super().__init__(runtime, params)
        self._sums: cl.Buffer | None = None
        #: the chained scan's tile words and the epoch of its last call
        self._state: cl.Buffer | None = None
        self._epoch = 0

    @property
    def family(self) -> str:
        return "scan_chained" if self.chained else "scan"

    @property
    def variant(self) -> str:
        return self.type_name

    def template_values(self):
        return {"dtype": self.type_name, "inclusive": self.inclusive}

    def _spec_for(self, params: dict):
        if params.get("shape") == "chained":
            check_chained_params(params)
        return super()._spec_for(params)

    @classmethod
    def default_params(cls, traits: DeviceTraits, shape: str | None = None, strip=False):
        """Heuristics: GPU tiles of 256 x 8 = 2048 elements (8 KiB of local memory,
        few tile sums); CPU four chunks per compute unit (load balance, tiny
        chunk-sum scan); chained tiles of 256 x 32 = 8192 on GPUs (32 elements
        in registers per work-item: eight 16-byte loads in flight each) looking back a
        wavefront of tiles per step (fewer polls than a look-back of 256),
        tiles by ticket (safe in any dispatch order); 16384 (L2-sized) on CPUs."""
        shape = shape or traits.kind
        params: dict[str, Any]
        if shape == "chained":
            if traits.is_gpu:
                wf = clamp_wavefront(traits)
                wg = max(wf, min(256, traits.max_work_group_size))
                params = {
                    "shape": "chained",
                    "work_group_size": wg,
                    "items_per_thread": 32,
                    "wavefront": wf,
                    "lookback": wf,
                    "order": "ticket",
                }
            else:
                params = {
                    "shape": "chained",
                    "work_group_size": 1,
                    "items_per_thread": 16384,
                    "wavefront": 1,
                    "lookback": 1,
                    "order": "ticket",
                }
        elif shape == "gpu":
            params = {
                "shape": "gpu",
                "work_group_size": min(256, traits.max_work_group_size),
                "items_per_thread": 8,
                "wavefront": clamp_wavefront(traits),
            }
            if params["work_group_size"] < params["wavefront"]:
                params["work_group_size"] = params["wavefront"]
        else:
            params = {"shape": "cpu", "work_items": default_work_items(traits)}
        if strip:
            params.pop("shape")
        return params

    def _scratch(self, count: int):
        if self._sums is None or self._sums.size < 4 * count:
            self._sums = cl.Buffer(self.runtime.context, cl.mem_flags.READ_WRITE, 4 * max(count, 1))
        return self._sums

    def _chained_state(self, tiles: int):
        """The chained scan's state for ``tiles`` tiles and this call's epoch.

        Zeroed only when (re)allocated and when the epoch wraps: every call
        gets a new epoch, which makes the words of earlier calls read as empty."""
        size = 8 * (1 + tiles)
        if self._state is None or self._state.size < size:
            self._state = cl.Buffer(self.runtime.context, cl.mem_flags.READ_WRITE, size)
            self._epoch = EPOCHS - 1  # forces the zeroing below
        self._epoch += 1
        if self._epoch >= EPOCHS:
            cl.enqueue_fill_buffer(
                self.runtime.queue, self._state, np.uint32(0), 0, self._state.size
            )
            self._epoch = 1
        return self._state, np.uint32(self._epoch)

    def __call__(self, src, dst, n=None, total=None):
        buf_src = check_array(self.runtime, src, "src", self.dtype)
        buf_dst = check_array(self.runtime, dst, "dst", self.dtype)
        if dst.size < src.size:
            raise RbgenError(f"dst holds {dst.size} elements, shorter than src ({src.size})")
        buf_total = (
            None
            if total is None
            else check_array(self.runtime, total, "total", self.dtype, min_size=1)
        )
        capacity, device_count = resolve_count(self.runtime, n, src.size)
        return self.enqueue(buf_src, buf_dst, capacity, device_count, buf_total)

    def params_for(self, capacity: int):
        params = super().params_for(capacity)
        if self.chained and self.params_override is None and params.get("shape") != "chained":
            params = self.default_params(self.runtime.traits, "chained")
        return params

    def _checked(self, params: dict, capacity: int) -> dict:
        """A chained scan must pass its guard, else reduce-then-scan."""
        if params["shape"] == "chained" and not chained_scan_works(self.runtime, params):
            return self.default_params(self.runtime.traits)
        return params

    def enqueue(self, src, dst, capacity: int, device_count, total):
        """Launch on raw buffers (arguments already checked); used by other primitives."""
        params, program = self.program(capacity)
        rt, cap = self.runtime, np.uint32(capacity)
        if params["shape"] == "chained":  # one launch
            wg = params["work_group_size"]
            tiles = max(1, ceil_div(capacity, wg * params["items_per_thread"]))
            state, epoch = self._chained_state(tiles)
            kernel = program.kernel("scan_chained")
            rt.bound(kernel).bind(src, dst, cap, device_count, state, epoch, total)
            return rt.launch(kernel, tiles * wg, wg)
        if params["shape"] == "gpu":
            wg = params["work_group_size"]
            tiles = max(1, ceil_div(capacity, wg * params["items_per_thread"]))
            sums = self._scratch(tiles)
            k_reduce, k_sums, k_scan = (
                program.kernel(k) for k in ("reduce_tiles", "scan_tile_sums", "scan_tiles")
            )
            rt.bound(k_reduce).bind(src, cap, device_count, sums)
            rt.bound(k_sums).bind(sums, cap, device_count, total)
            rt.bound(k_scan).bind(src, dst, cap, device_count, sums)
            rt.launch(k_reduce, tiles * wg, wg)
            rt.launch(k_sums, wg, wg)
            return rt.launch(k_scan, tiles * wg, wg)
        chunks = params["work_items"]
        sums = self._scratch(chunks)
        k_reduce, k_sums, k_scan = (
            program.kernel(k) for k in ("reduce_chunks", "scan_chunk_sums", "scan_chunks")
        )
        rt.bound(k_reduce).bind(src, cap, device_count, sums)
        rt.bound(k_sums).bind(sums, total)
        rt.bound(k_scan).bind(src, dst, cap, device_count, sums)
        rt.launch(k_reduce, chunks, 1)
        rt.launch(k_sums, 1, 1)
        return rt.launch(k_scan, chunks, 1)


def check_chained_params(params: dict) -> None:
    """Constraints between the chained template's parameters (each is checked
    alone by the template): the CPU shape is one serial work-item; the GPU
    shape keeps a work-item's elements in registers and polls at most one
    predecessor per work-item, at least a wavefront's worth."""
    wg, ipt, wf, lb = (
        params.get(k) for k in ("work_group_size", "items_per_thread", "wavefront", "lookback")
    )
    if (wg == 1) != (wf == 1):
        raise RbgenError(
            f"params: chained scan with work_group_size={wg} and wavefront={wf}; "
            f"wavefront 1 goes with work_group_size 1 (CPU shape) only"
        )
    if wg == 1 and lb != 1:
        raise RbgenError(
            f"params: lookback={lb} with work_group_size 1; the serial CPU shape "
            f"looks back one tile at a time (lookback 1)"
        )
    if (
        wg != 1
        and wg is not None
        and isinstance(lb, int)
        and isinstance(wf, int)
        and not wf <= lb <= wg
    ):
        raise RbgenError(
            f"params: lookback={lb} must lie between wavefront={wf} and "
            f"work_group_size={wg} (one polled predecessor per work-item)"
        )
    if wg != 1 and isinstance(ipt, int) and ipt > CHAINED_MAX_ITEMS:
        raise RbgenError(
            f"params: items_per_thread={ipt} is more than the "
            f"{CHAINED_MAX_ITEMS} a chained work-item keeps in registers"
        )


#: the extension the chained scan's 64-bit tile words need
CHAINED_EXTENSION = INT64_ATOMICS


def chained_scan_works(runtime, params: dict) -> bool:
    """The chained scan's guard (a `device_check`): the device must offer 64-bit
    atomics, and two scans in a row (the second shorter, so that the first
    one's words are stale) on many-tile inputs must match numpy without
    hitting the spin limit. A failure warns and makes callers fall back."""
    return device_check(runtime, "chained scan", params, _probe_chained, "reduce-then-scan")


def _probe_chained(runtime, params: dict) -> tuple[bool, str]:
    if not runtime.has_extension(CHAINED_EXTENSION):
        return False, f"no {CHAINED_EXTENSION}"
    tile = params["work_group_size"] * params["items_per_thread"]
    rng = np.random.default_rng(12345)
    probe = Scan(runtime, np.uint32, inclusive=False, params=params)
    try:
        for n in (6 * tile + 3, 4 * tile + 1):
            x = rng.integers(0, 8, n).astype(np.uint32)
            src = cla.to_device(runtime.queue, x)
            dst = cla.empty_like(src)
            probe(src, dst)
            expected = np.concatenate([[0], np.cumsum(x, dtype=np.uint32)[:-1]])
            if not np.array_equal(dst.get(), expected):
                return False, f"wrong result at n={n}"
    except (cl.Error, RbgenError) as err:  # a build or launch failure: fall back too
        return False, f"{type(err).__name__}: {err}"[:300]
    flags = np.empty(2, np.uint32)
    assert probe._state is not None  # the chained probe calls above allocated it
    cl.enqueue_copy(runtime.queue, flags, probe._state, is_blocking=True)
    return (flags[1] == 0, "spin limit hit")


def chained_search_space(traits: DeviceTraits) -> list[dict]:
    """Candidates for the chained scan (family ``scan_chained``; also in `search_space`).

    GPU: 128-1024 work-items with 16-64 elements each in registers, looking
    back one predecessor per work-item; then the default tile looking back a
    whole work group of tiles at a time (the wide window, for comparison) and taking the
    tile of its group id instead of a ticket; CPU: one work-item per tile of
    4096-65536 elements (tickets)."""
    default = Scan.default_params(traits, "chained")
    space = [default]
    if traits.is_gpu:
        wf = clamp_wavefront(traits)
        for wg, ipt in (
            (256, 16),
            (256, 64),
            (128, 32),
            (128, 64),
            (512, 16),
            (512, 32),
            (1024, 16),
        ):
            if wf <= wg <= traits.max_work_group_size:
                space.append(dict(default, work_group_size=wg, items_per_thread=ipt, lookback=wg))
        space.append(dict(default, lookback=default["work_group_size"]))
        space.append(dict(default, order="group"))
    else:
        for ipt in (4096, 65536):
            space.append(dict(default, items_per_thread=ipt))
    return unique_params(space)


def search_space(traits: DeviceTraits) -> list[dict]:
    """Candidate parameters the tuner tries on a device (heuristic default first):
    reduce-then-scan in the device's shape, then the chained scan's candidates
    (the tuner rejects those where the guard fails)."""
    return tiled_or_chunked_space(Scan.default_params(traits), traits) + chained_search_space(
        traits
    )
