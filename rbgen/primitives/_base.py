"""What every primitive shares: argument checks, element counts, shape choice.

Element counts. Every primitive takes ``n`` as ``None`` (the whole array), a
host ``int``, or a device count (a pyopencl uint32 array of one element). A
device count is never read back: kernels receive the array's *capacity* and a
pointer to the count (NULL for host counts), launch over the capacity and stop
at ``min(count, capacity)``. So a pipeline can chain primitives whose sizes are
only known on the device without a blocking read.

Shapes. Each primitive has two algorithm shapes rendered from two templates:
``"gpu"`` (tiles of work_group_size * items_per_thread elements, local-memory
scans with barriers) and ``"cpu"`` (a few work-items, each owning one long
contiguous chunk, with private counters and no barriers). A parameter dict
always carries ``"shape"``; the remaining keys are the template's parameters.
"""

from __future__ import annotations

import hashlib
import math
import warnings
from typing import Any, cast

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ..codegen import TEMPLATE_DIR, KernelTemplate, compile_spec
from ..device import DeviceTraits, Runtime
from ..errors import RbgenError

#: OpenCL C names of the element types primitives accept.
CL_TYPES = {np.dtype(np.uint32): "uint", np.dtype(np.int32): "int", np.dtype(np.float32): "float"}


class PrimitiveTemplate(KernelTemplate):
    """A KernelTemplate whose hash also covers the primitives' shared include.

    The tuning cache is keyed by `source_hash`; a primitive's kernels depend on
    its own file and ``primitives/common.cl.mako`` only (no layouts), so a
    struct added elsewhere does not invalidate tuned results.
    """

    INCLUDES: tuple[str, ...] = ("primitives/common.cl.mako",)

    def source_hash(self) -> str:
        h = hashlib.sha256()
        for path in (self.path, *self.INCLUDES):
            h.update((TEMPLATE_DIR / path).read_bytes())
        return h.hexdigest()[:16]


def cl_type(dtype, what: str) -> str:
    """The OpenCL type name for ``dtype``, or an error naming ``what``."""
    try:
        return CL_TYPES[np.dtype(dtype)]
    except (KeyError, TypeError):
        raise RbgenError(
            f"{what}: dtype {dtype!r} is not supported; expected one of uint32, int32, float32"
        ) from None


def check_array(
    runtime: Runtime, array, name: str, dtype=None, min_size: int = 0
) -> cl.Buffer | None:
    """Validate a pyopencl array argument and return its buffer (None for an empty one).

    It must be a pyopencl Array of ``dtype`` (when given), contiguous, start
    at its buffer's beginning, live in ``runtime``'s context and hold at least
    ``min_size`` elements. Each failure names the argument.
    """
    if not isinstance(array, cla.Array):
        raise RbgenError(f"{name} must be a pyopencl.array.Array, got {type(array).__name__}")
    if dtype is not None and array.dtype != np.dtype(dtype):
        raise RbgenError(f"{name} has dtype {array.dtype}, expected {np.dtype(dtype)}")
    if array.ndim != 1 or not array.flags.c_contiguous:
        raise RbgenError(
            f"{name} must be a contiguous 1-D array (shape {array.shape}, strides {array.strides})"
        )
    if array.offset != 0:
        raise RbgenError(
            f"{name} must start at the beginning of its buffer (offset "
            f"{array.offset} bytes); copy it or slice from 0"
        )
    if array.context != runtime.context:
        raise RbgenError(f"{name} belongs to another OpenCL context than this primitive's runtime")
    if array.size < min_size:
        raise RbgenError(f"{name} holds {array.size} elements, needs at least {min_size}")
    return cast(cl.Buffer, array.base_data) if array.size else None


def resolve_count(runtime: Runtime, n, capacity: int, name: str = "n"):
    """``(capacity, device_count_buffer_or_None)`` for a count argument.

    Host counts shrink the capacity (nothing past them is touched); device
    counts keep it and are clamped to it by the kernels.
    """
    if n is None:
        return capacity, None
    if isinstance(n, cla.Array):
        check_array(runtime, n, name, np.uint32, min_size=1)
        return capacity, n.base_data
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)):
        raise RbgenError(
            f"{name} must be None, an int or a device uint32 array of one "
            f"element, got {type(n).__name__}"
        )
    n = int(n)
    if not 0 <= n <= capacity:
        raise RbgenError(f"{name}={n} is outside 0..{capacity} (the array's length)")
    return n, None


def size_bucket(capacity: int) -> int:
    """The tuning size bucket of an element count: the even exponent nearest
    to log2(capacity), 10..26. Bucket b is tuned at 2^b elements and serves
    the counts nearest to it on a log scale, 2^(b-1) up to (not including) 2^(b+1)."""
    k = 2 * math.floor(math.log2(max(capacity, 1)) / 2 + 0.5)
    return min(max(k, 10), 26)


def clamp_wavefront(traits: DeviceTraits) -> int:
    """32 or 64: the sub-scan width of the GPU shape (never relied on for lock-step)."""
    return 64 if traits.wavefront >= 64 else 32


def default_work_items(traits: DeviceTraits) -> int:
    """CPU shape: four chunks per compute unit balance load without much scan overhead."""
    return 4 * max(1, traits.compute_units)


def split_params(params: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """``(shape, template parameters)`` of a primitive parameter dict."""
    params = dict(params)
    shape = params.pop("shape", None)
    if shape not in ("gpu", "cpu", "chained"):
        raise RbgenError(
            f"params['shape'] must be 'gpu' or 'cpu' (or 'chained' for a chained "
            f"Scan), got {shape!r}"
        )
    return shape, params


class Primitive:
    """Base of the primitive classes: picks and builds the kernels per size.

    Subclasses define ``family`` (the tuning family name), ``variant`` (e.g.
    the dtype), ``TEMPLATES = {"gpu": ..., "cpu": ...}``, ``default_params``
    and ``template_values`` (the fixed, non-tunable template parameters).
    """

    TEMPLATES: dict[str, KernelTemplate] = {}

    def __init__(self, runtime: Runtime, params: dict | None = None):
        if not isinstance(runtime, Runtime):
            raise RbgenError(f"runtime must be an rbgen.Runtime, got {type(runtime).__name__}")
        self.runtime = runtime
        self.params_override = dict(params) if params is not None else None
        if self.params_override is not None:
            self._spec_for(self.params_override)  # validate now, not at the first call
        self._programs: dict[tuple, tuple[dict, Any]] = {}

    @property
    def family(self) -> str:
        return ""

    @property
    def variant(self) -> str:
        return ""

    @classmethod
    def default_params(cls, traits: DeviceTraits) -> dict[str, Any]:
        raise NotImplementedError

    def template_values(self) -> dict[str, Any]:
        return {}

    def _spec_for(self, params: dict):
        shape, values = split_params(params)
        if shape not in self.TEMPLATES:
            raise RbgenError(
                f"params['shape']={shape!r} is not a shape of {type(self).__name__}; "
                f"expected one of {sorted(self.TEMPLATES)}"
            )
        if "wavefront" in values and values.get("work_group_size", 0) < values["wavefront"]:
            raise RbgenError(
                f"params: work_group_size={values.get('work_group_size')} is smaller "
                f"than wavefront={values['wavefront']}"
            )
        return self.TEMPLATES[shape].spec(**values, **self.template_values())

    def params_for(self, capacity: int) -> dict[str, Any]:
        """Explicit params, else the tuned winner for this size bucket, else the heuristic."""
        if self.params_override is not None:
            return dict(self.params_override)
        tuned = self._tuned_params(capacity)
        return tuned if tuned is not None else self.default_params(self.runtime.traits)

    def _tuned_params(self, capacity: int) -> dict[str, Any] | None:
        from .. import tuning

        return tuning.lookup(self.runtime.traits, self.family, self.variant, size_bucket(capacity))

    def _checked(self, params: dict, capacity: int) -> dict:
        """Hook: ``params``, or a fallback where they name an opt-in shape that
        failed its `device_check` on this device (or cannot take ``capacity``)."""
        return params

    def program(self, capacity: int):
        """``(params, Compiled)`` for arrays of ``capacity`` elements, built once
        per size bucket (a fallback chosen by `_checked` included)."""
        bucket = size_bucket(capacity)
        key = (tuple(sorted(self.template_values().items())), bucket)
        entry = self._programs.get(key)
        if entry is None:
            params = self._checked(self.params_for(capacity), capacity)
            try:
                spec = self._spec_for(params)
            except RbgenError:
                # a tuned entry that no longer fits the template: fall back
                params = self.default_params(self.runtime.traits)
                spec = self._spec_for(params)
            entry = self._programs[key] = (params, compile_spec(self.runtime, spec))
        return entry


#: outcomes of `device_check`, per (context, check, params)
DEVICE_CHECKS: dict[tuple, bool] = {}


def device_check(runtime: Runtime, name: str, params: dict, probe, fallback: str) -> bool:
    """Whether an opt-in shape (one that relies on behaviour OpenCL does not
    promise, such as forward progress between work groups) works on this
    device: ``probe(runtime, params) -> (ok, why)`` runs once per context,
    check and parameters (it may read results back: call it at set-up or from
    a first call, never inside a step). A failure warns, naming the device,
    the reason and ``fallback`` (what callers use instead)."""
    key = (id(runtime.context), name, tuple(sorted(params.items())))
    if key not in DEVICE_CHECKS:
        DEVICE_CHECKS[key] = True  # the probe itself runs the shape it checks
        ok, why = probe(runtime, params)
        if not ok:
            warnings.warn(
                f"{name} with {params} failed its check on "
                f"{runtime.traits.device_name} ({why}); using {fallback} instead",
                RuntimeWarning,
                stacklevel=4,
            )
        DEVICE_CHECKS[key] = bool(ok)
    return DEVICE_CHECKS[key]


def ceil_div(a: int, b: int) -> int:
    return -(-a // b)


def tiled_or_chunked_space(default: dict, traits: DeviceTraits) -> list[dict]:
    """Search space shared by the scan-shaped primitives (scan, compact), default first.

    GPU: tiles of 128-512 work-items with 4-16 items each (local-memory scans);
    CPU: 1-16 long chunks per compute unit (no barriers)."""
    space = [default]
    if traits.is_gpu:
        wf = clamp_wavefront(traits)
        for wg in (128, 256, 512):
            for ipt in (4, 8, 16):
                if wf <= wg <= traits.max_work_group_size:
                    space.append(
                        {
                            "shape": "gpu",
                            "work_group_size": wg,
                            "items_per_thread": ipt,
                            "wavefront": wf,
                        }
                    )
    else:
        cu = max(1, traits.compute_units)
        space += [{"shape": "cpu", "work_items": k * cu} for k in (1, 2, 4, 8, 16)]
    return unique_params(space)


def unique_params(space: list[dict]) -> list[dict]:
    """The candidates in order, each once."""
    unique = []
    for p in space:
        if p not in unique:
            unique.append(p)
    return unique
