"""Kernel launches that set an argument only when its value changed.

Why: a World step is tens of launches, and on some drivers (NVIDIA's) the host cost
of setting arguments through pyopencl (``set_args``, or ``set_arg`` for one scalar)
exceeds the enqueue itself. Most
arguments are the same buffers and the same scalars step after step, so a
`BoundKernel` remembers what it last set per argument index and calls the
driver only for those that differ: a buffer by identity (re-set after a
reallocation), a scalar or small numpy array by value. Scalars are passed to
the driver as raw bytes (pyopencl's own generated invokers do the same),
a fraction of the generic path's cost.

OpenCL kernel arguments belong to the ``cl.Kernel`` object, and one kernel
object may be used by several owners (programs are cached per source): the
cache therefore lives with the kernel, one `BoundKernel` per kernel object,
obtained with `bound` (or ``Runtime.bound``). Every caller of a kernel must
go through it; a direct ``kernel.set_args`` would make its cache lie (call
`BoundKernel.forget` after one).

A kernel launched many times per step with different scalars (the solver's
first group and pass flags) gets one kernel object per distinct set of values
(`instance`), each with its arguments set once, instead of re-setting them
per launch. (Passing such values in the global work offset does not work
everywhere: PoCL 6 folds ``get_global_offset(0) >> 16`` to 0, as if the
offset were always small.)
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np
import pyopencl as cl


class BoundKernel:
    """One ``cl.Kernel`` with a cache of its argument values (see the module docstring)."""

    __slots__ = ("runtime", "kernel", "_values", "_given", "_set_bytes")

    def __init__(self, runtime, kernel: cl.Kernel):
        self.runtime = runtime
        self.kernel = kernel
        self._values: list = [_UNSET] * kernel.num_args  # what the driver holds
        self._given: list = [_UNSET] * kernel.num_args  # the object last passed (fast path)
        # raw-bytes setter of pyopencl's generated invokers; the public set_arg otherwise
        self._set_bytes = getattr(kernel, "_set_arg_buf", None) or kernel.set_arg

    def set(self, index: int, value) -> None:
        """Set argument ``index`` unless it already holds ``value``.

        ``value``: a ``cl.MemoryObject`` or pyopencl Array (compared by
        identity of the buffer), a numpy scalar (by type and value) or a small
        numpy array (by dtype and bytes; it is copied).
        """
        if value is self._given[index]:  # the same object again (never a numpy array)
            return
        old = self._values[index]
        given = value
        if isinstance(value, np.generic):
            if type(old) is type(value) and old == value:
                self._given[index] = given
                return
            self._set_bytes(index, value)
        elif isinstance(value, np.ndarray):
            given = _UNSET  # may be changed in place by its owner: compare bytes every time
            if (
                isinstance(old, np.ndarray)
                and old.dtype == value.dtype
                and old.tobytes() == value.tobytes()
            ):
                return
            value = np.ascontiguousarray(value).copy()
            self._set_bytes(index, value)
        else:
            if hasattr(value, "base_data"):  # a pyopencl Array: its buffer
                value = value.data
            if old is not value:
                self.kernel.set_arg(index, value)
        self._values[index] = value
        self._given[index] = given

    def bind(self, *args) -> BoundKernel:
        """Set every argument in order (only the changed ones reach the driver)."""
        if len(args) != len(self._given):
            raise TypeError(
                f"kernel {self.kernel.function_name} takes {len(self._given)} "
                f"arguments, got {len(args)}"
            )
        return self._bind_from(0, args)

    def bind_first(self, *args) -> BoundKernel:
        """Set the first ``len(args)`` arguments (the rest stay as they are)."""
        return self._bind_from(0, args)

    def bind_at(self, first: int, *args) -> BoundKernel:
        """Set arguments ``first``, ``first + 1``, ... to ``args`` (the rest stay as they
        are; `rbgen.codegen.Binder` sets declared arguments through it)."""
        return self._bind_from(first, args)

    @property
    def num_args(self) -> int:
        """The kernel's argument count."""
        return len(self._given)

    def bind_last(self, *args) -> BoundKernel:
        """Set the last ``len(args)`` arguments (the rest stay as they are)."""
        return self._bind_from(len(self._values) - len(args), args)

    def _bind_from(self, first: int, args) -> BoundKernel:
        """`set` arguments first, first + 1, ... to ``args``, skipping the call for the
        object last passed and for a scalar made afresh with the same value (what `set`
        would find itself; a step passes dozens of those)."""
        given = self._given
        for index, value in enumerate(args, first):
            old = given[index]
            if value is not old and not (
                type(value) is type(old) and type(value) in _SCALARS and value == old
            ):
                self.set(index, value)
        return self

    def forget(self) -> None:
        """Drop the cache (after arguments were set around this object)."""
        self._values = [_UNSET] * len(self._values)
        self._given = [_UNSET] * len(self._given)

    def launch(self, global_size: int, local_size: int | None, wait_for=None) -> cl.Event:
        """Enqueue over ``global_size`` work-items (1-D) with the arguments as set, counted
        in ``runtime.counters``."""
        runtime = self.runtime
        runtime.count_launch(self.kernel)
        return cl.enqueue_nd_range_kernel(
            runtime.queue,
            self.kernel,
            (int(global_size),),
            None if local_size is None else (int(local_size),),
            wait_for=wait_for,
        )

    def over(self, count: int, local_size: int, *args) -> cl.Event:
        """`bind` ``args``, then launch over ``count`` items rounded up to whole groups
        (at least one group)."""
        if args:
            self.bind(*args)
        return self.launch(max(1, -(-int(count) // local_size)) * local_size, local_size)


#: the numpy scalar types `bind` compares by value inline (those the launchers pass)
_SCALARS = frozenset((np.uint32, np.int32, np.float32, np.uint64, np.int64))


class _Unset:
    """Marker of an argument never set through the cache (equal to nothing)."""

    def __eq__(self, other):
        return False

    __hash__ = object.__hash__


_UNSET = _Unset()


@contextlib.contextmanager
def launches_by_kernel(runtime) -> Iterator[dict[str, int]]:
    """``with launches_by_kernel(runtime) as counts:`` counts the launches ``runtime``
    enqueues inside the block by kernel name (``counts``: name -> launches; they add up to
    the block's ``runtime.counters["launches"]``). Outside such a block a launch pays one
    test for it; inside, a driver query of the name (diagnostics: a benchmark's last step)."""
    counts: dict[str, int] = {}
    previous, runtime.kernel_launches = runtime.kernel_launches, counts
    try:
        yield counts
    finally:
        runtime.kernel_launches = previous
        if previous is not None:  # (an enclosing count sees these launches too)
            for name, n in counts.items():
                previous[name] = previous.get(name, 0) + n


def bound(runtime, kernel: cl.Kernel) -> BoundKernel:
    """The one `BoundKernel` of ``kernel`` in ``runtime`` (made on first use)."""
    registry = runtime.__dict__.setdefault("_bound_kernels", {})
    entry = registry.get(kernel)
    if entry is None:
        entry = registry[kernel] = BoundKernel(runtime, kernel)
    return entry


def instance(runtime, built, name: str) -> BoundKernel:
    """A NEW kernel object of ``name`` from ``built`` (a `rbgen.codegen` built program),
    with arguments of its own: for a kernel launched with several fixed sets of scalars."""
    return bound(runtime, cl.Kernel(built.program, name))
