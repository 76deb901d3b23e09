"""OpenCL devices: discovery, description and choice.

Everything above this layer asks a `DeviceTraits` (never pyopencl directly)
what the device is like, so that templates are specialised from one place:
wavefront width, local memory, work-group limits and a stable fingerprint
that keys the program and tuning caches.

Choosing a device: an explicit argument, else the ``RBGEN_DEVICE``
environment variable, else the first GPU, else the PoCL CPU device. A choice is
an index ``"P:D"`` (platform, device) or a case-insensitive substring of
``"<platform name> <device name>"``; one that matches nothing raises
`DeviceNotFoundError` listing what is available. The default passes over
devices that cannot compile a kernel (`build_failure`), with a warning.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import warnings
from functools import cached_property
from typing import Any, cast

import pyopencl as cl

from .errors import DeviceNotFoundError

ENV_DEVICE = "RBGEN_DEVICE"
#: the extension of 64-bit integer atomics (the chained scan's tile flags, the summed
#: warm start's per-body sums)
INT64_ATOMICS = "cl_khr_int64_base_atomics"

#: Wavefront (lock-step SIMD group) widths by vendor. We never rely on
#: lock-step execution for correctness; the width sizes tiles and sub-scans.
NVIDIA_WAVEFRONT = 32
AMD_WAVEFRONT = 64


@dataclasses.dataclass(frozen=True)
class DeviceTraits:
    """What templates and heuristics need to know about one OpenCL device."""

    platform_name: str
    device_name: str
    vendor: str
    is_gpu: bool
    compute_units: int
    wavefront: int
    local_mem_size: int
    max_work_group_size: int
    driver_version: str
    opencl_version: str
    #: the OpenCL extensions the device lists (plans choose by them; not part of the
    #: fingerprint, which the driver version already separates)
    extensions: tuple[str, ...] = dataclasses.field(default=(), metadata={"fingerprint": False})

    def has_extension(self, name: str) -> bool:
        """Whether the device lists the OpenCL extension ``name``."""
        return name in self.extensions

    @property
    def is_cpu(self) -> bool:
        return not self.is_gpu

    @property
    def kind(self) -> str:
        """``"gpu"`` or ``"cpu"``: selects the algorithm shape of primitives."""
        return "gpu" if self.is_gpu else "cpu"

    @property
    def fingerprint(self) -> str:
        """Stable identity of device + driver; keys the program and tuning caches.

        Readable prefix plus a short hash of every field, so two drivers of the
        same device never share cached binaries or tuning results.
        """
        text = "|".join(
            str(getattr(self, f.name))
            for f in dataclasses.fields(self)
            if f.metadata.get("fingerprint", True)
        )
        digest = hashlib.sha256(text.encode()).hexdigest()[:12]
        slug = "".join(c if c.isalnum() else "-" for c in self.device_name.lower())
        slug = "-".join(part for part in slug.split("-") if part)[:40]
        return f"{slug}-{digest}"

    @classmethod
    def of(cls, device: cl.Device) -> DeviceTraits:
        is_gpu = bool(device.type & cl.device_type.GPU)
        vendor = device.vendor.strip()
        return cls(
            platform_name=device.platform.name.strip(),
            device_name=device.name.strip(),
            vendor=vendor,
            is_gpu=is_gpu,
            compute_units=int(device.max_compute_units),
            wavefront=_wavefront_width(device, vendor, is_gpu),
            local_mem_size=int(device.local_mem_size),
            max_work_group_size=int(device.max_work_group_size),
            driver_version=device.driver_version.strip(),
            opencl_version=device.version.strip(),
            extensions=tuple(sorted(device.extensions.split())),
        )

    def describe(self) -> str:
        return (
            f"{self.device_name} [{self.platform_name}] {self.kind.upper()}, "
            f"{self.compute_units} CUs, wavefront {self.wavefront}, "
            f"local mem {self.local_mem_size // 1024} KiB, "
            f"max work-group {self.max_work_group_size}, driver {self.driver_version}"
        )


def _wavefront_width(device: cl.Device, vendor: str, is_gpu: bool) -> int:
    """32 on NVIDIA, 64 on AMD GPUs, the warp query where a driver offers it, else 1."""
    low = vendor.lower()
    if is_gpu and "nvidia" in low:
        return NVIDIA_WAVEFRONT
    if is_gpu and ("amd" in low or "advanced micro" in low):
        return AMD_WAVEFRONT
    if is_gpu:
        for attr in ("warp_size_nv", "wavefront_width_amd"):
            try:
                return int(getattr(device, attr))
            except Exception:  # noqa: BLE001 - extension query not offered
                pass
    return 1


@dataclasses.dataclass(frozen=True)
class DeviceEntry:
    """One device as listed by `list_devices`: its ``P:D`` index and handle."""

    index: str
    device: cl.Device

    @property
    def label(self) -> str:
        return f"{self.device.platform.name.strip()} {self.device.name.strip()}"


def list_devices() -> list[DeviceEntry]:
    """Every OpenCL device of every platform, indexed ``"P:D"``."""
    entries = []
    try:
        platforms = cl.get_platforms()
    except cl.Error:
        return []
    for p, platform in enumerate(platforms):
        try:
            devices = platform.get_devices()
        except cl.Error:
            continue
        for d, device in enumerate(devices):
            entries.append(DeviceEntry(f"{p}:{d}", device))
    return entries


#: the kernel `build_failure` compiles to see whether a device's compiler works at all
_PROBE_SOURCE = "__kernel void rbgen_probe(__global float* x) { x[get_global_id(0)] *= 2.0f; }"
_build_failures: dict[int, str | None] = {}


def build_failure(device: cl.Device) -> str | None:
    """None if ``device`` compiles a trivial kernel, else why not (the compiler's words).

    Once per device and process (a fraction of a second; PoCL caches the result on
    disk). Why: a listed device need not work. The PoCL bundled with pyopencl's wheels
    (LLVM 14) fails every build on CPUs newer than its LLVM ("unknown target CPU
    'generic'", seen on AMD Zen 5), and a default that picks it would fail on the first
    kernel with a message about the kernel, not the device."""
    key = device.int_ptr
    if key not in _build_failures:
        try:
            context = cl.Context([device])
            cl.Program(context, _PROBE_SOURCE).build()
            _build_failures[key] = None
        except cl.Error as err:
            lines = [line.strip() for line in str(err).splitlines()]
            reason = next(
                (line for line in lines if "error" in line.lower() and line != lines[0]),
                lines[-1] if lines else type(err).__name__,
            )
            _build_failures[key] = reason
    return _build_failures[key]


def is_pocl(device: cl.Device) -> bool:
    """Whether a device is PoCL's (pyopencl's bundled build or the system's), by its
    platform's name."""
    name = device.platform.name.lower()
    return "pocl" in name or "portable computing language" in name


def default_device() -> cl.Device:
    """The first GPU if any, else the first PoCL CPU device, else the first device: among
    the devices that compile a kernel, with a warning naming each one skipped."""
    entries = list_devices()
    if not entries:
        raise DeviceNotFoundError(
            "no OpenCL device found; install pocl-binary-distribution for a CPU device"
        )
    usable = []
    for entry in entries:
        reason = build_failure(entry.device)
        if reason is None:
            usable.append(entry)
        else:
            warnings.warn(
                f"OpenCL device {entry.index} ({entry.label}) cannot compile a kernel "
                f"({reason}); not used by default",
                RuntimeWarning,
                stacklevel=2,
            )
    if not usable:
        listing = "\n".join(f"  {e.index}  {e.label}: {build_failure(e.device)}" for e in entries)
        raise DeviceNotFoundError(
            f"no OpenCL device here compiles a kernel:\n{listing}\n(on a CPU newer than the "
            f"PoCL bundled with pyopencl, install the system's PoCL, e.g. Debian's "
            f"pocl-opencl-icd)"
        )
    for entry in usable:
        if entry.device.type & cl.device_type.GPU:
            return entry.device
    for entry in usable:
        if is_pocl(entry.device):
            return entry.device
    return usable[0].device


def select_device(choice: str | cl.Device | None = None) -> cl.Device:
    """Resolve a device choice (argument, then ``RBGEN_DEVICE``, then default)."""
    if isinstance(choice, cl.Device):
        return choice
    if choice is None:
        choice = os.environ.get(ENV_DEVICE) or None
    if choice is None:
        return default_device()
    return match_devices(choice)[0]


def match_devices(choice: str) -> list[cl.Device]:
    """Every device matching ``choice`` (``P:D`` index or name substring)."""
    entries = list_devices()
    text = str(choice).strip()
    hits = [e.device for e in entries if e.index == text]
    if not hits:
        hits = [e.device for e in entries if text.lower() in e.label.lower()]
    if not hits:
        listing = "\n".join(f"  {e.index}  {e.label}" for e in entries) or "  (none)"
        raise DeviceNotFoundError(
            f"device {choice!r} matches no OpenCL device; available:\n{listing}"
        )
    return hits


#: the device choice ``shape:NAME``: a CPU device standing in for the GPU ``NAME``
SHAPE_PREFIX = "shape:"

#: GPUs a CPU device can stand in for: the traits rbgen's plans read, as the GPU reports
#: them. A Runtime of ``shape:NAME`` specialises, plans and launches everything as it would
#: on that GPU, and the CPU's OpenCL builds and runs it: for checking GPU-only template
#: branches and launch shapes (persistent lanes, warps of 32, 48 KiB of local memory) and
#: a GPU plan's physics where no GPU is at hand; not the GPU compiler's own errors, its
#: races or its speed. The CPU's extensions are kept (the kernels must build there), and
#: its compute units are halved (at least 1): a persistent launch runs two work groups
#: per compute unit, which then all run at once on the CPU's threads, so its device-wide
#: barrier is exercised rather than given up. Its fingerprint differs from the CPU's and
#: the GPU's, so neither's program cache, tuning or exports are mixed with it.
GPU_SHAPES: dict[str, dict[str, Any]] = {
    "h200": {
        "platform_name": "NVIDIA CUDA",
        "device_name": "NVIDIA H200 (shape on a CPU)",
        "vendor": "NVIDIA Corporation",
        "is_gpu": True,
        "wavefront": 32,
        "local_mem_size": 49152,
        "max_work_group_size": 1024,
        "driver_version": "550.54.15",
        "opencl_version": "OpenCL 3.0 CUDA",
    }
}


def shaped_traits(traits: DeviceTraits, shape: str) -> DeviceTraits:
    """``traits`` of a CPU device as the GPU ``shape`` (`GPU_SHAPES`) would report them."""
    return dataclasses.replace(
        traits, **GPU_SHAPES[shape], compute_units=max(1, traits.compute_units // 2)
    )


def cpu_device() -> cl.Device:
    """The first CPU device that compiles a kernel (a GPU shape runs on it)."""
    for entry in list_devices():
        if entry.device.type & cl.device_type.CPU and build_failure(entry.device) is None:
            return entry.device
    raise DeviceNotFoundError("a GPU shape needs a CPU OpenCL device that compiles a kernel")


def _shape_of(choice) -> str | None:
    """The GPU shape a device choice names (``shape:NAME``), else None."""
    if not isinstance(choice, str) or not choice.strip().startswith(SHAPE_PREFIX):
        return None
    shape = choice.strip()[len(SHAPE_PREFIX) :]
    if shape not in GPU_SHAPES:
        raise DeviceNotFoundError(
            f"device {choice!r}: no GPU shape {shape!r}; shapes: "
            + ", ".join(SHAPE_PREFIX + name for name in sorted(GPU_SHAPES))
        )
    return shape


def resolve_device(choice: str | cl.Device | None = None) -> tuple[cl.Device, DeviceTraits]:
    """The device a choice names (as `select_device`) and the traits rbgen plans for: its
    own, or for ``shape:NAME`` the CPU device's as that GPU's (`GPU_SHAPES`)."""
    if choice is None:
        choice = os.environ.get(ENV_DEVICE) or None
    shape = _shape_of(choice)
    device = cpu_device() if shape is not None else select_device(choice)
    traits = DeviceTraits.of(device)
    return device, traits if shape is None else shaped_traits(traits, shape)


class Runtime:
    """A device with its context and in-order command queue.

    Every rbgen object that owns kernels or buffers is built for one Runtime.
    ``profiling=True`` gives event timestamps (the tuner and benchmarks need
    them; they cost launch latency on some drivers, so the default is off).
    ``device`` ``shape:NAME`` (`GPU_SHAPES`): the CPU device, planned for as the GPU.
    """

    def __init__(self, device: str | cl.Device | None = None, *, profiling: bool = False):
        self.device, self.traits = resolve_device(device)
        self.context = cl.Context([self.device])
        props = cast(
            cl.command_queue_properties,
            cl.command_queue_properties.PROFILING_ENABLE if profiling else 0,
        )
        self.queue = cl.CommandQueue(self.context, self.device, properties=props)
        self.profiling = profiling
        #: launches and blocking reads issued through `launch` and `read`;
        #: benchmarks report them per step (on a GPU each costs as much as a small kernel).
        self.counters = {"launches": 0, "blocking_reads": 0}
        #: launches by kernel name while `rbgen.launch.launches_by_kernel` counts them (None:
        #: not counted; the name is a driver query, so only a diagnosed step pays for it)
        self.kernel_launches: dict[str, int] | None = None
        #: active spec logs (`rbgen.codegen.SpecLog`): every compile_spec adds to each
        self.spec_logs: list[dict] = []

    def count_launch(self, kernel: cl.Kernel) -> None:
        """Count one launch of ``kernel`` (every enqueue of a kernel goes through here: `launch`
        and `rbgen.launch.BoundKernel.launch`), by name too while
        `rbgen.launch.launches_by_kernel` counts (the name is a driver query)."""
        self.counters["launches"] += 1
        if self.kernel_launches is not None:
            name = kernel.function_name
            self.kernel_launches[name] = self.kernel_launches.get(name, 0) + 1

    def launch(
        self, kernel: cl.Kernel, global_size: int, local_size: int | None, wait_for=None
    ) -> cl.Event:
        """Enqueue a 1-D kernel whose arguments are already set, and count it."""
        self.count_launch(kernel)
        return cl.enqueue_nd_range_kernel(
            self.queue,
            kernel,
            (int(global_size),),
            None if local_size is None else (int(local_size),),
            wait_for=wait_for,
        )

    def has_extension(self, name: str) -> bool:
        """Whether the device lists the OpenCL extension ``name`` (a whole token of its
        extension string)."""
        return self.traits.has_extension(name)

    def read(self, device_array, host_array=None):
        """Blocking read of a device buffer or pyopencl array, counted."""
        self.counters["blocking_reads"] += 1
        if hasattr(device_array, "get"):
            return device_array.get(queue=self.queue, ary=host_array)
        cl.enqueue_copy(self.queue, host_array, device_array, is_blocking=True)
        return host_array

    def bound(self, kernel: cl.Kernel):
        """The `rbgen.launch.BoundKernel` of ``kernel``: its argument cache, shared by every
        caller of that kernel object (arguments are set only when they change)."""
        from .launch import bound

        return bound(self, kernel)

    @cached_property
    def profiling_queue(self) -> cl.CommandQueue:
        """A second queue with profiling on (for timing with events)."""
        if self.profiling:
            return self.queue
        return cl.CommandQueue(
            self.context, self.device, properties=cl.command_queue_properties.PROFILING_ENABLE
        )

    def __repr__(self) -> str:
        return f"Runtime({self.traits.describe()})"


def buffer_of(array) -> cl.Buffer:
    """The OpenCL buffer of a pyopencl array (one without an offset)."""
    return cast(cl.Buffer, array.data)


def coerce_runtime(runtime: Runtime | str | cl.Device | None) -> Runtime:
    """Accept a Runtime, a device choice, or None (default device)."""
    if isinstance(runtime, Runtime):
        return runtime
    return Runtime(runtime)
