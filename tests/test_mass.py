"""Mass properties: closed forms for spheres, boxes, capsules; volume integrals for hulls."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from rbgen.errors import RbgenError
from rbgen.shapes import Box, Capsule, ConvexHull, Plane, Sphere
from tests.pipeline.narrowphase.reference import quat_matrix


def test_sphere_and_box_closed_forms():
    """Sphere: m = rho 4/3 pi r^3, I = 2/5 m r^2. Box: m = rho 8abc, I_x = m (b^2 + c^2) / 3."""
    s = Sphere(0.7).mass_properties(density=2.0)
    m = 2.0 * 4 / 3 * np.pi * 0.7**3
    assert s.mass == pytest.approx(m)
    np.testing.assert_allclose(s.inertia, [0.4 * m * 0.49] * 3)
    b = Box((1.0, 2.0, 3.0)).mass_properties(mass=6.0)
    np.testing.assert_allclose(b.inertia, [6 * 13 / 3, 6 * 10 / 3, 6 * 5 / 3])
    assert b.com == (0, 0, 0) and b.rotation == (0, 0, 0, 1)


def test_capsule_matches_a_fine_mesh():
    c = Capsule(0.4, 0.6).mass_properties(density=1.0)
    mesh = trimesh.creation.capsule(height=1.2, radius=0.4, count=[64, 64])
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))  # z -> y
    props = mesh.mass_properties
    assert c.mass == pytest.approx(props["volume"], rel=2e-3)
    np.testing.assert_allclose(c.inertia, np.diag(props["inertia"]), rtol=5e-3)


def test_hull_of_a_box_equals_the_box(rng):
    corners = Box((0.5, 1.0, 1.5)).local_vertices()
    hull = ConvexHull(np.vstack([corners, rng.uniform(-0.4, 0.4, (10, 3))]))
    np.testing.assert_allclose(
        hull.mass_properties(density=3.0).inertia,
        Box((0.5, 1.0, 1.5)).mass_properties(density=3.0).inertia,
        rtol=1e-9,
    )


def test_hull_frame_reproduces_the_input_inertia(rng):
    """R diag(I) R^T, with R from the returned quaternion, equals trimesh's inertia tensor
    of the input points about their centre of mass; stored vertices map back to the input."""
    pts = rng.normal(size=(40, 3)) * (2.0, 1.0, 0.5) + (1, 2, 3)
    hull = ConvexHull(pts, name="blob")
    props = hull.mass_properties(mass=5.0)
    mesh = trimesh.convex.convex_hull(pts)
    ref = mesh.mass_properties
    r = quat_matrix(props.rotation)
    np.testing.assert_allclose(props.com, ref["center_mass"], atol=1e-10)
    tensor = r @ np.diag(props.inertia) @ r.T
    np.testing.assert_allclose(
        tensor, ref["inertia"] * 5.0 / ref["mass"], atol=1e-9 * np.abs(tensor).max()
    )
    mapped = hull.vertices @ r.T + props.com
    d = np.linalg.norm(mapped[:, None] - pts[None], axis=-1)
    assert np.all(d.min(axis=1) < 1e-9)
    # the stored frame is principal: its inertia tensor is diagonal
    stored = trimesh.convex.convex_hull(hull.vertices).mass_properties
    off = stored["inertia"] - np.diag(np.diag(stored["inertia"]))
    assert np.abs(off).max() < 1e-9 * np.abs(stored["inertia"]).max()
    np.testing.assert_allclose(stored["center_mass"], 0, atol=1e-10)


def test_bad_mass_arguments_name_the_shape():
    with pytest.raises(RbgenError, match="exactly one"):
        Sphere(1.0).mass_properties()
    with pytest.raises(RbgenError, match="box.*mass must be a positive"):
        Box((1, 1, 1)).mass_properties(mass=-1.0)
    with pytest.raises(RbgenError, match="plane"):
        Plane().mass_properties(mass=1.0)
