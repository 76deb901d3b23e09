"""What the step pipeline remembers about bodies between steps, kept true when the World
sets or removes bodies.

Three memories are keyed by body indices: the constraint ring's last generation (warm
starts: each constraint's impulses, found next step by its pair key, and its edge's
colour, `rbgen.pipeline.constraints`), the narrowphase's separating-axis cache (last step's best
axis per pair-list index, keyed by the pair) and an incremental broadphase's sorted
endpoints. Setting a body's state makes its contacts' impulses stale; removing bodies
renumbers the survivors, so an old key can name another pair, of other shapes. These
functions run between steps (the World has checked every step in flight), never on a
step's path.

A constraint whose pair is set to (`layouts.SOLVER_NONE`, `layouts.SOLVER_NONE`) is
never found again (no real pair has a == b), so forgetting it costs nothing on the
device and needs no change to the kernels.
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from . import layouts

NONE = np.uint32(layouts.SOLVER_NONE)


def _last_constraints(runtime, pipeline):
    """(device array of the last step's constraints, their host copy) or None."""
    constraints = pipeline.constraints.constraints
    if constraints.capacity == 0:
        return None
    count = int(runtime.read(constraints.count)[0])
    if count == 0:
        return None
    device = constraints.constraints
    return device, runtime.read(device[:count])


def _write_back(runtime, device, host, first: int = 0) -> None:
    cl.enqueue_copy(
        runtime.queue,
        device.base_data,
        np.ascontiguousarray(host),
        dst_offset=device.offset + first * device.dtype.itemsize,
        is_blocking=True,
    )


def forget_bodies(runtime, pipeline, affected: np.ndarray) -> int:
    """The next step warm-starts no contact of a body where ``affected`` (a bool mask over
    the bodies) is set: their state was set, so the old impulses would push them from a
    configuration they have left. Returns the constraints forgotten."""
    if pipeline is None or not np.any(affected):
        return 0
    last = _last_constraints(runtime, pipeline)
    if last is None:
        return 0
    device, records = last
    a, b = records["body_a"].astype(np.int64), records["body_b"].astype(np.int64)
    inside = (a < len(affected)) & (b < len(affected))  # (else already forgotten)
    hit = inside & (
        affected[np.minimum(a, len(affected) - 1)] | affected[np.minimum(b, len(affected) - 1)]
    )
    if not np.any(hit):
        return 0
    records["body_a"][hit] = NONE
    records["body_b"][hit] = NONE
    _write_back(runtime, device, records)
    return int(hit.sum())


def renumber_bodies(runtime, pipeline, mapping: np.ndarray) -> None:
    """Bodies were removed and the survivors renumbered (``mapping``: old index -> new,
    -1 removed): the last constraints of surviving pairs are renumbered and kept in their
    order (so that the next step, whose pairs come in the same order, finds each at its
    own index), those of removed bodies are forgotten; the separating-axis cache and an
    incremental broadphase's history are cleared (a cached axis of another pair of shapes
    could name a face that the new pair does not have)."""
    if pipeline is None:
        return
    last = _last_constraints(runtime, pipeline)
    if last is not None:
        device, records = last
        a, b = records["body_a"].astype(np.int64), records["body_b"].astype(np.int64)
        valid = (a < len(mapping)) & (b < len(mapping))
        new_a = np.where(valid, mapping[np.minimum(a, len(mapping) - 1)], -1)
        new_b = np.where(valid, mapping[np.minimum(b, len(mapping) - 1)], -1)
        keep = (new_a >= 0) & (new_b >= 0)
        kept = records[keep]
        kept["body_a"], kept["body_b"] = new_a[keep], new_b[keep]
        records[: len(kept)] = kept
        records["body_a"][len(kept) :] = NONE
        records["body_b"][len(kept) :] = NONE
        _write_back(runtime, device, records)
        # each contact's edge (its inherited colour) moves with it
        constraints = pipeline.constraints.constraints
        edges, first = constraints.edges, constraints.first_contact_edge
        old = runtime.read(edges[first : first + len(records)])
        moved = old[keep]
        moved["body_a"], moved["body_b"] = new_a[keep], new_b[keep]
        _write_back(runtime, edges, moved, first)
        # The generation's table maps old keys to old indices. Left as it is, a lookup
        # would still find only the right pair, but whether it finds it would depend on
        # the order the table was filled in (atomics): the physics would not repeat. So it
        # is emptied: a survivor is found at its own index (in order, as above) or not at
        # all. (`ContactConstraints` has no public hook for this yet: see its _clear.)
        constraints._clear(constraints._generations[constraints._current])
    cache = getattr(pipeline.narrowphase.narrowphase, "sat_cache", None)  # (after a query)
    if cache is not None:
        cl.enqueue_fill_buffer(runtime.queue, cache.base_data, np.uint32(0), 0, cache.nbytes)
    broadphase = pipeline.broadphase.broadphase
    if hasattr(broadphase, "reset"):
        broadphase.reset()  # an incremental broadphase's sorted endpoints name old bodies
