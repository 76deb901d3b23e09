"""A World's step as a launch schedule that a C++ host replays (``schedule.json``).

The schedule is data the World's own steps produce, not a second implementation: a
`rbgen.schedule.record.Recorder` captures every command a World enqueues, and
`record_schedule` runs the World a few times to learn what changes with its capacities:

1. the main run: the World at its initial capacities (each rounded up to a power of two),
   `MAIN_STEPS` steps, each followed by simulated redos of the last one and two steps;
2. one sweep per capacity a stage grows on overflow: that capacity from 1 up to
   ``2 ** grow_rungs`` times its initial value, doubling, a few steps at each value
   (and redos), the others at their initial values.

`rbgen.schedule.infer` turns the runs into step variants (a prologue and a cycle, e.g.
the constraint ring's four generations), numbers that are constants or tables over a
capacity's powers of two, followers (capacities that catch up lazily), renewals and the
undo before a redo; `rbgen.schedule.format` writes the file and checks every recorded
number against it. ``rbgen/host/SCHEDULE.md`` is the format's description for hosts.
"""

from __future__ import annotations

from .drive import Run
from .infer import Inference, Variants, find_cycle, split

#: steps of the main run (enough for a prologue and two cycles of the longest kinds)
MAIN_STEPS = 16
#: default: how many doublings above its initial value each capacity is recorded for
GROW_RUNGS = 2


def ceil_rung(value: int) -> int:
    """The smallest k with 2**k >= value (value >= 1)."""
    return max(0, int(value) - 1).bit_length()


def record_schedule(
    build, initial: dict[str, int], *, dt: float = 1 / 60, grow_rungs: int = GROW_RUNGS
) -> tuple[Inference, list[Run]]:
    """Record the runs of the World that ``build()`` makes (a fresh, unstepped World each
    call) and infer its schedule. ``initial``: each grown capacity's initial value (rounded
    up to a power of two). Returns the inference and the runs (closed; their Worlds hold
    the recorded buffers until they are dropped)."""
    rungs = {name: ceil_rung(value) for name, value in initial.items()}
    max_rungs = {name: r + int(grow_rungs) for name, r in rungs.items()}
    runs: list[Run] = []
    try:
        main = Run(build, dt, {name: 1 << r for name, r in rungs.items()})
        runs.append(main)
        for n in range(MAIN_STEPS):
            main.step()
            for count in (1, 2):
                if n + 1 >= count:
                    main.redo(count)
        main.close()
        sizes = [b.size for b in sorted(main.recorder.buffers.values(), key=lambda b: b.index)]
        variants = Variants(
            *find_cycle([[split(c, sizes) for c in s.commands] for s in main.steps])
        )
        per_rung = 2 * variants.cycle + 1  # (a transition, a steady cycle, a new position)
        sweeps = {}
        for name in rungs:
            run = Run(build, dt, {**{n: 1 << r for n, r in rungs.items()}, name: 1})
            runs.append(run)
            for r in range(max_rungs[name] + 1):
                if r:
                    run.grow(name, 1 << r)
                for _ in range(per_rung + (0 if r else variants.prologue)):
                    run.step()
                run.redo(1)
                run.redo(2)
            run.close()
            sweeps[name] = run
        return Inference(main, sweeps, max_rungs), runs
    except BaseException:
        for run in runs:
            run.close()
        raise


__all__ = ["GROW_RUNGS", "MAIN_STEPS", "Inference", "Run", "ceil_rung", "record_schedule"]
