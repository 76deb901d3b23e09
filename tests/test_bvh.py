"""The quantized BVH (`rbgen.bvh`): its structure, its boxes, its walks and subtrees.

Every property is checked on random boxes of boundary sizes (1, 2, 3, 31, 32, 33, 1000)
and on degenerate inputs (every box the same, a flat layer): depth-first order with
escape offsets, every primitive once in leaf order, every node's quantized box holding
its subtree's primitive boxes, a walk finding exactly what overlaps the quantized leaf
boxes and never missing an exact overlap, subtrees covering the leaves once.
"""

from __future__ import annotations

import numpy as np
import pytest

from rbgen import bvh
from rbgen.errors import RbgenError

SIZES = [1, 2, 3, 31, 32, 33, 1000]


def random_boxes(rng, n: int, flat: bool = False):
    centres = rng.uniform(-50, 50, (n, 3))
    if flat:
        centres[:, 1] = 0.0
    half = rng.uniform(0.0, 2.0, (n, 3))
    return centres - half, centres + half


def check_structure(tree: bvh.Bvh, lower, upper):
    n = len(lower)
    nodes = tree.nodes
    assert len(nodes) == 2 * n - 1 and tree.leaf_count == n
    assert sorted(tree.order.tolist()) == list(range(n))
    index = nodes["index"].astype(np.int64)
    leaves = index[index >= 0]
    assert leaves.tolist() == list(range(n))  # depth-first: leaves in order
    sizes = tree.subtree_sizes()
    # an inner node's children: node + 1 and node + 1 + size(node + 1); sizes add up
    inner = np.flatnonzero(index < 0)
    left = inner + 1
    right = left + sizes[left]
    np.testing.assert_array_equal(sizes[inner], 1 + sizes[left] + sizes[right])
    q = bvh.unpack_bounds(nodes["bounds"])
    assert np.all(q[:, :3] <= q[:, 3:]) and q.min() >= 0 and q.max() <= bvh.QUANTA
    for child in (left, right):  # a parent's box holds its children's
        assert np.all(q[inner, :3] <= q[child, :3]) and np.all(q[inner, 3:] >= q[child, 3:])
    # a leaf's dequantized box holds its primitive's box
    node_lower, node_upper = tree.node_boxes()
    leaf_nodes = np.flatnonzero(index >= 0)
    primitive = tree.order[index[leaf_nodes]]
    assert np.all(node_lower[leaf_nodes] <= lower[primitive])
    assert np.all(node_upper[leaf_nodes] >= upper[primitive])


@pytest.mark.parametrize("n", SIZES)
def test_structure_and_boxes(rng, n):
    """Depth-first nodes with escape offsets, leaves in order, boxes that hold their
    subtrees (quantized outwards), for random boxes."""
    lower, upper = random_boxes(rng, n)
    check_structure(bvh.build(lower, upper), lower, upper)


@pytest.mark.parametrize("case", ["identical", "flat", "points"])
def test_degenerate_inputs(rng, case):
    """Every box the same (equal Morton codes: split in the middle), a flat layer (zero
    extent on one axis), and zero-size boxes still give valid trees."""
    n = 257
    if case == "identical":
        lower, upper = np.zeros((n, 3)), np.ones((n, 3))
    elif case == "flat":
        lower, upper = random_boxes(rng, n, flat=True)
        lower[:, 1] = upper[:, 1] = 0.0
    else:
        lower = upper = rng.uniform(-1, 1, (n, 3))
    check_structure(bvh.build(lower, upper), lower, upper)


@pytest.mark.parametrize("n", [1, 33, 1000])
def test_walk_finds_every_overlap(rng, n):
    """A walk returns the leaves whose quantized boxes overlap the query, in leaf order, a
    superset of the exact overlaps (nothing missed) and no more than brute force on the
    quantized boxes."""
    lower, upper = random_boxes(rng, n)
    tree = bvh.build(lower, upper)
    node_q = bvh.unpack_bounds(tree.nodes["bounds"])
    index = tree.nodes["index"]
    leaf_nodes = np.flatnonzero(index >= 0)
    leaf_q = node_q[leaf_nodes][np.argsort(index[leaf_nodes])]
    for _ in range(40):
        centre = rng.uniform(-60, 60, 3)
        half = rng.uniform(0, 10, 3)
        q_lo, q_hi = bvh.quantize_query(tree, centre - half, centre + half)
        found = tree.query(centre - half, centre + half)
        expected = np.flatnonzero(
            np.all(leaf_q[:, :3] <= q_hi, axis=1) & np.all(q_lo <= leaf_q[:, 3:], axis=1)
        )
        np.testing.assert_array_equal(found, expected)
        exact = np.flatnonzero(
            np.all(lower[tree.order] <= centre + half, axis=1)
            & np.all(centre - half <= upper[tree.order], axis=1)
        )
        assert set(exact) <= set(found)


@pytest.mark.parametrize("max_nodes", [1, 16, 128, 4096])
def test_subtrees_cover_the_leaves_once(rng, max_nodes):
    """The subtrees of a size are contiguous node ranges, none larger than the size, each
    under a larger parent, together holding every leaf once, in order."""
    lower, upper = random_boxes(rng, 1000)
    tree = bvh.build(lower, upper)
    subtrees = tree.subtrees(max_nodes)
    sizes = tree.subtree_sizes()
    assert np.all(subtrees[:, 1] <= max_nodes)
    np.testing.assert_array_equal(sizes[subtrees[:, 0]], subtrees[:, 1])
    index = tree.nodes["index"]
    covered = np.concatenate([index[r : r + s][index[r : r + s] >= 0] for r, s in subtrees])
    assert covered.tolist() == list(range(1000))
    if max_nodes >= len(tree.nodes):
        assert subtrees.tolist() == [[0, len(tree.nodes)]]


def test_bad_input_is_refused():
    with pytest.raises(RbgenError, match="no primitives"):
        bvh.build(np.zeros((0, 3)), np.zeros((0, 3)), "test mesh")
    with pytest.raises(RbgenError, match="not finite"):
        bvh.build(np.array([[0, 0, np.nan]]), np.ones((1, 3)))


@pytest.mark.parametrize("offset", [0.0, 1e3, 1e5])
def test_thin_boxes_far_from_the_origin_stay_inside_their_nodes(rng, offset):
    """A flat layer (zero extent on y) of tiny boxes far from the origin: the quantization
    box keeps float32 rounding below a quantum, so every leaf still holds its box."""
    n = 200
    centres = offset + rng.uniform(-5, 5, (n, 3))
    centres[:, 1] = offset
    half = rng.uniform(0, 1e-7, (n, 3))
    lower, upper = centres - half, centres + half
    check_structure(bvh.build(lower, upper), lower, upper)
