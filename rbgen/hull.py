"""Convex hull cooking: from points (or a trimesh) to what the narrowphase reads.

Cooking happens once on the host, so the device never builds topology:

* qhull's triangles are merged into planar polygons (triangles whose planes
  agree within `COPLANAR_TOLERANCE` of the hull size), each polygon ordered
  counter-clockwise seen from outside, with its plane ``n.x = d`` (n outward,
  unit);
* the unique edge directions (antiparallel edges merged) for the
  separating-axis test's edge-edge axes, and every edge with its two faces
  (the arcs of the Gauss map, which prune the edge pairs of hull-hull tests);
* the exact mass properties (trimesh volume integrals), after which the
  vertices are re-centred on the centre of mass and rotated into the principal
  frame of inertia (`rbgen.mass` explains the stored frame).

Limits (checked, with an error naming the shape): at most
`MAX_FACE_VERTICES` vertices on one face (the clipping stage keeps one face
in private memory), at most `MAX_HULL_VERTICES` vertices and
`MAX_HULL_FACES` faces (feature ids keep 11 bits per face). Cost note: the
hull-hull separating-axis test is O(F_A V_B + F_B V_A + E_A E_B) with the
Gauss-map pruning of edge pairs (a cheap test per pair), and only the
surviving pairs cost more; against spheres and planes any hull within the
limits is cheap.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .errors import RbgenError
from .mass import SolidIntegrals, mesh_integrals, principal_frame, quaternion_from_matrix

MAX_FACE_VERTICES = 32
MAX_HULL_VERTICES = 4096
MAX_HULL_FACES = 2048
#: qhull facets whose unit normals differ by less than this angle (radians),
#: and whose offsets by less than this times the hull size, form one polygon.
COPLANAR_TOLERANCE = 1e-6
#: edge directions closer than this to (anti)parallel count as one direction.
PARALLEL_TOLERANCE = 1e-6


@dataclasses.dataclass(frozen=True)
class CookedHull:
    """A convex polyhedron in its principal frame, ready to pack."""

    vertices: np.ndarray  # (V, 3) float64, centre of mass at the origin
    faces: tuple  # F arrays of vertex indices, counter-clockwise from outside
    planes: np.ndarray  # (F, 4): outward unit normal, offset d (n.x = d on the face)
    edge_directions: np.ndarray  # (E, 3) unit, one per direction up to sign
    edges: np.ndarray  # (E', 4) v0, v1, f0, f1: every edge with its two faces
    volume: float
    com: np.ndarray  # centre of mass in the input frame
    rotation: tuple  # quaternion (x, y, z, w): stored frame -> input frame
    unit_inertia: np.ndarray  # principal inertia per unit mass (3,)

    def triangles(self) -> np.ndarray:
        """Fan triangulation of the polygons (outward orientation)."""
        return _fan(self.faces)


def _fan(faces) -> np.ndarray:
    return np.array(
        [(f[0], f[k], f[k + 1]) for f in faces for k in range(1, len(f) - 1)], dtype=np.int64
    )


def cook(points, name: str = "ConvexHull") -> CookedHull:
    """Cook the convex hull of ``points`` (N x 3); ``name`` is used in error messages."""
    try:
        pts = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise RbgenError(
            f"{name}: points must be an (N, 3) array of finite numbers, got {points!r:.80}"
        ) from None
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise RbgenError(f"{name}: points must be an (N, 3) array, got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise RbgenError(f"{name}: points contain NaN or infinity")
    if len(pts) < 4:
        raise RbgenError(f"{name}: a hull needs at least 4 non-coplanar points, got {len(pts)}")
    size = float(np.max(np.ptp(pts, axis=0)))
    if size <= 0:
        raise RbgenError(f"{name}: all points coincide (zero extents)")
    centred = pts - pts.mean(axis=0)
    if np.linalg.matrix_rank(centred, tol=1e-9 * size) < 3:
        raise RbgenError(f"{name}: points are coplanar or collinear (zero volume)")
    vertices, faces, planes = _polygons(pts, size, name)
    integrals = mesh_integrals(vertices, _fan(faces), name)
    if integrals.volume < 1e-12 * size**3:
        raise RbgenError(f"{name}: hull volume {integrals.volume:g} is negligible for its size")
    return _to_principal_frame(vertices, faces, planes, integrals, name)


def _polygons(pts: np.ndarray, size: float, name: str):
    """Hull vertices and merged planar polygons with their planes."""
    from scipy.spatial import ConvexHull as QHull
    from scipy.spatial import QhullError

    try:
        qhull = QHull(pts)
    except QhullError as err:
        first = str(err).strip().splitlines()[0] if str(err).strip() else "qhull failed"
        raise RbgenError(f"{name}: degenerate point set ({first})") from None
    used = np.unique(qhull.simplices)
    if len(used) > MAX_HULL_VERTICES:
        raise RbgenError(
            f"{name}: hull has {len(used)} vertices, more than "
            f"MAX_HULL_VERTICES={MAX_HULL_VERTICES}"
        )
    remap = -np.ones(len(pts), np.int64)
    remap[used] = np.arange(len(used))
    vertices = pts[used]
    normals = qhull.equations[:, :3]
    offsets = -qhull.equations[:, 3]
    group_of = -np.ones(len(normals), np.int64)
    groups: list[list[int]] = []
    for i in range(len(normals)):
        if group_of[i] >= 0:
            continue
        same = (
            (normals @ normals[i] > 1 - 0.5 * COPLANAR_TOLERANCE**2)
            & (np.abs(offsets - offsets[i]) < COPLANAR_TOLERANCE * size)
            & (group_of < 0)
        )
        group_of[same] = len(groups)
        groups.append(list(np.nonzero(same)[0]))
    if len(groups) > MAX_HULL_FACES:
        raise RbgenError(
            f"{name}: hull has {len(groups)} faces, more than MAX_HULL_FACES={MAX_HULL_FACES}"
        )
    faces, planes = [], []
    for g in groups:
        n = normals[g].mean(axis=0)
        n /= np.linalg.norm(n)
        idx = np.unique(remap[qhull.simplices[g]].reshape(-1))
        polygon = _without_collinear(vertices, _counter_clockwise(vertices, idx, n), n, size)
        if len(polygon) > MAX_FACE_VERTICES:
            raise RbgenError(
                f"{name}: a face has {len(polygon)} vertices, more than "
                f"MAX_FACE_VERTICES={MAX_FACE_VERTICES}"
            )
        faces.append(polygon)
        # the plane touches the hull: no vertex lies above it (a face's separation is
        # exact when measured with the plane offset)
        planes.append((*n, float(np.max(vertices @ n))))
    # vertices left only on the straight sides of polygons are not corners: drop them
    corners = np.unique(np.concatenate(faces))
    compact = -np.ones(len(vertices), np.int64)
    compact[corners] = np.arange(len(corners))
    return vertices[corners], tuple(compact[f] for f in faces), np.array(planes, np.float64)


def _without_collinear(vertices, polygon, normal, size) -> np.ndarray:
    """The polygon without vertices on straight runs of its boundary."""
    polygon = list(polygon)
    changed = True
    while changed and len(polygon) > 3:
        changed = False
        for k in range(len(polygon)):
            prev, cur, nxt = (
                vertices[polygon[k - 1]],
                vertices[polygon[k]],
                vertices[polygon[(k + 1) % len(polygon)]],
            )
            if np.dot(np.cross(cur - prev, nxt - cur), normal) <= 1e-9 * size * size:
                del polygon[k]
                changed = True
                break
    return np.array(polygon, np.int64)


def edge_adjacency(faces, name: str) -> np.ndarray:
    """(E, 4) int64 rows v0, v1, f0, f1: each edge once, v0 -> v1 counter-clockwise around
    face f0 (seen from outside), f1 the face on its other side."""
    owner = {}
    for f, polygon in enumerate(faces):
        for a, b in zip(polygon, np.roll(polygon, -1)):
            owner[(int(a), int(b))] = f
    edges = []
    for (a, b), f in owner.items():
        g = owner.get((b, a))
        if g is None:
            raise RbgenError(f"{name}: the hull surface is not closed at edge ({a}, {b})")
        if a < b:
            edges.append((a, b, f, g))
    return np.array(edges, np.int64).reshape(-1, 4)


def _counter_clockwise(vertices: np.ndarray, idx: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Polygon vertex indices ordered counter-clockwise when seen from +normal."""
    p = vertices[idx]
    centre = p.mean(axis=0)
    u = p[0] - centre
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    angles = np.arctan2((p - centre) @ v, (p - centre) @ u)
    return idx[np.argsort(angles)]


def unique_edge_directions(vertices: np.ndarray, faces) -> np.ndarray:
    """One unit direction per family of (anti)parallel polygon edges."""
    starts = np.concatenate([f for f in faces])
    ends = np.concatenate([np.roll(f, -1) for f in faces])
    d = vertices[ends] - vertices[starts]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    kept = np.zeros((len(d), 3))
    count = 0
    for e in d:
        if count == 0 or np.max(np.abs(kept[:count] @ e)) <= 1 - PARALLEL_TOLERANCE:
            kept[count] = e
            count += 1
    return kept[:count].copy()


def _to_principal_frame(vertices, faces, planes, integrals: SolidIntegrals, name) -> CookedHull:
    moments, axes = principal_frame(integrals.inertia)
    if np.any(moments <= 0):
        raise RbgenError(f"{name}: inertia is not positive definite (degenerate hull)")
    # stored = axes^T (input - com); input = axes stored + com
    local = (vertices - integrals.centroid) @ axes
    normals = planes[:, :3] @ axes
    offsets = planes[:, 3] - planes[:, :3] @ integrals.centroid
    local_planes = np.column_stack([normals, offsets])
    return CookedHull(
        vertices=local,
        faces=faces,
        planes=local_planes,
        edge_directions=unique_edge_directions(local, faces),
        edges=edge_adjacency(faces, name),
        volume=integrals.volume,
        com=integrals.centroid.copy(),
        rotation=quaternion_from_matrix(axes),
        unit_inertia=moments / integrals.volume,
    )


def box_hull(half_extents) -> CookedHull:
    """A box as a cooked hull (already principal: no qhull, exact planes)."""
    h = np.asarray(half_extents, np.float64)
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    vertices = signs * h
    # index = 4 (x>0) + 2 (y>0) + (z>0); each face counter-clockwise seen from outside
    faces = (
        np.array([4, 6, 7, 5]),
        np.array([0, 1, 3, 2]),  # +x, -x
        np.array([2, 3, 7, 6]),
        np.array([0, 4, 5, 1]),  # +y, -y
        np.array([1, 5, 7, 3]),
        np.array([0, 2, 6, 4]),
    )  # +z, -z
    planes = np.array(
        [
            [1, 0, 0, h[0]],
            [-1, 0, 0, h[0]],
            [0, 1, 0, h[1]],
            [0, -1, 0, h[1]],
            [0, 0, 1, h[2]],
            [0, 0, -1, h[2]],
        ],
        np.float64,
    )
    a2, b2, c2 = h**2
    return CookedHull(
        vertices,
        faces,
        planes,
        np.eye(3),
        edge_adjacency(faces, "box"),
        float(8 * h.prod()),
        np.zeros(3),
        (0.0, 0.0, 0.0, 1.0),
        np.array([(b2 + c2) / 3, (a2 + c2) / 3, (a2 + b2) / 3]),
    )
