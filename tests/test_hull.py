"""Hull cooking: polygons, planes, edge directions, limits and degenerate input."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from rbgen import hull
from rbgen.errors import RbgenError
from rbgen.shapes import ConvexHull


def check_polyhedron(cooked, points_in_frame):
    """Every vertex on or below every plane, each face's vertices on its plane and
    counter-clockwise seen from outside, and Euler's V - E + F = 2."""
    v = cooked.vertices
    n, d = cooked.planes[:, :3], cooked.planes[:, 3]
    scale = np.abs(v).max()
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    assert np.all(v @ n.T - d <= 1e-9 * scale)
    assert np.all(points_in_frame @ n.T - d <= 1e-9 * scale)
    edges = set()
    for face, normal, offset in zip(cooked.faces, n, d):
        p = v[face]
        np.testing.assert_allclose(p @ normal, offset, atol=1e-9 * scale)
        turn = np.cross(np.roll(p, -1, axis=0) - p, np.roll(p, -2, axis=0) - np.roll(p, -1, axis=0))
        assert np.all(turn @ normal > -1e-12 * scale**2)
        edges |= {tuple(sorted(e)) for e in zip(face, np.roll(face, -1))}
    assert len(v) - len(edges) + len(cooked.faces) == 2


def stored_frame(cooked, points):
    """Input points expressed in the cooked (principal) frame."""
    from tests.pipeline.narrowphase.reference import quat_matrix

    return (np.asarray(points) - cooked.com) @ quat_matrix(cooked.rotation)


def test_cube_points_merge_into_six_quads(rng):
    """8 corners + interior points of a rotated, shifted cube: 6 quads, 3 edge directions."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    pts = np.vstack([corners, rng.uniform(-0.9, 0.9, (20, 3))]) @ q.T + (3, -2, 1)
    cooked = hull.cook(pts, "cube")
    assert len(cooked.vertices) == 8
    assert sorted(len(f) for f in cooked.faces) == [4] * 6
    assert len(cooked.edge_directions) == 3
    check_polyhedron(cooked, stored_frame(cooked, pts))
    np.testing.assert_allclose(cooked.com, (3, -2, 1), atol=1e-12)


def test_random_hull_and_icosphere(rng):
    pts = rng.normal(size=(60, 3)) * (1.0, 0.5, 2.0)
    cooked = hull.cook(pts, "blob")
    check_polyhedron(cooked, stored_frame(cooked, pts))
    ico = ConvexHull.from_trimesh(trimesh.creation.icosphere(subdivisions=3))
    c = ico.cooked()
    assert len(c.vertices) == 642 and len(c.faces) == 1280
    check_polyhedron(c, c.vertices)


def test_cylinder_caps_are_single_polygons():
    """A 24-sided prism: 2 caps of 24 vertices + 24 side quads; 25 edge directions."""
    angles = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.sin(angles)])
    pts = np.vstack([np.column_stack([ring, np.full(24, z)]) for z in (-0.5, 0.5)])
    cooked = hull.cook(pts, "prism")
    assert sorted(len(f) for f in cooked.faces) == [4] * 24 + [24, 24]
    assert len(cooked.edge_directions) == 12 + 1  # opposite sides share a direction, + axis
    check_polyhedron(cooked, stored_frame(cooked, pts))


@pytest.mark.parametrize(
    "points,match",
    [
        (np.zeros((3, 3)), "at least 4"),
        (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0.5, 0.2, 0]]), "coplanar"),
        (np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]]), "coplanar or collinear"),
        (np.ones((5, 3)), "zero extents"),
        (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, np.nan]]), "NaN"),
        (np.zeros((4, 2)), r"\(N, 3\)"),
    ],
)
def test_degenerate_hulls_name_the_shape(points, match):
    with pytest.raises(RbgenError, match=match) as err:
        ConvexHull(points, name="rock 7")
    assert "rock 7" in str(err.value)


def test_face_vertex_limit_names_the_shape():
    angles = np.linspace(0, 2 * np.pi, hull.MAX_FACE_VERTICES + 1, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.sin(angles)])
    pts = np.vstack([np.column_stack([ring, np.full(len(ring), z)]) for z in (0, 1)])
    with pytest.raises(RbgenError, match="MAX_FACE_VERTICES") as err:
        ConvexHull(pts, name="wheel")
    assert "wheel" in str(err.value)


def test_edges_know_their_faces(rng):
    """Each edge v0 -> v1 runs counter-clockwise around f0 and clockwise around f1;
    together the edges are every polygon side exactly once."""
    cooked = hull.cook(rng.normal(size=(40, 3)), "blob")
    sides = {
        (int(a), int(b)): f
        for f, poly in enumerate(cooked.faces)
        for a, b in zip(poly, np.roll(poly, -1))
    }
    assert 2 * len(cooked.edges) == len(sides)
    for v0, v1, f0, f1 in cooked.edges:
        assert sides[(v0, v1)] == f0 and sides[(v1, v0)] == f1


def test_points_on_edges_and_faces_are_not_corners():
    """A cube sampled on its edges and faces (a 5 x 5 x 5 grid): 8 corners, 6 quads."""
    g = np.linspace(-1, 1, 5)
    pts = np.array([[x, y, z] for x in g for y in g for z in g])
    cooked = hull.cook(pts, "grid cube")
    assert len(cooked.vertices) == 8
    assert sorted(len(f) for f in cooked.faces) == [4] * 6
    assert len(cooked.edges) == 12
