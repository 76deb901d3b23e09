"""The primitives' tuning families: search spaces, benchmark inputs, checks.

Each family tells `rbgen.tuning` how to build a candidate for a variant, and
gives a benchmark input with a numpy check of the result, so that a candidate
that computes a wrong answer on this device is never chosen however fast.
Inputs are random but seeded by the tuner, and include duplicate keys for the
sort so that stability is part of the check.
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from .. import tuning
from . import bound_search, compact, fill, radix_sort, reduce, scan
from .bound_search import BoundSearch
from .compact import Compact
from .fill import Fill
from .radix_sort import RadixSort
from .reduce import Reduce
from .scan import Scan

_NP = {"uint": np.uint32, "int": np.int32, "float": np.float32}


def _bench_scan(runtime, prim: Scan, n, rng):
    # small ints whose every prefix sum is exact: in float32 that needs sums <= 2^24
    # (0..7 at 16M elements reaches 2^26, where any other summation order rounds differently)
    top = 8 if np.dtype(prim.dtype).kind in "iu" else max(2, min(8, (1 << 24) // max(n, 1)))
    x = rng.integers(0, top, n).astype(prim.dtype)
    src = cla.to_device(runtime.queue, x)
    dst = cla.empty_like(src)
    expected = np.concatenate([[0], np.cumsum(x, dtype=np.float64)[:-1]]).astype(prim.dtype)
    return (lambda: prim(src, dst)), (lambda: np.array_equal(dst.get(), expected))


def _bench_sort(runtime, prim: RadixSort, n, rng):
    keys = rng.integers(0, max(2, n // 4), n, dtype=np.uint32)  # duplicates: checks stability
    order = np.argsort(keys, kind="stable")
    d_keys = cla.empty(runtime.queue, n, np.uint32)
    d_values = cla.empty(runtime.queue, n, np.uint32) if prim.with_values else None
    values = np.arange(n, dtype=np.uint32)

    src_keys = cla.to_device(runtime.queue, keys)
    src_values = cla.to_device(runtime.queue, values)

    def prepare():  # restore the unsorted input; not timed
        cl.enqueue_copy(runtime.queue, d_keys.base_data, src_keys.base_data)
        if d_values is not None:
            cl.enqueue_copy(runtime.queue, d_values.base_data, src_values.base_data)

    def run():
        return prim(d_keys, d_values)

    cast(Any, run).prepare = prepare  # a function attribute: tuning.time_samples looks for it

    def check():
        ok = np.array_equal(d_keys.get(), keys[order])
        return ok and (d_values is None or np.array_equal(d_values.get(), order.astype(np.uint32)))

    return run, check


def _bench_reduce(runtime, prim: Reduce, n, rng):
    assert prim.dtype is not None  # Reduce rejects a None dtype (cl_type)
    x = rng.integers(-100, 100, n).astype(prim.dtype)
    src = cla.to_device(runtime.queue, x)
    out = cla.empty(runtime.queue, 1, prim.dtype)
    expected = {"sum": x.astype(np.float64).sum(), "min": x.min(), "max": x.max()}[prim.op]
    return (lambda: prim(src, out)), (lambda: out.get()[0] == expected)


def _bench_compact(runtime, prim: Compact, n, rng):
    flags = (rng.random(n) < 0.3).astype(np.uint32)
    d_flags = cla.to_device(runtime.queue, flags)
    out = cla.empty(runtime.queue, n, np.uint32)
    count = cla.empty(runtime.queue, 1, np.uint32)
    kept = np.flatnonzero(flags)

    def check():
        c = int(count.get()[0])
        return c == kept.size and np.array_equal(out.get()[:c], kept)

    return (lambda: prim(d_flags, out, count)), check


def _bench_fill(runtime, prim: Fill, n, rng):
    """A device count: host counts use the driver's fill, not the tuned kernel."""
    array = cla.zeros(runtime.queue, n, prim.dtype)
    count = cla.to_device(runtime.queue, np.array([n], np.uint32))
    value = prim.dtype.type(rng.integers(1, 1000))
    return (lambda: prim(array, value, n=count)), (lambda: bool(np.all(array.get() == value)))


def _bench_bound_search(runtime, prim: BoundSearch, n, rng):
    """n sorted keys, n / 16 random queries (each costs ~log2(n) cache misses)."""
    keys = np.sort(rng.integers(0, n, n, dtype=np.uint32))
    queries = rng.integers(0, n + 10, max(1, n // 16), dtype=np.uint32)
    d_keys, d_queries = cla.to_device(runtime.queue, keys), cla.to_device(runtime.queue, queries)
    out = cla.empty(runtime.queue, queries.size, np.uint32)
    expected = np.searchsorted(keys, queries, side="left" if prim.side == "lower" else "right")
    return (lambda: prim(d_keys, d_queries, out)), (lambda: np.array_equal(out.get(), expected))


def _build_scan(runtime, variant, params, chained=False):
    """A scan candidate; a chained one that fails its guard is rejected, not
    timed as the reduce-then-scan it would fall back to."""
    prim = Scan(runtime, _NP[variant], inclusive=False, chained=chained, params=params)
    if params["shape"] == "chained" and not scan.chained_scan_works(runtime, params):
        raise RuntimeError("the chained scan failed its guard on this device")
    return prim


def _build_sort(runtime, variant, params):
    """A sort candidate; a onesweep one that fails its guard is rejected, not
    timed as the split sort it would fall back to."""
    prim = RadixSort(runtime, 32, with_values=(variant == "kv"), params=params)
    if params["shape"] == "onesweep" and not radix_sort.onesweep_works(runtime, params):
        raise RuntimeError("the onesweep sort failed its guard on this device")
    return prim


FAMILIES = [
    tuning.Family(
        "scan",
        ("uint", "float"),
        scan.search_space,
        _build_scan,
        _bench_scan,
        lambda: Scan.TEMPLATES,
    ),
    tuning.Family(
        "scan_chained",
        ("uint",),
        scan.chained_search_space,
        lambda rt, v, p: _build_scan(rt, v, p, chained=True),
        _bench_scan,
        lambda: {"chained": Scan.TEMPLATES["chained"]},
    ),
    tuning.Family(
        "radix_sort",
        ("kv", "keys"),
        radix_sort.search_space,
        _build_sort,
        _bench_sort,
        lambda: RadixSort.TEMPLATES,
    ),
    tuning.Family(
        "reduce",
        ("sum-float",),
        reduce.search_space,
        lambda rt, v, p: Reduce(rt, _NP[v.split("-")[1]], v.split("-")[0], params=p),
        _bench_reduce,
        lambda: Reduce.TEMPLATES,
    ),
    tuning.Family(
        "compact",
        ("indices",),
        compact.search_space,
        lambda rt, v, p: Compact(rt, params=p),
        _bench_compact,
        lambda: Compact.TEMPLATES,
    ),
    tuning.Family(
        "fill",
        ("uint",),
        fill.search_space,
        lambda rt, v, p: Fill(rt, _NP[v], params=p),
        _bench_fill,
        lambda: Fill.TEMPLATES,
    ),
    tuning.Family(
        "bound_search",
        ("lower",),
        bound_search.search_space,
        lambda rt, v, p: BoundSearch(rt, v, params=p),
        _bench_bound_search,
        lambda: BoundSearch.TEMPLATES,
    ),
]
for _family in FAMILIES:
    tuning.register(_family)
