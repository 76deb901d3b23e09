"""What the renderer and the recorders need of a World: its bodies' shapes once,
their transforms per frame.

`Bodies` is read from a World once (shapes, each body's shape, which bodies
are static, colours) because that changes only when bodies are added;
`Frame` is one read of the transforms. `bodies_of` is the one place that
reads the World's body table, so a change in the World's storage touches one
function here.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..errors import RbgenError
from ..shapes import Plane, Shape
from .meshes import local_bounds

#: colours of dynamic bodies (linear RGB): muted hues that stay apart under shadow
PALETTE = np.array(
    [
        (0.80, 0.36, 0.24),
        (0.90, 0.62, 0.20),
        (0.36, 0.58, 0.80),
        (0.45, 0.70, 0.40),
        (0.70, 0.45, 0.70),
        (0.85, 0.80, 0.45),
        (0.35, 0.70, 0.70),
        (0.78, 0.52, 0.42),
    ],
    np.float32,
)
#: colour of static bodies (shaded with a checker of 1 m squares)
STATIC_COLOUR = (0.62, 0.63, 0.62)


@dataclasses.dataclass(frozen=True)
class Bodies:
    """The bodies of a scene without their motion.

    ``shapes``: the distinct shapes; ``shape_index`` (N,) int: each body's entry in
    ``shapes``; ``static`` (N,) bool; ``colours`` (N, 3) float32 linear RGB.
    """

    shapes: tuple
    shape_index: np.ndarray
    static: np.ndarray
    colours: np.ndarray

    @property
    def count(self) -> int:
        return len(self.shape_index)

    @classmethod
    def make(cls, shapes, shape_index, static=None, colours=None) -> Bodies:
        """Validated `Bodies`; colours default to `default_colours`."""
        shapes = tuple(shapes)
        for k, shape in enumerate(shapes):
            if not isinstance(shape, Shape):
                raise RbgenError(f"shapes[{k}] must be an rbgen shape, got {type(shape).__name__}")
        index = np.asarray(shape_index, dtype=np.int64).reshape(-1)
        if len(index) and (index.min() < 0 or index.max() >= len(shapes)):
            raise RbgenError(
                f"shape_index must lie in [0, {len(shapes)}), got values "
                f"{index.min()}..{index.max()}"
            )
        static = (
            np.zeros(len(index), bool) if static is None else np.asarray(static, bool).reshape(-1)
        )
        if static.shape != index.shape:
            raise RbgenError(
                f"static must have one flag per body ({len(index)}), got shape {static.shape}"
            )
        colours = default_colours(static) if colours is None else np.asarray(colours, np.float32)
        if colours.shape != (len(index), 3):
            raise RbgenError(f"colours must have shape ({len(index)}, 3), got {colours.shape}")
        return cls(shapes, index, static, np.ascontiguousarray(colours, np.float32))


def default_colours(static) -> np.ndarray:
    """Palette colours by body index (neighbours in a lattice differ), grey for static."""
    static = np.asarray(static, bool)
    # a mixing hash of the index (murmur3's finaliser), so that rows, layers and
    # diagonals of a lattice show no colour pattern
    h = np.arange(len(static), dtype=np.uint64)
    mask = np.uint64(0xFFFFFFFF)
    h = (h ^ (h >> np.uint64(16))) * np.uint64(0x85EBCA6B) & mask
    h = (h ^ (h >> np.uint64(13))) * np.uint64(0xC2B2AE35) & mask
    h ^= h >> np.uint64(16)
    picks = (h % np.uint64(len(PALETTE))).astype(np.int64)
    colours = PALETTE[picks].copy()
    colours[static] = STATIC_COLOUR
    return colours


@dataclasses.dataclass(frozen=True)
class Frame:
    """One instant: ``positions`` (N, 3) and ``orientations`` (N, 4, x y z w), float32."""

    positions: np.ndarray
    orientations: np.ndarray

    @classmethod
    def make(cls, positions, orientations, count: int) -> Frame:
        p = np.ascontiguousarray(positions, np.float32)
        q = np.ascontiguousarray(orientations, np.float32)
        if p.shape != (count, 3):
            raise RbgenError(f"positions must have shape ({count}, 3), got {p.shape}")
        if q.shape != (count, 4):
            raise RbgenError(f"orientations must have shape ({count}, 4), got {q.shape}")
        return cls(p, q)


def bodies_of(world) -> Bodies:
    """The `Bodies` of a World (static bodies: those of zero inverse mass)."""
    # the World's host mirror of its body records (its BodyStore's; the one place here
    # that knows where the World keeps it)
    store: Any = getattr(world, "_bodies", None)
    table = store.host if hasattr(store, "host") else world._host
    return Bodies.make(world.shapes.shapes, table["shape"], table["inv_mass"] == 0)


def frame_of(world) -> Frame:
    """One read of a World's transforms (positions first: it syncs the host mirror once)."""
    positions = world.positions
    return Frame.make(positions, world.orientations, len(positions))


def scene_bounds(
    bodies: Bodies, frame: Frame, dynamic_only: bool = False
) -> tuple[np.ndarray, np.ndarray] | None:
    """(lower, upper) of every bounded body (planes left out), rotated boxes bounded by
    their local bounds' corners; None when no body is bounded."""
    lows, highs = [], []
    for k, shape in enumerate(bodies.shapes):
        mask = bodies.shape_index == k
        if dynamic_only:
            mask &= ~bodies.static
        if not mask.any() or isinstance(shape, Plane):
            continue
        bounds = local_bounds(shape)
        assert bounds is not None  # None for planes only, left out above
        lo, hi = bounds
        corners = np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        )
        radius = float(np.linalg.norm(corners, axis=1).max())
        p = frame.positions[mask].astype(float)
        if len(p) > 64:  # many bodies: a sphere about each is bound enough
            lows.append(p.min(axis=0) - radius)
            highs.append(p.max(axis=0) + radius)
            continue
        world = rotate(frame.orientations[mask].astype(float)[:, None, :], corners[None])
        world = world + p[:, None, :]
        lows.append(world.reshape(-1, 3).min(axis=0))
        highs.append(world.reshape(-1, 3).max(axis=0))
    if not lows:
        return None
    return np.min(lows, axis=0), np.max(highs, axis=0)


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4; x, y, z, w)."""
    xyz, w = q[..., :3], q[..., 3:4]
    t = 2.0 * np.cross(xyz, v)
    return v + w * t + np.cross(xyz, t)
