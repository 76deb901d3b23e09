"""Constraint batching: invariants of the device batches against the host reference.

Invariants (checked on random constraint-edge graphs, every algorithm, both solve
forms): every edge's item appears exactly once in ``order``; no dynamic body is
touched by two groups that run in the same solver launch (work groups never
synchronise); static bodies are ignored. Lanes form: no dynamic body appears twice in
one batch (except the serial last batch). Serial form: a group is one batch (none when
empty) listing its edges in increasing index order. Batching sees edges only: edges of
another constraint kind (their items tagged with another kind) are coloured with the
contacts' by the same rules.
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array
import pytest

from rbgen import layouts
from rbgen.errors import RbgenError
from rbgen.pipeline.batching import batch_host, make_batcher
from rbgen.pipeline.batching.global_colouring import GlobalBatcher

#: an item kind other than the contacts' (edges of a joint-like kind, made up here)
OTHER_KIND = 1
SPATIAL = [(mode, form) for mode in ("cells", "slabs", "columns") for form in ("lanes", "serial")]


def random_graph(rng, n_bodies, n_constraints, static_fraction=0.1, chain=False):
    dynamic = rng.random(n_bodies) >= static_fraction
    if n_bodies:
        dynamic[0] = False  # a shared "ground"
    if chain:
        a = np.arange(n_constraints) % max(1, n_bodies - 1)
        b = a + 1
    else:
        a = rng.integers(0, n_bodies, n_constraints)
        b = (a + 1 + rng.integers(0, max(1, n_bodies - 1), n_constraints)) % n_bodies
    a, b = np.minimum(a, b), np.maximum(a, b)
    return a.astype(np.uint32), b.astype(np.uint32), dynamic


def contact_items(n):
    """Items of n contact edges: the contact kind, indices 0 .. n - 1."""
    return (layouts.EDGE_CONTACT << layouts.EDGE_KIND_SHIFT | np.arange(n)).astype(np.uint32)


def mixed_items(rng, n, other_fraction=0.3):
    """Items of n edges, some of another kind: each kind's indices count from 0 in edge
    order (as each kind indexes its own array)."""
    other = rng.random(n) < other_fraction
    items = np.zeros(n, np.uint32)
    for kind, mask in ((layouts.EDGE_CONTACT, ~other), (OTHER_KIND, other)):
        items[mask] = kind << layouts.EDGE_KIND_SHIFT | np.arange(np.count_nonzero(mask))
    return items


def make_edges(a, b, points, items=None, colours=None, padding=0):
    """ConstraintEdge records (``padding`` unused ones after them)."""
    n = len(a)
    edges = layouts.CONSTRAINT_EDGE.zeros(max(1, n + padding))
    edges["body_a"][:n], edges["body_b"][:n] = a, b
    edges["item"][:n] = contact_items(n) if items is None else items
    edges["colour"] = layouts.SOLVER_NONE
    if colours is not None:
        edges["colour"][:n] = colours
    edges["point"][:n, :3] = points
    return edges


def new_batcher(runtime, mode, solve_form="lanes", cell_size=1.5, **options):
    """A batcher of algorithm ``mode`` (spatial ones laid out for ``solve_form``, with
    cells of ``cell_size`` and slabs across x)."""
    if mode == "global":
        return make_batcher(runtime, "global", **options)
    batcher = make_batcher(runtime, mode, solve_form=solve_form, **options)
    batcher.configure(cell_size=cell_size, slab_axis=(1.0, 0.0, 0.0))
    return batcher


def groups_of(batcher, n):
    """Each edge's level-1 group after a call (global batching: all in group 0)."""
    if batcher.mode == "global":
        return np.zeros(n, np.uint32)
    return batcher.edge_group.get()[:n]


def run_device(
    runtime,
    a,
    b,
    dynamic,
    rng=None,
    hints=None,
    items=None,
    mode="cells",
    solve_form="lanes",
    **options,
):
    """Bodies scattered in a 20 m box, edge points 0.5 m from B (cell size 1.5 m); the
    count on the device, launches over a larger capacity. Global mode: ``hints`` are the
    edges' inherited colours (None: a first step, none inherited), and the colour field
    it hands on is checked against the colours it gave. Returns (batcher, order, batch
    offsets, batch counts, each edge's group)."""
    queue = runtime.queue
    rng = rng or np.random.default_rng(0)
    bodies = layouts.BODY.zeros(max(1, len(dynamic)))
    bodies["inv_mass"][: len(dynamic)] = np.where(dynamic, 1.0, 0.0)
    bodies["position"][:, :3] = rng.uniform(-10, 10, (len(bodies), 3))
    points = bodies["position"][b, :3] + rng.uniform(-0.3, 0.3, (len(a), 3))
    edges = make_edges(a, b, points, items, hints, padding=7)
    d_edges = cl_array.to_device(queue, edges)
    count = cl_array.to_device(queue, np.array([len(a)], np.uint32))
    batcher = new_batcher(runtime, mode, solve_form, **options)
    batcher(d_edges, count, cl_array.to_device(queue, bodies), len(dynamic), len(edges))
    order, offsets, batch_counts = batcher.read_batches()
    if batcher.mode == "global":  # the field holds the colour, or none if provisional
        handed_on = d_edges.get()["colour"][: len(a)]
        inherited = handed_on != layouts.SOLVER_NONE
        colours = batcher.edge_batch.get()[: len(a)]
        assert np.array_equal(handed_on[inherited], colours[inherited])
    return batcher, order[: len(a)], offsets, batch_counts, groups_of(batcher, len(a))


def lattice(side: int):
    """A dense side x side lattice of unit-pitch dynamic bodies in the x-z plane, one
    edge per pair of grid neighbours (one connected pile), its point halfway:
    (body_a, body_b, Body records, ConstraintEdge records)."""
    ids = np.arange(side * side).reshape(side, side)
    a = np.r_[ids[:-1, :].ravel(), ids[:, :-1].ravel()].astype(np.uint32)
    b = np.r_[ids[1:, :].ravel(), ids[:, 1:].ravel()].astype(np.uint32)
    bodies = layouts.BODY.zeros(side * side)
    bodies["inv_mass"] = 1.0
    gx, gz = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    bodies["position"][:, 0], bodies["position"][:, 2] = gx.ravel(), gz.ravel()
    points = (bodies["position"][a, :3] + bodies["position"][b, :3]) / 2
    return a, b, bodies, make_edges(a, b, points)


def check_invariants(batcher, a, b, dynamic, order, offsets, batch_counts, groups, items=None):
    """Every invariant of the module docstring; ``items``: the edges' items (contacts'
    when None). ``order`` lists items; they are mapped back to edges to check bodies."""
    n = len(a)
    items = contact_items(n) if items is None else np.asarray(items)
    assert sorted(order.tolist()) == sorted(items.tolist()), "every edge exactly once"
    edge_of = {int(item): e for e, item in enumerate(items)}
    listed = np.array([edge_of[int(item)] for item in order], np.int64)
    for first, count in batcher.launch_plan:  # groups running in one launch
        owner = {}
        for i in np.flatnonzero((groups >= first) & (groups < first + count)):
            for x in (int(a[i]), int(b[i])):
                if dynamic[x]:
                    assert owner.setdefault(x, groups[i]) == groups[i], f"body {x} in two groups"
    total = 0
    lanes = batcher.solve_form == "lanes"
    for g in range(batcher.group_count):
        nb = int(batch_counts[g])
        assert nb <= batcher.max_batches
        if not lanes:  # one batch in index order, or none
            members = listed[offsets[g, 0] : offsets[g, 1]]
            assert nb == (len(members) > 0)
            assert np.all(np.diff(members) > 0)
            assert np.array_equal(members, np.flatnonzero(groups == g))
        for k in range(nb):
            members = listed[offsets[g, k] : offsets[g, k + 1]]
            assert np.all(groups[members] == g)
            total += len(members)
            if k == batcher.max_batches - 1 or not lanes:
                continue  # the remainder slot is solved by one lane
            seen = set()
            for i in members:
                for x in (int(a[i]), int(b[i])):
                    if dynamic[x]:
                        assert x not in seen, f"body {x} twice in batch {k} of group {g}"
                        seen.add(x)
    assert total == n


def edge_batches(order, offsets, items, group=0):
    """Each edge's batch in group ``group`` (from the listing; -1: not in it)."""
    edge_of = {int(item): e for e, item in enumerate(items)}
    batches = np.full(len(items), -1)
    for k in range(len(offsets[group]) - 1):
        for item in order[offsets[group, k] : offsets[group, k + 1]]:
            batches[edge_of[int(item)]] = k
    return batches


@pytest.mark.parametrize("mode,solve_form", SPATIAL)
@pytest.mark.parametrize(
    "n_bodies,n_constraints", [(1, 0), (2, 1), (9, 31), (100, 333), (2000, 5003)]
)
def test_batches_are_independent(runtime, rng, n_bodies, n_constraints, mode, solve_form):
    a, b, dynamic = random_graph(rng, n_bodies, n_constraints)
    batcher, *result = run_device(
        runtime, a, b, dynamic, rng, group_count=5, mode=mode, solve_form=solve_form
    )
    check_invariants(batcher, a, b, dynamic, *result)
    if solve_form == "serial":
        return
    # The device's maximal sets stay close to the greedy reference's colour count.
    host = batch_host(a, b, dynamic)
    device_batches = int(result[2].max()) if n_constraints else 0
    reference = int(host.max()) + 1 if n_constraints else 0
    assert device_batches <= 2 * reference + 2


@pytest.mark.parametrize("mode", ["global", "cells", "slabs", "columns"])
@pytest.mark.parametrize("n_bodies,n_constraints", [(9, 31), (100, 333), (2000, 5003)])
def test_edges_of_other_kinds_share_the_colours(runtime, rng, n_bodies, n_constraints, mode):
    """Edges of two kinds (contacts and a made-up other kind, items tagged by kind and
    indexed per kind) are batched as one graph: ``order`` lists every item once and no two
    edges of a batch share a dynamic body, whatever their kinds (lanes form; the serial
    form keeps index order over both). Global batching with index bids colours exactly as
    the brute-force sequential first-fit colouring in edge order (batch_host), kinds
    notwithstanding; a batch holds edges of both kinds."""
    a, b, dynamic = random_graph(rng, n_bodies, n_constraints)
    items = mixed_items(rng, n_constraints)
    assert len(np.unique(items >> layouts.EDGE_KIND_SHIFT)) == 2
    options = {"ordered_rounds": 2**31} if mode == "global" else {"group_count": 5}
    for solve_form in ("lanes",) if mode == "global" else ("lanes", "serial"):
        batcher, order, offsets, counts, groups = run_device(
            runtime, a, b, dynamic, rng, items=items, mode=mode, solve_form=solve_form, **options
        )
        check_invariants(batcher, a, b, dynamic, order, offsets, counts, groups, items)
    if mode == "global":
        reference = batch_host(a, b, dynamic)
        batches = edge_batches(order, offsets, items)
        assert np.array_equal(batches, reference)
        kinds = items >> layouts.EDGE_KIND_SHIFT
        assert any(len(np.unique(kinds[batches == k])) == 2 for k in np.unique(batches))


@pytest.mark.parametrize("work_group_size", [1, 32, 64])
@pytest.mark.parametrize("mode", ["global", "cells"])
def test_tiny_batch_limit_sends_the_rest_to_the_serial_slot(runtime, work_group_size, mode):
    """A star (every edge on body 1) needs one batch per edge: with 4 batch slots, 3
    batches and the remainder in the serial last slot, nothing dropped; a chain colours
    in two batches (lanes form)."""
    star_b = np.arange(2, 40, dtype=np.uint32)
    star_a = np.ones_like(star_b)
    dynamic = np.ones(40, bool)
    batcher, *result = run_device(
        runtime, star_a, star_b, dynamic, mode=mode, max_batches=4, work_group_size=work_group_size
    )
    check_invariants(batcher, star_a, star_b, dynamic, *result)
    assert int(result[2].max()) == 4
    a = np.arange(300, dtype=np.uint32)
    batcher, *result = run_device(
        runtime,
        a,
        a + 1,
        np.ones(301, bool),
        mode=mode,
        max_batches=4,
        work_group_size=work_group_size,
    )
    check_invariants(batcher, a, a + 1, np.ones(301, bool), *result)


@pytest.mark.parametrize("work_group_size", [1, 32, 64, 256])
@pytest.mark.parametrize(
    "n_bodies,n_constraints", [(1, 0), (2, 1), (9, 31), (100, 333), (2000, 5003)]
)
def test_global_mode_colours_every_edge(runtime, rng, n_bodies, n_constraints, work_group_size):
    """Global mode (every compute unit, global marks, device-wide barriers): one group of
    every edge; batches share no dynamic body and stay close to the sequential greedy
    colouring (the Jones-Plassmann rounds colour each winner greedily)."""
    a, b, dynamic = random_graph(rng, n_bodies, n_constraints)
    batcher, *result = run_device(
        runtime, a, b, dynamic, rng, mode="global", work_group_size=work_group_size
    )
    assert batcher.launch_plan == [(0, 1)] and batcher.group_count == 1
    check_invariants(batcher, a, b, dynamic, *result)
    order, offsets, batch_counts, _ = result
    host = batch_host(a, b, dynamic)
    reference = int(host.max()) + 1 if n_constraints else 0
    assert int(batch_counts[0]) <= reference + 2
    assert n_constraints == 0 or int(batch_counts[0]) >= 1
    # no empty batch below the highest one (colours are taken lowest first)
    sizes = np.diff(offsets[0, : int(batch_counts[0]) + 1].astype(np.int64))
    assert np.all(sizes > 0)


def test_global_mode_sends_a_hub_past_64_colours_to_the_serial_batch(runtime):
    """A star of 100 edges on one dynamic body needs 100 colours: 64 batches of one, the
    other 36 in the serial last slot (nothing dropped), listed in index order (one lane
    solves it in that order: the result must not depend on timing)."""
    star_b = np.arange(2, 102, dtype=np.uint32)
    star_a = np.ones_like(star_b)
    dynamic = np.ones(102, bool)
    batcher, *result = run_device(
        runtime, star_a, star_b, dynamic, mode="global", work_group_size=32
    )
    check_invariants(batcher, star_a, star_b, dynamic, *result)
    order, offsets, batch_counts, _ = result
    assert int(batch_counts[0]) == batcher.max_batches
    sizes = np.diff(offsets[0].astype(np.int64))
    assert np.all(sizes[:64] == 1) and np.all(sizes[64:-1] == 0) and sizes[-1] == 36
    serial = order[offsets[0, -2] : offsets[0, -1]]
    assert np.all(np.diff(serial.astype(np.int64)) > 0)


@pytest.mark.parametrize("n_bodies,n_constraints", [(9, 31), (2000, 5003)])
def test_global_mode_colours_do_not_depend_on_the_launch(runtime, rng, n_bodies, n_constraints):
    """The colours depend on the priorities alone, not on how many lanes take part or in
    which order their atomics land: with hashed bids only, launches of 1, 64 and 256 lanes
    a work group give every edge the same colour and the same batch sizes."""
    a, b, dynamic = random_graph(rng, n_bodies, n_constraints)
    results = []
    for work_group_size in (1, 64, 256):
        batcher, order, offsets, counts, _ = run_device(
            runtime,
            a,
            b,
            dynamic,
            rng,
            mode="global",
            work_group_size=work_group_size,
            ordered_rounds=0,
        )
        results.append(
            (batcher.edge_batch.get()[:n_constraints], int(counts[0]), offsets[0].copy())
        )
    for colours, count, offsets in results[1:]:
        assert np.array_equal(colours, results[0][0])
        assert count == results[0][1]
        assert np.array_equal(offsets, results[0][2])


def global_colouring(runtime, a, b, dynamic, hints=None, **options):
    """One global-mode colouring of the graph (every invariant checked): (each edge's
    colour, its colour field, i.e. the colour handed to the next step, the batch count)."""
    queue = runtime.queue
    bodies = layouts.BODY.zeros(max(1, len(dynamic)))
    bodies["inv_mass"][: len(dynamic)] = np.where(dynamic, 1.0, 0.0)
    edges = make_edges(a, b, np.zeros((len(a), 3)), colours=hints)
    d_edges = cl_array.to_device(queue, edges)
    batcher = GlobalBatcher(runtime, **options)
    batcher(
        d_edges,
        cl_array.to_device(queue, np.array([len(a)], np.uint32)),
        cl_array.to_device(queue, bodies),
        len(dynamic),
        len(edges),
    )
    order, offsets, counts = batcher.read_batches()
    check_invariants(
        batcher, a, b, dynamic, order[: len(a)], offsets, counts, np.zeros(len(a), np.uint32)
    )
    return (batcher.edge_batch.get()[: len(a)], d_edges.get()["colour"][: len(a)], int(counts[0]))


@pytest.mark.parametrize("work_group_size", [1, 64])
@pytest.mark.parametrize("n_bodies,n_constraints", [(9, 31), (2000, 5003)])
def test_global_mode_ordered_rounds_colour_first_fit_in_index_order(
    runtime, rng, n_bodies, n_constraints, work_group_size
):
    """Bids of edge indices make the Jones-Plassmann rounds the sequential first-fit
    colouring in index order (batch_host) exactly, every colour handed on; with hashed
    bids only, the colours are valid but not those."""
    a, b, dynamic = random_graph(rng, n_bodies, n_constraints)
    reference = batch_host(a, b, dynamic)
    colours, field, count = global_colouring(
        runtime, a, b, dynamic, ordered_rounds=2**31, work_group_size=work_group_size
    )
    assert np.array_equal(colours, reference)
    assert np.array_equal(field, colours)
    assert count == int(reference.max()) + 1
    if n_constraints > 1000:  # (a small graph might come out the same)
        hashed, _, _ = global_colouring(
            runtime, a, b, dynamic, ordered_rounds=0, work_group_size=work_group_size
        )
        assert not np.array_equal(hashed, reference)


def test_global_mode_spreads_the_ordered_rounds_over_steps(runtime):
    """A chain of 300 edges on 301 dynamic bodies in index order needs 300 ordered rounds
    (each link waits for the one before). With 64 a step, a step's first 64 links get the
    first-fit colours (0, 1, 0, ...) and hand them on; the rest are coloured by hashed
    bids, validly, but hand on none; fed back as the next step's inherited colours (as the
    constraint setup does), the ordered rounds go on from there: after five steps every
    link holds its first-fit colour, and a sixth changes nothing."""
    a = np.arange(300, dtype=np.uint32)
    b = a + 1
    dynamic = np.ones(301, bool)
    reference = np.arange(300) % 2
    hints = None
    for step in range(1, 7):
        colours, field, count = global_colouring(
            runtime, a, b, dynamic, hints, ordered_rounds=64, work_group_size=32
        )
        done = min(300, 64 * step)
        assert np.array_equal(field[:done], reference[:done]), f"step {step}"
        assert np.all(field[done:] == layouts.SOLVER_NONE), f"step {step}"
        assert np.array_equal(colours[:done], reference[:done])
        hints = field
    assert count == 2


def inherited_colours_kept(a, b, dynamic, hints, colours=64):
    """Host reference of global mode's step 1: a hint below ``colours`` is kept unless
    another hinted edge has the same colour on one of its dynamic bodies."""
    claims = {}
    for i, k in enumerate(hints):
        if k < colours:
            for x in (int(a[i]), int(b[i])):
                if dynamic[x]:
                    claims[(x, int(k))] = claims.get((x, int(k)), 0) + 1
    return np.array(
        [
            k < colours and all(claims[(int(x), int(k))] == 1 for x in (a[i], b[i]) if dynamic[x])
            for i, k in enumerate(hints)
        ],
        bool,
    )


@pytest.mark.parametrize("work_group_size", [1, 64])
@pytest.mark.parametrize("n_bodies,n_constraints", [(9, 31), (100, 333), (2000, 5003)])
def test_global_mode_keeps_the_colours_it_inherits(
    runtime, rng, n_bodies, n_constraints, work_group_size
):
    """A step whose edges inherit the colours of the last step (the same constraint graph)
    gets exactly the same colours; random inherited colours, with clashes, still give
    valid batches, and every inherited colour that clashes with none on its bodies is kept
    (the host reference of the clash rule)."""
    a, b, dynamic = random_graph(rng, n_bodies, n_constraints)
    options = dict(mode="global", work_group_size=work_group_size)
    batcher, *first = run_device(runtime, a, b, dynamic, rng, **options)
    colours = batcher.edge_batch.get()[:n_constraints]
    batcher, *again = run_device(runtime, a, b, dynamic, rng, hints=colours, **options)
    check_invariants(batcher, a, b, dynamic, *again)
    assert np.array_equal(batcher.edge_batch.get()[:n_constraints], colours)
    assert int(again[2][0]) == int(first[2][0])

    hints = rng.integers(0, 80, n_constraints).astype(np.uint32)  # some past 64: none
    hints[rng.random(n_constraints) < 0.2] = layouts.SOLVER_NONE
    batcher, *result = run_device(runtime, a, b, dynamic, rng, hints=hints, **options)
    check_invariants(batcher, a, b, dynamic, *result)
    got = batcher.edge_batch.get()[:n_constraints]
    kept = inherited_colours_kept(a, b, dynamic, hints)
    assert np.array_equal(got[kept], hints[kept])


@pytest.mark.parametrize("rounds", [-1, 1.5, "64", 2**32])
def test_global_mode_refuses_bad_ordered_rounds(runtime, rounds):
    with pytest.raises(RbgenError, match="ordered_rounds must be a non-negative integer"):
        GlobalBatcher(runtime, ordered_rounds=rounds)


def test_unknown_algorithm_and_solve_form_are_refused(runtime):
    with pytest.raises(RbgenError, match="batching must be one of"):
        make_batcher(runtime, "hexagons")
    with pytest.raises(RbgenError, match="solve_form must be one of"):
        make_batcher(runtime, "cells", solve_form="tpu")
    batcher = make_batcher(runtime, "cells")  # no cell size yet
    edges = cl_array.to_device(runtime.queue, make_edges([0], [1], [[0.0, 0.0, 0.0]]))
    with pytest.raises(RbgenError, match="cell_size"):
        batcher(edges, cl_array.to_device(runtime.queue, np.array([1], np.uint32)), None, 2, 1)


@pytest.mark.parametrize("mode", ["slabs", "columns"])
@pytest.mark.parametrize("solve_form", ["lanes", "serial"])
def test_slabs_and_columns_keep_each_stack_in_one_group(runtime, solve_form, mode):
    """Slabs across x, columns across x and z: stacks 8 boxes tall on a 6 x 6 grid (pitch
    1.6 m, cells 1.5 m), edges between vertical neighbours and the ground: every stack's
    edges share one group (a slab or a column runs along gravity) and nothing lands in the
    leftovers (no body is wider than a cell). The stacks of one slab share its group; the
    columns, one stack each, spread over groups enough to keep 16 cores busy where the 6
    slabs (3 a colour) could not: with 50 groups a colour, 9 columns a colour land in at
    least 8 groups of their colour (a hash: two columns of a colour may share a group,
    which is as correct)."""
    side, height = 6, 8
    positions, a, b = [[0.0, -1.0, 0.0]], [], []
    for x in range(side):
        for z in range(side):
            below = 0
            for level in range(height):
                positions.append([1.6 * x + 0.7, 0.5 + level, 1.6 * z + 0.7])
                a.append(below)
                b.append(len(positions) - 1)
                below = len(positions) - 1
    positions = np.array(positions)
    bodies = layouts.BODY.zeros(len(positions))
    bodies["inv_mass"][1:] = 1.0
    bodies["position"][:, :3] = positions
    a, b = np.array(a, np.uint32), np.array(b, np.uint32)
    edges = make_edges(a, b, positions[b] + [0.2, -0.5, 0.2])
    batcher = new_batcher(runtime, mode, solve_form, group_count=50)
    order, offsets, batch_counts, groups = batch_records(
        runtime, batcher, edges, bodies, bodies["inv_mass"] > 0
    )
    stacks = groups.reshape(side * side, height)
    assert np.all(stacks == stacks[:, :1]), "a stack split over groups"
    slab = np.floor((1.6 * np.arange(side) + 0.9) / 1.5).astype(int)
    if mode == "slabs":
        assert len(np.unique(stacks[:, 0])) == len(np.unique(slab)) > 1
    else:
        u, v = np.meshgrid(slab, slab, indexing="ij")
        colour = (u & 1 | (v & 1) << 1).ravel()
        assert len(batcher.launch_plan) == 5
        assert np.array_equal(stacks[:, 0] // 50, colour), "a column in another colour's groups"
        for c in range(4):
            assert len(np.unique(stacks[colour == c, 0])) >= 8, f"colour {c}"
    assert not np.any(groups == batcher.launch_plan[-1][0]), "leftovers"


def batch_records(runtime, batcher, edges, bodies, dynamic=None):
    """Batch ConstraintEdge records ``edges`` between Body records ``bodies`` (every
    invariant checked; ``dynamic``: all bodies if None): (order, batch offsets, batch
    counts, each edge's group)."""
    queue = runtime.queue
    d_edges = cl_array.to_device(queue, edges)
    count = cl_array.to_device(queue, np.array([len(edges)], np.uint32))
    batcher(d_edges, count, cl_array.to_device(queue, bodies), len(bodies), len(edges))
    order, offsets, batch_counts = batcher.read_batches()
    groups = groups_of(batcher, len(edges))
    dynamic = np.ones(len(bodies), bool) if dynamic is None else dynamic
    check_invariants(
        batcher,
        edges["body_a"],
        edges["body_b"],
        dynamic,
        order[: len(edges)],
        offsets,
        batch_counts,
        groups,
        edges["item"],
    )
    return order, offsets, batch_counts, groups


def test_host_reference_colours_properly(rng):
    a, b, dynamic = random_graph(rng, 50, 200)
    batches = batch_host(a, b, dynamic)
    for k in np.unique(batches):
        members = np.flatnonzero(batches == k)
        bodies = [x for i in members for x in (a[i], b[i]) if dynamic[x]]
        assert len(bodies) == len(set(bodies))


@pytest.mark.parametrize("solve_form", ["lanes", "serial"])
def test_cells_spread_a_pile_and_route_oversized_bodies_to_leftovers(runtime, rng, solve_form):
    """Cells mode: a dense 2-D lattice of bodies with edges to their neighbours (one
    connected pile) spreads over many groups; bodies scattered 10x the cell size apart
    on an oversized body's edges land in the leftover group, never in two concurrent
    groups."""
    side = 30
    a, b, bodies, edges = lattice(side)
    dynamic = np.ones(side * side, bool)
    # body 0 is "huge": it also touches bodies far away
    far = rng.choice(np.arange(1, side * side), 25, replace=False)
    extra = make_edges(np.zeros(25, np.uint32), far, bodies["position"][far, :3] / 2)
    extra["item"] = contact_items(len(edges) + 25)[len(edges) :]
    edges = np.concatenate([edges, extra]).astype(edges.dtype)
    batcher = new_batcher(runtime, "cells", solve_form, group_count=7)
    order, offsets, batch_counts, groups = batch_records(runtime, batcher, edges, bodies, dynamic)
    a_all, b_all = edges["body_a"], edges["body_b"]
    assert len(np.unique(groups)) > 20
    leftover = batcher.launch_plan[-1][0]
    # body 0's far edges lie in cells of other groups; only the first group to claim
    # body 0 in each of the 8 colours keeps its edges on it, the others go to the
    # leftovers (27 edges over 56 groups: some always do)
    touching = groups[(a_all == 0) | (b_all == 0)]
    kept = touching[touching != leftover]
    colours = kept // batcher.groups_per_colour
    for colour in np.unique(colours):
        assert len(np.unique(kept[colours == colour])) == 1, f"colour {colour}"
    assert np.count_nonzero(touching == leftover) >= 1


@pytest.mark.parametrize("mode", ["cells", "slabs", "columns"])
def test_serial_form_lists_each_group_in_index_order(runtime, rng, mode):
    """Serial form: each group's edges are listed in index order (one work-item lists
    them, no atomics decide the order), and the count on the device may be below the
    capacity the launches are sized for. The per-colour body claims race (the first
    claim wins) wherever work groups run concurrently, so only the order inside each
    group is fixed, run after run."""
    a, b, dynamic = random_graph(rng, 500, 1777)
    for _ in range(2):
        batcher, order, offsets, batch_counts, groups = run_device(
            runtime,
            a,
            b,
            dynamic,
            np.random.default_rng(1),
            group_count=6,
            mode=mode,
            solve_form="serial",
        )
        check_invariants(batcher, a, b, dynamic, order, offsets, batch_counts, groups)
        listed_groups = groups[order]
        assert np.all(np.diff(listed_groups.astype(np.int64)) >= 0), "grouped"
        same_group = listed_groups[1:] == listed_groups[:-1]
        assert np.all(np.diff(order.astype(np.int64))[same_group] > 0), "index order in a group"


@pytest.mark.parametrize("solve_form", ["lanes", "serial"])
def test_slabs_spread_a_pile_over_every_group(runtime, rng, solve_form):
    """Slabs across a tilted axis: a dense lattice (one connected pile) of 40 x 40 bodies at
    unit pitch in slabs 1.5 m wide gives 33 slabs, 16-17 per colour: with 8 groups per colour
    every group of both colours is used, and no body is in two concurrent groups."""
    side = 40
    a, b, bodies, edges = lattice(side)
    edges = edges[rng.permutation(len(a))]
    edges["item"] = contact_items(len(edges))
    batcher = new_batcher(runtime, "slabs", solve_form, group_count=8)
    batcher.configure(cell_size=1.5, slab_axis=(0.96, 0.0, 0.28))
    order, offsets, batch_counts, groups = batch_records(runtime, batcher, edges, bodies)
    assert len(batcher.launch_plan) == 3
    assert set(np.unique(groups).tolist()) == set(range(16))  # no leftovers
    queue = runtime.queue
    batcher.configure(cell_size=1.5, slab_axis=(0.0, 0.0, 0.0))
    with pytest.raises(RbgenError, match="slab_axis"):
        batcher(
            cl_array.to_device(queue, edges),
            cl_array.to_device(queue, np.array([len(edges)], np.uint32)),
            cl_array.to_device(queue, bodies),
            len(bodies),
            len(edges),
        )


@pytest.mark.parametrize("solve_form", ["lanes", "serial"])
def test_slabs_spread_few_slabs_over_both_halves_of_the_groups(runtime, solve_form):
    """A pile only 7 m wide in slabs 1.5 m wide: 5 slabs, 3 of one colour and 2 of the
    other, for 8 groups a colour. PoCL hands each thread a contiguous range of a launch's
    groups, so the slabs of a colour must not crowd into its first groups: in each colour
    the slabs' groups split evenly between the lower and the upper half of its groups (at
    most one apart), every slab in a group of its own. The slab is that of the edge's
    point."""
    a, b, bodies, edges = lattice(8)
    batcher = new_batcher(runtime, "slabs", solve_form, group_count=8)
    groups = batch_records(runtime, batcher, edges, bodies)[3]
    slab = np.floor(edges["point"][:, 0] / 1.5).astype(int)
    for colour, slabs in ((0, 3), (1, 2)):
        used = np.unique(groups[slab % 2 == colour]) - colour * 8
        assert len(used) == slabs, f"colour {colour}: groups {used.tolist()}"
        lower, upper = np.count_nonzero(used < 4), np.count_nonzero(used >= 4)
        assert abs(lower - upper) <= 1, f"colour {colour}: groups {used.tolist()}"
