"""Every broadphase against the brute-force reference, and the shared interface.

The expected pairs always come from `brute_force_pairs` (float64 numpy, all
n(n-1)/2 candidates) on the same float32 boxes, with the touching rule of the
package: closed boxes, a < b, never two static bodies, sorted by (a, b).
"""

from __future__ import annotations

import numpy as np
import pytest

from rbgen import layouts
from rbgen.errors import RbgenError
from rbgen.pipeline.broadphase import make_broadphase
from rbgen.pipeline.broadphase.reference import brute_force_pairs

from .conftest import KINDS, make_aabbs, pack


def query(broadphase, aabbs, static):
    count = broadphase.find_pairs(aabbs, static)
    pairs = broadphase.host_pairs()
    assert count == len(pairs)
    return pairs


@pytest.mark.parametrize("n", [0, 1, 2, 3, 37, 1000])
def test_mixed_sizes_match_brute_force(broadphase, rng, n):
    aabbs, static = make_aabbs(rng, n, "mixed")
    np.testing.assert_array_equal(
        query(broadphase, aabbs, static), brute_force_pairs(aabbs, static)
    )


@pytest.mark.parametrize("kind", [k for k in KINDS if k != "mixed"])
def test_distributions_match_brute_force(broadphase, rng, kind):
    aabbs, static = make_aabbs(rng, 1000 if kind != "identical" else 301, kind)
    np.testing.assert_array_equal(
        query(broadphase, aabbs, static), brute_force_pairs(aabbs, static)
    )


def test_ten_thousand_bodies(runtime, rng):
    """The large case, once, on the grid (the default broadphase)."""
    aabbs, static = make_aabbs(rng, 10_000, "clustered")
    np.testing.assert_array_equal(
        query(make_broadphase(runtime, "grid"), aabbs, static), brute_force_pairs(aabbs, static)
    )


def test_touching_rule(broadphase):
    """Sharing a face, an edge or a corner is a pair; a gap of 1e-3 is not."""
    lower = np.array(
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 1, 1], [2.001, 0, 0], [0, 0, 2.001]], np.float32
    )
    aabbs = pack(lower, lower + 1)
    pairs = query(broadphase, aabbs, None)
    assert {tuple(p) for p in pairs} == {(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)}
    np.testing.assert_array_equal(pairs, brute_force_pairs(aabbs))


def test_static_pairs_are_dropped(broadphase):
    lower = np.zeros((4, 3), np.float32)
    static = np.array([1, 1, 0, 1], np.uint32)
    pairs = query(broadphase, pack(lower, lower + 1), static)
    assert [tuple(p) for p in pairs] == [(0, 2), (1, 2), (2, 3)]


def test_overflow_grows_and_keeps_every_pair(runtime, rng):
    for name, options in (
        ("grid", {"emission": "slot"}),
        ("grid", {"emission": "owner"}),
        ("sap", {}),
    ):
        broadphase = make_broadphase(runtime, name, capacity=1, **options)
        aabbs, static = make_aabbs(rng, 300, "clustered")
        broadphase.enqueue(aabbs, static)
        assert broadphase.check() is False  # the first query overflowed
        assert broadphase.capacity > 1
        np.testing.assert_array_equal(
            query(broadphase, aabbs, static), brute_force_pairs(aabbs, static)
        )


def test_enqueue_does_not_block(runtime, rng):
    """A query is a fixed sequence of enqueues; only `check` waits (on its own copy)."""
    broadphase = make_broadphase(runtime, "grid")
    aabbs, static = make_aabbs(rng, 500, "uniform")
    import pyopencl.array as cla

    device_aabbs = cla.to_device(runtime.queue, aabbs)
    device_static = cla.to_device(runtime.queue, static)
    broadphase.find_pairs(device_aabbs, device_static)  # build and allocate
    before = runtime.counters["blocking_reads"]
    broadphase.enqueue(device_aabbs, device_static)
    assert runtime.counters["blocking_reads"] == before
    assert broadphase.check()
    assert int(broadphase.count.get()[0]) == len(brute_force_pairs(aabbs, static))


def test_check_reads_a_status_the_query_did_not(broadphase, rng):
    """enqueue(read_status=False) (a caller that copies the status with its own reads)
    makes no status copy; check() then reads it itself: an overflow is still seen and
    grown (not for sap3, which alternates between two pair buffers: test_sap3 covers its
    overflow), a bad body still named, and a complete query's pairs are brute force's."""
    import pyopencl as cl

    aabbs, static = make_aabbs(rng, 300, "clustered")
    broadphase.find_pairs(aabbs, static)  # build and allocate
    copies = []
    original = cl.enqueue_copy
    cl.enqueue_copy = lambda *a, **k: copies.append(k.get("is_blocking")) or original(*a, **k)
    try:
        if broadphase.name != "sap3":
            broadphase.buffer.allocate(1)  # the next query overflows
            broadphase.enqueue(aabbs, static, read_status=False)
            assert False not in copies  # no non-blocking status read
            assert broadphase.check() is False and broadphase.capacity > 1
        copies.clear()
        broadphase.enqueue(aabbs, static, read_status=False)
        assert False not in copies
    finally:
        cl.enqueue_copy = original
    assert broadphase.check()
    np.testing.assert_array_equal(broadphase.host_pairs(), brute_force_pairs(aabbs, static))
    aabbs["upper"][7, 0] = np.nan
    broadphase.enqueue(aabbs, static, read_status=False)
    with pytest.raises(RbgenError, match="body 7 "):
        broadphase.check()


@pytest.mark.parametrize("bad", ["nan", "inverted"])
def test_invalid_aabb_names_the_body(broadphase, rng, bad):
    aabbs, static = make_aabbs(rng, 50, "uniform")
    body = int(rng.integers(0, 50))
    if bad == "nan":
        aabbs["upper"][body, 1] = np.nan
    else:
        aabbs["lower"][body, 2] = aabbs["upper"][body, 2] + 1
    with pytest.raises(RbgenError, match=f"body {body} "):
        broadphase.find_pairs(aabbs, static)


def test_bad_arguments(runtime):
    with pytest.raises(RbgenError, match="unknown broadphase 'octree'"):
        make_broadphase(runtime, "octree")
    for capacity in (-5, 0, 2.5):
        with pytest.raises(RbgenError, match="capacity"):
            make_broadphase(runtime, "grid", capacity=capacity)
    with pytest.raises(RbgenError, match="large_factor"):
        make_broadphase(runtime, "grid", large_factor=-1.0)
    with pytest.raises(RbgenError, match="bucketing"):
        make_broadphase(runtime, "grid", bucketing="bogo")
    with pytest.raises(RbgenError, match="bad option"):
        make_broadphase(runtime, "sap", colour="red")
    broadphase = make_broadphase(runtime, "grid")
    with pytest.raises(RbgenError, match="Aabb layout"):
        broadphase.find_pairs(np.zeros((4, 6), np.float32))
    with pytest.raises(RbgenError, match="static has 2 flags for 4 bodies"):
        broadphase.find_pairs(layouts.AABB.zeros(4), np.zeros(2, np.uint32))
