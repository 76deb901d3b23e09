"""Host references of the midphase: brute force (every body box against every triangle
box) and small scenes to check and tune it on. Tests and the tuner compare the device's
output with these, pair for pair."""

from __future__ import annotations

import numpy as np

from .. import layouts


def terrain(cells: int, spacing: float, rng, roughness: float = 0.3):
    """(vertices, triangles) of a random height field of 2 cells^2 triangles."""
    n = cells + 1
    x, z = np.meshgrid(np.arange(n) * spacing, np.arange(n) * spacing, indexing="ij")
    y = roughness * rng.standard_normal((n, n))
    vertices = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
    v00 = (i * n + j).ravel()
    v01, v10, v11 = v00 + 1, v00 + n, v00 + n + 1
    triangles = np.concatenate([np.stack([v00, v01, v10], 1), np.stack([v10, v01, v11], 1)])
    return vertices, triangles


def bodies_above(
    count: int, mesh, shape_index: int, rng, mesh_index: int = 0, height: float = 0.5
) -> np.ndarray:
    """`Body` records: body 0 the mesh (static, at the origin), then ``count`` bodies of
    shape ``shape_index`` at random places just above its box."""
    lower, upper = mesh.local_box()
    bodies = layouts.BODY.zeros(count + 1)
    bodies["orientation"][:, 3] = 1.0
    bodies["shape"][0] = mesh_index
    bodies["shape"][1:] = shape_index
    bodies["inv_mass"][1:] = 1.0
    p = rng.uniform(lower, upper, (count, 3))
    p[:, 1] = rng.uniform(lower[1] - height, upper[1] + height, count)
    bodies["position"][1:, :3] = p
    q = rng.normal(size=(count, 4))
    bodies["orientation"][1:] = q / np.linalg.norm(q, axis=1)[:, None]
    return bodies


def triangle_boxes(mesh) -> tuple[np.ndarray, np.ndarray]:
    """Each triangle's exact box (float32, from its float32 vertices), in the mesh's order."""
    corners = mesh.vertices[mesh.triangles]
    return corners.min(axis=1), corners.max(axis=1)


def brute_force(meshes, bodies: np.ndarray, aabbs: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """The midphase's output for ``pairs`` (`Pair` records): ``meshes`` maps a body index to
    its TriangleMesh (or is the one mesh, for every body whose shape is mesh_index 0 in
    `bodies_above`'s scenes); a pair with a mesh becomes its (pair, 1 + triangle) for every
    triangle whose box overlaps the other body's box (closed), in triangle order; other
    pairs are copied. The mesh bodies must be unrotated (the device's exact case)."""
    if not isinstance(meshes, dict):
        meshes = {int(i): meshes for i in np.flatnonzero(bodies["inv_mass"] == 0)}
    boxes = {i: triangle_boxes(m) for i, m in meshes.items()}
    out = []
    for pair in pairs:
        a, b = int(pair["a"]), int(pair["b"])
        mesh = a if a in meshes else (b if b in meshes else None)
        if mesh is None:
            out.append(pair)
            continue
        other = b if mesh == a else a
        p = bodies["position"][mesh, :3]
        lower = (aabbs["lower"][other, :3] - p).astype(np.float32)
        upper = (aabbs["upper"][other, :3] - p).astype(np.float32)
        tri_lower, tri_upper = boxes[mesh]
        hit = np.flatnonzero(
            np.all(tri_lower <= upper, axis=1) & np.all(lower <= tri_upper, axis=1)
        )
        records = layouts.PAIR.zeros(len(hit))
        records["a"], records["b"], records["sub"] = a, b, hit + 1
        out.extend(records)
    result = layouts.PAIR.zeros(len(out))
    if out:
        result[:] = np.array(out, dtype=layouts.PAIR.dtype)
    return result
