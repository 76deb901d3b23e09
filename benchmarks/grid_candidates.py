"""Candidates per body of the owner-emission grid, one level against two, counted on the host.

    python benchmarks/grid_candidates.py [--scene ragdolls] [--n 300] [--steps 60]
                                         [--fine-factors 4 2 1.5] [--device D]

Steps a scene (`rbgen.harness`) ``--steps`` times, reads its world AABBs and counts,
with numpy, what the owner query of grid_owner.cl.mako walks for every grid body: the
list heads it reads (cells visited) and the list entries it walks (candidates, itself
and bodies of lower index included), bucket folding as on the device
(``grid_dim_for``); environment 0 only (a World). Each fine factor is one row
(levels by `reference.grid_levels`); ``fine_factor = large_factor`` (4) is the
one-level grid; the first row is the one-level grid with the 27 cells around the
owner's own visited (the query before two levels), the last the default fine factor
with a bucket per cell (no folding: the candidates that folding far cells onto the
visited buckets adds). Also printed: the overlapping
pairs per grid body (what the candidates are for), and the mean candidates over fine
and over coarse bodies apart.
"""

from __future__ import annotations

import argparse

import numpy as np

#: the 27 neighbour offsets in the order of neighbour_offset (cells.cl.mako)
OFFSETS = np.array([(m % 3 - 1, m // 3 % 3 - 1, m // 9 - 1) for m in range(27)], np.int64)


def scene_aabbs_after(scene: str, n: int, steps: int, device=None):
    """(Aabb array, collision words) of ``scene`` with ``n`` after ``steps`` steps."""
    from rbgen.harness import build_scene

    world, _, _, _ = build_scene(scene, n, device)
    for _ in range(steps):
        world.step(1 / 60)
    count = world.body_count
    aabbs = world.runtime.read(world._pipeline.prepare.aabbs)[:count]
    words = world.runtime.read(world._device.static)[:count]
    return aabbs, words


def cell_size(sizes: np.ndarray) -> float:
    """grid_cell_size of the largest size (0 for none)."""
    return float(np.float32(1.01) * np.float32(sizes.max())) if len(sizes) else 0.0


def cells(points: np.ndarray, side: float) -> np.ndarray:
    return np.floor(points.astype(np.float32) / np.float32(side)).astype(np.int64)


def bucket(cell: np.ndarray, dim: int) -> np.ndarray:
    folded = cell % dim
    return (folded[..., 2] * dim + folded[..., 1]) * dim + folded[..., 0]


def count_owner_visits(
    aabbs,
    words,
    fine_factor: float,
    large_factor: float = 4.0,
    all_27: bool = False,
    folded: bool = True,
) -> dict:
    """Cells visited and candidates walked per grid body of the owner query, as means
    (``all_27``: every owner walks the 27 cells around its own, the rule before
    cells_to_visit; ``folded=False``: a bucket per cell, what folding adds)."""
    from rbgen.pipeline.broadphase.grid import grid_dim_for
    from rbgen.pipeline.broadphase.reference import COARSE, FINE, grid_levels

    lower = aabbs["lower"][:, :3].astype(np.float32)
    upper = aabbs["upper"][:, :3].astype(np.float32)
    size = np.max(upper - lower, axis=1)
    levels = grid_levels(aabbs, words, fine_factor, large_factor)
    fine, coarse = np.flatnonzero(levels == FINE), np.flatnonzero(levels == COARSE)
    dim = grid_dim_for(len(lower))
    fine_side, coarse_side = cell_size(size[fine]), cell_size(size[coarse])

    def key(cell):
        if folded:
            return bucket(cell, dim)
        cell = cell + (1 << 20)  # (21 bits an axis: one key per cell)
        return (cell[..., 2] << 42) | (cell[..., 1] << 21) | cell[..., 0]

    def table(bodies, side):
        """Bodies filed per key: (sorted keys, counts)."""
        return np.unique(key(cells(lower[bodies], side)), return_counts=True)

    def walk(owners, lists, side):
        """(heads read, entries walked) per owner: the cells from one below the lower
        corner's to the upper corner's on each axis (cells_to_visit)."""
        low = cells(lower[owners], side)
        span = np.clip(cells(upper[owners], side) - low, 0, 1)
        visited = np.all(OFFSETS[None] <= span[:, None, :], axis=2) | all_27
        around = key(low[:, None, :] + OFFSETS[None])
        keys, counts = lists
        at = np.clip(np.searchsorted(keys, around), 0, len(keys) - 1)
        entries = np.where(keys[at] == around, counts[at], 0)
        return visited.sum(axis=1), (entries * visited).sum(axis=1)

    heads = np.zeros(len(lower), np.int64)
    walked = np.zeros(len(lower), np.int64)
    visits = [(fine, fine, fine_side)]  # (owners, bodies filed, cell side) of each walk
    if len(coarse):
        visits += [(fine, coarse, coarse_side), (coarse, coarse, coarse_side)]
        visits += [(coarse, fine, coarse_side)]
    for owners, filed, side in visits:
        if len(owners) and len(filed):
            read, entries = walk(owners, table(filed, side), side)
            heads[owners] += read
            walked[owners] += entries
    grid = np.concatenate([fine, coarse])
    return {
        "fine": len(fine),
        "coarse": len(coarse),
        "large": int((levels == 2).sum()),
        "fine_cell": fine_side,
        "coarse_cell": coarse_side,
        "heads": heads[grid].mean(),
        "candidates": walked[grid].mean(),
        "fine_candidates": walked[fine].mean() if len(fine) else 0.0,
        "coarse_candidates": walked[coarse].mean() if len(coarse) else 0.0,
    }


def grid_pairs_per_body(aabbs, words) -> float:
    """Overlapping pairs with a grid body (either side), per grid body (environment 0)."""
    from rbgen.pipeline.broadphase.reference import LARGE, grid_levels, grid_pairs

    pairs = grid_pairs(aabbs, words & 1)
    small = grid_levels(aabbs, words) != LARGE
    both = small[pairs[:, 0]] & small[pairs[:, 1]]
    return 2 * int(both.sum()) / max(1, int(small.sum()))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="ragdolls")
    parser.add_argument("--n", type=int, default=300)
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--fine-factors", type=float, nargs="+", default=[4.0, 2.0, 1.5])
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)

    aabbs, words = scene_aabbs_after(args.scene, args.n, args.steps, args.device)
    print(
        f"{args.scene} {args.n} after {args.steps} steps: {len(aabbs)} bodies, "
        f"{grid_pairs_per_body(aabbs, words):.2f} overlapping pairs with another grid body "
        f"per grid body"
    )
    print(
        f"{'fine factor':>11} {'fine':>7} {'coarse':>6} {'large':>5} {'fine cell':>9} "
        f"{'coarse cell':>11} {'heads':>6} {'candidates':>10} {'(fine':>7} {'coarse)':>8}"
    )
    rows = [("1 level, 27", 4.0, True, True)]
    rows += [(f"{f:g}", f, False, True) for f in args.fine_factors]
    rows += [("2, unfolded", 2.0, False, False)]
    for label, factor, all_27, folded in rows:
        row = count_owner_visits(aabbs, words, factor, all_27=all_27, folded=folded)
        print(
            f"{label:>11} {row['fine']:>7} {row['coarse']:>6} {row['large']:>5} "
            f"{row['fine_cell']:>9.3f} {row['coarse_cell']:>11.3f} {row['heads']:>6.1f} "
            f"{row['candidates']:>10.1f} {row['fine_candidates']:>7.1f} "
            f"{row['coarse_candidates']:>8.1f}"
        )


if __name__ == "__main__":
    main()
