"""Reads of a World's transforms that do not drain its queue: `World.snapshot_frame`.

A blocking read (``World.positions``, `rbgen.render.scene.frame_of`) waits for every
enqueued step to finish before it copies the bodies back, so the host stops feeding the
device and the overlap of host and device is lost at each read. A snapshot instead
enqueues ONE non-blocking copy of the body records, in queue order after the steps
enqueued so far, into pinned host memory, and returns a `PendingFrame`; its `result`
waits for that copy only (and for the report copies of the steps before it, which the
queue finished before the copy), and gives the same `Frame` a blocking read made at the
snapshot would have given, bit for bit:

* later steps cannot change it: they are enqueued after the copy on the World's in-order
  queue, so the copy reads the records before any of them runs;
* a step before the snapshot that overflowed is redone (`rbgen.guard`) with every step
  after it; the redo enqueues the snapshot's copy again right after the redone step it
  followed, so the frame is the redone state, as a blocking read would have seen it;
  `result` checks the steps the snapshot follows before it trusts the copy;
* adding or removing bodies after the snapshot changes nothing in it: it owns its host
  memory and keeps the body count it was taken with (`PendingFrame.count`);
* a step before the snapshot that could not be redone (`rbgen.errors.CapacityOverflowError`:
  the World went back to before it) leaves no state to give: `result` raises
  `RbgenError` saying so.

Pinned buffers are reused from a small pool per World (`SnapshotCopies`): a recording that
keeps one snapshot pending at a time alternates between two.
"""

from __future__ import annotations

import weakref
from typing import TYPE_CHECKING, cast

import numpy as np
import pyopencl as cl

from . import layouts
from .device import buffer_of
from .errors import RbgenError
from .render.scene import Frame

if TYPE_CHECKING:
    from .world import World

#: free pinned buffers a World keeps for later snapshots
POOL_SIZE = 2


class _Pinned:
    """A pinned (``ALLOC_HOST_PTR``, mapped once) host array of ``capacity`` body records.

    The map is not waited for (a blocking map would drain the queue): the copies into
    it are enqueued after it on the same in-order queue, and the host reads it only
    after a copy's event."""

    __slots__ = ("buffer", "records", "capacity")

    def __init__(self, runtime, capacity: int):
        self.capacity = capacity
        self.buffer = cl.Buffer(
            runtime.context, cl.mem_flags.ALLOC_HOST_PTR, capacity * layouts.BODY.itemsize
        )
        flags = cast(cl.map_flags, cl.map_flags.READ | cl.map_flags.WRITE)
        self.records, _ = cl.enqueue_map_buffer(
            runtime.queue, self.buffer, flags, 0, (capacity,), layouts.BODY.dtype, is_blocking=False
        )


class PendingFrame:
    """The transforms of a World's bodies at one instant, on their way to the host.

    Made by `World.snapshot_frame` (see `rbgen.snapshot`): ``count`` is the number of
    bodies then, ``step`` the World's step count then. `result` (or `wait`) waits for the
    snapshot's copy only and returns the `rbgen.render.Frame` a blocking read at the
    snapshot would have returned, whatever the World did since; later calls return the
    same Frame. `done` tells, without waiting, whether the copy has completed.
    """

    def __init__(self, count: int, step: int, frame: Frame | None = None):
        self.count = count
        self.step = step
        self._frame = frame
        self._error: str | None = None
        # set while the copy is pending (a snapshot read from the host copy has none)
        self._world: World | None = None
        self._pinned: _Pinned | None = None
        self._event: cl.Event | None = None
        #: the World's step tag the snapshot follows (its steps' in-flight entries)
        self._after_tag = step - 1
        #: the copy read a state that a redo replaced (copied again when the redo reaches
        #: the snapshot's place)
        self._stale = False
        self._copies = 0

    # ------------------------------------------------------------- reading
    def result(self) -> Frame:
        """The snapshot's `Frame` (waits for its copy; `RbgenError` if the steps before it
        were undone, `rbgen.errors.CapacityOverflowError` if checking them fails so)."""
        if self._frame is not None:
            return self._frame
        if self._error is not None:
            raise RbgenError(self._error)
        world = self._world
        assert world is not None and self._event is not None  # (pending until resolved)
        while True:
            copies = self._copies
            self._event.wait()
            # the steps the snapshot follows must have passed their check: one that failed
            # is redone now, and its redo copies the snapshot again (then wait for that)
            world._snapshots.settle(world, self)
            if self._error is not None:
                raise RbgenError(self._error)
            assert not self._stale  # (a redo copies it again before its check returns)
            if self._copies == copies:
                break
        records = self._pinned_records()
        # (copies: the pinned buffer goes back to the pool)
        frame = Frame(records["position"][:, :3].copy(), records["orientation"].copy())
        self._frame = frame
        world._snapshots.release(self)
        return frame

    def wait(self) -> Frame:
        """`result`: the snapshot's Frame, once its copy is done."""
        return self.result()

    def done(self) -> bool:
        """Whether the copy has completed (`result` may still check the steps before it).
        Never waits."""
        if self._event is None:
            return True
        status = self._event.command_execution_status
        return bool(status == cl.command_execution_status.COMPLETE)

    def _pinned_records(self) -> np.ndarray:
        assert self._pinned is not None
        return self._pinned.records[: self.count]

    def __repr__(self) -> str:
        state = "resolved" if self._frame is not None else "pending"
        return f"PendingFrame({self.count} bodies after step {self.step}, {state})"


class SnapshotCopies:
    """A World's snapshots: the pool of pinned buffers, the snapshots whose steps may
    still be redone, and what a redo does to them (`World` calls `invalidate`,
    `copy_before` and `copy_stale` from its redo path, `forget` when steps are undone)."""

    def __init__(self, runtime):
        self.runtime = runtime
        self._free: list[_Pinned] = []
        #: pending snapshots whose copy is on the device queue (dropped ones vanish)
        self._live: weakref.WeakSet[PendingFrame] = weakref.WeakSet()

    # ------------------------------------------------------------- snapshots
    def take(self, world: World) -> PendingFrame:
        """A snapshot of ``world`` (see `World.snapshot_frame`)."""
        bodies = world._bodies
        count = bodies.count
        if count == 0 or bodies.device_stale or not bodies.host_stale:
            # the host copy is the current state (nothing stepped since it was read, or
            # bodies added or set since the last step): no device read is needed
            host = bodies.host
            frame = Frame(host["position"][:, :3].copy(), host["orientation"].copy())
            return PendingFrame(count, world.steps, frame)
        pending = PendingFrame(count, world.steps)
        pending._world = world
        pending._pinned = self._claim(count)
        self._copy(world, pending)
        self._live.add(pending)
        return pending

    def _claim(self, count: int) -> _Pinned:
        """A free pinned buffer of at least ``count`` records (the smallest such), or a new
        one."""
        for k in reversed(range(len(self._free))):  # (largest first in the list)
            if self._free[k].capacity >= count:
                return self._free.pop(k)
        return _Pinned(self.runtime, count)

    def _copy(self, world: World, pending: PendingFrame) -> None:
        pending._event = cl.enqueue_copy(
            self.runtime.queue,
            pending._pinned_records(),
            buffer_of(world._device.bodies),
            is_blocking=False,
        )
        pending._copies += 1

    def release(self, pending: PendingFrame) -> None:
        """``pending`` is resolved: its pinned buffer goes back to the pool."""
        self._live.discard(pending)
        pinned, pending._pinned, pending._world, pending._event = pending._pinned, None, None, None
        if pinned is not None:
            # (the largest kept: a count that grew must not leave only small ones)
            self._free.append(pinned)
            self._free.sort(key=lambda p: -p.capacity)
            del self._free[POOL_SIZE:]

    def settle(self, world: World, pending: PendingFrame) -> None:
        """Check the enqueued steps up to the snapshot's (not the ones after it)."""
        later = sum(1 for e in world._guard.in_flight if e.tag > pending._after_tag)
        world._check_in_flight(keep=later)

    # ------------------------------------------------------------- redos
    def invalidate(self, failed_tag: int) -> None:
        """A redo restored the bodies to before the step tagged ``failed_tag``: the
        snapshots that followed it read a state the redo replaces."""
        for pending in list(self._live):
            if pending._after_tag >= failed_tag:
                pending._stale = True

    def copy_before(self, world: World, tag: int) -> None:
        """A redone step tagged ``tag`` is about to be enqueued: copy again the replaced
        snapshots that come before it."""
        self._copy_stale(world, lambda p: p._after_tag < tag)

    def copy_stale(self, world: World) -> None:
        """The redo is enqueued: copy again the replaced snapshots still waiting (they
        followed its last step)."""
        self._copy_stale(world, lambda p: True)

    def _copy_stale(self, world: World, which) -> None:
        """Copy again, in the order they were taken, the replaced snapshots ``which``
        selects (a World keeps a few live snapshots: the scan is short)."""
        for pending in sorted(self._live, key=lambda p: p._after_tag):
            if pending._stale and which(pending):
                self._copy(world, pending)
                pending._stale = False

    def forget(self, tag: int) -> None:
        """The steps from the one tagged ``tag`` were undone for good: the snapshots that
        followed them have no state to give."""
        for pending in list(self._live):
            if pending._after_tag >= tag:
                pending._stale = False
                pending._error = (
                    f"the snapshot after step {pending.step} has no state: step {tag} "
                    f"before it could not be redone, and the World went back to before it"
                )
                self.release(pending)
