"""With device counts, every primitive only enqueues: no blocking read, no wait.

Blocking copies, ``Array.get`` and event waits are made to fail while a chain
of primitives runs whose sizes all live on the device; the results are then
checked against numpy.
"""

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from rbgen.primitives import BoundSearch, Compact, Fill, RadixSort, Reduce, Scan


def test_chain_without_round_trips(runtime, rng, monkeypatch):
    q = runtime.queue
    capacity = 20_000
    keys = rng.integers(0, 500, capacity, dtype=np.uint32)
    flags = (rng.random(capacity) < 0.5).astype(np.uint32)
    d_keys, d_flags = cla.to_device(q, keys), cla.to_device(q, flags)
    d_values = cla.to_device(q, np.arange(capacity, dtype=np.uint32))
    count = cla.to_device(q, np.array([15_000], np.uint32))
    kept, kept_count = cla.empty(q, capacity, np.uint32), cla.empty(q, 1, np.uint32)
    offsets, total = cla.empty(q, capacity, np.uint32), cla.empty(q, 1, np.uint32)
    largest = cla.empty(q, 1, np.uint32)
    starts = cla.empty(q, 600, np.uint32)
    queries = cla.to_device(q, np.arange(600, dtype=np.uint32))
    filled = cla.to_device(q, np.zeros(capacity, np.uint32))
    primitives = [
        Compact(runtime),
        RadixSort(runtime, key_bits=9),
        Scan(runtime),
        Reduce(runtime, np.uint32, "max"),
        BoundSearch(runtime),
        Fill(runtime),
    ]
    reads_before = runtime.counters["blocking_reads"]

    def forbidden(*args, **kwargs):
        raise AssertionError("a primitive waited for the device")

    original_copy = cl.enqueue_copy

    def copy_without_blocking(queue, dest, src, **kwargs):
        if kwargs.get("is_blocking", True) and isinstance(dest, np.ndarray):
            raise AssertionError("a primitive read back from the device")
        return original_copy(queue, dest, src, **kwargs)

    with monkeypatch.context() as patch:
        patch.setattr(cla.Array, "get", forbidden)
        patch.setattr(cl, "wait_for_events", forbidden)
        patch.setattr(cl, "enqueue_copy", copy_without_blocking)
        compact, sort, scan, reduce, search, fill = primitives
        compact(d_flags, kept, kept_count, n=count)  # kept indices, count on device
        sort(d_keys, d_values, n=kept_count)  # sort a prefix of that length
        scan(d_keys, offsets, n=kept_count, total=total)
        reduce(d_keys, largest, n=kept_count)
        search(d_keys, queries, starts, n_keys=kept_count)
        fill(filled, 9, n=kept_count)
    assert runtime.counters["blocking_reads"] == reads_before

    m = int(np.count_nonzero(flags[:15_000]))
    assert kept_count.get()[0] == m
    assert np.array_equal(kept.get()[:m], np.flatnonzero(flags[:15_000]))
    order = np.argsort(keys[:m], kind="stable")
    sorted_keys = keys[:m][order]
    assert np.array_equal(d_keys.get()[:m], sorted_keys)
    assert np.array_equal(d_keys.get()[m:], keys[m:])
    assert np.array_equal(d_values.get()[:m], order)
    assert np.array_equal(offsets.get()[:m], np.concatenate([[0], np.cumsum(sorted_keys)[:-1]]))
    assert total.get()[0] == sorted_keys.sum()
    assert largest.get()[0] == sorted_keys.max()
    assert np.array_equal(starts.get(), np.searchsorted(sorted_keys, np.arange(600), "left"))
    f = filled.get()
    assert np.all(f[:m] == 9) and np.all(f[m:] == 0)
