"""Quantized bounding-volume hierarchies over boxes (triangles of a mesh), built on the host.

`build` takes one box per primitive and returns a `Bvh`: a binary tree in depth-first
order whose leaves hold one primitive each, so that a walk needs no stack (an inner node
stores the size of its subtree: skipping it is ``node + size``) and visits the leaves in
increasing order. The primitives are renumbered in leaf order (`Bvh.order`), so that a
walk emits them sorted, and every node box is quantized to 16 bits per axis inside the
BVH's quantization box (`BvhNode`: 16 bytes a node), rounded outwards with one quantum
of slack, so a query that overlaps a primitive's box always overlaps every box above it.

Why on the host: a mesh is static, built once when it is made and shared by every World
that adds it; the build is a few vectorised numpy passes (a Morton sort, then one pass
per tree level), fast enough for meshes of millions of triangles, and its result does
not depend on the device. What does depend on the device, how large a subtree fits in
local memory, is a parameter of the traversal (`subtrees` lists the subtrees of a size).

The tree: the primitives are sorted by the Morton code of their box centres on a cubic
grid (so a flat terrain is split in x and z first), and a node over the sorted range
[lo, hi) splits it where the highest Morton bit that differs in the range changes (the
binary radix tree of Karras 2012), or at the middle where the codes are all equal.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from . import layouts
from .errors import RbgenError

#: quantized coordinates run 0 .. QUANTA; the build keeps one quantum of slack each side
QUANTA = layouts.BVH_QUANTA
#: Morton bits per axis (63-bit codes)
MORTON_BITS = 21


@dataclasses.dataclass(frozen=True)
class Bvh:
    """A quantized BVH (see the module docstring).

    ``nodes``: `BvhNode` records in depth-first order (2 n - 1 for n primitives);
    ``order``: leaf k holds input primitive ``order[k]``; ``lower``, ``upper``: the
    quantization box (float32; a quantum is (upper - lower) / QUANTA per axis).
    """

    nodes: np.ndarray
    order: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    @property
    def leaf_count(self) -> int:
        return len(self.order)

    @property
    def quantum(self) -> np.ndarray:
        return (self.upper.astype(np.float64) - self.lower) / QUANTA

    def node_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Every node's box, dequantized: (lower, upper), (nodes, 3) float64."""
        q = unpack_bounds(self.nodes["bounds"])
        return (self.lower + q[:, :3] * self.quantum, self.lower + q[:, 3:] * self.quantum)

    def subtree_sizes(self) -> np.ndarray:
        """Nodes in each node's subtree (1 for a leaf)."""
        index = self.nodes["index"].astype(np.int64)
        return np.where(index >= 0, 1, -index)

    def subtrees(self, max_nodes: int) -> np.ndarray:
        """(root, size) of the subtrees of at most ``max_nodes`` nodes whose parent's is
        larger: what a traversal stages in local memory. They cover every leaf once, in
        depth-first order."""
        sizes = self.subtree_sizes()
        roots, node, end = [], 0, len(sizes)
        while node < end:  # the walk above the subtrees
            if sizes[node] <= max_nodes:
                roots.append((node, sizes[node]))
                node += sizes[node]
            else:
                node += 1
        return np.asarray(roots, np.int64).reshape(-1, 2)

    def query(self, lower, upper) -> np.ndarray:
        """Leaves whose quantized boxes overlap the box [lower, upper] (closed), in leaf
        order: a host walk, for tests (the device's leaf test also checks the exact box)."""
        q_lower, q_upper = quantize_query(self, lower, upper)
        bounds = unpack_bounds(self.nodes["bounds"])
        index = self.nodes["index"]
        found, node = [], 0
        while node < len(index):
            hit = bool(np.all(bounds[node, :3] <= q_upper) and np.all(q_lower <= bounds[node, 3:]))
            if index[node] >= 0:
                if hit:
                    found.append(int(index[node]))
                node += 1
            else:
                node += 1 if hit else int(-index[node])
        return np.asarray(found, np.int64)


def unpack_bounds(bounds: np.ndarray) -> np.ndarray:
    """(n, 3) packed uint32 bounds to (n, 6) ints: lower xyz, upper xyz."""
    b = np.asarray(bounds, np.uint32).astype(np.int64)
    return np.stack(
        [
            b[:, 0] & 0xFFFF,
            b[:, 0] >> 16,
            b[:, 1] & 0xFFFF,
            b[:, 1] >> 16,
            b[:, 2] & 0xFFFF,
            b[:, 2] >> 16,
        ],
        axis=1,
    )


def pack_bounds(q: np.ndarray) -> np.ndarray:
    """(n, 6) quantized lower xyz, upper xyz to the (n, 3) packed uint32 bounds."""
    q = np.asarray(q, np.uint32)
    return np.stack(
        [q[:, 0] | q[:, 1] << 16, q[:, 2] | q[:, 3] << 16, q[:, 4] | q[:, 5] << 16], axis=1
    ).astype(np.uint32)


def quantize_query(bvh: Bvh, lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """A box in quantized coordinates, rounded outwards by one quantum and clamped (as the
    device does it)."""
    scale = QUANTA / (bvh.upper.astype(np.float64) - bvh.lower)
    lo = np.floor((np.asarray(lower, np.float64) - bvh.lower) * scale) - 1
    hi = np.ceil((np.asarray(upper, np.float64) - bvh.lower) * scale) + 1
    return np.clip(lo, 0, QUANTA), np.clip(hi, 0, QUANTA)


def morton_codes(points: np.ndarray, lower: np.ndarray, extent: float) -> np.ndarray:
    """63-bit Morton codes of points on a cubic grid of 2^21 cells per side over the cube
    at ``lower`` with side ``extent``."""
    cells = (1 << MORTON_BITS) - 1
    grid = np.clip((points - lower) * (cells / extent), 0, cells).astype(np.uint64)
    code = np.zeros(len(points), np.uint64)
    for axis in range(3):
        x = grid[:, axis]
        # spread 21 bits to every third bit
        x = (x | x << np.uint64(32)) & np.uint64(0x1F00000000FFFF)
        x = (x | x << np.uint64(16)) & np.uint64(0x1F0000FF0000FF)
        x = (x | x << np.uint64(8)) & np.uint64(0x100F00F00F00F00F)
        x = (x | x << np.uint64(4)) & np.uint64(0x10C30C30C30C30C3)
        x = (x | x << np.uint64(2)) & np.uint64(0x1249249249249249)
        code |= x << np.uint64(2 - axis)
    return code


def _highest_bit(x: np.ndarray) -> np.ndarray:
    """Index of the highest set bit of positive uint64 values."""
    bits = np.zeros(len(x), np.int64)
    x = x.copy()
    for shift in (32, 16, 8, 4, 2, 1):
        big = x >= (np.uint64(1) << np.uint64(shift))
        bits[big] += shift
        x[big] >>= np.uint64(shift)
    return bits


def build(lower: np.ndarray, upper: np.ndarray, what: str = "BVH") -> Bvh:
    """The BVH of primitives with boxes [lower[i], upper[i]] ((n, 3) arrays, n >= 1)."""
    lower = np.asarray(lower, np.float64)
    upper = np.asarray(upper, np.float64)
    n = len(lower)
    if n == 0:
        raise RbgenError(f"{what}: no primitives to build a BVH over")
    if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper))):
        raise RbgenError(f"{what}: a primitive box is not finite")
    box_lower, box_upper = lower.min(axis=0), upper.max(axis=0)
    # the quantization box: the boxes' hull with two quanta of slack on each side (see
    # quantize), no thinner on any axis than a millionth of its largest side nor than
    # 4 * QUANTA float32 steps at its coordinates (so that a quantum is at least four
    # float32 steps there, and rounding never moves a box by one), corners in float32
    extent = box_upper - box_lower
    step = float(np.spacing(np.float32(max(np.abs(box_lower).max(), np.abs(box_upper).max(), 1.0))))
    floor = max(float(extent.max()) * 1e-6, 1e-6, 4.0 * QUANTA * step)
    extent = np.maximum(extent, floor)
    quantum = extent / (QUANTA - 4)
    q_lower = (box_lower - 2 * quantum).astype(np.float32)
    q_lower = np.where(
        q_lower > box_lower - quantum, np.nextafter(q_lower, np.float32(-np.inf)), q_lower
    ).astype(np.float64)
    q_upper = (q_lower + QUANTA * quantum).astype(np.float32)
    q_upper = np.where(
        q_upper < box_upper + quantum, np.nextafter(q_upper, np.float32(np.inf)), q_upper
    ).astype(np.float64)

    # leaves in Morton order of their centres (ties: input order, so the build is deterministic)
    codes = morton_codes(0.5 * (lower + upper), box_lower, float(extent.max()))
    order = np.argsort(codes, kind="stable")
    codes = codes[order]

    # the tree, one level at a time: the ranges [lo, hi) of the level's nodes, their indices
    index = np.zeros(2 * n - 1, np.int64)
    leaves, levels = [], []  # (node, leaf) of every leaf; (parents, left, right) per level
    lo, hi, at = np.array([0]), np.array([n]), np.array([0])
    while len(lo):
        leaf = hi - lo == 1
        leaves.append((at[leaf], lo[leaf]))
        lo, hi, at = lo[~leaf], hi[~leaf], at[~leaf]
        if not len(lo):
            break
        index[at] = -(2 * (hi - lo) - 1)
        first, last = codes[lo], codes[hi - 1]
        differ = np.flatnonzero(first != last)
        split = (lo + hi) // 2
        if len(differ):
            bit = _highest_bit(first[differ] ^ last[differ]).astype(np.uint64)
            prefix = (last[differ] >> bit) << bit  # the first code with that bit set
            split[differ] = np.searchsorted(codes, prefix, side="left")
        left, right = at + 1, at + 2 * (split - lo)
        levels.append((at, left, right))
        lo, hi, at = (
            np.concatenate([lo, split]),
            np.concatenate([split, hi]),
            np.concatenate([left, right]),
        )
    leaf_nodes = np.concatenate([a for a, _ in leaves])
    leaf_ranks = np.concatenate([r for _, r in leaves])
    index[leaf_nodes] = leaf_ranks

    # quantized boxes: the leaves' rounded outwards by a quantum, then bottom-up unions
    # (exact on integers, so a parent's box holds its children's)
    bvh_quantum = (q_upper - q_lower) / QUANTA
    q_leaf = np.concatenate(
        [
            np.floor((lower[order] - q_lower) / bvh_quantum) - 1,
            np.ceil((upper[order] - q_lower) / bvh_quantum) + 1,
        ],
        axis=1,
    )
    q = np.empty((2 * n - 1, 6), np.int32)
    q[leaf_nodes] = np.clip(q_leaf, 0, QUANTA).astype(np.int32)[leaf_ranks]
    for parents, left, right in reversed(levels):
        q[parents, :3] = np.minimum(q[left, :3], q[right, :3])
        q[parents, 3:] = np.maximum(q[left, 3:], q[right, 3:])
    nodes = layouts.BVH_NODE.zeros(2 * n - 1)
    nodes["bounds"] = pack_bounds(q)
    nodes["index"] = index
    return Bvh(
        nodes=nodes,
        order=order.astype(np.int64),
        lower=q_lower.astype(np.float32),
        upper=q_upper.astype(np.float32),
    )
