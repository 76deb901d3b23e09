"""Forces and torques from Python for the next step (`World.apply_forces`).

`apply_forces(ids, forces, torques=None, points=None)` adds to each body's sums for the
next step, on the host, in float64 (`numpy.add.at`: repeated ids add up in a fixed
order, so the sums are deterministic). A force given with a point of application (world
coordinates) adds a torque (point - x) x F about the centre of mass x; x is the body's
position at the step's start, which only the device knows without a blocking read, so
the host keeps sum(point x F) and sum(F) of those forces apart and the step's
preparation kernel subtracts x x sum(F): per body a ``force`` (sum F), a ``lever_force``
(sum F of the forces given with points) and a ``moment`` (torques + sum point x F).

At the step's first enqueue the sums written since the last step become float4 device
arrays (one per field written: a push without torques or points uploads 16 bytes a
body), uploaded by non-blocking copies from pinned memory and kept under the step's tag
(the World's step number) while the step may be redone: a redone step, or the next
substep of the same `World.step`, reads the same arrays again (the forces act during
the whole step: each of its substeps). The sums then start again from zero: the forces
act during one step only. A step whose redo could not be made (the World raised and
went back to before it) takes its forces with it. Pending sums follow their bodies
through `World.remove_bodies`.
"""

from __future__ import annotations

from typing import cast

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from .bodies import body_ids, floats
from .device import buffer_of
from .errors import RbgenError

#: steps back from the newest whose uploaded forces are kept (a redo reaches back at
#: most over the steps in flight, `rbgen.guard.STEPS_IN_FLIGHT`, each of them at most
#: one `World.step`)
KEEP_STEPS = 3


def _vectors(value, n: int, what: str, ids: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) finite float64 rows, or one row (3,) for all; names the bad row's body."""
    try:
        arr = floats(value)
    except (TypeError, ValueError):
        raise RbgenError(
            f"{what} must be numbers of shape ({n}, 3) or (3,), got {type(value).__name__}"
        ) from None
    if arr.shape == (3,):
        arr = np.broadcast_to(arr, (n, 3))
    if arr.shape != (n, 3):
        raise RbgenError(f"{what} must have shape ({n}, 3) or (3,) for {n} ids, got {arr.shape}")
    if not np.isfinite(arr).all():
        bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
        body = int(ids[bad[0]]) if ids is not None else int(bad[0])
        raise RbgenError(f"{what}: body {body} has a NaN or infinite value {arr[bad[0]].tolist()}")
    return arr


#: the sums kept per body, in the order of the prepare kernel's arrays and mask bits
FIELDS = ("force", "lever_force", "moment")


class ExternalForces:
    """The pending sums of one World and the uploaded arrays of its recent steps.

    The sums are three (count, 3) float64 arrays (`FIELDS`); only the fields some call
    wrote since the last step are converted and cleared (a push without torques or
    points costs one field)."""

    def __init__(self, runtime):
        self.runtime = runtime
        self.count = 0
        self._sums = [np.zeros((0, 3)) for _ in FIELDS]
        self._used = [False] * len(FIELDS)
        #: tag -> the uploaded forces of the steps that may be redone (None: the step ran
        #: without forces, and its redo must too: forces given since are the next step's)
        self._steps: dict[int, StepForces | None] = {}
        #: per field, uploads no step needs any more (reused: no allocation a step)
        self._spare: list[list[_Upload]] = [[] for _ in FIELDS]
        #: whether the World was given forces (set by it once its memory check passed):
        #: from then on its estimate counts the uploads (`rbgen.memory.FORCE_UPLOADS`)
        self.given = False

    @property
    def _pending(self) -> bool:
        return any(self._used)

    def resize(self, count: int) -> None:
        """The World's body count is now ``count`` (pending sums of kept indices stay)."""
        if count != self.count:
            keep = min(count, self.count)
            for k, old in enumerate(self._sums):
                self._sums[k] = np.zeros((count, 3))
                self._sums[k][:keep] = old[:keep]
            self.count = count
            self._spare = [[] for _ in FIELDS]

    def forget(self, tag: int) -> None:
        """The steps from ``tag`` on were undone for good: their forces go with them."""
        for old in [t for t in self._steps if t >= tag]:
            self._retire(old)

    def renumber(self, mapping: np.ndarray) -> None:
        """Bodies were removed (``mapping[old]`` is the new index or -1): pending sums
        follow their bodies; a removed body's are dropped."""
        kept = mapping >= 0
        self._sums = [sums[: len(mapping)][kept] for sums in self._sums]
        self.count = int(kept.sum())
        self._spare = [[] for _ in FIELDS]

    def drop(self, ids: np.ndarray) -> None:
        """Pending sums of bodies ``ids`` are dropped (their environment was reset)."""
        for k, used in enumerate(self._used):
            if used:
                self._sums[k][ids] = 0.0

    def drop_pending(self) -> None:
        for k, used in enumerate(self._used):
            if used:
                self._sums[k][:] = 0.0
        self._used = [False] * len(FIELDS)

    def add(self, ids, forces, torques=None, points=None) -> None:
        """Add to the sums of bodies ``ids`` (see the module docstring); every argument
        is checked before anything is added."""
        self.accumulate(*self.checked(ids, forces, torques, points))

    def checked(self, ids, forces, torques=None, points=None) -> tuple:
        """The arguments of `add` checked (errors name the argument and the body), as
        `accumulate` takes them."""
        ids = body_ids(ids, self.count, "ids")
        n = len(ids)
        force = _vectors(forces, n, "forces", ids)
        torque = None if torques is None else _vectors(torques, n, "torques", ids)
        point = None if points is None else _vectors(points, n, "points", ids)
        return ids, force, torque, point

    def accumulate(self, ids: np.ndarray, force, torque=None, point=None) -> None:
        """`add` without its checks: ``ids`` int64 in range, the rest (len(ids), 3) finite
        (a WorldBatch's, checked by it). Strictly increasing ids (a batch's, or any
        list without repeats in order) add by plain indexing; others by np.add.at, which
        sums repeats in order."""
        if len(ids) == 0:
            return
        if ids[-1] - ids[0] == len(ids) - 1 and bool(np.all(ids[1:] > ids[:-1])):
            where: slice | np.ndarray | None = slice(int(ids[0]), int(ids[-1]) + 1)
        elif bool(np.all(ids[1:] > ids[:-1])):
            where = ids
        else:
            where = None  # repeats or disorder: np.add.at

        def add(k: int, values) -> None:
            if where is None:
                np.add.at(self._sums[k], ids, values)
            else:
                self._sums[k][where] += values
            self._used[k] = True

        add(0, force)
        if point is not None:
            add(1, force)
            add(2, np.cross(point, force))
        if torque is not None:
            add(2, torque)

    def _upload(self, k: int) -> _Upload:
        """A spare upload of this body count for field ``k``, or a new one."""
        pool = self._spare[k]
        while pool:
            upload = pool.pop()
            if upload.count == max(1, self.count):
                upload.wait()
                return upload
        return _Upload(self.runtime, max(1, self.count))

    def for_step(self, tag: int) -> StepForces | None:
        """The device arrays of step ``tag`` (None: no forces), uploaded at its first
        call (non-blocking, only the fields written) and kept for a redo."""
        for old in [t for t in self._steps if t < tag - KEEP_STEPS]:
            self._retire(old)  # (older than any redo)
        if tag in self._steps:
            return self._steps[tag]
        if not self._pending:
            self._steps[tag] = None
            return None
        uploads: list[_Upload | None] = [None] * len(FIELDS)
        for k, used in enumerate(self._used):
            if used:
                upload = uploads[k] = self._upload(k)
                upload.send(self.runtime.queue, self._sums[k], self.count)
        step = self._steps[tag] = StepForces(uploads)
        self.drop_pending()
        return step

    def _retire(self, tag: int) -> None:
        step = self._steps.pop(tag)
        if step is None:
            return
        for k, upload in enumerate(step.uploads):
            if upload is not None:
                self._spare[k].append(upload)


class _Upload:
    """One field's device float4 array and the pinned host array it is copied from."""

    def __init__(self, runtime, count: int):
        self.count = count
        self.device = cla.empty(runtime.queue, count, np.dtype((np.float32, 4)))
        self.buffer = cl.Buffer(runtime.context, cl.mem_flags.ALLOC_HOST_PTR, 16 * count)
        flags = cast(cl.map_flags, cl.map_flags.READ | cl.map_flags.WRITE)
        self.host, _ = cl.enqueue_map_buffer(
            runtime.queue, self.buffer, flags, 0, (count, 4), np.dtype(np.float32)
        )
        self.host[:] = 0.0
        self.event: cl.Event | None = None

    def wait(self) -> None:
        if self.event is not None:
            self.event.wait()  # (long done: the step that used it is checked)

    def send(self, queue, sums: np.ndarray, count: int) -> None:
        """Copy ``sums`` ((count, 3) float64) to the device (non-blocking, by DMA from
        pinned memory: no staging copy)."""
        self.host[:count, :3] = sums
        self.event = cl.enqueue_copy(queue, buffer_of(self.device), self.host, is_blocking=False)


class StepForces:
    """The forces of one step as the prepare kernel takes them: a device float4 array
    per `FIELDS` entry (None: all zero, not uploaded) and the mask of those given (bit
    k: ``FIELDS[k]``)."""

    def __init__(self, uploads: list):
        self.uploads = uploads
        self.mask = sum(1 << k for k, u in enumerate(uploads) if u is not None)

    def arrays(self) -> list:
        return [None if u is None else u.device for u in self.uploads]
