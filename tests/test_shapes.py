"""Shapes and their packing into the device arrays (Shape records + hull topology)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from rbgen import layouts
from rbgen.errors import RbgenError
from rbgen.shapes import (
    Box,
    Capsule,
    ConvexHull,
    Plane,
    ShapeTable,
    Sphere,
    shape_type,
    shape_types,
)


def test_table_deduplicates_and_packs_topology(rng):
    table = ShapeTable()
    box = table.add(Box((1.0, 2.0, 0.5)))
    assert table.add(Box((1.0, 2.0, 0.5))) == box
    ball = table.add(Sphere(0.3))
    rock = table.add(ConvexHull(rng.normal(size=(30, 3)), name="rock"))
    ground = table.add(Plane((0, 2, 0), 1.0))
    assert table.type_names() == ("box", "hull", "plane", "sphere")
    packed = table.pack_all()
    records = packed.shapes
    assert records.dtype == layouts.SHAPE.dtype and packed.faces.dtype == layouts.HULL_FACE.dtype
    assert list(records["type"][[box, ball, rock, ground]]) == [
        Box.type_code,
        Sphere.type_code,
        ConvexHull.type_code,
        Plane.type_code,
    ]
    np.testing.assert_allclose(records["extents"][ground], (0, 1, 0, 1.0))
    for index in (box, rock):
        shape, rec = table.shapes[index], records[index]
        cooked = shape.cooked()
        v0, nv = rec["vertex_offset"], rec["vertex_count"]
        np.testing.assert_allclose(
            packed.vertices[v0 : v0 + nv, :3], cooked.vertices, rtol=1e-6, atol=1e-6
        )
        faces = packed.faces[rec["face_offset"] : rec["face_offset"] + rec["face_count"]]
        for face, polygon, plane in zip(faces, cooked.faces, cooked.planes):
            start = face["index_offset"]
            idx = packed.face_indices[start : start + face["index_count"]]
            np.testing.assert_array_equal(idx, polygon)
            np.testing.assert_allclose(face["plane"], plane, rtol=1e-6, atol=1e-6)
        e0, ne = rec["edge_offset"], rec["edge_count"]
        np.testing.assert_allclose(
            packed.edges[e0 : e0 + ne, :3], cooked.edge_directions, atol=1e-6
        )
    # the legacy 2-tuple: records and hull vertices
    legacy_records, legacy_vertices = table.pack()
    np.testing.assert_array_equal(legacy_records, records)
    assert table.max_face_vertices() == max(
        len(f) for s in (box, rock) for f in table.shapes[s].cooked().faces
    )


def test_box_cooked_as_hull_matches_its_extents():
    box = Box((0.5, 1.0, 2.0))
    c = box.cooked()
    np.testing.assert_allclose(np.abs(c.vertices), np.broadcast_to((0.5, 1.0, 2.0), (8, 3)))
    np.testing.assert_allclose(c.planes[:, 3], [0.5, 0.5, 1.0, 1.0, 2.0, 2.0])
    for polygon, plane in zip(c.faces, c.planes):
        np.testing.assert_allclose(c.vertices[polygon] @ plane[:3], plane[3])
        p = c.vertices[polygon]
        assert np.dot(np.cross(p[1] - p[0], p[2] - p[1]), plane[:3]) > 0  # counter-clockwise


def test_empty_table_and_bad_shapes():
    packed = ShapeTable().pack_all()
    assert len(packed.shapes) == 1 and len(packed.vertices) == 1 and len(packed.faces) == 1
    with pytest.raises(RbgenError, match="rbgen shape"):
        ShapeTable().add("box")
    with pytest.raises(RbgenError, match="trimesh"):
        ConvexHull.from_trimesh(np.zeros((4, 3)))
    with pytest.raises(RbgenError, match="half_extents"):
        Box((1.0, 0.0, 1.0))
    assert Capsule(0.5, 1.0).cooked() is None


def test_from_trimesh_uses_the_mesh_vertices():
    mesh = trimesh.creation.box(extents=(2.0, 4.0, 6.0))
    hull = ConvexHull.from_trimesh(mesh)
    np.testing.assert_allclose(np.sort(np.abs(hull.vertices), axis=0).max(axis=0), (1.0, 2.0, 3.0))
    assert hull.mass_properties(density=1.0).mass == pytest.approx(48.0)


def test_shape_classes_are_the_registry_entries_and_bound_their_shapes(rng):
    """Each shape class is its type's entry (code = its RB_SHAPE_<NAME> constant, the name
    ShapeTable reports, an AABB template); bounding radius about the centre of mass: a
    sphere's radius, a capsule's r + h, a box's |half extents|, a hull's farthest vertex;
    a plane is unbounded (it has no vertices). Meshes and compounds are entries too
    (rbgen.mesh, rbgen.compound)."""
    from rbgen import Compound, TriangleMesh

    assert set(shape_types()) == {Sphere, Box, Capsule, ConvexHull, Plane, TriangleMesh, Compound}
    assert len(shape_types()) == 7
    for cls in shape_types():
        assert shape_type(cls.type_name) is cls
        assert layouts.constants()[cls.type_constant] == cls.type_code
        assert cls.type_constant == f"RB_SHAPE_{cls.type_name.upper()}"
        assert cls.aabb_template == f"shapes/{cls.type_name}.cl.mako"
    assert {c for c in shape_types() if c.static_only} == {Plane, TriangleMesh}
    assert Sphere(0.7).bounding_radius() == 0.7
    assert Capsule(0.3, 1.2).bounding_radius() == pytest.approx(1.5)
    assert Box((1.0, 2.0, 2.0)).bounding_radius() == pytest.approx(3.0)
    points = rng.normal(size=(20, 3))
    hull = ConvexHull(points)
    assert hull.bounding_radius() == pytest.approx(np.linalg.norm(hull.vertices, axis=1).max())
    with pytest.raises(RbgenError, match="plane has no vertex representation"):
        Plane().bounding_radius()
    with pytest.raises(RbgenError, match="no shape type named 'torus'"):
        shape_type("torus")
