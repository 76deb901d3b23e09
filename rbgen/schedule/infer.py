"""From recorded runs to a schedule: the step variants, and every number as a function of
the capacities.

Inputs (`rbgen.schedule.drive`): the main run (a World at its initial capacities, with
simulated redos) and one sweep per capacity that a stage grows on overflow (a World that
starts that capacity at 1 and doubles it, up to the largest the schedule covers, a few
steps at each value). Every capacity in a recording is a power of two, its "rung".

* **Variants**: the main run's steps are a prologue and a cycle (the smallest period that
  repeats at least twice): step n enqueues variant ``n`` before the prologue's end, else
  ``p + (n - p) % c``. Every step of every run must be its variant's commands with the
  same kernels and buffers in the same places; only numbers may differ.
* **Numbers** (a scalar argument, a global size, a fill's or copy's offset and size,
  a buffer's size) are constants, or a table over the rungs of one capacity, found by
  trying the capacities in turn: the first whose rungs determine every sample wins.
  Capacities that a stage declares but does not grow (a ring generation's) are
  "followers": they take their leader's value when a step of certain variants finds
  them smaller, learnt from the sweeps and checked against every step.
* **Renewal**: a buffer that Python reallocated when a capacity changed is reallocated
  (with its initial contents) by the host when that capacity changes.
* **Undo**: what restoring the bodies and rewinding the stages enqueue before a redo,
  per variant of the first redone step.

Anything that does not fit (a number no capacity explains, a step that is not its
variant, a buffer reallocated without a capacity change) raises `RbgenError` naming the
kernel and argument, so that an export never writes a schedule that replays wrongly.
"""

from __future__ import annotations

import dataclasses

from ..errors import RbgenError
from .record import Command, Recorder

#: the cycle lengths and prologue lengths a schedule may have
MAX_CYCLE = 8
MAX_PROLOGUE = 4


@dataclasses.dataclass
class Structure:
    """A command without its numbers: what must be the same in every run."""

    key: tuple
    quantities: list


def split(command: Command, sizes: list[int]) -> tuple[tuple, list]:
    """(structure, numbers) of a command; ``sizes``: the run's buffer sizes by index."""
    op = command[0]
    if op == "launch":
        _, kernel, args, global_size, local_size = command
        if len(global_size) != 1 or (local_size is not None and len(local_size) != 1):
            raise RbgenError(f"a launch of kernel {kernel} is not one-dimensional")
        structure = (
            "launch",
            kernel,
            tuple(a if a[0] in ("buffer", "null") else (a[0],) for a in args),
        )
        numbers = [a[1] for a in args if a[0] in ("scalar", "local")]
        numbers += [global_size[0], None if local_size is None else local_size[0]]
        return structure, numbers
    if op == "fill":
        _, buffer, pattern, offset, size = command
        whole = offset == 0 and size == sizes[buffer]
        return ("fill", buffer), [pattern, offset, "whole" if whole else size]
    if op == "copy":
        _, dst, src, dst_offset, src_offset, size = command
        whole = dst_offset == src_offset == 0 and size == sizes[dst] == sizes[src]
        return ("copy", dst, src), [dst_offset, src_offset, "whole" if whole else size]
    if op == "write":
        _, buffer, offset, data = command
        return ("write", buffer), [offset, data]
    raise RbgenError(f"unknown recorded command {op!r}")


def _buffers(key: tuple) -> list[int]:
    if key[0] == "launch":
        return [a[1] for a in key[2] if a[0] == "buffer"]
    return list(key[1:])


def _relabel(key: tuple, buffers: dict, kernels: dict) -> tuple:
    if key[0] == "launch":
        return (
            "launch",
            kernels[key[1]],
            tuple(("buffer", buffers[a[1]]) if a[0] == "buffer" else a for a in key[2]),
        )
    return (key[0], *(buffers[b] for b in key[1:]))


def find_cycle(steps: list[list]) -> tuple[int, int]:
    """(prologue, cycle) of a list of steps: the shortest cycle, then the shortest
    prologue, such that the steps after the prologue repeat with that period at least
    twice."""
    for cycle in range(1, MAX_CYCLE + 1):
        for prologue in range(0, MAX_PROLOGUE + 1):
            if len(steps) - prologue < 2 * cycle + 1:
                break
            if all(steps[i] == steps[i + cycle] for i in range(prologue, len(steps) - cycle)):
                return prologue, cycle
    raise RbgenError(
        f"schedule: the World's {len(steps)} recorded steps do not repeat with "
        f"a period of at most {MAX_CYCLE} steps after at most {MAX_PROLOGUE}: "
        f"a step enqueues something that changes every step"
    )


class Variants:
    """Step n's variant for a prologue of ``p`` and a cycle of ``c`` steps."""

    def __init__(self, prologue: int, cycle: int):
        self.prologue, self.cycle = prologue, cycle

    def __call__(self, n: int) -> int:
        p, c = self.prologue, self.cycle
        return n if n < p else p + (n - p) % c

    def __len__(self) -> int:
        return self.prologue + self.cycle


def rung(value: int, name: str) -> int:
    if value < 1 or value & (value - 1):
        raise RbgenError(
            f"schedule: capacity {name} = {value} in a recording is not a power "
            f"of two (the recordings set every capacity to one)"
        )
    return value.bit_length() - 1


class Inference:
    """The schedule's content, inferred from ``main`` and ``sweeps`` (see the module
    docstring). ``max_rungs``: the largest rung each grown capacity reaches in its sweep.
    """

    def __init__(self, main, sweeps: dict, max_rungs: dict[str, int]):
        self.main, self.sweeps, self.max_rungs = main, sweeps, dict(max_rungs)
        self.runs = [main, *sweeps.values()]
        main_rec: Recorder = main.recorder
        self.kernels = sorted(main_rec.kernels.values(), key=lambda k: k.index)
        self.buffers = sorted(main_rec.buffers.values(), key=lambda b: b.index)
        sizes = [b.size for b in self.buffers]
        full = [[split(c, sizes) for c in step.commands] for step in main.steps]
        self.variants = Variants(*find_cycle(full))
        #: per variant: [(structure key, numbers)] of the main run
        self.steps = [full[v] for v in range(len(self.variants))]
        self.grown = sorted(main.owner)
        self.followers = sorted(
            {name for step in main.steps for name in step.values} - set(self.grown)
        )
        self.vars = self.grown + self.followers
        self._check_redos(sizes)
        self._gather()
        self._learn_followers()
        self._learn_renewals()

    # ------------------------------------------------------------------ main run
    def _check_redos(self, sizes: list[int]) -> None:
        """Redone steps are their variants; the undo of a redo depends only on the variant
        of its first step (its commands' structure is the main run's)."""
        self.undo: dict[int, list] = {}
        for redo in self.main.redos:
            for k, commands in enumerate(redo.steps):
                v = self.variants(redo.first + k)
                if [split(c, sizes) for c in commands] != self.steps[v]:
                    raise RbgenError(
                        f"schedule: a redone step (variant {v}) enqueued other "
                        f"commands than the step it redoes"
                    )
            undo = [split(c, sizes) for c in redo.undo]
            v = self.variants(redo.first)
            if [k for k, _ in self.undo.setdefault(v, undo)] != [k for k, _ in undo]:
                raise RbgenError(
                    f"schedule: restoring and rewinding before a redo from a "
                    f"step of variant {v} enqueued different commands for "
                    f"different redos"
                )
        missing = [v for v in range(len(self.variants)) if v not in self.undo]
        if missing:
            raise RbgenError(f"schedule: no redo was recorded from a step of variants {missing}")

    # ------------------------------------------------------------------ samples
    def _gather(self) -> None:
        """Align every run's steps with the variants; collect each number's samples with
        the capacities' rungs at that step, and each buffer's objects over time."""
        #: number key -> [(value, state index)]; states: [{capacity: rung}]
        self.samples: dict[tuple, list] = {}
        self.states: list[dict[str, int]] = []
        #: per run: per step: {capacity: value}
        self.values: list[list[dict[str, int]]] = []
        #: (run index, logical buffer) -> [(step, object index)]
        self.objects: dict[tuple[int, int], list[tuple[int, int]]] = {}
        for r, run in enumerate(self.runs):
            rec: Recorder = run.recorder
            infos = sorted(rec.buffers.values(), key=lambda b: b.index)
            sizes = [b.size for b in infos]
            bmap: dict[int, int] = {} if r else {b.index: b.index for b in self.buffers}
            kmap: dict[int, int] = {} if r else {k.index: k.index for k in self.kernels}
            run_values = []
            for n, step in enumerate(run.steps):
                v = self.variants(n)
                expected = self.steps[v]
                got = [split(c, sizes) for c in step.commands]
                if len(got) != len(expected):
                    raise RbgenError(
                        self._mismatch(r, n, v, f"{len(got)} commands instead of {len(expected)}")
                    )
                state = {name: rung(value, name) for name, value in step.values.items()}
                self.states.append(state)
                s = len(self.states) - 1
                run_values.append(step.values)
                for i, ((key, numbers), (want, _)) in enumerate(zip(got, expected)):
                    self._map(key, want, bmap, kmap, r, n, v, i)
                    for j, value in enumerate(numbers):
                        self.samples.setdefault(("step", v, i, j), []).append((value, s))
                    for obj in _buffers(key):
                        logical = bmap[obj]
                        self.objects.setdefault((r, logical), []).append((n, obj))
                        self.samples.setdefault(("size", logical), []).append((sizes[obj], s))
            for redo in run.redos:  # (enqueued after step redo.first + redo.count - 1)
                v = self.variants(redo.first)
                s = len(self.states) - len(run.steps) + redo.first + redo.count - 1
                got = [split(c, sizes) for c in redo.undo]
                if [k[0] for k, _ in got] != [k[0] for k, _ in self.undo[v]]:
                    raise RbgenError(
                        f"schedule: the undo before a redo from a step of "
                        f"variant {v} differs between runs"
                    )
                for i, ((key, numbers), (want, _)) in enumerate(zip(got, self.undo[v])):
                    self._map(key, want, bmap, kmap, r, redo.first, v, i)
                    for j, value in enumerate(numbers):
                        self.samples.setdefault(("undo", v, i, j), []).append((value, s))
                for k, commands in enumerate(redo.steps):
                    redone = [split(c, sizes) for c in commands]
                    expected_step = self.steps[self.variants(redo.first + k)]
                    for i, ((key, _), (w, _)) in enumerate(zip(redone, expected_step)):
                        self._map(key, w, bmap, kmap, r, redo.first + k, v, i)
            self.values.append(run_values)
            run.logical = bmap  # (object index -> logical buffer, for the inits)

    def _map(self, key, want, bmap, kmap, r, n, v, i) -> None:
        if (
            key[0] != want[0]
            or len(key) != len(want)
            or (key[0] == "launch" and len(key[2]) != len(want[2]))
        ):
            raise RbgenError(
                self._mismatch(r, n, v, f"command {i} is {key[0]}, expected {want[0]}")
            )
        if key[0] == "launch":
            kernel = kmap.setdefault(key[1], want[1])
            if kernel != want[1]:
                raise RbgenError(
                    self._mismatch(r, n, v, f"command {i} launches another kernel object")
                )
        for obj, logical in zip(_buffers(key), _buffers(want)):
            if bmap.setdefault(obj, logical) != logical:
                raise RbgenError(
                    self._mismatch(
                        r,
                        n,
                        v,
                        f"command {i} ({self.describe(('step', v, i, 0))}) binds a "
                        f"buffer that is also buffer {bmap[obj]} elsewhere",
                    )
                )
        if key[0] == "launch" and tuple(a[0] for a in key[2]) != tuple(a[0] for a in want[2]):
            raise RbgenError(self._mismatch(r, n, v, f"command {i} binds other argument kinds"))

    def _mismatch(self, r: int, n: int, v: int, what: str) -> str:
        run = "the main run" if r == 0 else f"the sweep of {list(self.sweeps)[r - 1]}"
        return (
            f"schedule: step {n} of {run} is not variant {v} of the main run: {what} "
            f"(a step's commands must not depend on its capacities but by numbers)"
        )

    def describe(self, key: tuple) -> str:
        """A number's place, for messages."""
        if key[0] == "size":
            b = self.buffers[key[1]]
            return f"the size of buffer {key[1]} ({b.name or 'unnamed'})"
        kind, v, i, j = key
        command = (self.steps[v] if kind == "step" else self.undo[v])[i][0]
        if command[0] != "launch":
            field = {
                "fill": ("pattern", "offset", "size"),
                "copy": ("dst_offset", "src_offset", "size"),
                "write": ("offset", "data"),
            }[command[0]][j]
            return f"{command[0]} {field} of command {i} of variant {v}"
        kernel = self.kernels[command[1]]
        numbered = [p for p, a in enumerate(command[2]) if a[0] in ("scalar", "local")]
        if j < len(numbered):
            position = numbered[j]
            name = kernel.signature[position][0] if position < len(kernel.signature) else "?"
            what = f"argument {position} ({name})"
        else:
            what = "global size" if j == len(numbered) else "local size"
        return f"{what} of kernel {kernel.name} ({kernel.spec.path}), command {i} of variant {v}"

    # ------------------------------------------------------------------ followers
    def _learn_followers(self) -> None:
        """Each follower's leader and the variants whose steps make it catch up."""
        self.follow: dict[str, dict] = {}
        for name in self.followers:
            leaders, at = set(self.grown), set()
            for run_values in self.values:
                for n in range(1, len(run_values)):
                    before, after = run_values[n - 1], run_values[n]
                    if after[name] != before[name]:
                        at.add(self.variants(n))
                        leaders &= {g for g in self.grown if after[g] == after[name]}
            if not at:  # never changed: it follows its leader from the first step
                leaders = {
                    g
                    for g in self.grown
                    if all(vals[0][g] == vals[0][name] for vals in self.values)
                }
            if len(leaders) != 1:
                raise RbgenError(
                    f"schedule: capacity {name} follows none of the grown "
                    f"capacities {self.grown} alone"
                )
            leader = leaders.pop()
            rule = {"leader": leader, "at": sorted(at)}
            for run_values in self.values:
                value = run_values[0][leader]
                for n, vals in enumerate(run_values):
                    if n and self.variants(n) in at and value < vals[leader]:
                        value = vals[leader]
                    if value != vals[name]:
                        raise RbgenError(
                            f"schedule: capacity {name} does not follow {leader} "
                            f"at the steps of variants {rule['at']} (step {n})"
                        )
            self.follow[name] = rule

    # ------------------------------------------------------------------ renewals
    def _changed(self, r: int, n: int) -> set[tuple[str, int]]:
        """The capacities that step ``n`` of run ``r`` found changed, with their new rungs."""
        if n == 0:
            return set()
        before, after = self.values[r][n - 1], self.values[r][n]
        return {
            (name, rung(after[name], name)) for name in self.vars if after[name] != before[name]
        }

    def _learn_renewals(self) -> None:
        """The capacity changes that give each buffer a new allocation, as Python did: a
        capacity whose every change renewed it (the usual case), else, for what that
        leaves unexplained, a grown capacity reaching certain rungs (a buffer remade when
        its owner's input crosses a size bucket). Each renewal must be explained."""
        renewals: dict[int, list[set]] = {}
        quiet: dict[int, list[set]] = {}
        for (r, logical), seen in self.objects.items():
            for (n1, o1), (n2, o2) in zip(seen, seen[1:]):
                changed = set().union(*(self._changed(r, m) for m in range(n1 + 1, n2 + 1)))
                (renewals if o1 != o2 else quiet).setdefault(logical, []).append(changed)
        #: logical buffer -> {capacity: [rungs whose reaching renews it]}
        self.renew_on: dict[int, dict[str, list[int]]] = {}
        for logical, intervals in renewals.items():
            silent = quiet.get(logical, [])
            names = {name for c in intervals for name, _ in c}
            whole = {name for name in names if not any(name == n for q in silent for n, _ in q)}
            unexplained = [c for c in intervals if not any(n in whole for n, _ in c)]
            events = {
                e
                for c in unexplained
                for e in c
                if e[0] in self.grown and not any(e in q for q in silent)
            }
            if any(not c & events for c in unexplained):
                raise RbgenError(
                    f"schedule: buffer {logical} "
                    f"({self.buffers[logical].name or 'unnamed'}) was "
                    f"reallocated without a capacity change that explains it"
                )
            table = {name: list(self.range_of(name))[1:] for name in whole}
            for name, r in events:
                table.setdefault(name, [])
                if r not in table[name]:
                    table[name].append(r)
            self.renew_on[logical] = {
                name: sorted(table[name]) for name in sorted(table, key=self.vars.index)
            }

    # ------------------------------------------------------------------ numbers
    def range_of(self, name: str) -> range:
        """The rungs a capacity takes (a follower: its leader's)."""
        leader = self.follow[name]["leader"] if name in self.follow else name
        return range(0, self.max_rungs[leader] + 1)

    def number(self, key: tuple):
        """A number as a constant, or {"by": capacity, "values": [per rung]}."""
        samples = self.samples.get(key)
        if samples is None:
            raise RbgenError(f"schedule: no sample of {self.describe(key)}")
        values = {_hashable(v) for v, _ in samples}
        if len(values) == 1:
            return samples[0][0]
        for name in self.vars:
            table: dict = {}
            if all(
                table.setdefault(self.states[s][name], _hashable(v)) == _hashable(v)
                for v, s in samples
            ):
                missing = [k for k in self.range_of(name) if k not in table]
                if missing:
                    raise RbgenError(
                        f"schedule: {self.describe(key)} depends on {name}, "
                        f"but no step was recorded at its rungs {missing}"
                    )
                by_rung = {self.states[s][name]: v for v, s in samples}
                return {"by": name, "values": [by_rung[k] for k in self.range_of(name)]}
        shown = sorted({(v if not isinstance(v, bytes) else v.hex()) for v, _ in samples}, key=str)[
            :6
        ]
        raise RbgenError(
            f"schedule: {self.describe(key)} takes values {shown} that no "
            f"single capacity ({', '.join(self.vars)}) determines"
        )


def _hashable(value):
    return value if not isinstance(value, list) else tuple(value)
