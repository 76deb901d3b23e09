"""Driving a World through the steps a schedule is recorded from.

A `Run` is one fresh World (from the caller's ``build``), recorded from its first step:
its steps are enqueued as the World enqueues them (``World._enqueue_step``), but never
checked: an overflowed step is not redone, so that every step's commands are the ones a
step enqueues, whatever its buffers held. `grow` sets a capacity between steps, as a
stage's `recover` does after an overflow (to an exact value: `Stage.set_capacity`), and
`redo` replays the guard's redo of the last steps (restore the bodies, rewind the
constraint ring, enqueue them again), recording what the restore and the rewind enqueue.
The World is thrown away afterwards: its bodies hold whatever the unchecked steps made.
"""

from __future__ import annotations

import dataclasses

from ..errors import RbgenError
from ..guard import STEPS_IN_FLIGHT
from .record import Command, Recorder


@dataclasses.dataclass
class RecordedStep:
    """One enqueued step: its commands and every capacity once it was enqueued."""

    commands: list[Command]
    values: dict[str, int]


@dataclasses.dataclass
class Redo:
    """A simulated redo from step ``first`` of ``count`` steps: what the restore and the
    rewind enqueued, and the redone steps' commands."""

    first: int
    count: int
    undo: list[Command]
    steps: list[list[Command]]


class Run:
    """One World recorded from its first step (see the module docstring).

    ``capacities``: the value of each capacity a stage grows on overflow, set before the
    first step (names as `rbgen.pipeline.step.Stage.capacities` gives them)."""

    def __init__(self, build, dt: float, capacities: dict[str, int]):
        from ..world import World

        world = build()
        if not isinstance(world, World):
            raise RbgenError(
                f"schedule: build() returned {type(world).__name__}, not an rbgen.World"
            )
        if world.steps or world._pipeline is not None:
            raise RbgenError(
                "schedule: build() must return a World that has not stepped yet "
                "(a schedule is recorded from the first step)"
            )
        self.world, self.dt = world, float(dt)
        self.recorder = Recorder(world.runtime).__enter__()
        self._recording = True
        self.steps: list[RecordedStep] = []
        self.redos: list[Redo] = []
        #: capacities set before step n (n -> {name: value})
        self.grown: dict[int, dict[str, int]] = {}
        try:
            if world._bodies.count == 0 or not world._bodies.has_dynamic:
                raise RbgenError("schedule: the World has no dynamic body (nothing to step)")
            world._upload()
            pipeline = world._steps
            self.owner = {
                name: stage
                for stage in pipeline.stages
                for name in stage.report_protocol().get("capacities", {})
            }
            for name, value in capacities.items():
                self._set(name, value)
            if self.recorder.take():
                raise RbgenError("schedule: the World enqueued commands before its first step")
        except BaseException:
            self.close()
            raise

    @property
    def pipeline(self):
        return self.world._steps

    def values(self) -> dict[str, int]:
        """Every stage's capacities now."""
        found: dict[str, int] = {}
        for stage in self.pipeline.stages:
            found.update(stage.capacities())
        return found

    def _set(self, name: str, value: int) -> None:
        if name not in self.owner:
            raise RbgenError(
                f"schedule: no stage grows a capacity named {name!r}; "
                f"capacities: {sorted(self.owner)}"
            )
        self.owner[name].set_capacity(name, int(value))

    def step(self) -> RecordedStep:
        """Enqueue one step (unchecked) and record it."""
        self.world._enqueue_step(self.dt)
        self.world._guard.in_flight.clear()  # (never checked: see the module docstring)
        recorded = RecordedStep(self.recorder.take(), self.values())
        self.steps.append(recorded)
        return recorded

    def grow(self, name: str, value: int) -> None:
        """Set a capacity before the next step (as `recover` does after an overflow)."""
        self._set(name, value)
        self.grown.setdefault(len(self.steps), {})[name] = int(value)
        if self.recorder.take():
            raise RbgenError(
                f"schedule: growing {name} enqueued commands (a stage's "
                f"set_capacity must only reallocate)"
            )

    def redo(self, count: int) -> Redo:
        """Redo the last ``count`` steps as the step guard does, recording it."""
        world, guard = self.world, self.world._guard
        first = len(self.steps) - count
        world.runtime.queue.finish()
        guard.drop(count)
        slot = guard.serial % STEPS_IN_FLIGHT
        world._restore(slot)
        world._pipeline_rewind(count)
        undo = self.recorder.take()
        steps = []
        for _ in range(count):
            world._enqueue_step(self.dt)
            guard.in_flight.clear()
            steps.append(self.recorder.take())
        redo = Redo(first, count, undo, steps)
        self.redos.append(redo)
        return redo

    def close(self) -> None:
        """Stop recording (what was recorded stays; the World is left to be thrown away)."""
        if self._recording:
            self._recording = False
            self.recorder.__exit__(None, None, None)
            try:
                self.world.runtime.queue.finish()
            except Exception:  # noqa: BLE001 - a broken queue: nothing more to wait for
                pass
