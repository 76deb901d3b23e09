"""The step guard: the step report, the overflow check and the redo.

After every enqueued step the stages that can fail it (a buffer too small, a persistent
launch that gave up) have their status gathered on the device into one report, read
into pinned host memory by ONE non-blocking copy (a small copy costs a GPU queue as
much as a launch). `check` looks at the report of the step before the last, whose copy
is long done, so the host never waits for the device to drain. A step that failed is
redone with every step after it: the queue is drained, each failing stage recovers
(grows its buffer), the bodies are restored from the backup the failed step's first
kernel wrote, the constraint history is rewound, and the steps are enqueued again. So
no pair or contact is ever dropped. A persistent launch that gave up asks the World for
a new plan without persistent launches (`Replan`).

A redo that cannot be made (the growth does not fit in memory, a step that still
overflows after `MAX_REDOS`, a recovery that raises) leaves the bodies restored to
before the failed step and forgets it and the steps after it (``forget``), then raises:
the World is as it was before that step, never part-way through one.
"""

from __future__ import annotations

from typing import cast

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from .device import buffer_of
from .errors import CapacityOverflowError

#: enqueued steps whose report may be unchecked: a step checks the one before the last,
#: whose report copy is done by then (the constraint ring keeps both steps' warm starts)
STEPS_IN_FLIGHT = 2
#: redos of one step before giving up (each grows the buffers that overflowed)
MAX_REDOS = 16


class Replan(Exception):
    """A persistent launch gave up: the World must plan without persistent launches."""


class _InFlight:
    """One enqueued step: its dt, backup slot, the caller's tag (the World's step
    number), and a pinned copy of its report.

    The copy's event is kept: pyopencl returns a NannyEvent for a copy into host
    memory, and deleting one waits for its copy."""

    __slots__ = ("dt", "slot", "tag", "host", "copied")

    def __init__(self, dt, slot, tag, host, copied):
        self.dt, self.slot, self.tag, self.host, self.copied = dt, slot, tag, host, copied


class StepGuard:
    """Reports, checks and redoes the steps of one pipeline (see the module docstring)."""

    def __init__(self, runtime):
        self.runtime = runtime
        self.pipeline = None
        self.in_flight: list[_InFlight] = []
        self.serial = 0  # steps enqueued, picks the backup slot
        #: steps redone because a buffer overflowed (each grew the buffer)
        self.overflows = 0
        #: those redos by the stage that asked for them (a redo two stages asked for counts
        #: for both): a grown buffer, or the broadphase's change of algorithm
        self.overflows_by_stage: dict[str, int] = {}
        self._pinned: dict = {}  # slot -> (pinned buffer, mapped uint32 words)

    def attach(self, pipeline) -> None:
        """Lay out the report of ``pipeline``'s stages (after a build or a replan)."""
        self.pipeline = pipeline
        reporting = [s for s in pipeline.stages if s.report_words]
        reporting.sort(key=lambda s: not s.writes_report)  # (stable: step order otherwise)
        self._layout, offset = [], 0
        for stage in reporting:
            self._layout.append((stage, offset))
            offset += stage.report_words
        self.words = max(1, offset)
        self.report = cla.zeros(self.runtime.queue, self.words, np.uint32)
        for stage, offset in self._layout:
            if stage.writes_report:
                stage.attach_report(self.report, offset)
        self._pinned = {}

    def next_slot(self) -> int:
        slot = self.serial % STEPS_IN_FLIGHT
        self.serial += 1
        return slot

    def finish_step(self, dt: float, slot: int, tag: int = 0) -> None:
        """Gather the report of the step just enqueued and start its non-blocking read."""
        queue = self.runtime.queue
        for stage, offset in self._layout:
            if not stage.writes_report:
                stage.report(queue, self.report, offset)
        pinned = self._pinned.get(slot)
        if pinned is None:
            buffer = cl.Buffer(self.runtime.context, cl.mem_flags.ALLOC_HOST_PTR, 4 * self.words)
            flags = cast(cl.map_flags, cl.map_flags.READ | cl.map_flags.WRITE)
            host, _ = cl.enqueue_map_buffer(
                queue, buffer, flags, 0, (self.words,), np.dtype(np.uint32)
            )
            pinned = self._pinned[slot] = (buffer, host)
        host = pinned[1]
        self.in_flight.append(
            _InFlight(
                dt,
                slot,
                tag,
                host,
                cl.enqueue_copy(queue, host, buffer_of(self.report), is_blocking=False),
            )
        )

    def drop(self, steps: int) -> None:
        """Forget the last ``steps`` enqueued steps (they are being redone). Their redo
        takes their backup slots, so that a step's slot follows its place in the step
        sequence, as a C++ host replaying `rbgen.schedule` assumes."""
        del self.in_flight[len(self.in_flight) - steps :]
        self.serial -= steps

    def problems(self, entry: _InFlight) -> dict:
        """The failing stages of a step and what each reported."""
        entry.copied.wait()
        found = {}
        for stage, offset in self._layout:
            problem = stage.problem(entry.host[offset : offset + stage.report_words])
            if problem is not None:
                found[stage] = problem
        return found

    def check(self, keep: int, restore, rewind, enqueue, afford=None, forget=None) -> None:
        """Check the oldest enqueued steps until at most ``keep`` remain unchecked; redo
        from a failed one: ``restore(slot, tag)`` restores the bodies of that backup slot (the
        failed step, tagged ``tag``, found them so),
        ``rewind(steps)`` forgets that many steps' constraint history, ``enqueue(dt,
        tag)`` enqueues a step, ``afford(problems)`` raises when the recoveries would not
        fit in memory, ``forget(tag)`` is told that the steps from the one tagged
        ``tag`` are undone for good (then the error is raised). Raises `Replan` (the
        steps are then forgotten, not redone: its argument lists their (dt, tag)) when a
        persistent launch gave up."""
        redone = 0
        while len(self.in_flight) > keep:
            entry = self.in_flight[0]
            problems = self.problems(entry)
            if not problems:
                self.in_flight.pop(0)
                continue
            redone += 1
            self.runtime.queue.finish()
            redo = [(e.dt, e.tag) for e in self.in_flight]
            restore(entry.slot, entry.tag)
            rewind(len(redo))
            self.drop(len(redo))
            solve = self.pipeline.solve
            if solve in problems:
                solve.clear_abandoned()
                self.report.fill(np.uint32(0))
                raise Replan(redo)
            try:
                if redone > MAX_REDOS:
                    raise CapacityOverflowError(
                        f"a step still overflowed after {MAX_REDOS} redos with grown buffers "
                        f"({', '.join(f'{s.name}: {p}' for s, p in problems.items())}); the "
                        f"World is as it was before that step"
                    )
                if afford is not None:
                    afford(problems)
                for stage, problem in problems.items():
                    stage.recover(problem)
            except BaseException:
                self.report.fill(np.uint32(0))
                if forget is not None:
                    forget(entry.tag)
                raise
            self.overflows += 1
            for stage in problems:
                self.overflows_by_stage[stage.name] = self.overflows_by_stage.get(stage.name, 0) + 1
            for dt, tag in redo:
                enqueue(dt, tag)
