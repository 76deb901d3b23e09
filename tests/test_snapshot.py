"""World.snapshot_frame (issue 28): a non-blocking read of the transforms gives, bit for bit,
what a blocking read at the snapshot gives, whatever the World does before `result`:
later steps, redone steps, bodies removed or added; an empty World too."""

from __future__ import annotations

import gc

import numpy as np
import pytest

import rbgen
from rbgen.errors import MemoryLimitError, RbgenError
from rbgen.render.scene import Frame, frame_of
from rbgen.snapshot import PendingFrame
from rbgen.world import World

BOX = rbgen.Box((0.5, 0.5, 0.5))
DT = 1 / 60


def pile(world, count=8, gap=0.05):
    """A ground and ``count`` boxes in a leaning tower, ``gap`` apart (they topple: every
    step moves them)."""
    world.add_static(rbgen.Box((20, 1, 20)), position=(0, -1, 0))
    world.add_bodies(
        BOX, positions=[[0.15 * i, 0.5 + (1 + gap) * i, 0.05 * i] for i in range(count)]
    )
    return world


def assert_frames_equal(a: Frame, b: Frame):
    assert a.positions.dtype == b.positions.dtype == np.float32
    assert a.orientations.dtype == b.orientations.dtype == np.float32
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.orientations, b.orientations)


def test_later_steps_do_not_change_a_snapshot(runtime):
    """A snapshot, then 10 more steps: its frame is the blocking read's at the snapshot
    (the bodies have moved since); its arrays are the caller's (writeable, contiguous,
    not the pinned buffer a later snapshot reuses)."""
    world = pile(World(runtime))
    for _ in range(5):
        world.step(DT)
    pending = world.snapshot_frame()
    assert isinstance(pending, PendingFrame) and pending.count == 9 and pending.step == 5
    blocking = frame_of(world)  # (reads the same state: nothing ran in between)
    for _ in range(10):
        world.step(DT)
    assert not np.array_equal(world.positions, blocking.positions)  # (they moved)
    frame = pending.result()
    assert_frames_equal(frame, blocking)
    assert pending.wait() is frame and pending.done()
    assert frame.positions.flags.c_contiguous and frame.positions.flags.writeable
    later = world.snapshot_frame().result()  # (may reuse the pinned buffer)
    assert_frames_equal(frame, blocking)
    assert_frames_equal(later, frame_of(world))


def test_snapshot_of_a_state_the_host_holds_is_ready_at_once(runtime):
    """Before the first step, after a set or a blocking read, the host copy is the state:
    no copy is enqueued and the frame equals the blocking read."""
    world = pile(World(runtime))
    pending = world.snapshot_frame()
    assert pending.done()
    assert_frames_equal(pending.result(), frame_of(world))
    world.step(DT)
    world.positions = world.positions + np.float32(0.25)
    assert_frames_equal(world.snapshot_frame().result(), frame_of(world))


def test_snapshots_of_overflowing_steps_are_the_redone_state(runtime):
    """One-pair and one-manifold buffers overflow and redo steps (a snapshot taken after
    a step that is later redone is copied again after the redone step): every snapshot
    equals, bit for bit, the blocking read of the same scene with ample buffers, whether
    it is resolved at once or 20 steps later."""
    small = pile(World(runtime, pair_capacity=1, manifold_capacity=1))
    ample = pile(World(runtime))
    snapshots, expected = [], []
    for step in range(20):
        small.step(DT)
        ample.step(DT)
        pending = small.snapshot_frame()
        if step % 3 == 0:
            pending.result()  # (resolved at once: its own check redoes the step)
        snapshots.append(pending)
        expected.append(frame_of(ample))
    assert small.overflows >= 1 and ample.overflows == 0
    assert any(p._copies > 1 for p in snapshots)  # (some were copied again by a redo)
    for pending, frame in zip(snapshots, expected):
        assert_frames_equal(pending.result(), frame)
    assert_frames_equal(frame_of(small), frame_of(ample))


def test_removed_and_added_bodies_do_not_change_a_snapshot(runtime):
    """Bodies removed, then added, then steps, between a snapshot and its result: the
    frame keeps the snapshot's bodies and values."""
    world = pile(World(runtime))
    for _ in range(4):
        world.step(DT)
    pending = world.snapshot_frame()
    blocking = frame_of(world)
    world.remove_bodies([1, 2, 3])
    world.step(DT)
    world.add_bodies(rbgen.Sphere(0.3), positions=[[3, 2, 0], [4, 2, 0]])
    for _ in range(3):
        world.step(DT)
    assert world.body_count == 8 and pending.count == 9
    assert_frames_equal(pending.result(), blocking)


def test_empty_world_snapshot_is_the_blocking_read(runtime):
    """No bodies (before and after a step, and after every body is removed): an empty
    frame, as the blocking read gives."""
    world = World(runtime)
    for _ in range(2):
        pending = world.snapshot_frame()
        assert pending.count == 0
        frame = pending.result()
        assert frame.positions.shape == (0, 3) and frame.orientations.shape == (0, 4)
        assert_frames_equal(frame, frame_of(world))
        world.step(DT)
    world = pile(World(runtime), 2)
    world.step(DT)
    world.remove_bodies(np.arange(world.body_count))
    world.step(DT)
    assert_frames_equal(world.snapshot_frame().result(), frame_of(world))


def test_dropped_snapshots_leave_the_world_stepping(runtime):
    """Snapshots never resolved (dropped) hold nothing the World needs: redos go on."""
    small = pile(World(runtime, pair_capacity=1, manifold_capacity=1))
    for _ in range(6):
        small.step(DT)
        small.snapshot_frame()
        gc.collect()
    assert small.overflows >= 1
    ample = pile(World(runtime))
    for _ in range(6):
        ample.step(DT)
    assert_frames_equal(frame_of(small), frame_of(ample))


def test_snapshot_after_a_step_that_could_not_be_redone_has_no_state(runtime):
    """A growth refused by the memory limit undoes the step (`rbgen.guard`): the snapshot
    taken after it raises as the blocking read does, then says it has no state."""
    probe = pile(World(runtime, pair_capacity=1, manifold_capacity=1), gap=0)
    held = probe._memory.need(probe.body_count, probe.shapes.type_names()).total
    world = World(runtime, pair_capacity=1, manifold_capacity=1, memory_limit=held + 1024)
    pile(world, gap=0)  # (boxes in touch: the first step overflows)
    world.step(DT)
    pending = world.snapshot_frame()
    with pytest.raises(MemoryLimitError):
        pending.result()
    with pytest.raises(RbgenError, match="no state"):
        pending.result()
