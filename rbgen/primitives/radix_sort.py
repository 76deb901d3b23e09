"""Stable LSD radix sort of uint32 keys, optionally carrying uint32 values.

One pass per digit of ``radix_bits`` bits over the low ``key_bits`` bits of
the keys (bits above are ignored). Four shapes:

- ``"cpu"`` (radix_sort_chunked), ``"gpu"`` (radix_sort_tiled) and ``"split"``
  (radix_sort_split) share one loop per pass: count digits per chunk or tile
  into a digit-major table, scan the table with `Scan`, scatter each chunk or
  tile stably. They differ in the ranking: "cpu" walks long chunks serially;
  "gpu" keeps RADIX counters per work-item, cheap for 4-bit digits only;
  "split" sorts the tile in local memory by one or two 4-bit splits with
  packed counters, so 8-bit digits (half the passes and launches) need little
  local memory.
- ``"onesweep"`` (radix_sort_onesweep) counts every pass's digits once, then
  launches once per pass: tiles rank like "split" and find their output
  offsets by decoupled look-back over earlier tiles' counts. The look-back
  needs forward progress of started work groups, so it is checked once per
  device and parameters (`onesweep_works`); where the check fails, and for
  ``ONESWEEP_MAX_KEYS`` keys or more, the sort uses "split".

GPUs default to `GPU_DEFAULT_SHAPE`. Passes ping-pong between the caller's
arrays and scratch arrays owned by the sorter; after an odd number of passes
a copy brings the result back, so the sort is in place. Only the first n
elements are read or written. Float keys sort through `float_to_sortable_uint`.
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ..codegen import Param, compile_spec, power_of_two, work_group_size_param
from ..device import DeviceTraits
from ..errors import RbgenError
from ._base import (
    Primitive,
    PrimitiveTemplate,
    ceil_div,
    check_array,
    clamp_wavefront,
    device_check,
    resolve_count,
    unique_params,
)
from .scan import Scan

#: the shape GPUs get by default, one place to flip it: "split" (8-bit digits
#: ranked by two 4-bit splits, half the passes of "gpu"'s 4-bit digits);
#: "onesweep" has fewer launches but its guard costs a blocking probe at first use
GPU_DEFAULT_SHAPE = "split"

_WITH_VALUES = Param("with_values", (True, False), "move a uint value with every key")
_WAVEFRONT = Param("wavefront", (32, 64), "segment width of the work-group scan")


def _tile_params(
    radix_bits: str, work_group_size: str, work_group_text: str, items_per_thread: str
) -> list[Param]:
    """The parameters every tile shape takes; the docs say what each shape does with them."""
    return [
        _WITH_VALUES,
        Param("radix_bits", (4, 8), radix_bits),
        Param("work_group_size", power_of_two(32, 1024), work_group_size, work_group_text),
        Param("items_per_thread", (1, 2, 4, 8, 16, 32), items_per_thread),
        _WAVEFRONT,
    ]


class _TileTemplate(PrimitiveTemplate):
    """The tile shapes also include the kernels they share."""

    INCLUDES = PrimitiveTemplate.INCLUDES + ("primitives/radix_sort_tiles.cl.mako",)


TILED = _TileTemplate(
    "primitives/radix_sort_tiled.cl.mako",
    _tile_params(
        "bits per pass: 8 halves the passes but needs 16x the local counters",
        "work-items per tile; RADIX * WG counters must fit in local memory",
        "a power of two from 32 to 1024, at least the wavefront",
        "consecutive keys ranked serially by each work-item",
    )
    + [
        Param(
            "counter_type",
            ("uint", "ushort"),
            "local rank counters: ushort halves their local memory (tiles < 65536 keys)",
        ),
    ],
    doc="Radix sort pass kernels, GPU shape: tile histograms and stable tile scatter.",
    roles={"keys": "inout"},
    defaults=lambda traits: _template_defaults(traits, "gpu"),
)

SPLIT = _TileTemplate(
    "primitives/radix_sort_split.cl.mako",
    _tile_params(
        "bits per pass, ranked by one or two 4-bit splits of the tile: 8 halves the passes",
        "work-items per tile; 8 packed counters each, plus the tile, in local memory",
        "a power of two from 32 to 1024, at least the wavefront",
        "consecutive keys ranked serially by each work-item: amortises the scans",
    ),
    doc="Radix sort pass kernels, GPU shape: tile histograms, tile sorted by 4-bit splits.",
    roles={"keys": "inout"},
    defaults=lambda traits: _template_defaults(traits, "split"),
)

ONESWEEP = _TileTemplate(
    "primitives/radix_sort_onesweep.cl.mako",
    _tile_params(
        "bits per pass, ranked by one or two 4-bit splits of the tile",
        "work-items per tile, at least one per digit (each looks back for its digit)",
        "a power of two from 32 to 1024, at least the wavefront and 2^radix_bits",
        "consecutive keys ranked serially by each work-item: amortises scans and look-back",
    ),
    doc="Radix sort, one launch per pass: digit totals once, tile look-back for tile offsets.",
    roles={"keys": "inout"},
    defaults=lambda traits: _template_defaults(traits, "onesweep"),
)

CHUNKED = PrimitiveTemplate(
    "primitives/radix_sort_chunked.cl.mako",
    [
        _WITH_VALUES,
        Param(
            "radix_bits",
            (4, 8, 11),
            "bits per pass: private histograms of 2^11 counters still fit a CPU's L1",
        ),
        Param(
            "work_items",
            lambda v: isinstance(v, int) and 1 <= v <= 4096,
            "chunks (one work-item each): a small multiple of the compute units",
            "an int from 1 to 4096",
        ),
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
    TEMPLATES = {"gpu": TILED, "split": SPLIT, "onesweep": ONESWEEP, "cpu": CHUNKED}

    def __init__(self, runtime, key_bits: int = 32, with_values: bool = True, *, params=None):
        if (
            isinstance(key_bits, bool)
            or not isinstance(key_bits, (int, np.integer))
            or not 1 <= key_bits <= 32
        ):
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
        shape = params.get("shape")
        if shape not in ("split", "onesweep"):
            return super()._spec_for(params)
        # shapes of this primitive only (the shared check knows gpu and cpu)
        values = {k: v for k, v in params.items() if k != "shape"}
        wg = values.get("work_group_size", 0)
        if wg < values.get("wavefront", 0):
            raise RbgenError(
                f"params: work_group_size={wg} is smaller than wavefront={values['wavefront']}"
            )
        if shape == "onesweep" and wg < 1 << values.get("radix_bits", 0):
            raise RbgenError(
                f"params: work_group_size={wg} is smaller than the "
                f"{1 << values['radix_bits']} digits of a onesweep pass"
            )
        return self.TEMPLATES[shape].spec(**values, **self.template_values())

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
        (four passes over 32-bit keys) in tiles of 256 x 8 keys (256 x 16 needs 45 KiB
        of local memory, which leaves one work group per compute unit); "onesweep" tiles of 256 x 16
        where they fit in local memory, else 256 x 8 (its
        look-back needs a work-item per digit: 4-bit digits on devices whose
        work groups hold fewer than 256); "gpu" 4-bit digits over tiles of
        256 x 8 keys (16 KiB of rank counters plus the 17 KiB tile). CPUs:
        8-bit digits (four passes, a 1 KiB private histogram) in one chunk per CU."""
        shape = shape or (GPU_DEFAULT_SHAPE if traits.is_gpu else "cpu")
        wf = clamp_wavefront(traits)
        wg = max(wf, min(256, traits.max_work_group_size))
        if shape in ("split", "onesweep"):
            bits = 4 if shape == "onesweep" and wg < 256 else 8
            items = (
                16
                if (
                    shape == "onesweep"
                    and tile_local_bytes(shape, wg, 16, bits) <= _usable_local(traits)
                )
                else 8
            )
            return {
                "shape": shape,
                "radix_bits": bits,
                "work_group_size": wg,
                "items_per_thread": items,
                "wavefront": wf,
            }
        if shape == "gpu":
            return {
                "shape": "gpu",
                "radix_bits": 4,
                "work_group_size": wg,
                "items_per_thread": 8,
                "wavefront": wf,
            }
        # one chunk per compute unit: each chunk scatters to RADIX output streams,
        # and more streams than the caches hold slow the scatter down
        return {"shape": "cpu", "radix_bits": 8, "work_items": max(1, traits.compute_units)}

    def _buffer(self, name: str, count: int) -> cl.Buffer:
        buf = self._scratch.get(name)
        if buf is None or buf.size < 4 * count:
            buf = self._scratch[name] = cl.Buffer(
                self.runtime.context, cl.mem_flags.READ_WRITE, 4 * max(count, 1)
            )
        return buf

    def __call__(self, keys, values=None, n=None):
        buf_keys = check_array(self.runtime, keys, "keys", np.uint32)
        if self.with_values:
            if values is None:
                raise RbgenError("values is required: this RadixSort was built with_values=True")
            buf_values = check_array(self.runtime, values, "values", np.uint32)
            if values.size < keys.size:
                raise RbgenError(
                    f"values holds {values.size} elements, shorter than keys ({keys.size})"
                )
        elif values is not None:
            raise RbgenError("values given, but this RadixSort was built with_values=False")
        else:
            buf_values = None
        capacity, device_count = resolve_count(self.runtime, n, keys.size)
        return self.enqueue(buf_keys, buf_values, capacity, device_count)

    def _checked(self, params: dict, capacity: int) -> dict:
        """A onesweep sort must fit its 30-bit status words and pass its guard,
        else this sorter uses the split shape's defaults."""
        if params["shape"] == "onesweep" and (
            capacity >= ONESWEEP_MAX_KEYS or not onesweep_works(self.runtime, params)
        ):
            return self.default_params(self.runtime.traits, "split")
        return params

    def enqueue(self, keys, values, capacity: int, device_count):
        """Sort raw buffers (arguments already checked)."""
        if capacity == 0:
            return None
        params, program = self.program(capacity)
        if params["shape"] == "cpu":
            groups = params["work_items"]
            global_size, local_size = groups, 1
        else:
            wg = params["work_group_size"]
            groups = ceil_div(capacity, wg * params["items_per_thread"])
            global_size, local_size = groups * wg, wg
        pair = [
            (keys, values),
            (
                self._buffer("keys", capacity),
                self._buffer("values", capacity) if values is not None else None,
            ),
        ]
        passes = ceil_div(self.key_bits, params["radix_bits"])
        if params["shape"] == "onesweep":
            event = self._onesweep_passes(program, params, pair, capacity, device_count, groups)
        else:
            event = self._table_passes(
                program, params, pair, capacity, device_count, groups, global_size, local_size
            )
        if passes % 2:
            (k_in, v_in), (k_out, v_out) = pair[1], pair[0]
            vals = (v_in, v_out) if values is not None else ()
            copy = program.kernel("copy_back")
            self.runtime.bound(copy).bind(k_in, k_out, *vals, np.uint32(capacity), device_count)
            event = self.runtime.launch(copy, global_size, local_size)
        return event

    def _table_passes(
        self, program, params, pair, capacity, device_count, groups, global_size, local_size
    ):
        """Per pass: count digits per tile/chunk, scan the digit table, scatter."""
        rt, cap, bits = self.runtime, np.uint32(capacity), params["radix_bits"]
        table = self._buffer("table", groups << bits)
        count, scatter = program.kernel("count_digits"), program.kernel("scatter_digits")
        event = None
        for p in range(ceil_div(self.key_bits, bits)):
            shift = p * bits
            mask = np.uint32((1 << min(bits, self.key_bits - shift)) - 1)
            (k_in, v_in), (k_out, v_out) = pair[p % 2], pair[1 - p % 2]
            rt.bound(count).bind(k_in, cap, device_count, np.uint32(shift), mask, table)
            rt.launch(count, global_size, local_size)
            self.scan.enqueue(table, table, groups << bits, None, None)
            vals = (v_in, v_out) if v_in is not None else ()
            rt.bound(scatter).bind(
                k_in, k_out, *vals, cap, device_count, np.uint32(shift), mask, table
            )
            event = rt.launch(scatter, global_size, local_size)
        return event

    def _onesweep_passes(self, program, params, pair, capacity, device_count, tiles):
        """Zero the look-back state, count every pass's digits once, then one
        launch per pass (see radix_sort_onesweep.cl.mako for the state's layout)."""
        rt, cap, bits = self.runtime, np.uint32(capacity), params["radix_bits"]
        wg = params["work_group_size"]
        passes = ceil_div(self.key_bits, bits)
        max_passes = ceil_div(32, bits)
        words = 1 + max_passes + (max_passes << bits) + passes * (tiles << bits)
        state = self._buffer("state", words)
        cl.enqueue_fill_buffer(rt.queue, state, np.uint32(0), 0, 4 * words)
        key_bits = np.uint32(self.key_bits)
        count = program.kernel("count_all_digits")
        rt.bound(count).bind(pair[0][0], cap, device_count, key_bits, state)
        rt.launch(count, min(tiles, 4 * max(1, rt.traits.compute_units)) * wg, wg)
        sort_pass = program.kernel("sort_pass")
        event = None
        for p in range(passes):
            (k_in, v_in), (k_out, v_out) = pair[p % 2], pair[1 - p % 2]
            vals = (v_in, v_out) if v_in is not None else ()
            rt.bound(sort_pass).bind(
                k_in, k_out, *vals, cap, device_count, key_bits, np.uint32(p), state
            )
            event = rt.launch(sort_pass, tiles * wg, wg)
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
    return (bits ^ np.where(bits >> 31, np.uint32(0x80000000), np.uint32(0xFFFFFFFF))).view(
        np.float32
    )


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


def tile_local_bytes(
    shape: str,
    work_group_size: int,
    items_per_thread: int,
    radix_bits: int = 8,
    with_values: bool = True,
) -> int:
    """Local memory of the split or onesweep shape's tile kernel: the padded tile
    (keys and values), 8 packed counters per work-item, per-digit bases (and
    for onesweep the tile's histogram and ticket), scan scratch."""
    padded = lambda words: words + words // 32  # noqa: E731
    tile = padded(work_group_size * items_per_thread) * (2 if with_values else 1)
    digits = (2 if shape == "onesweep" else 1) << radix_bits
    return 4 * (
        tile
        + padded(8 * work_group_size)
        + digits
        + 2 * work_group_size
        + work_group_size // 32
        + 2
    )


#: onesweep status words count keys in 30 bits; larger sorts use the split shape
ONESWEEP_MAX_KEYS = 1 << 30


def onesweep_works(runtime, params: dict) -> bool:
    """The onesweep shape's guard (a `device_check`): sort a many-tile input with
    duplicates and compare with numpy; a failure (wrong result or the
    device-side spin limit hit) warns and makes callers use the split shape."""
    return device_check(runtime, "onesweep radix sort", params, _probe_onesweep, "the split shape")


def _probe_onesweep(runtime, params: dict) -> tuple[bool, str]:
    tile = params["work_group_size"] * params["items_per_thread"]
    n = 24 * tile + 5
    keys = np.random.default_rng(12345).integers(0, n // 3, n, dtype=np.uint32) * 2654435761
    keys = keys.astype(np.uint32)
    probe = RadixSort(runtime, 32, with_values=True, params=params)
    d_keys = cla.to_device(runtime.queue, keys)
    d_values = cla.to_device(runtime.queue, np.arange(n, dtype=np.uint32))
    probe(d_keys, d_values)
    flag = np.empty(1, np.uint32)
    cl.enqueue_copy(runtime.queue, flag, probe._scratch["state"], is_blocking=True)
    if flag[0] != 0:
        return False, "spin limit hit"
    order = np.argsort(keys, kind="stable")
    ok = np.array_equal(d_keys.get(), keys[order]) and np.array_equal(
        d_values.get(), order.astype(np.uint32)
    )
    return ok, "wrong result"


def _usable_local(traits: DeviceTraits) -> int:
    """Local memory a sort kernel may plan for (a little left to the compiler)."""
    return traits.local_mem_size - 1024


def search_space(traits: DeviceTraits) -> list[dict]:
    """Candidate parameters the tuner tries on a device (heuristic default first)."""
    space = [RadixSort.default_params(traits)]
    cu = max(1, traits.compute_units)
    if traits.is_gpu:
        wf = clamp_wavefront(traits)
        for shape, bits, wg, ipt in (
            ("split", 8, 128, 16),
            ("split", 8, 256, 8),
            ("split", 8, 256, 16),
            ("split", 8, 512, 4),
            ("split", 8, 512, 8),
            ("split", 8, 1024, 4),
            ("split", 4, 256, 16),
            ("onesweep", 8, 256, 16),
            ("onesweep", 8, 256, 8),
            ("onesweep", 8, 512, 8),
        ):
            if wf <= wg <= traits.max_work_group_size and tile_local_bytes(
                shape, wg, ipt, bits
            ) <= _usable_local(traits):
                space.append(
                    {
                        "shape": shape,
                        "radix_bits": bits,
                        "work_group_size": wg,
                        "items_per_thread": ipt,
                        "wavefront": wf,
                    }
                )
        for bits, wg, ipt in (
            (4, 128, 8),
            (4, 128, 16),
            (4, 256, 4),
            (4, 256, 8),
            (4, 512, 4),
            (8, 64, 8),
            (8, 64, 16),
            (8, 128, 4),
        ):
            # rank counters + the tile's keys and values (padded 1/32) + scan scratch
            local = (wg << bits) * (2 if bits == 8 else 4) + 2 * 4 * (wg * ipt * 33 // 32) + 12 * wg
            if wf <= wg <= traits.max_work_group_size and local <= traits.local_mem_size - 2048:
                space.append(
                    {
                        "shape": "gpu",
                        "radix_bits": bits,
                        "work_group_size": wg,
                        "items_per_thread": ipt,
                        "wavefront": wf,
                    }
                )
    else:
        for bits in (8, 11):
            for k in (1, 2, 4, 8):
                space.append({"shape": "cpu", "radix_bits": bits, "work_items": k * cu})
    return unique_params(space)
