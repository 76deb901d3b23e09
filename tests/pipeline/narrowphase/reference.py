"""Float64 numpy references for the narrowphase tests (written for the tests).

`sat` is a brute-force separating-axis test between two convex polyhedra
given by world vertices, world outward face normals and world edge
directions: every face normal (oriented from A to B) and every cross product
of edge directions (both orientations) is a candidate; the separation along
an axis L (from A to B) is min(B . L) - max(A . L). The largest separation is
the signed distance for separated shapes and minus the penetration depth for
overlapping ones.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rbgen import layouts


def quat_matrix(q) -> np.ndarray:
    x, y, z, w = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def random_quaternions(rng, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def axis_angle(axis, angle) -> np.ndarray:
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    return np.array([*(axis * np.sin(angle / 2)), np.cos(angle / 2)])


def make_bodies(shape_ids, positions, orientations=None, inv_mass=1.0) -> np.ndarray:
    n = len(shape_ids)
    bodies = layouts.BODY.zeros(n)
    bodies["shape"] = shape_ids
    bodies["position"][:, :3] = np.asarray(positions, np.float64).reshape(n, 3)
    if orientations is None:
        bodies["orientation"][:, 3] = 1.0
    else:
        bodies["orientation"] = np.asarray(orientations, np.float64).reshape(n, 4)
    bodies["inv_mass"] = inv_mass
    bodies["friction"] = 0.5
    return bodies


def pair_records(pairs, sub=0) -> np.ndarray:
    """`Pair` records of (a, b) body index pairs, all with sub-feature ``sub``."""
    idx = np.asarray(pairs, np.int64).reshape(-1, 2)
    records = layouts.PAIR.zeros(len(idx))
    records["a"], records["b"], records["sub"] = idx[:, 0], idx[:, 1], sub
    return records


@dataclasses.dataclass
class Placed:
    """A cooked convex shape in world placement (float64)."""

    vertices: np.ndarray
    normals: np.ndarray
    edges: np.ndarray

    @classmethod
    def of(cls, shape, position, orientation) -> Placed:
        c = shape.cooked()
        r = quat_matrix(orientation)
        return cls(
            c.vertices @ r.T + np.asarray(position, np.float64),
            c.planes[:, :3] @ r.T,
            c.edge_directions @ r.T,
        )


@dataclasses.dataclass
class SatAnswer:
    separation: float  # max over all axes
    axis: np.ndarray  # its axis, from A to B
    best_face: float  # best over face axes
    best_edge: float  # best over edge axes (-inf when none)
    runner_up: float  # best separation along an axis not parallel to `axis`
    #: an edge axis within float32 rounding of the face-aligned rule's angle or depth limit
    aligned_undecided: bool = False


def _separation(a: Placed, b: Placed, axis: np.ndarray) -> float:
    """Separation of b from a along +-axis (the larger: the line's gap)."""
    pa, pb = a.vertices @ axis, b.vertices @ axis
    return float(max(pb.min() - pa.max(), pa.min() - pb.max()))


def sat(
    a: Placed,
    b: Placed,
    face_aligned_deg: float | None = None,
    face_aligned_tolerance: float = 0.0,
) -> SatAnswer:
    """The separating-axis answer of two convex shapes in float64. ``face_aligned_deg``:
    an edge-pair axis within this angle of a face normal of either shape is no axis when
    that face (the shallower, where a face of each shape is within the angle) is at most
    ``face_aligned_tolerance`` deeper than it, unless the edge axis
    separates and the face does not (the box-box kernel's rule: the face axis measures
    that direction, and its manifold does not flicker)."""
    axes, is_edge = [], []
    normals = np.vstack([a.normals, b.normals])
    cos_limit = None if face_aligned_deg is None else np.cos(np.radians(face_aligned_deg))
    undecided = False
    for n in a.normals:
        axes.append(n), is_edge.append(False)
    for n in b.normals:
        axes.append(-n), is_edge.append(False)
    for ea in a.edges:
        for eb in b.edges:
            cross = np.cross(ea, eb)
            s = np.linalg.norm(cross)
            if s < 1e-4:
                continue
            if cos_limit is not None:
                cosines = np.abs(normals @ (cross / s))
                if np.any(np.abs(cosines - cos_limit) < 1e-6):
                    undecided = True
                aligned = np.flatnonzero(cosines > cos_limit)
                if aligned.size:
                    gap = _separation(a, b, cross / s)
                    # the shallower of the aligned faces (one of each box at most)
                    face = max(_separation(a, b, normals[k]) for k in aligned)
                    deeper = face - (gap - face_aligned_tolerance)
                    if abs(deeper) < 1e-5 or (gap > 0 and abs(face) < 1e-5):
                        undecided = True
                    if deeper >= 0 and (gap <= 0 or face > 0):
                        continue
            axes.append(cross / s), is_edge.append(True)
            axes.append(-cross / s), is_edge.append(True)
    axes = np.array(axes)
    is_edge = np.array(is_edge)
    separations = (b.vertices @ axes.T).min(axis=0) - (a.vertices @ axes.T).max(axis=0)
    best = int(np.argmax(separations))
    axis = axes[best]
    others = np.abs(axes @ axis) < 1 - 1e-6
    return SatAnswer(
        float(separations[best]),
        axis,
        float(separations[~is_edge].max()),
        float(separations[is_edge].max()) if is_edge.any() else -np.inf,
        float(separations[others].max()) if others.any() else -np.inf,
        undecided,
    )
