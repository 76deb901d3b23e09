"""Standard scenes as plain numpy data: BoxBox, the dropped pile, the pyramid.

Examples, tests, benchmarks and the World all build the same scenes from here,
so a number measured in one place means the same scene everywhere.

BoxBox is Bullet3's GpuConvexScene: an ``nx * ny * nz`` lattice of unit-mass
cubes (half extent 1) on a static ground whose top face is the plane y = 0.
Layer j sits at y = 1 + 2j, so stacked cubes touch face to face, and every
second layer is shifted by 1 along x and z, so each cube rests on four cubes
of the layer below (the x and z pitch is 2.2, leaving gaps of 0.2 inside a
layer).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from . import layouts
from .errors import RbgenError

#: (nx, ny, nz) of the BoxBox sizes quoted by Bullet3 and our benchmarks.
STANDARD_BOXBOX_DIMS = {
    1_000: (10, 10, 10),
    8_000: (20, 20, 20),
    27_000: (30, 30, 30),
    111_375: (45, 55, 45),
    # (issue 24's largest: a wide lattice 25 boxes tall)
    1_000_000: (200, 25, 200),
}

#: Half thickness of the ground slab (its top face is y = 0).
GROUND_HALF_THICKNESS = 1.0
#: Horizontal margin of the ground slab beyond the lattice, on every side.
GROUND_MARGIN = 50.0


@dataclasses.dataclass(frozen=True)
class BoxScene:
    """Boxes of one size on a static ground slab, as numpy arrays.

    ``positions`` are box centres (N, 3) float32, all boxes share
    ``half_extents`` (3,) and ``mass``; orientations are the identity. The
    ground is a static box (``ground_position``, ``ground_half_extents``)
    whose top face is the plane ``ground_normal . x = ground_offset``.
    """

    positions: np.ndarray
    half_extents: np.ndarray
    mass: float
    ground_position: np.ndarray
    ground_half_extents: np.ndarray
    ground_normal: np.ndarray
    ground_offset: float
    dims: tuple[int, int, int]

    @property
    def count(self) -> int:
        """Number of dynamic boxes (the ground not included)."""
        return len(self.positions)


def boxbox_scene(nx: int, ny: int, nz: int) -> BoxScene:
    """The BoxBox lattice: box (i, j, k) at x = ((j+1) mod 2) + 2.2 i,
    y = 1 + 2 j, z = ((j+1) mod 2) + 2.2 k, half extent 1, mass 1."""
    for name, value in (("nx", nx), ("ny", ny), ("nz", nz)):
        if not isinstance(value, (int, np.integer)) or value < 0:
            raise RbgenError(f"boxbox_scene: {name} must be a non-negative integer, got {value!r}")
    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    shift = (j + 1) % 2
    positions = np.stack([shift + 2.2 * i, 1.0 + 2.0 * j, shift + 2.2 * k], axis=-1)
    positions = positions.reshape(-1, 3).astype(np.float32)
    # Ground slab: covers the lattice's x and z range [-1, 2.2 (n - 1) + 2] plus a
    # margin on every side; its top face is y = 0.
    reach = np.array([2.2 * max(nx - 1, 0) + 2.0, 0.0, 2.2 * max(nz - 1, 0) + 2.0])
    centre = np.array([(reach[0] - 1.0) / 2, -GROUND_HALF_THICKNESS, (reach[2] - 1.0) / 2])
    half = np.array(
        [
            (reach[0] + 1.0) / 2 + GROUND_MARGIN,
            GROUND_HALF_THICKNESS,
            (reach[2] + 1.0) / 2 + GROUND_MARGIN,
        ]
    )
    return BoxScene(
        positions=positions,
        half_extents=np.ones(3, np.float32),
        mass=1.0,
        ground_position=centre.astype(np.float32),
        ground_half_extents=half.astype(np.float32),
        ground_normal=np.array([0.0, 1.0, 0.0], np.float32),
        ground_offset=0.0,
        dims=(int(nx), int(ny), int(nz)),
    )


def standard_boxbox_dims(count: int) -> tuple[int, int, int]:
    """(nx, ny, nz) for a standard BoxBox size: 1000, 8000, 27000, 111375 or 1000000."""
    try:
        return STANDARD_BOXBOX_DIMS[int(count)]
    except (KeyError, ValueError, TypeError):
        raise RbgenError(
            f"no standard BoxBox size {count!r}; known sizes: {sorted(STANDARD_BOXBOX_DIMS)}"
        ) from None


def standard_boxbox_scene(count: int) -> BoxScene:
    """The BoxBox scene with one of the standard box counts."""
    return boxbox_scene(*standard_boxbox_dims(count))


def scene_aabbs(scene: BoxScene, ground: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """World AABBs of a scene as an `Aabb` array, and a uint32 static flag per body.

    With ``ground`` the ground slab is body 0 (static) and box n is body n + 1,
    the order in which Bullet3's scene creates them.
    """
    lower = scene.positions - scene.half_extents
    upper = scene.positions + scene.half_extents
    static = np.zeros(len(lower), np.uint32)
    if ground:
        lower = np.concatenate([[scene.ground_position - scene.ground_half_extents], lower])
        upper = np.concatenate([[scene.ground_position + scene.ground_half_extents], upper])
        static = np.concatenate([[1], static]).astype(np.uint32)
    aabbs = layouts.AABB.zeros(len(lower))
    aabbs["lower"][:, :3] = lower
    aabbs["upper"][:, :3] = upper
    return aabbs, static


def pile_positions(
    n: int, layers: int = 5, pitch: float = 1.5, jitter: float = 0.01, seed: int = 0
) -> np.ndarray:
    """Centres of ``n`` unit boxes dropped in a loose grid: ``layers`` layers (fewer for
    small n) at ``pitch`` from y = 1, the square side just large enough, jittered by up
    to ``jitter`` in every axis (``seed``); they land in columns of ``layers``."""
    layers = min(layers, int(n))
    side = int(np.ceil(np.sqrt(n / layers)))
    i, j, k = np.meshgrid(np.arange(side), np.arange(layers), np.arange(side), indexing="ij")
    positions = np.stack([pitch * i, 1.0 + pitch * j, pitch * k], -1).reshape(-1, 3)[:n]
    return positions + np.random.default_rng(seed).uniform(-jitter, jitter, positions.shape)


def pyramid_positions(rows: int, gap: float = 0.02) -> np.ndarray:
    """Centres of a 2-D pyramid of unit boxes with ``rows`` rows on the ground (y = 0),
    ``gap`` between neighbours of a row; the last box is the top."""
    return np.array(
        [
            [(i - (rows - r - 1) / 2) * (1 + gap), 0.5 + r, 0.0]
            for r in range(rows)
            for i in range(rows - r)
        ]
    ).reshape(-1, 3)


# --------------------------------------------------------------------------
# The terrain scene: a height field and a rain of bodies above it.

#: cells per side of the terrain scene's default height field: 2,000,000 triangles
TERRAIN_CELLS = 1000
#: its cell size (m)
TERRAIN_SPACING = 1.0


def terrain_heights(cells: int, spacing: float = TERRAIN_SPACING, seed: int = 0) -> np.ndarray:
    """(cells + 1, cells + 1) heights of a procedural terrain: rolling hills (four octaves of
    sines along random directions, 4 m from trough to crest at 80 m and halving with the
    wavelength) and 2 cm of noise; slopes stay under about 12 degrees, so that boxes rest."""
    if not isinstance(cells, (int, np.integer)) or cells < 1:
        raise RbgenError(f"terrain cells must be a positive integer, got {cells!r}")
    rng = np.random.default_rng(seed)
    x = np.arange(cells + 1) * float(spacing)
    gx, gz = np.meshgrid(x, x, indexing="ij")
    heights = np.zeros_like(gx)
    for octave in range(4):
        wavelength, amplitude = 80.0 / 2**octave, 1.0 / 2**octave
        for _ in range(2):
            angle, phase = rng.uniform(0, 2 * np.pi, 2)
            along = gx * np.cos(angle) + gz * np.sin(angle)
            heights += amplitude * np.sin(2 * np.pi * along / wavelength + phase)
    return heights + rng.uniform(-0.01, 0.01, heights.shape)


def height_field(heights: np.ndarray, spacing: float = TERRAIN_SPACING):
    """(vertices, triangles) of a height field: vertex (i, j) at (i, h[i, j], j) times the
    spacing, two triangles a cell, counter-clockwise seen from above."""
    heights = np.asarray(heights, np.float64)
    nx, nz = heights.shape
    gx, gz = np.meshgrid(np.arange(nx) * spacing, np.arange(nz) * spacing, indexing="ij")
    vertices = np.stack([gx.ravel(), heights.ravel(), gz.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(nz - 1), indexing="ij")
    v00 = (i * nz + j).ravel()
    triangles = np.concatenate(
        [np.stack([v00, v00 + 1, v00 + nz], 1), np.stack([v00 + nz, v00 + 1, v00 + nz + 1], 1)]
    )
    return vertices, triangles


def rain_positions(
    n: int,
    heights: np.ndarray,
    spacing: float = TERRAIN_SPACING,
    pitch: float = 1.6,
    layers: int = 4,
    clearance: float = 1.0,
    seed: int = 0,
) -> np.ndarray:
    """Centres of ``n`` bodies above the middle of a height field: a square grid of
    ``pitch`` in ``layers`` layers (fewer for small n), the lowest ``clearance`` above the
    highest ground under the grid, jittered by 10 cm."""
    layers = max(1, min(layers, int(n)))
    side = int(np.ceil(np.sqrt(n / layers)))
    extent = (heights.shape[0] - 1) * spacing
    start = 0.5 * (extent - pitch * (side - 1))
    i, j, k = np.meshgrid(np.arange(side), np.arange(layers), np.arange(side), indexing="ij")
    x, z = start + pitch * i.ravel(), start + pitch * k.ravel()
    cells = np.clip((np.stack([x, z], 1) / spacing).astype(int), 0, heights.shape[0] - 1)
    base = heights[cells[:, 0], cells[:, 1]].max() if len(cells) else 0.0
    y = base + clearance + pitch * j.ravel()
    rng = np.random.default_rng(seed)
    positions = np.stack([x, y, z], 1)[:n]
    return positions + rng.uniform(-0.1, 0.1, positions.shape)
