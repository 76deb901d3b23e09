"""Recording what a World enqueues: every launch, fill and copy of its steps, as data.

A `Recorder` is active only while `rbgen export` records a schedule. It intercepts the
OpenCL enqueues of one runtime's queue at pyopencl's boundary (``enqueue_nd_range_kernel``,
``enqueue_fill_buffer``, ``enqueue_copy``, ``Array.fill`` and ``Kernel.__call__``, the
path of pyopencl's own kernels), so that whatever a stage
enqueues, now or after a change, is recorded without the stage knowing about the
recorder, and a World step outside recording pays nothing for it. A launch's arguments
are read from the kernel's `rbgen.launch.BoundKernel`, through which every argument is
set; a kernel whose arguments were set around it, or one of pyopencl's own generated
kernels, cannot be replayed and is refused by name.

What is recorded (`Command`):

* ``launch``: the kernel object (a program file and a kernel name), its arguments in
  order (a buffer, a NULL buffer, a scalar's bytes, local memory), global and local size;
* ``fill``: a buffer, the pattern's bytes, offset and size;
* ``copy``: device to device, with offsets and size;
* ``write``: host bytes into a buffer that already exists (constant host data).

A buffer is known by its ``cl_mem`` (the recorder keeps every buffer it has seen alive, so
that no address is reused while it records). Its initial contents are the fill or upload
that pyopencl's array module made when it was allocated (``cla.zeros``, ``cla.to_device``)
before any command used it; a buffer without one (``cla.empty``, ``cl.Buffer``) starts
uninitialised. Copies to the host change nothing on the device and are not recorded.
"""

from __future__ import annotations

import dataclasses
import re
import sys
from types import FrameType
from typing import Any

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ..codegen import _COMPILED, kernel_signatures
from ..errors import RbgenError


@dataclasses.dataclass
class BufferInfo:
    """One device buffer the recording saw: its size, initial contents and what the
    kernels call it."""

    index: int
    mem: Any
    size: int
    #: ("none", b"") uninitialised, ("fill", pattern) or ("data", bytes): its contents when
    #: it was allocated
    init: tuple[str, bytes] = ("none", b"")
    #: the argument name and element type of the first kernel argument it was bound to
    name: str | None = None
    ctype: str | None = None


@dataclasses.dataclass(frozen=True)
class KernelInfo:
    """One kernel object: its program (spec and build options) and kernel name."""

    index: int
    spec: Any
    options: tuple[str, ...]
    name: str
    #: per argument: (name, C type) from the kernel's signature
    signature: tuple[tuple[str, str], ...]


#: one command: ("launch", kernel index, args, global size, local size) with args a tuple of
#: ("buffer", buffer index) | ("null",) | ("scalar", bytes) | ("local", bytes);
#: ("fill", buffer, pattern, offset, size); ("copy", dst, src, dst offset, src offset, size);
#: ("write", buffer, offset, bytes)
Command = tuple


class Recorder:
    """Records the commands one runtime's queue receives (see the module docstring).

    ``with Recorder(runtime) as rec:`` installs the interception; `take` returns (and
    clears) the commands recorded since the last `take`. ``buffers`` and ``kernels`` are
    indexed in order of first appearance, over the whole recording.
    """

    def __init__(self, runtime):
        self.runtime = runtime
        self.buffers: dict[int, BufferInfo] = {}
        self.kernels: dict[int, KernelInfo] = {}
        self.commands: list[Command] = []
        self._saved: dict = {}
        self._inside_fill = False
        self._programs: dict[int, tuple] = {}

    # ------------------------------------------------------------------ interception
    def __enter__(self) -> Recorder:
        if getattr(cl, "_rbgen_recording", None) is not None:
            raise RbgenError("a schedule recording is already active in this process")
        self._saved = {
            "enqueue_nd_range_kernel": cl.enqueue_nd_range_kernel,
            "enqueue_fill_buffer": cl.enqueue_fill_buffer,
            "enqueue_copy": cl.enqueue_copy,
            "fill": cla.Array.fill,
            "call": cl.Kernel.__call__,
        }
        # (replaced while recording only; mypy sees pyopencl's signatures)
        cl.enqueue_nd_range_kernel = self._launch  # type: ignore[assignment]
        cl.enqueue_fill_buffer = self._fill
        cl.enqueue_copy = self._copy
        cla.Array.fill = _array_fill(self, self._saved["fill"])  # type: ignore[method-assign]
        cl.Kernel.__call__ = _kernel_call(self, self._saved["call"])  # type: ignore[method-assign]
        cl._rbgen_recording = self  # type: ignore[attr-defined]
        return self

    def __exit__(self, *exc) -> None:
        cl.enqueue_nd_range_kernel = self._saved["enqueue_nd_range_kernel"]
        cl.enqueue_fill_buffer = self._saved["enqueue_fill_buffer"]
        cl.enqueue_copy = self._saved["enqueue_copy"]
        cla.Array.fill = self._saved["fill"]  # type: ignore[method-assign]
        cl.Kernel.__call__ = self._saved["call"]  # type: ignore[method-assign]
        cl._rbgen_recording = None  # type: ignore[attr-defined]

    def take(self) -> list[Command]:
        """The commands recorded since the last call."""
        commands, self.commands = self.commands, []
        return commands

    def _ours(self, queue) -> bool:
        return queue is not None and queue.int_ptr == self.runtime.queue.int_ptr

    def _launch(self, queue, kernel, global_size, local_size, *args, **kwargs):
        event = self._saved["enqueue_nd_range_kernel"](
            queue, kernel, global_size, local_size, *args, **kwargs
        )
        if self._ours(queue) and not self._inside_fill:
            info = self._kernel(kernel)
            values = self._arguments(kernel, info)
            self.commands.append(
                (
                    "launch",
                    info.index,
                    values,
                    tuple(int(g) for g in global_size),
                    None if local_size is None else tuple(int(x) for x in local_size),
                )
            )
        return event

    def _fill(self, queue, mem, pattern, offset, size, *args, **kwargs):
        if self._ours(queue) and not self._inside_fill:
            pattern_bytes = np.asarray(pattern).tobytes()
            if _from_array_module() and mem.int_ptr not in self.buffers:
                self._buffer(mem, init=("fill", pattern_bytes))  # cla.zeros
            else:
                self.commands.append(
                    ("fill", self._buffer(mem).index, pattern_bytes, int(offset), int(size))
                )
        return self._saved["enqueue_fill_buffer"](
            queue, mem, pattern, offset, size, *args, **kwargs
        )

    def _copy(self, queue, dest, src, **kwargs):
        if self._ours(queue) and not self._inside_fill:
            self._record_copy(dest, src, kwargs)
        return self._saved["enqueue_copy"](queue, dest, src, **kwargs)

    def _record_copy(self, dest, src, kwargs) -> None:
        dest_mem = isinstance(dest, cl.MemoryObjectHolder)
        src_mem = isinstance(src, cl.MemoryObjectHolder)
        if not dest_mem:
            return  # to the host: nothing changes on the device
        if not src_mem:  # from the host
            data = np.ascontiguousarray(src).tobytes()
            offset = int(kwargs.get("dst_offset", 0) or 0)
            if _from_array_module() and dest.int_ptr not in self.buffers and offset == 0:
                self._buffer(dest, init=("data", data))  # cla.to_device
            else:
                self.commands.append(("write", self._buffer(dest).index, offset, data))
            return
        d, s = self._buffer(dest), self._buffer(src)
        size = kwargs.get("byte_count")
        dst_offset = int(kwargs.get("dst_offset", 0) or 0)
        src_offset = int(kwargs.get("src_offset", 0) or 0)
        if size is None:
            size = min(d.size - dst_offset, s.size - src_offset)
        self.commands.append(("copy", d.index, s.index, dst_offset, src_offset, int(size)))

    def array_fill(self, array: cla.Array, value) -> None:
        """`Array.fill` (pyopencl's own kernel): recorded as the fill it is."""
        if not self._ours(array.queue):
            return
        mem = array.base_data
        pattern = np.asarray(value, array.dtype).tobytes()
        self.commands.append(
            ("fill", self._buffer(mem).index, pattern, int(array.offset), int(array.nbytes))
        )

    # ------------------------------------------------------------------ objects
    def _buffer(self, mem, init: tuple[str, bytes] = ("none", b"")) -> BufferInfo:
        info = self.buffers.get(mem.int_ptr)
        if info is None:
            info = self.buffers[mem.int_ptr] = BufferInfo(
                len(self.buffers), mem, int(mem.size), init
            )
        return info

    def _kernel(self, kernel) -> KernelInfo:
        info = self.kernels.get(kernel.int_ptr)
        if info is not None:
            return info
        program = kernel.get_info(cl.kernel_info.PROGRAM)
        found = self._program_of(program.int_ptr)
        name = kernel.function_name
        if found is None:
            raise RbgenError(
                f"kernel {name!r} was launched from a program rbgen did not "
                f"compile (pyopencl's own kernels, e.g. an Array operation, "
                f"cannot be exported): enqueue it through rbgen.codegen"
            )
        spec, options = found
        signature = kernel_signatures(spec.source).get(name, [])
        info = KernelInfo(
            len(self.kernels), spec, options, name, tuple((a["name"], a["type"]) for a in signature)
        )
        self.kernels[kernel.int_ptr] = info
        self._kernel_objects = getattr(self, "_kernel_objects", [])
        self._kernel_objects.append(kernel)  # (alive: no address reused while recording)
        return info

    def _program_of(self, pointer: int):
        if pointer not in self._programs:
            for (_, spec, options), compiled in list(_COMPILED.items()):
                self._programs.setdefault(compiled.program.int_ptr, (spec, options))
        return self._programs.get(pointer)

    def _arguments(self, kernel, info: KernelInfo) -> tuple:
        registry = self.runtime.__dict__.get("_bound_kernels", {})
        bound = registry.get(kernel)
        if bound is None:
            raise RbgenError(
                f"kernel {info.name} ({info.spec.path}) was launched with "
                f"arguments not set through rbgen.launch.BoundKernel: the "
                f"schedule cannot know them"
            )
        values = []
        for position, value in enumerate(bound._values):
            arg_name, ctype = (
                info.signature[position]
                if position < len(info.signature)
                else (f"arg{position}", "")
            )
            values.append(self._argument(value, info, position, arg_name, ctype))
        return tuple(values)

    def _argument(self, value, info: KernelInfo, position: int, name: str, ctype: str) -> tuple:
        if value is None:
            return ("null",)
        if isinstance(value, cl.MemoryObjectHolder):
            buffer = self._buffer(value)
            if buffer.name is None:
                buffer.name, buffer.ctype = name, _element_type(ctype)
            return ("buffer", buffer.index)
        if isinstance(value, cl.LocalMemory):
            return ("local", int(value.size))
        if isinstance(value, (np.generic, np.ndarray)):
            return ("scalar", np.ascontiguousarray(value).tobytes())
        raise RbgenError(
            f"kernel {info.name} ({info.spec.path}) argument {position} "
            f"({name}) holds {type(value).__name__}, which the schedule cannot "
            f"replay (never set through BoundKernel?)"
        )


def _array_fill(recorder: Recorder, original):
    def fill(self, value, queue=None, wait_for=None):
        recorder.array_fill(self, value)
        recorder._inside_fill = True
        try:
            return original(self, value, queue=queue, wait_for=wait_for)
        finally:
            recorder._inside_fill = False

    return fill


def _kernel_call(recorder: Recorder, original):
    """``kernel(queue, ...)``: pyopencl's own launches (its Array operations), whose
    enqueue bypasses the module's function: refused while recording a queue of ours."""

    def call(self, queue, *args, **kwargs):
        if recorder._ours(queue) and not recorder._inside_fill:
            raise RbgenError(
                f"kernel {self.function_name!r} was launched from a program rbgen "
                f"did not compile (pyopencl's own kernels, e.g. an Array "
                f"operation, cannot be exported): enqueue it through "
                f"rbgen.codegen"
            )
        return original(self, queue, *args, **kwargs)

    return call


def _from_array_module() -> bool:
    """Whether the enqueue was made by pyopencl's array module (an allocation's zeros or
    upload) rather than by rbgen's code."""
    frame: FrameType | None = sys._getframe(1)
    for _ in range(8):
        if frame is None:
            return False
        module = frame.f_globals.get("__name__", "")
        if module == __name__:
            frame = frame.f_back
            continue
        if module.startswith("rbgen"):
            return False
        if module == "pyopencl.array":
            return True
        frame = frame.f_back
    return False


def _element_type(ctype: str) -> str | None:
    """``Body`` for ``__global const Body*``, None for a type that is not a pointer."""
    if "*" not in ctype:
        return None
    words = [
        w
        for w in re.findall(r"\w+", ctype.split("*")[0])
        if w
        not in (
            "__global",
            "global",
            "const",
            "restrict",
            "__restrict",
            "volatile",
            "__constant",
            "constant",
        )
    ]
    return words[-1] if words else None
