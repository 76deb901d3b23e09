"""Sleeping islands: bodies at rest drop out of the step until something wakes them.

A body's rest timer grows while its fastest surface point (|v| + |w| extent) moves
slower than ``sleep_threshold`` and restarts otherwise; an island (awake dynamic bodies
connected by the step's contacts and joints; static bodies connect nothing) whose every
body has rested ``sleep_time`` falls asleep, as in Box2D v3 and Jolt. A sleeping body is
static to every other stage: its `Body.inv_mass` is 0 (no gravity, no integration, no
colour conflict, infinite mass in the solver: its velocities are zeroed and its pose
does not change) and its collision word has `layouts.GROUP_STATIC` (the broadphase
already skips pairs of two static bodies, so a sleeping pile makes no pairs within
itself or with the ground). Its own inverse mass waits in its `layouts.BODY_SLEEP`
record.

An island wakes whole (its bodies keep its label, the lowest body index, while asleep)
when an awake dynamic body touches one of its bodies (a contact edge between them; for
that one step it was static to the toucher), when a force is applied to one of its
bodies (before that step's forces act), and when the host changes one of its bodies or
their joints, or gravity (`wake_islands` on the host copy of the records). Its contacts'
warm start is lost while it sleeps (it has no pairs): the woken island's first step
starts its contacts cold.

Device work, all without a blocking read (`rbgen/templates/pipeline/sleep.cl.mako`):
four launches at the end of a step (rest timers, union-find over the edges, island
roots, fall asleep or wake; a lock-free union-find rather than label propagation, which
would need as many launches as the longest chain of bodies is long), and at the start
of a step that has forces or follows a host change while bodies may sleep, two launches
(forces wake islands; bodies and collision words made to agree with the records).
Every record is backed up by the step's first end-of-step launch, so that a redone step
starts from the same sleep state (`restore`).
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from .. import layouts
from ..codegen import KernelTemplate, compile_spec, work_group_size_param
from ..device import DeviceTraits, Runtime, buffer_of

TEMPLATE = KernelTemplate(
    "pipeline/sleep.cl.mako",
    [work_group_size_param("bodies or edges per work group; memory-bound")],
    doc="Sleeping islands: rest timers, union-find islands, falling asleep and waking.",
    roles={
        "bodies": "inout",
        "records": "inout",
        "backup": "out",
        "parent": "inout",
        "marks": "inout",
        "words": "inout",
    },
    defaults=lambda traits: {"work_group_size": default_work_group_size(traits)},
)


def default_work_group_size(traits: DeviceTraits) -> int:
    """128 on GPUs; 64 on CPUs (PoCL vectorises across work-items)."""
    return min(128 if traits.is_gpu else 64, traits.max_work_group_size)


# ----------------------------------------------------------------- host records
def fresh_records(inv_mass: np.ndarray, extents: np.ndarray) -> np.ndarray:
    """`BodySleep` records of awake bodies that have not rested yet (each its own island)."""
    records = layouts.BODY_SLEEP.zeros(len(inv_mass))
    records["island"] = np.arange(len(inv_mass), dtype=np.uint32)
    records["inv_mass"] = inv_mass
    records["extent"] = extents
    return records


def wake_islands(records: np.ndarray, ids) -> int:
    """Wake (in place) every sleeping island that holds one of the bodies ``ids`` (an
    index array or a bool mask); the woken bodies' timers restart. Returns how many
    bodies woke."""
    ids = np.asarray(ids)
    chosen = records[ids]
    labels = chosen["island"][chosen["asleep"] == layouts.SLEEP_ASLEEP]
    if len(labels) == 0:
        return 0
    woken = (records["asleep"] == layouts.SLEEP_ASLEEP) & np.isin(records["island"], labels)
    records["asleep"][woken] = layouts.SLEEP_AWAKE
    records["timer"][woken] = 0.0
    return int(woken.sum())


def renumber(records: np.ndarray, mapping: np.ndarray) -> np.ndarray:
    """The records after a removal (``mapping``: old index -> new, -1 removed): the
    islands of removed bodies are woken, the survivors' labels renumbered (a sleeping
    island's label is one of its own bodies, so it survives when the island does)."""
    records = records.copy()
    wake_islands(records, mapping < 0)
    kept = records[mapping >= 0]
    asleep = kept["asleep"] == layouts.SLEEP_ASLEEP
    kept["island"] = np.where(
        asleep, mapping[kept["island"].astype(np.int64)], np.arange(len(kept))
    ).astype(np.uint32)
    return kept


# ----------------------------------------------------------------- device
class Sleeping:
    """The sleep records of a World's bodies on the device and the kernels that keep them
    (see the module docstring). ``backups``: one record backup per step in flight."""

    def __init__(self, runtime: Runtime, backups: int, work_group_size: int | None = None):
        self.runtime = runtime
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        self.spec = TEMPLATE.spec(work_group_size=self.work_group_size)
        program = compile_spec(runtime, self.spec)
        self._begin = runtime.bound(program.kernel("sleep_begin"))
        self._link = runtime.bound(program.kernel("sleep_link"))
        self._islands = runtime.bound(program.kernel("sleep_islands"))
        self._forced = runtime.bound(program.kernel("sleep_wake_forced"))
        self._apply = runtime.bound(program.kernel("sleep_apply"))
        self._environments = runtime.bound(program.kernel("sleep_wake_environments"))
        # (host arrays of the last environment reset, alive until its upload is done)
        self._keep: list = []
        self.backup_count = int(backups)
        self.count = 0
        self.records: cla.Array | None = None
        #: the host changed bodies or records since the last step while a body may be
        #: asleep: the next step's first launches make the device bodies and collision
        #: words agree with the records
        self.stale = False
        #: a body may be asleep (records with sleepers adopted, or a step ran since)
        self.may_sleep = False
        #: per backup slot: whether its step began stale (its redo must do as it did)
        self._began_stale = [False] * self.backup_count

    def adopt(self, records: np.ndarray) -> None:
        """Replace every record by ``records`` (between steps)."""
        queue = self.runtime.queue
        n = len(records)
        host = records if n else layouts.BODY_SLEEP.zeros(1)
        # (the device's bodies may still be asleep as the old records had them)
        had_sleepers = self.may_sleep
        self.may_sleep = bool(np.any(records["asleep"] != layouts.SLEEP_AWAKE))
        self.stale = self.stale or had_sleepers or self.may_sleep
        if self.records is not None and n == self.count and n > 0:
            self.records.set(np.ascontiguousarray(host), queue=queue)
            return
        self.count = n
        self.records = cla.to_device(queue, np.ascontiguousarray(host))
        self.backups = [cla.empty_like(self.records) for _ in range(self.backup_count)]
        self.parent = cla.zeros(queue, max(1, n), np.uint32)
        self.marks = cla.zeros(queue, max(1, n), np.uint32)

    def bodies_uploaded(self) -> None:
        """The host wrote every body (each with its own inverse mass, no sleeping bit in
        its collision word): the next step makes the sleeping ones agree again."""
        self.stale = self.stale or self.may_sleep

    def read(self) -> np.ndarray:
        """The records now (a blocking read; between steps)."""
        assert self.records is not None
        return self.runtime.read(self.records)[: self.count]

    def _clear_marks(self) -> None:
        cl.enqueue_fill_buffer(
            self.runtime.queue, buffer_of(self.marks), np.uint32(0), 0, self.marks.nbytes
        )

    def _agree(self, bodies, words, decide: bool) -> None:
        self._apply.over(
            self.count,
            self.work_group_size,
            bodies,
            self.records,
            words,
            self.marks,
            np.uint32(self.count),
            np.uint32(decide),
        )

    def begin(self, bodies, words, forces, slot: int) -> None:
        """The start of the step of backup ``slot``: a force on a sleeping body wakes its
        island; after a host change, the bodies and collision words are made to agree
        with the records. ``forces``: the step's `rbgen.forces.StepForces` (None: none)."""
        self._began_stale[slot] = self.stale
        if self.count == 0 or (forces is None and not self.stale):
            return
        self._clear_marks()
        if forces is not None:
            arrays = forces.arrays()
            self._forced.over(
                self.count,
                self.work_group_size,
                self.records,
                self.marks,
                np.uint32(self.count),
                *[self.records if a is None else a for a in arrays],
                np.uint32(sum(1 << k for k, a in enumerate(arrays) if a is not None)),
            )
        self._agree(bodies, words, decide=False)
        self.stale = False

    def end(self, bodies, words, edges, edge_count, edge_capacity: int, slot: int, settings, dt):
        """The end of a step: rest timers, islands, and islands falling asleep or waking
        (``edges``/``edge_count``: the step's constraint edges, launched over
        ``edge_capacity``; the records are first backed up into ``slot``)."""
        if self.count == 0:
            return
        self.may_sleep = True
        n, wg = np.uint32(self.count), self.work_group_size
        self._begin.over(
            self.count,
            wg,
            bodies,
            self.records,
            self.backups[slot],
            self.parent,
            self.marks,
            n,
            np.float32(dt),
            np.float32(settings.sleep_threshold),
        )
        self._link.over(edge_capacity, wg, edges, edge_count, self.records, self.parent, self.marks)
        self._islands.over(
            self.count,
            wg,
            self.records,
            self.parent,
            self.marks,
            n,
            np.float32(settings.sleep_time),
        )
        self._agree(bodies, words, decide=True)

    def restore(self, slot: int, bodies, words) -> None:
        """Back to the records of the step of ``slot`` (its redo), the bodies (restored
        already) and collision words made to agree with them; the redone step begins as
        that step did."""
        self.stale = self._began_stale[slot]
        if self.count == 0:
            return
        cl.enqueue_copy(self.runtime.queue, buffer_of(self.records), buffer_of(self.backups[slot]))
        self._clear_marks()
        self._agree(bodies, words, decide=False)

    def wake_environments(self, words, env_flags: np.ndarray) -> None:
        """Wake every body of the environments whose ``env_flags`` (one uint32 per
        environment) is set (a `rbgen.batch.WorldBatch` reset them: between steps, no
        blocking read); ``words``: the bodies' collision words."""
        if self.count == 0:
            return
        queue = self.runtime.queue
        if self._keep:
            queue.finish()  # (the last call's upload is done: its host array may go)
        flags = np.ascontiguousarray(env_flags, np.uint32)
        d_flags = cla.to_device(queue, flags, async_=True)
        self._keep = [flags, d_flags]
        self._environments.over(
            self.count, self.work_group_size, self.records, words, d_flags, np.uint32(self.count)
        )
        self.stale = self.stale or self.may_sleep
