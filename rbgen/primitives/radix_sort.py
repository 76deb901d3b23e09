"""Stable LSD radix sort of uint32 keys, optionally carrying uint32 values.

One pass per digit of ``radix_bits`` bits over the low ``key_bits`` bits of
the keys (bits above are ignored): count digits per tile (GPU shapes) or per
chunk (CPU shape) into a digit-major table, scan the table with `Scan`, then
scatter each tile/chunk stably. Three shapes share that loop and differ in how
a tile is ranked: ``"gpu"`` (radix_sort_tiled) keeps RADIX counters per
work-item, cheap for 4-bit digits only; ``"split"`` (radix_sort_split) sorts
the tile in local memory by one or two 4-bit splits with packed counters, so
8-bit digits (half the passes, half the launches) cost little local memory;
``"cpu"`` (radix_sort_chunked) walks long chunks serially. Passes ping-pong
between the caller's arrays and scratch arrays owned by the sorter; after an
odd number of passes a copy brings the result back, so the sort is in place.
Only the first n elements are read or written. Float keys sort through
`float_to_sortable_uint`.
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ..codegen import compile_spec, Param, power_of_two, work_group_size_param
from ..device import DeviceTraits
from ..errors import RbgenError
from ._base import (PrimitiveTemplate, Primitive, ceil_div, check_array, clamp_wavefront,
                    resolve_count, unique_params)
from .scan import Scan

#: the shape GPUs get by default ("split": 8-bit digits ranked by two 4-bit
#: splits, half the passes of "gpu"'s 4-bit digits); one place to flip it
GPU_DEFAULT_SHAPE = "split"

_WITH_VALUES = Param("with_values", (True, False), "move a uint value with every key")
_WAVEFRONT = Param("wavefront", (32, 64), "segment width of the work-group scan")


class _TileTemplate(PrimitiveTemplate):
    """The tile shapes also include the kernels they share."""

    INCLUDES = PrimitiveTemplate.INCLUDES + ("primitives/radix_sort_tiles.cl.mako",)


TILED = _TileTemplate(
    "primitives/radix_sort_tiled.cl.mako",
    [
        _WITH_VALUES,
        Param("radix_bits", (4, 8),
              "bits per pass: 8 halves the passes but needs 16x the local counters"),
        Param("work_group_size", power_of_two(32, 1024),
              "work-items per tile; RADIX * WG counters must fit in local memory",
              "a power of two from 32 to 1024, at least the wavefront"),
        Param("items_per_thread", (1, 2, 4, 8, 16, 32),
              "consecutive keys ranked serially by each work-item"),
        _WAVEFRONT,
        Param("counter_type", ("uint", "ushort"),
              "local rank counters: ushort halves their local memory (tiles < 65536 keys)"),
    ],
    doc="Radix sort pass kernels, GPU shape: tile histograms and stable tile scatter.",
    roles={"keys": "inout"},
    defaults=lambda traits: _template_defaults(traits, "gpu"),
)

SPLIT = _TileTemplate(
    "primitives/radix_sort_split.cl.mako",
    [
        _WITH_VALUES,
        Param("radix_bits", (4, 8),
              "bits per pass, ranked by one or two 4-bit splits of the tile: 8 halves the passes"),
        Param("work_group_size", power_of_two(32, 1024),
              "work-items per tile; 8 packed counters each, plus the tile, in local memory",
              "a power of two from 32 to 1024, at least the wavefront"),
        Param("items_per_thread", (1, 2, 4, 8, 16, 32),
              "consecutive keys ranked serially by each work-item: amortises the scans"),
        _WAVEFRONT,
    ],
    doc="Radix sort pass kernels, GPU shape: tile histograms, tile sorted by 4-bit splits.",
    roles={"keys": "inout"},
    defaults=lambda traits: _template_defaults(traits, "split"),
)

CHUNKED = PrimitiveTemplate(
    "primitives/radix_sort_chunked.cl.mako",
    [
        _WITH_VALUES,
        Param("radix_bits", (4, 8, 11),
              "bits per pass: private histograms of 2^11 counters still fit a CPU's L1"),
        Param("work_items", lambda v: isinstance(v, int) and 1 <= v <= 4096,
              "chunks (one work-item each): a small multiple of the compute units",
              "an int from 1 to 4096"),
    ],
    doc="Radix sort pass kernels, CPU shape: private chunk histograms, sequential scatter.",
    defaults=lambda traits: _template_defaults(traits, "cpu"),
)


class RadixSort(Primitive):
    """``RadixSort(runtime, key_bits=32, with_values=True)(keys, values=None, n=None)``.

    Sorts ``keys`` (uint32 pyopencl array) in place, stably, by their low
    ``key_bits`` bits, moving ``values`` along when built ``with_values``.
    ``n``: None (all keys), a host int or a device uint32 count.
    """

    family = "radix_sort"
    TEMPLATES = {"gpu": TILED, "split": SPLIT, "cpu": CHUNKED}

    def __init__(self, runtime, key_bits: int = 32, with_values: bool = True, *, params=None):
        if isinstance(key_bits, bool) or not isinstance(key_bits, (int, np.integer)) \
                or not 1 <= key_bits <= 32:
            raise RbgenError(f"key_bits must be an int from 1 to 32, got {key_bits!r}")
        self.key_bits = int(key_bits)
        self.with_values = bool(with_values)
        super().__init__(runtime, params)
        self.scan = Scan(runtime, np.uint32, inclusive=False)
        self._scratch: dict[str, cl.Buffer] = {}

    @property
    def variant(self) -> str:
        return "kv" if self.with_values else "keys"

    def template_values(self):
        return {"with_values": self.with_values}

    def _spec_for(self, params):
        params = self.template_params(params)
        if params.get("shape") != "split":
            return super()._spec_for(params)
        # "split" is a shape of this primitive only (the shared check knows gpu and cpu)
        values = {k: v for k, v in params.items() if k != "shape"}
        if values.get("work_group_size", 0) < values.get("wavefront", 0):
            raise RbgenError(f"params: work_group_size={values.get('work_group_size')} is smaller "
                             f"than wavefront={values['wavefront']}")
        return SPLIT.spec(**values, **self.template_values())

    @staticmethod
    def template_params(params: dict) -> dict:
        """Tunable params plus the derived ``counter_type`` of the GPU shape."""
        params = dict(params)
        if params.get("shape") == "gpu":
            tile = params["work_group_size"] * params["items_per_thread"]
            if tile > 65536:
                raise RbgenError(f"params: a tile of {tile} keys exceeds 65536")
            params["counter_type"] = "ushort" if params["radix_bits"] == 8 else "uint"
        return params

    @classmethod
    def default_params(cls, traits: DeviceTraits, shape: str | None = None):
        """Heuristics. GPUs get `GPU_DEFAULT_SHAPE`: "split" sorts 8-bit digits
        (four passes over 32-bit keys) in tiles of 256 x 16 keys (a 33 KiB tile
        of keys and values plus 8 KiB of packed counters fit 48 KiB of local
        memory; 256 x 8 where less is available); "gpu" 4-bit digits over tiles
        of 256 x 8 keys (16 KiB of rank counters plus the 17 KiB tile). CPUs:
        8-bit digits (four passes, a 1 KiB private histogram) in one chunk per CU."""
        shape = shape or (GPU_DEFAULT_SHAPE if traits.is_gpu else "cpu")
        wf = clamp_wavefront(traits)
        wg = max(wf, min(256, traits.max_work_group_size))
        if shape == "split":
            items = 16 if split_local_bytes(wg, 16) <= _usable_local(traits) else 8
            return {"shape": "split", "radix_bits": 8, "work_group_size": wg,
                    "items_per_thread": items, "wavefront": wf}
        if shape == "gpu":
            return {"shape": "gpu", "radix_bits": 4, "work_group_size": wg,
                    "items_per_thread": 8, "wavefront": wf}
        # one chunk per compute unit: each chunk scatters to RADIX output streams,
        # and more streams than the caches hold slow the scatter down
        return {"shape": "cpu", "radix_bits": 8, "work_items": max(1, traits.compute_units)}

    def _buffer(self, name: str, count: int) -> cl.Buffer:
        buf = self._scratch.get(name)
        if buf is None or buf.size < 4 * count:
            buf = self._scratch[name] = cl.Buffer(self.runtime.context, cl.mem_flags.READ_WRITE,
                                                  4 * max(count, 1))
        return buf

    def __call__(self, keys, values=None, n=None):
        buf_keys = check_array(self.runtime, keys, "keys", np.uint32)
        if self.with_values:
            if values is None:
                raise RbgenError("values is required: this RadixSort was built with_values=True")
            buf_values = check_array(self.runtime, values, "values", np.uint32)
            if values.size < keys.size:
                raise RbgenError(f"values holds {values.size} elements, shorter than keys "
                                 f"({keys.size})")
        elif values is not None:
            raise RbgenError("values given, but this RadixSort was built with_values=False")
        else:
            buf_values = None
        capacity, device_count = resolve_count(self.runtime, n, keys.size)
        return self.enqueue(buf_keys, buf_values, capacity, device_count)

    def enqueue(self, keys, values, capacity: int, device_count):
        """Sort raw buffers (arguments already checked)."""
        if capacity == 0:
            return None
        params, program = self.program(capacity)
        rt, cap = self.runtime, np.uint32(capacity)
        bits = params["radix_bits"]
        if params["shape"] in ("gpu", "split"):
            wg = params["work_group_size"]
            groups = ceil_div(capacity, wg * params["items_per_thread"])
            global_size, local_size = groups * wg, wg
        else:
            groups = params["work_items"]
            global_size, local_size = groups, 1
        table = self._buffer("table", groups << bits)
        pair = [(keys, values), (self._buffer("keys", capacity),
                                 self._buffer("values", capacity) if values is not None else None)]
        count, scatter, copy = (program.kernel(k) for k in
                                ("count_digits", "scatter_digits", "copy_back"))
        passes = ceil_div(self.key_bits, bits)
        event = None
        for p in range(passes):
            shift = p * bits
            mask = np.uint32((1 << min(bits, self.key_bits - shift)) - 1)
            (k_in, v_in), (k_out, v_out) = pair[p % 2], pair[1 - p % 2]
            rt.bound(count).bind(k_in, cap, device_count, np.uint32(shift), mask, table)
            rt.launch(count, global_size, local_size)
            self.scan.enqueue(table, table, groups << bits, None, None)
            vals = (v_in, v_out) if values is not None else ()
            rt.bound(scatter).bind(k_in, k_out, *vals, cap, device_count, np.uint32(shift), mask,
                                   table)
            event = rt.launch(scatter, global_size, local_size)
        if passes % 2:
            (k_in, v_in), (k_out, v_out) = pair[1], pair[0]
            vals = (v_in, v_out) if values is not None else ()
            rt.bound(copy).bind(k_in, k_out, *vals, cap, device_count)
            event = rt.launch(copy, global_size, local_size)
        return event


def _template_defaults(traits: DeviceTraits, shape: str) -> dict:
    params = RadixSort.template_params(RadixSort.default_params(traits, shape))
    params.pop("shape")
    return {"with_values": True, **params}


FLOAT_KEYS = PrimitiveTemplate(
    "primitives/sortable_float.cl.mako",
    [work_group_size_param("elements per work group; memory-bound")],
    doc="Order-preserving float32 <-> uint32 key flips.",
    defaults=lambda traits: {"work_group_size": 64},
)


def float_to_sortable_uint(x, runtime=None):
    """Order-preserving map of float32 to uint32 keys.

    Flip every bit of negative floats and only the sign bit of the others: then
    unsigned order equals float order (-0.0 sorts just below +0.0; NaNs with the
    sign bit clear sort after +inf). Takes a numpy array (returns numpy) or a
    pyopencl array (returns a new device array; ``runtime`` is then required).
    `sortable_uint_to_float` inverts it.
    """
    if isinstance(x, cla.Array):
        return _flip_on_device(runtime, x, np.float32, "float_to_sortable", np.uint32)
    bits = _host_bits(x, np.float32, "x")
    return bits ^ np.where(bits >> 31, np.uint32(0xFFFFFFFF), np.uint32(0x80000000))


def sortable_uint_to_float(u, runtime=None):
    """Inverse of `float_to_sortable_uint` (numpy or pyopencl arrays)."""
    if isinstance(u, cla.Array):
        return _flip_on_device(runtime, u, np.uint32, "sortable_to_float", np.float32)
    bits = _host_bits(u, np.uint32, "u")
    return (bits ^ np.where(bits >> 31, np.uint32(0x80000000), np.uint32(0xFFFFFFFF))
            ).view(np.float32)


def _host_bits(x, dtype, name):
    x = np.asarray(x)
    if x.dtype != np.dtype(dtype):
        raise RbgenError(f"{name} has dtype {x.dtype}, expected {np.dtype(dtype)}")
    return x.view(np.uint32)


def _flip_on_device(runtime, array, dtype, kernel_name, out_dtype):
    if runtime is None:
        raise RbgenError("runtime is required to convert a device array")
    src = check_array(runtime, array, "keys", dtype)
    out = cla.empty(runtime.queue, array.shape, out_dtype)
    if array.size:
        wg = 64
        kernel = compile_spec(runtime, FLOAT_KEYS.spec(work_group_size=wg)).kernel(kernel_name)
        runtime.bound(kernel).bind(src, out.base_data, np.uint32(array.size))
        runtime.launch(kernel, ceil_div(array.size, wg) * wg, wg)
    return out


def split_local_bytes(work_group_size: int, items_per_thread: int, radix_bits: int = 8,
                      with_values: bool = True) -> int:
    """Local memory of the split shape's scatter kernel: the padded tile (keys and
    values), 8 packed counters per work-item, per-digit bases, scan scratch."""
    padded = lambda words: words + words // 32  # noqa: E731
    tile = padded(work_group_size * items_per_thread) * (2 if with_values else 1)
    return 4 * (tile + padded(8 * work_group_size) + (1 << radix_bits) + 2 * work_group_size
                + work_group_size // 32 + 1)


def _usable_local(traits: DeviceTraits) -> int:
    """Local memory a sort kernel may plan for (a little left to the compiler)."""
    return traits.local_mem_size - 1024


def search_space(traits: DeviceTraits) -> list[dict]:
    """Candidate parameters the tuner tries on a device (heuristic default first)."""
    space = [RadixSort.default_params(traits)]
    cu = max(1, traits.compute_units)
    if traits.is_gpu:
        wf = clamp_wavefront(traits)
        for bits, wg, ipt in ((8, 128, 16), (8, 256, 8), (8, 256, 16), (8, 512, 4), (8, 512, 8),
                              (8, 1024, 4), (4, 256, 16)):
            if wf <= wg <= traits.max_work_group_size \
                    and split_local_bytes(wg, ipt, bits) <= _usable_local(traits):
                space.append({"shape": "split", "radix_bits": bits, "work_group_size": wg,
                              "items_per_thread": ipt, "wavefront": wf})
        for bits, wg, ipt in ((4, 128, 8), (4, 128, 16), (4, 256, 4), (4, 256, 8), (4, 512, 4),
                              (8, 64, 8), (8, 64, 16), (8, 128, 4)):
            # rank counters + the tile's keys and values (padded 1/32) + scan scratch
            local = (wg << bits) * (2 if bits == 8 else 4) + 2 * 4 * (wg * ipt * 33 // 32) + 12 * wg
            if wf <= wg <= traits.max_work_group_size and local <= traits.local_mem_size - 2048:
                space.append({"shape": "gpu", "radix_bits": bits, "work_group_size": wg,
                              "items_per_thread": ipt, "wavefront": wf})
    else:
        for bits in (8, 11):
            for k in (1, 2, 4, 8):
                space.append({"shape": "cpu", "radix_bits": bits, "work_items": k * cu})
    return unique_params(space)
