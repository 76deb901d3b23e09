"""Static triangle meshes: `TriangleMesh`, its checks, BVH and active edges; `load_mesh`.

A `TriangleMesh` is level geometry (terrain, buildings, rooms): static only, and
two-sided (a triangle collides from either side). Made once, it is shared by every
World that adds it. Construction checks the input (errors name the vertex or triangle),
drops zero-area triangles with one warning, builds the quantized BVH (`rbgen.bvh`: on
the host, once per mesh) and renumbers the triangles in its leaf order, so the midphase
emits them sorted; ``source_triangles[k]`` is the input index of triangle k.

Active edges: a contact whose closest feature on a triangle is an edge (or a vertex)
tilts its normal off the face. On an edge between two coplanar triangles, or in a
concave fold, that tilt is an artefact of cutting the surface into triangles (a box
sliding across a tessellated floor would bump on every seam), so such an edge is
*inactive* and the narrowphase gives its contacts the face normal. An edge is active
when it is open (one triangle), shared by more than two, or a convex fold sharper than
`ACTIVE_EDGE_DEGREES` (seen from the triangles' front, counter-clockwise, side; where
the two windings disagree, any fold that sharp). The flags are computed once, from the
edge adjacency, when the mesh is made.
"""

from __future__ import annotations

import hashlib
import math
import warnings

import numpy as np

from . import bvh as bvh_build
from . import layouts
from .errors import RbgenError
from .shapes import Shape, ShapeTable

#: a fold between two triangles flatter than this is an internal edge (no bump)
ACTIVE_EDGE_DEGREES = 5.0
#: a triangle whose height is below this fraction of its longest edge has zero area
#: (to float32 arithmetic: its normal would be noise)
DEGENERATE_HEIGHT = 1e-7

_STATIC_ONLY_HINT = (
    "; a TriangleMesh cannot move: for a dynamic body use a "
    "rbgen.ConvexHull (ConvexHull.from_trimesh(mesh): its convex hull) or a "
    "rbgen.Compound of hulls (a convex decomposition)"
)


class TriangleMesh(Shape):
    """A static, two-sided triangle mesh (see the module docstring).

    ``vertices``: (V, 3) finite numbers; ``triangles``: (T, 3) vertex indices. The mesh
    is in the frame of the body it is added as (``add_static(mesh, position, orientation)``).
    ``name`` appears in messages.
    """

    type_name = "mesh"
    label = "triangle mesh"
    type_code = layouts.SHAPE_MESH
    extents_doc = (
        "triangles face_* in MeshTriangle, BVH child_* in BvhNode, quantization "
        "box vertex_offset/2 in the hull vertices; static only"
    )
    aabb_template = "shapes/mesh.cl.mako"
    static_only = True
    static_only_hint = _STATIC_ONLY_HINT
    table_arrays = {
        "mesh_vertices": "float4 vertices of every mesh (mesh frame)",
        "mesh_triangles": "MeshTriangle records of every mesh, in BVH leaf order",
        "bvh_nodes": "BvhNode records of every mesh's BVH",
    }

    def __init__(self, vertices, triangles, name: str = "TriangleMesh"):
        self.name = str(name)
        vertices, triangles = _checked(vertices, triangles, self.name)
        keep = _non_degenerate(vertices, triangles)
        dropped = int(np.count_nonzero(~keep))
        if dropped == len(triangles):
            raise RbgenError(
                f"{self.name}: every triangle is degenerate (zero area); nothing to collide with"
            )
        if dropped:
            first = int(np.flatnonzero(~keep)[0])
            warnings.warn(
                f"{self.name}: dropped {dropped} degenerate (zero-area) triangle"
                f"{'s' if dropped > 1 else ''} of {len(triangles)} (the first: "
                f"triangle {first})",
                stacklevel=2,
            )
        source = np.flatnonzero(keep)
        if len(source) > layouts.MAX_MESH_TRIANGLES:
            raise RbgenError(
                f"{self.name}: {len(source)} triangles; at most "
                f"{layouts.MAX_MESH_TRIANGLES} per mesh (split it into meshes)"
            )
        kept = triangles[source]
        p0, p1, p2 = (vertices[kept[:, k]] for k in range(3))
        tree = bvh_build.build(
            np.minimum(np.minimum(p0, p1), p2), np.maximum(np.maximum(p0, p1), p2), self.name
        )
        del p0, p1, p2
        self.vertices = vertices.astype(np.float32)
        self.triangles = triangles[source][tree.order]
        self.source_triangles = source[tree.order]
        self.bvh = tree
        self.active_edges = active_edges(vertices, self.triangles)
        self._device: dict = {}  # (device_arrays at vertex offset 0, made once)
        digest = hashlib.sha1(self.vertices.tobytes())
        digest.update(self.triangles.astype(np.int64).tobytes())
        self._digest = digest.hexdigest()

    @classmethod
    def from_trimesh(cls, mesh, name: str | None = None) -> TriangleMesh:
        """The triangles of a ``trimesh.Trimesh``."""
        if not (hasattr(mesh, "vertices") and hasattr(mesh, "faces")):
            raise RbgenError(
                f"TriangleMesh.from_trimesh expects a trimesh.Trimesh, got {type(mesh).__name__}"
            )
        source = getattr(mesh, "metadata", {}).get("name", "mesh")
        label = name or f"TriangleMesh.from_trimesh({source})"
        return cls(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces), name=label)

    @property
    def triangle_count(self) -> int:
        return len(self.triangles)

    def key(self):
        return ("mesh", self._digest)

    def bounding_radius(self) -> float:
        return float(np.linalg.norm(self.vertices, axis=1).max())

    def local_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The quantization box (lower, upper): the mesh's box and two quanta."""
        return self.bvh.lower, self.bvh.upper

    def pack(self, record, hull_vertices):
        hull_vertices.extend(self.local_box())

    def nbytes(self) -> int:
        """Device bytes of the mesh: vertices, triangles and BVH nodes."""
        return (
            16 * len(self.vertices)
            + layouts.MESH_TRIANGLE.itemsize * len(self.triangles)
            + layouts.BVH_NODE.itemsize * len(self.bvh.nodes)
        )

    def device_arrays(self, vertex_offset: int = 0):
        """(float4 vertices, MeshTriangle records with vertex indices from
        ``vertex_offset``, BvhNode records): this mesh's part of the table arrays (made
        once for offset 0, the one-mesh case: an upload then copies nothing on the host)."""
        if vertex_offset == 0 and self._device:
            return self._device["arrays"]
        vertices = np.zeros((len(self.vertices), 4), np.float32)
        vertices[:, :3] = self.vertices
        records = layouts.MESH_TRIANGLE.zeros(len(self.triangles))
        records["vertices"] = self.triangles + vertex_offset
        records["edges"] = self.active_edges
        if vertex_offset == 0:
            for array in (vertices, records):
                array.flags.writeable = False
            self._device["arrays"] = (vertices, records, self.bvh.nodes)
        return vertices, records, self.bvh.nodes

    @classmethod
    def pack_arrays(cls, table: ShapeTable, records: np.ndarray) -> dict:
        meshes = [(i, s) for i, s in enumerate(table.shapes) if isinstance(s, cls)]
        if not meshes:
            return {}
        chunks, v, t, n = [], 0, 0, 0
        for i, mesh in meshes:
            vertices, triangles, nodes = mesh.device_arrays(v)
            rec = records[i]
            rec["face_offset"], rec["face_count"] = t, len(triangles)
            rec["child_offset"], rec["child_count"] = n, len(nodes)
            chunks.append((vertices, triangles, nodes))
            v, t, n = v + len(vertices), t + len(triangles), n + len(nodes)
        if len(chunks) == 1:  # (one mesh: its arrays as they are, no copy of millions)
            return dict(zip(cls.table_arrays, chunks[0]))
        return {
            name: np.concatenate([c[k] for c in chunks]) for k, name in enumerate(cls.table_arrays)
        }


def load_mesh(path, name: str | None = None) -> TriangleMesh:
    """A `TriangleMesh` from an OBJ, STL, PLY (or any format trimesh reads) file; the
    scene's meshes are merged into one."""
    import trimesh

    try:
        loaded = trimesh.load(str(path), force="mesh")
    except Exception as err:  # noqa: BLE001 - trimesh raises many kinds; name the file
        raise RbgenError(f"load_mesh: cannot read {path!s}: {err}") from None
    if not hasattr(loaded, "faces") or len(loaded.faces) == 0:
        raise RbgenError(f"load_mesh: {path!s} holds no triangles")
    return TriangleMesh.from_trimesh(loaded, name=name or f"load_mesh({path!s})")


# ----------------------------------------------------------------- construction


def _checked(vertices, triangles, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float64 vertices and (T, 3) int64 triangles, or an error naming the first
    bad vertex or triangle."""
    try:
        v = np.asarray(vertices, np.float64)
    except (TypeError, ValueError):
        raise RbgenError(f"{name}: vertices must be an (V, 3) array of numbers") from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise RbgenError(f"{name}: vertices must have shape (V, 3), got {v.shape}")
    if len(v) == 0:
        raise RbgenError(f"{name}: the mesh is empty (no vertices)")
    bad = np.flatnonzero(~np.all(np.isfinite(v), axis=1))
    if len(bad):
        raise RbgenError(f"{name}: vertex {bad[0]} is not finite: {v[bad[0]].tolist()}")
    t = np.asarray(triangles)
    if t.ndim != 2 or t.shape[1] != 3 or (t.size and not np.issubdtype(t.dtype, np.integer)):
        raise RbgenError(
            f"{name}: triangles must be an (T, 3) array of vertex indices, got "
            f"shape {t.shape} and dtype {t.dtype}"
        )
    if len(t) == 0:
        raise RbgenError(f"{name}: the mesh is empty (no triangles)")
    t = t.astype(np.int64)
    bad = np.flatnonzero(np.any((t < 0) | (t >= len(v)), axis=1))
    if len(bad):
        row = t[bad[0]]
        index = int(row[(row < 0) | (row >= len(v))][0])
        raise RbgenError(
            f"{name}: triangle {bad[0]} {row.tolist()} has vertex index {index}, "
            f"outside 0..{len(v) - 1}"
        )
    return v, t


def _non_degenerate(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Which triangles have an area (height at least DEGENERATE_HEIGHT of the longest edge)."""
    p0, p1, p2 = (vertices[triangles[:, k]] for k in range(3))
    e0, e1, e2 = p1 - p0, p2 - p1, p0 - p2
    longest2 = np.maximum(np.maximum((e0 * e0).sum(1), (e1 * e1).sum(1)), (e2 * e2).sum(1))
    twice_area2 = (np.cross(e0, e1) ** 2).sum(1)
    # height = 2 area / longest edge
    return twice_area2 > DEGENERATE_HEIGHT**2 * longest2 * longest2


def active_edges(
    vertices: np.ndarray, triangles: np.ndarray, degrees: float = ACTIVE_EDGE_DEGREES
) -> np.ndarray:
    """The `MeshTriangle.edges` bits of every triangle (see the module docstring)."""
    vertices = np.asarray(vertices, np.float64)
    t = np.asarray(triangles, np.int64)
    count = len(t)
    p = vertices[t]
    normals = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    start = t.reshape(-1)  # edge 3 i + k: vertex k ->
    end = t[:, [1, 2, 0]].reshape(-1)  # vertex k + 1
    key = np.minimum(start, end) * (len(vertices) + 1) + np.maximum(start, end)
    order = np.argsort(key)
    keys = key[order]
    first = np.flatnonzero(np.concatenate([[True], keys[1:] != keys[:-1]]))
    sizes = np.diff(np.append(first, len(keys)))
    active = np.ones(3 * count, bool)  # open and non-manifold: active
    pairs = first[sizes == 2]
    e1, e2 = order[pairs], order[pairs + 1]
    t1, t2 = e1 // 3, e2 // 3
    n1, n2 = normals[t1], normals[t2]
    cos_fold = np.einsum("ij,ij->i", n1, n2)
    consistent = start[e1] == end[e2]  # opposite directions
    opposite = vertices[t[t2, (e2 % 3 + 2) % 3]]  # t2's vertex off the edge
    convex = np.einsum("ij,ij->i", n1, opposite - vertices[start[e1]]) < 0.0
    sharp = math.cos(math.radians(degrees))
    flag = np.where(consistent, (cos_fold < sharp) & convex, np.abs(cos_fold) < sharp)
    active[e1] = flag
    active[e2] = flag
    bits = active.reshape(count, 3).astype(np.uint32)
    return (bits[:, 0] | bits[:, 1] << 1 | bits[:, 2] << 2).astype(np.uint32)
