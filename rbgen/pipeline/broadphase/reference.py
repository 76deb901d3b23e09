"""Host (numpy) references for the broadphase: what the device must reproduce.

Both functions apply the same rules as every device broadphase (see the
package docstring): closed boxes (sharing a face, edge or corner counts as
overlap), pairs (a, b) with a < b, never two static bodies, sorted by (a, b).

`brute_force_pairs` tests every pair (O(n^2), blockwise): the ground truth in
tests. `grid_pairs` is a vectorised uniform grid for large scenes (benchmark
sanity counts at 100k bodies), exact because cells are keyed without hashing.
`grid_levels` is the owner-emission grid's split into fine, coarse and large
bodies (grid_owner.cl.mako), for tests and candidate counts.
Neither imports scipy (the benchmark machine has none).
"""

from __future__ import annotations

import numpy as np

from ...errors import RbgenError


def split_aabbs(aabbs) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) as (n, 3) float64 from an `Aabb` array or a (lower, upper) tuple."""
    if isinstance(aabbs, tuple):
        lower, upper = aabbs
    else:
        lower, upper = aabbs["lower"][:, :3], aabbs["upper"][:, :3]
    lower = np.asarray(lower, np.float64).reshape(-1, 3)
    upper = np.asarray(upper, np.float64).reshape(-1, 3)
    if lower.shape != upper.shape:
        raise RbgenError(f"lower {lower.shape} and upper {upper.shape} bounds differ in shape")
    return lower, upper


def _static_flags(static, n: int) -> np.ndarray:
    if static is None:
        return np.zeros(n, bool)
    static = np.asarray(static).reshape(-1) != 0
    if len(static) != n:
        raise RbgenError(f"static flags have {len(static)} entries for {n} bodies")
    return static


def _finish(a: np.ndarray, b: np.ndarray, static: np.ndarray) -> np.ndarray:
    keep = ~(static[a] & static[b])
    pairs = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)[keep].astype(np.uint32)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order]


def brute_force_pairs(aabbs, static=None, block: int = 2048) -> np.ndarray:
    """Every overlapping pair by testing all n (n - 1) / 2 candidates; (m, 2) uint32."""
    lower, upper = split_aabbs(aabbs)
    n = len(lower)
    static = _static_flags(static, n)
    found_a, found_b = [], []
    for start in range(0, n, block):
        stop = min(n, start + block)
        overlap = np.all(
            (lower[start:stop, None, :] <= upper[None, :, :])
            & (lower[None, :, :] <= upper[start:stop, None, :]),
            axis=2,
        )
        a, b = np.nonzero(overlap)
        a += start
        keep = a < b
        found_a.append(a[keep])
        found_b.append(b[keep])
    if not found_a:
        return np.zeros((0, 2), np.uint32)
    return _finish(np.concatenate(found_a), np.concatenate(found_b), static)


def grid_pairs(aabbs, static=None, large_factor: float = 4.0) -> np.ndarray:
    """Every overlapping pair with an exact host grid (min-corner cells).

    Boxes more than ``large_factor`` times the median size are tested against
    everything directly; the others sit in the cell of their lower corner, of
    side the largest of their extents, so overlapping boxes lie in the same or
    adjacent cells.
    """
    lower, upper = split_aabbs(aabbs)
    n = len(lower)
    static = _static_flags(static, n)
    if n < 2:
        return np.zeros((0, 2), np.uint32)
    extent = np.max(upper - lower, axis=1)
    large = ~(extent <= large_factor * np.median(extent))
    small = np.nonzero(~large)[0]
    found_a, found_b = [], []
    for index in np.nonzero(large)[0]:
        hit = np.nonzero(np.all((lower[index] <= upper) & (lower <= upper[index]), axis=1))[0]
        hit = hit[~large[hit] | (hit > index)]  # a large pair is found once, from its lower index
        found_a.append(np.full(len(hit), index))
        found_b.append(hit)
    if len(small):
        cell_size = 1.001 * float(np.max(extent[small])) or 1.0  # slack for rounding
        cells = np.floor(lower[small] / cell_size).astype(np.int64)
        cells -= cells.min(axis=0) - 1
        dims = cells.max(axis=0) + 2
        keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
        order = np.argsort(keys, kind="stable")
        sorted_keys, sorted_bodies = keys[order], small[order]
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    neighbour = keys + (dx * dims[1] + dy) * dims[2] + dz
                    first = np.searchsorted(sorted_keys, neighbour, "left")
                    last = np.searchsorted(sorted_keys, neighbour, "right")
                    count = last - first
                    a = np.repeat(small, count)
                    offsets = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
                    b = sorted_bodies[np.repeat(first, count) + offsets]
                    keep = a < b
                    a, b = a[keep], b[keep]
                    hit = np.all((lower[a] <= upper[b]) & (lower[b] <= upper[a]), axis=1)
                    found_a.append(a[hit])
                    found_b.append(b[hit])
    if not found_a:
        return np.zeros((0, 2), np.uint32)
    return _finish(np.concatenate(found_a), np.concatenate(found_b), static)


#: `grid_levels` codes, as body_levels in grid_owner.cl.mako
FINE, COARSE, LARGE = 0, 1, 2


def grid_levels(
    aabbs, words=None, fine_factor: float = 2.0, large_factor: float = 4.0
) -> np.ndarray:
    """Each body's level in the owner-emission grid (FINE, COARSE or LARGE), by the
    kernel's rule in float32: size (largest side) x 1.01 within ``fine_factor`` times the
    geometric mean size is fine, within ``large_factor`` times it coarse, else large;
    shared static geometry (collision word 0xFFFFFFFF) is large. The device sums the
    log sizes in another order, so a body within rounding of a threshold may differ."""
    lower, upper = split_aabbs(aabbs)
    size = np.max(upper.astype(np.float32) - lower.astype(np.float32), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_size = np.where(np.isfinite(size), np.log2(np.maximum(size, 1e-30)), 40.0)
    mean = np.float32(np.clip(log_size, -40.0, 40.0).mean()) if len(size) else np.float32(0)
    geometric = np.float32(np.exp2(mean))
    slack = np.float32(1.01)
    with np.errstate(invalid="ignore"):
        fine = size * slack <= np.float32(fine_factor) * geometric
        small = size * slack <= np.float32(large_factor) * geometric
    if words is not None:
        shared = np.asarray(words).reshape(-1) == 0xFFFFFFFF
        fine &= ~shared
        small &= ~shared
    return np.where(fine & small, FINE, np.where(small, COARSE, LARGE)).astype(np.uint32)
