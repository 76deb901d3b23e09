"""Constraint batching: invariants of the device batches against the host reference.

Invariants (checked on random constraint graphs, both level-1 modes, both
shapes): every constraint appears exactly once in ``order``; no dynamic body is
touched by two groups that run in the same solver launch (work groups never
synchronise); static bodies are ignored. GPU shape: no dynamic body appears
twice in one batch (except the serial last batch). CPU shape: a group is one
batch (none when empty) listing its constraints in increasing index order.
"""
from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array
import pytest

from rbgen import layouts
from rbgen.errors import RbgenError
from rbgen.pipeline.batching import ConstraintBatcher, batch_host


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


def run_device(runtime, a, b, dynamic, rng=None, hints=None, **kwargs):
    """Bodies scattered in a 20 m box, contact points 0.5 m from B (cell size 1.5 m).
    Global mode: ``hints`` are the constraints' inherited colours (None: a first step,
    none inherited). The one-group modes return groups of 0."""
    queue = runtime.queue
    rng = rng or np.random.default_rng(0)
    bodies = layouts.BODY.zeros(max(1, len(dynamic)))
    bodies["inv_mass"][: len(dynamic)] = np.where(dynamic, 1.0, 0.0)
    bodies["position"][:, :3] = rng.uniform(-10, 10, (len(bodies), 3))
    cons = layouts.CONTACT_CONSTRAINT.zeros(max(1, len(a)))
    cons["body_a"][: len(a)], cons["body_b"][: len(a)] = a, b
    cons["r_b"][:, 0, :3] = rng.uniform(-0.3, 0.3, (len(cons), 3))
    cons["group"] = layouts.SOLVER_NONE
    if hints is not None:
        cons["group"][: len(a)] = hints
    if kwargs.get("mode") in ("cells", "columns", "slabs"):
        kwargs.setdefault("cell_size", 1.5)
    capacity = len(a) + 7  # launches over capacity, count on the device
    d_cons = cl_array.to_device(queue, np.resize(cons, capacity) if len(a) else cons)
    d_bodies = cl_array.to_device(queue, bodies)
    count = cl_array.to_device(queue, np.array([len(a)], np.uint32))
    batcher = ConstraintBatcher(runtime, **kwargs)
    batcher(d_cons, count, d_bodies, len(dynamic), capacity)
    order, offsets, batch_counts = batcher.read_batches()
    groups = d_cons.get()["group"][: len(a)]
    if batcher.mode == "global":  # the field holds the colour, or none if provisional
        inherited = groups != layouts.SOLVER_NONE
        colours = batcher.constraint_batch.get()[: len(a)]
        assert np.array_equal(groups[inherited], colours[inherited])
    if batcher.mode in ("single", "global"):  # one group
        groups = np.zeros_like(groups)
    return batcher, order[: len(a)], offsets, batch_counts, groups


def lattice(side: int):
    """A dense side x side lattice of unit-pitch dynamic bodies in the x-z plane, one
    contact per pair of grid neighbours (one connected pile), contact point halfway:
    (body_a, body_b, Body records, ContactConstraint records)."""
    ids = np.arange(side * side).reshape(side, side)
    a = np.r_[ids[:-1, :].ravel(), ids[:, :-1].ravel()].astype(np.uint32)
    b = np.r_[ids[1:, :].ravel(), ids[:, 1:].ravel()].astype(np.uint32)
    bodies = layouts.BODY.zeros(side * side)
    bodies["inv_mass"] = 1.0
    gx, gz = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    bodies["position"][:, 0], bodies["position"][:, 2] = gx.ravel(), gz.ravel()
    cons = layouts.CONTACT_CONSTRAINT.zeros(len(a))
    cons["body_a"], cons["body_b"] = a, b
    cons["r_b"][:, 0, :3] = (bodies["position"][a, :3] - bodies["position"][b, :3]) / 2
    return a, b, bodies, cons


def check_invariants(batcher, a, b, dynamic, order, offsets, batch_counts, groups):
    n = len(a)
    assert sorted(order.tolist()) == list(range(n)), "every constraint exactly once"
    for first, count in batcher.launch_plan:  # groups running in one launch
        owner = {}
        for i in np.flatnonzero((groups >= first) & (groups < first + count)):
            for x in (int(a[i]), int(b[i])):
                if dynamic[x]:
                    assert owner.setdefault(x, groups[i]) == groups[i], f"body {x} in two groups"
    total = 0
    for g in range(batcher.group_count):
        nb = int(batch_counts[g])
        assert nb <= batcher.max_batches
        if not batcher.batches:  # one batch in index order, or none
            members = order[offsets[g, 0]: offsets[g, 1]]
            assert nb == (len(members) > 0)
            assert np.all(np.diff(members.astype(np.int64)) > 0)
            assert np.array_equal(members, np.flatnonzero(groups == g))
        for k in range(nb):
            members = order[offsets[g, k] - 0: offsets[g, k + 1]]
            assert np.all(groups[members] == g)
            total += len(members)
            if k == batcher.max_batches - 1 or not batcher.batches:
                continue  # the remainder slot is solved by one lane
            seen = set()
            for i in members:
                for x in (int(a[i]), int(b[i])):
                    if dynamic[x]:
                        assert x not in seen, f"body {x} twice in batch {k} of group {g}"
                        seen.add(x)
    assert total == n


@pytest.mark.parametrize("shape", ["gpu", "cpu"])
@pytest.mark.parametrize("mode", ["components", "cells", "columns", "slabs"])
@pytest.mark.parametrize("n_bodies,n_constraints", [(1, 0), (2, 1), (9, 31), (100, 333),
                                                   (2000, 5003)])
def test_batches_are_independent(runtime, rng, n_bodies, n_constraints, mode, shape):
    a, b, dynamic = random_graph(rng, n_bodies, n_constraints)
    batcher, *result = run_device(runtime, a, b, dynamic, rng, group_count=5, mode=mode,
                                  shape=shape)
    check_invariants(batcher, a, b, dynamic, *result)
    if shape == "cpu":
        return
    # The device's maximal sets stay close to the greedy reference's colour count.
    host = batch_host(a, b, dynamic)
    device_batches = int(result[2].max()) if n_constraints else 0
    reference = int(host.max()) + 1 if n_constraints else 0
    assert device_batches <= 2 * reference + 2


@pytest.mark.parametrize("work_group_size", [1, 32, 64])
def test_chain_and_tiny_batch_limit(runtime, rng, work_group_size):
    """A long chain is one component (one group); a 4-slot limit forces the serial remainder."""
    a, b, dynamic = random_graph(rng, 301, 300, static_fraction=0.0, chain=True)
    dynamic[:] = True
    batcher, *result = run_device(runtime, a, b, dynamic, group_count=3, max_batches=4,
                                  work_group_size=work_group_size, mode="components",
                                  shape="gpu")
    check_invariants(batcher, a, b, dynamic, *result)
    assert len(set(result[3].tolist())) == 1  # one component: one group
    # A star (every constraint on body 1) needs one batch per constraint: 3 + the remainder.
    star_b = np.arange(2, 40, dtype=np.uint32)
    star_a = np.ones_like(star_b)
    batcher, *result = run_device(runtime, star_a, star_b, np.ones(40, bool), group_count=3,
                                  max_batches=4, work_group_size=work_group_size,
                                  mode="components", shape="gpu")
    check_invariants(batcher, star_a, star_b, np.ones(40, bool), *result)
    assert int(result[2].max()) == 4


def one_group_options(mode):
    """Batcher options of the one-group modes for the tests' graphs (<= 2,048 bodies)."""
    return {"max_bodies": 2048} if mode == "single" else {}


@pytest.mark.parametrize("mode", ["single", "global"])
@pytest.mark.parametrize("work_group_size", [1, 32, 64, 256])
@pytest.mark.parametrize("n_bodies,n_constraints", [(1, 0), (2, 1), (9, 31), (100, 333),
                                                   (2000, 5003)])
def test_one_group_modes_colour_every_constraint(runtime, rng, n_bodies, n_constraints,
                                                 work_group_size, mode):
    """Single mode (one work group, local body marks) and global mode (every compute unit,
    global marks, grid barriers): one group of every constraint; batches share no dynamic
    body and stay close to the sequential greedy colouring (the Jones-Plassmann rounds
    colour each winner greedily)."""
    a, b, dynamic = random_graph(rng, n_bodies, n_constraints)
    batcher, *result = run_device(runtime, a, b, dynamic, rng, mode=mode, shape="gpu",
                                  work_group_size=work_group_size, **one_group_options(mode))
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


@pytest.mark.parametrize("mode", ["single", "global"])
def test_one_group_modes_send_a_hub_past_64_colours_to_the_serial_batch(runtime, mode):
    """A star of 100 constraints on one dynamic body needs 100 colours: 64 batches of one,
    the other 36 in the serial last slot (nothing dropped), listed in index order (one
    lane solves it in that order: the result must not depend on timing)."""
    star_b = np.arange(2, 102, dtype=np.uint32)
    star_a = np.ones_like(star_b)
    dynamic = np.ones(102, bool)
    batcher, *result = run_device(runtime, star_a, star_b, dynamic, mode=mode, shape="gpu",
                                  work_group_size=32, **one_group_options(mode))
    check_invariants(batcher, star_a, star_b, dynamic, *result)
    order, offsets, batch_counts, _ = result
    assert int(batch_counts[0]) == batcher.max_batches
    sizes = np.diff(offsets[0].astype(np.int64))
    assert np.all(sizes[:64] == 1) and np.all(sizes[64:-1] == 0) and sizes[-1] == 36
    if mode == "global":
        serial = order[offsets[0, -2]: offsets[0, -1]]
        assert np.all(np.diff(serial.astype(np.int64)) > 0)


@pytest.mark.parametrize("n_bodies,n_constraints", [(9, 31), (2000, 5003)])
def test_global_mode_colours_like_single_mode(runtime, rng, n_bodies, n_constraints):
    """The colours depend on the priorities alone, not on how many work groups take part or
    in which order their atomics land: global mode with hashed bids only gives every
    constraint the colour that single mode (one work group, hashed bids) gives it, and the
    same batch sizes."""
    a, b, dynamic = random_graph(rng, n_bodies, n_constraints)
    colours = {}
    for mode in ("single", "global"):
        options = one_group_options(mode) if mode == "single" else {"ordered_rounds": 0}
        batcher, order, offsets, counts, _ = run_device(runtime, a, b, dynamic, rng, mode=mode,
                                                        shape="gpu", work_group_size=64,
                                                        **options)
        colours[mode] = (batcher.constraint_batch.get()[:n_constraints], counts[0],
                         offsets[0].copy())
    assert np.array_equal(colours["single"][0], colours["global"][0])
    assert colours["single"][1] == colours["global"][1]
    assert np.array_equal(colours["single"][2], colours["global"][2])


def global_colouring(runtime, a, b, dynamic, hints=None, **options):
    """One global-mode colouring of the graph (every invariant checked): (each
    constraint's colour, its group field, i.e. the colour handed to the next step,
    the batch count)."""
    queue = runtime.queue
    bodies = layouts.BODY.zeros(max(1, len(dynamic)))
    bodies["inv_mass"][: len(dynamic)] = np.where(dynamic, 1.0, 0.0)
    cons = layouts.CONTACT_CONSTRAINT.zeros(max(1, len(a)))
    cons["body_a"][: len(a)], cons["body_b"][: len(a)] = a, b
    cons["group"] = layouts.SOLVER_NONE if hints is None else hints
    d_cons = cl_array.to_device(queue, cons)
    batcher = ConstraintBatcher(runtime, mode="global", shape="gpu", **options)
    batcher(d_cons, cl_array.to_device(queue, np.array([len(a)], np.uint32)),
            cl_array.to_device(queue, bodies), len(dynamic), len(cons))
    order, offsets, counts = batcher.read_batches()
    check_invariants(batcher, a, b, dynamic, order[: len(a)], offsets, counts,
                     np.zeros(len(a), np.uint32))
    return (batcher.constraint_batch.get()[: len(a)], d_cons.get()["group"][: len(a)],
            int(counts[0]))


@pytest.mark.parametrize("work_group_size", [1, 64])
@pytest.mark.parametrize("n_bodies,n_constraints", [(9, 31), (2000, 5003)])
def test_global_mode_ordered_rounds_colour_first_fit_in_index_order(
        runtime, rng, n_bodies, n_constraints, work_group_size):
    """Bids of constraint indices make the Jones-Plassmann rounds the sequential first-fit
    colouring in index order (batch_host) exactly, every colour handed on; with hashed
    bids only, the colours are valid but not those."""
    a, b, dynamic = random_graph(rng, n_bodies, n_constraints)
    reference = batch_host(a, b, dynamic)
    colours, field, count = global_colouring(runtime, a, b, dynamic, ordered_rounds=2**31,
                                             work_group_size=work_group_size)
    assert np.array_equal(colours, reference)
    assert np.array_equal(field, colours)
    assert count == int(reference.max()) + 1
    if n_constraints > 1000:  # (a small graph might come out the same)
        hashed, _, _ = global_colouring(runtime, a, b, dynamic, ordered_rounds=0,
                                        work_group_size=work_group_size)
        assert not np.array_equal(hashed, reference)


def test_global_mode_spreads_the_ordered_rounds_over_steps(runtime):
    """A chain of 300 constraints on 301 dynamic bodies in index order needs 300 ordered
    rounds (each link waits for the one before). With 64 a step, a step's first 64 links
    get the first-fit colours (0, 1, 0, ...) and hand them on; the rest are coloured by
    hashed bids, validly, but hand on none; fed back as the next step's inherited colours
    (as the constraint setup does), the ordered rounds go on from there: after five steps
    every link holds its first-fit colour, and a sixth changes nothing."""
    a = np.arange(300, dtype=np.uint32)
    b = a + 1
    dynamic = np.ones(301, bool)
    reference = np.arange(300) % 2
    hints = None
    for step in range(1, 7):
        colours, field, count = global_colouring(runtime, a, b, dynamic, hints,
                                                 ordered_rounds=64, work_group_size=32)
        done = min(300, 64 * step)
        assert np.array_equal(field[:done], reference[:done]), f"step {step}"
        assert np.all(field[done:] == layouts.SOLVER_NONE), f"step {step}"
        assert np.array_equal(colours[:done], reference[:done])
        hints = field
    assert count == 2


def inherited_colours_kept(a, b, dynamic, hints, colours=64):
    """Host reference of global mode's step 1: a hint below ``colours`` is kept unless
    another hinted constraint has the same colour on one of its dynamic bodies."""
    claims = {}
    for i, k in enumerate(hints):
        if k < colours:
            for x in (int(a[i]), int(b[i])):
                if dynamic[x]:
                    claims[(x, int(k))] = claims.get((x, int(k)), 0) + 1
    return np.array([k < colours and all(claims[(int(x), int(k))] == 1
                                         for x in (a[i], b[i]) if dynamic[x])
                     for i, k in enumerate(hints)], bool)


@pytest.mark.parametrize("work_group_size", [1, 64])
@pytest.mark.parametrize("n_bodies,n_constraints", [(9, 31), (100, 333), (2000, 5003)])
def test_global_mode_keeps_the_colours_it_inherits(runtime, rng, n_bodies, n_constraints,
                                                   work_group_size):
    """A step whose constraints inherit the colours of the last step (the same contact
    graph) gets exactly the same colours; random inherited colours, with clashes, still
    give valid batches, and every inherited colour that clashes with none on its bodies
    is kept (the host reference of the clash rule)."""
    a, b, dynamic = random_graph(rng, n_bodies, n_constraints)
    options = dict(mode="global", shape="gpu", work_group_size=work_group_size)
    batcher, *first = run_device(runtime, a, b, dynamic, rng, **options)
    colours = batcher.constraint_batch.get()[:n_constraints]
    batcher, *again = run_device(runtime, a, b, dynamic, rng, hints=colours, **options)
    check_invariants(batcher, a, b, dynamic, *again)
    assert np.array_equal(batcher.constraint_batch.get()[:n_constraints], colours)
    assert int(again[2][0]) == int(first[2][0])

    hints = rng.integers(0, 80, n_constraints).astype(np.uint32)  # some past 64: none
    hints[rng.random(n_constraints) < 0.2] = layouts.SOLVER_NONE
    batcher, *result = run_device(runtime, a, b, dynamic, rng, hints=hints, **options)
    check_invariants(batcher, a, b, dynamic, *result)
    got = batcher.constraint_batch.get()[:n_constraints]
    kept = inherited_colours_kept(a, b, dynamic, hints)
    assert np.array_equal(got[kept], hints[kept])


def test_single_mode_refuses_more_bodies_than_its_marks(runtime, rng):
    a, b, dynamic = random_graph(rng, 200, 50)
    with pytest.raises(RbgenError, match="at most 128 bodies"):
        run_device(runtime, a, b, dynamic, mode="single", shape="gpu", max_bodies=128)
    for mode in ("single", "global"):
        with pytest.raises(RbgenError, match="needs shape='gpu'"):
            ConstraintBatcher(runtime, mode=mode, shape="cpu")


@pytest.mark.parametrize("rounds", [-1, 1.5, "64", 2**32])
def test_global_mode_refuses_bad_ordered_rounds(runtime, rounds):
    with pytest.raises(RbgenError, match="ordered_rounds must be a non-negative integer"):
        ConstraintBatcher(runtime, mode="global", shape="gpu", ordered_rounds=rounds)


@pytest.mark.parametrize("shape", ["gpu", "cpu"])
def test_columns_keep_each_stack_in_one_group(runtime, rng, shape):
    """Columns mode: stacks 8 boxes tall on a 6 x 6 grid (pitch 1.6 m, cell 1.5 m), contacts
    between vertical neighbours and the ground: every stack's constraints share one group
    (the cells of a column run along gravity), stacks spread over many groups, and
    nothing lands in the leftovers (no body is wider than a cell)."""
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
    cons = layouts.CONTACT_CONSTRAINT.zeros(len(a))
    cons["body_a"], cons["body_b"] = a, b
    cons["r_b"][:, 0, :3] = [0.2, -0.5, 0.2]
    queue = runtime.queue
    batcher = ConstraintBatcher(runtime, mode="columns", group_count=50, cell_size=1.5,
                                shape=shape)
    d_cons = cl_array.to_device(queue, cons)
    count = cl_array.to_device(queue, np.array([len(cons)], np.uint32))
    batcher(d_cons, count, cl_array.to_device(queue, bodies), len(bodies), len(cons))
    order, offsets, batch_counts = batcher.read_batches()
    groups = d_cons.get()["group"]
    check_invariants(batcher, a, b, bodies["inv_mass"] > 0, order[: len(cons)], offsets,
                     batch_counts, groups)
    stacks = groups.reshape(side * side, height)
    assert np.all(stacks == stacks[:, :1]), "a stack split over groups"
    assert not np.any(groups == batcher.launch_plan[-1][0]), "leftovers"
    assert len(np.unique(groups)) > 12 and batcher.colours == 5
    batcher.column_axes = ((1.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    with pytest.raises(RbgenError, match="column_axes"):
        batcher(d_cons, count, cl_array.to_device(queue, bodies), len(bodies), len(cons))


def batch_records(runtime, batcher, cons, bodies, dynamic=None):
    """Batch ContactConstraint records ``cons`` between Body records ``bodies`` (every
    invariant checked; ``dynamic``: all bodies if None): (order, batch offsets, batch
    counts, each constraint's group)."""
    queue = runtime.queue
    d_cons = cl_array.to_device(queue, cons)
    count = cl_array.to_device(queue, np.array([len(cons)], np.uint32))
    batcher(d_cons, count, cl_array.to_device(queue, bodies), len(bodies), len(cons))
    order, offsets, batch_counts = batcher.read_batches()
    groups = d_cons.get()["group"]
    dynamic = np.ones(len(bodies), bool) if dynamic is None else dynamic
    check_invariants(batcher, cons["body_a"], cons["body_b"], dynamic, order[: len(cons)],
                     offsets, batch_counts, groups)
    return order, offsets, batch_counts, groups


def test_host_reference_colours_properly(rng):
    a, b, dynamic = random_graph(rng, 50, 200)
    batches = batch_host(a, b, dynamic)
    for k in np.unique(batches):
        members = np.flatnonzero(batches == k)
        bodies = [x for i in members for x in (a[i], b[i]) if dynamic[x]]
        assert len(bodies) == len(set(bodies))


@pytest.mark.parametrize("shape", ["gpu", "cpu"])
def test_cells_spread_a_pile_and_route_oversized_bodies_to_leftovers(runtime, rng, shape):
    """Cells mode: a dense 2-D lattice of bodies with contacts to their neighbours (one
    connected pile) spreads over many groups; bodies scattered 10x the cell size apart
    on an oversized body's contacts land in the leftover group, never in two
    concurrent groups."""
    side = 30
    a, b, bodies, cons = lattice(side)
    dynamic = np.ones(side * side, bool)
    # body 0 is "huge": it also touches bodies far away
    far = rng.choice(np.arange(1, side * side), 25, replace=False)
    extra = layouts.CONTACT_CONSTRAINT.zeros(25)
    extra["body_a"], extra["body_b"] = 0, far
    extra["r_b"][:, 0, :3] = -bodies["position"][far, :3] / 2
    cons = np.concatenate([cons, extra]).astype(cons.dtype)
    batcher = ConstraintBatcher(runtime, mode="cells", group_count=7, cell_size=1.5, shape=shape)
    order, offsets, batch_counts, groups = batch_records(runtime, batcher, cons, bodies, dynamic)
    a_all, b_all = cons["body_a"], cons["body_b"]
    assert len(np.unique(groups)) > 20
    leftover = batcher.launch_plan[-1][0]
    # body 0's far contacts lie in cells of other groups; only the first group to claim
    # body 0 in each of the 8 colours keeps its constraints on it, the others go to the
    # leftovers (27 constraints over 56 groups: some always do)
    touching = groups[(a_all == 0) | (b_all == 0)]
    kept = touching[touching != leftover]
    colours = kept // batcher.groups_per_colour
    for colour in np.unique(colours):
        assert len(np.unique(kept[colours == colour])) == 1, f"colour {colour}"
    assert np.count_nonzero(touching == leftover) >= 1


@pytest.mark.parametrize("mode", ["components", "cells", "columns", "slabs"])
def test_cpu_shape_lists_each_group_once_in_index_order_twice_running(runtime, rng, mode):
    """CPU shape: each group's constraints are listed in index order (one work-item lists
    them, no atomics decide the order), and the count on the device may be below the
    capacity the launches are sized for. With components the same input batched twice
    gives the same result; with cells and slabs the per-colour body claims race (the first
    claim wins) wherever work groups run concurrently (a GPU, or PoCL's threads: about one
    run in ten differed here), so only the order inside each group is fixed there."""
    a, b, dynamic = random_graph(rng, 500, 1777)
    first = run_device(runtime, a, b, dynamic, np.random.default_rng(1), group_count=6,
                       mode=mode, shape="cpu")
    second = run_device(runtime, a, b, dynamic, np.random.default_rng(1), group_count=6,
                        mode=mode, shape="cpu")
    for batcher, order, offsets, batch_counts, groups in (first, second):
        check_invariants(batcher, a, b, dynamic, order, offsets, batch_counts, groups)
        listed_groups = groups[order]
        assert np.all(np.diff(listed_groups.astype(np.int64)) >= 0), "grouped"
        same_group = listed_groups[1:] == listed_groups[:-1]
        assert np.all(np.diff(order.astype(np.int64))[same_group] > 0), "index order in a group"
    if mode == "components":
        assert np.array_equal(first[1], second[1])
        assert np.array_equal(first[3], second[3])
        assert first[0].launch_plan == second[0].launch_plan


def test_unknown_shape_is_refused(runtime):
    with pytest.raises(RbgenError, match="shape"):
        ConstraintBatcher(runtime, shape="tpu")


@pytest.mark.parametrize("shape", ["gpu", "cpu"])
def test_slabs_spread_a_pile_over_every_group(runtime, rng, shape):
    """Slabs across a tilted axis: a dense lattice (one connected pile) of 40 x 40 bodies at
    unit pitch in slabs 1.5 m wide gives 33 slabs, 16-17 per colour: with 8 groups per colour
    every group of both colours is used, and no body is in two concurrent groups."""
    side = 40
    a, b, bodies, cons = lattice(side)
    queue = runtime.queue
    order = rng.permutation(len(a))
    cons = cons[order]
    batcher = ConstraintBatcher(runtime, mode="slabs", group_count=8, cell_size=1.5, shape=shape)
    batcher.slab_axis = (0.96, 0.0, 0.28)
    d_cons = cl_array.to_device(queue, cons)
    count = cl_array.to_device(queue, np.array([len(cons)], np.uint32))
    order, offsets, batch_counts, groups = batch_records(runtime, batcher, cons, bodies)
    assert len(batcher.launch_plan) == 3
    assert set(np.unique(groups).tolist()) == set(range(16))  # no leftovers
    with pytest.raises(RbgenError, match="slab_axis"):
        batcher.slab_axis = (0.0, 0.0, 0.0)
        batcher(d_cons, count, cl_array.to_device(queue, bodies), len(bodies), len(cons))


@pytest.mark.parametrize("shape", ["gpu", "cpu"])
def test_slabs_spread_few_slabs_over_both_halves_of_the_groups(runtime, shape):
    """A pile only 7 m wide in slabs 1.5 m wide: 5 slabs, 3 of one colour and 2 of the
    other, for 8 groups a colour. PoCL hands each thread a contiguous range of a launch's
    groups, so the slabs of a colour must not crowd into its first groups (they did, and one
    of two cores solved the whole pile): in each colour the slabs' groups split evenly
    between the lower and the upper half of its groups (at most one apart), every slab in a
    group of its own."""
    a, b, bodies, cons = lattice(8)
    batcher = ConstraintBatcher(runtime, mode="slabs", group_count=8, cell_size=1.5, shape=shape)
    groups = batch_records(runtime, batcher, cons, bodies)[3]
    slab = np.floor((bodies["position"][b, 0] + cons["r_b"][:, 0, 0]) / 1.5).astype(int)
    for colour, slabs in ((0, 3), (1, 2)):
        used = np.unique(groups[slab % 2 == colour]) - colour * 8
        assert len(used) == slabs, f"colour {colour}: groups {used.tolist()}"
        lower, upper = np.count_nonzero(used < 4), np.count_nonzero(used >= 4)
        assert abs(lower - upper) <= 1, f"colour {colour}: groups {used.tolist()}"
