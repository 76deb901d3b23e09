"""Triangle meshes in a World: their checks, their active edges, their physics, their
export, and that worlds without meshes or compounds do not pay for them.

Physics, each against its closed form or the same scene on a plane:
* a box sliding across a floor of 3,200 triangles decelerates at mu g, as on a plane of
  the same friction (speeds within 2%), with |v_y| < 1 cm/s: no bump on the seams;
* a sphere rolls across the seams at the constant height of its radius, its speed
  5/7 of the start (rolling without slipping), as on a plane;
* boxes, hulls and compounds dropped on a rough terrain come to rest (every speed below
  5 cm/s after 8 s, none below the terrain; spheres and capsules roll on, but stay on it).
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pyopencl as cl
import pytest

import rbgen
from rbgen.errors import RbgenError
from rbgen.pipeline import midphase_reference as reference


def floor_mesh(cells: int, size: float) -> rbgen.TriangleMesh:
    """A flat square floor at y = 0 of 2 cells^2 triangles, centred on the origin."""
    n = cells + 1
    x, z = np.meshgrid(
        np.linspace(-size / 2, size / 2, n), np.linspace(-size / 2, size / 2, n), indexing="ij"
    )
    vertices = np.stack([x.ravel(), np.zeros(n * n), z.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij")
    v00 = (i * n + j).ravel()
    triangles = np.concatenate(
        [np.stack([v00, v00 + 1, v00 + n], 1), np.stack([v00 + n, v00 + 1, v00 + n + 1], 1)]
    )
    return rbgen.TriangleMesh(vertices, triangles, name="floor")


# ------------------------------------------------------------------ bad input


def test_bad_meshes_are_refused_naming_the_vertex_or_triangle():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [1, 0, 1]], float)
    t = np.array([[0, 2, 1], [1, 2, 3]])
    bad = v.copy()
    bad[2, 1] = np.nan
    with pytest.raises(RbgenError, match="vertex 2 is not finite"):
        rbgen.TriangleMesh(bad, t)
    bad[2, 1] = np.inf
    with pytest.raises(RbgenError, match="vertex 2 is not finite"):
        rbgen.TriangleMesh(bad, t)
    with pytest.raises(
        RbgenError,
        match=r"triangle 1 \[1, 2, 4\] has vertex index 4, "
        r"outside 0..3",
    ):
        rbgen.TriangleMesh(v, [[0, 2, 1], [1, 2, 4]])
    with pytest.raises(RbgenError, match="vertex index -1"):
        rbgen.TriangleMesh(v, [[0, 2, -1]])
    with pytest.raises(RbgenError, match="empty"):
        rbgen.TriangleMesh(np.zeros((0, 3)), np.zeros((0, 3), int))
    with pytest.raises(RbgenError, match="empty"):
        rbgen.TriangleMesh(v, np.zeros((0, 3), int))
    with pytest.raises(RbgenError, match=r"shape \(V, 3\)"):
        rbgen.TriangleMesh(v[:, :2], t)
    with pytest.raises(RbgenError, match="vertex indices"):
        rbgen.TriangleMesh(v, [[0.5, 1, 2]])


def test_degenerate_triangles_are_dropped_with_one_warning():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [1, 0, 1], [2, 0, 0]], float)
    t = np.array([[0, 2, 1], [0, 1, 4], [1, 2, 3], [3, 3, 2]])  # 1 and 3: zero area
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mesh = rbgen.TriangleMesh(v, t, name="ground")
    assert len(caught) == 1
    assert "ground: dropped 2 degenerate (zero-area) triangles of 4 (the first: triangle 1)" in str(
        caught[0].message
    )
    assert mesh.triangle_count == 2
    assert sorted(mesh.source_triangles.tolist()) == [0, 2]
    np.testing.assert_array_equal(
        np.sort(mesh.triangles, axis=1), np.sort(t[mesh.source_triangles], axis=1)
    )
    with pytest.raises(RbgenError, match="every triangle is degenerate"):
        rbgen.TriangleMesh(v, [[0, 1, 4]])


def test_a_mesh_cannot_be_dynamic():
    world = rbgen.World()
    mesh = floor_mesh(2, 2.0)
    with pytest.raises(
        RbgenError,
        match="TriangleMesh can only be static.*ConvexHull"
        r".*Compound of hulls",
    ):
        world.add_bodies(mesh, mass=1.0, positions=[(0, 0, 0)])
    assert world.body_count == 0
    world.add_static(mesh)
    assert world.body_count == 1


def test_active_edges():
    """Open edges are active; a shared edge between coplanar triangles, a concave fold
    and a convex fold under 5 degrees are inactive; a sharp convex fold is active; where
    the windings disagree, any sharp fold is active."""
    flat = floor_mesh(1, 2.0)
    # each triangle: two open sides (active), the diagonal (inactive)
    assert sorted(bin(int(e)).count("1") for e in flat.active_edges) == [2, 2]

    def fold(height, flip=False):
        v = np.array(
            [[-1, 0, 0], [0, height, 0], [1, 0, 0], [-1, 0, 2], [0, height, 2], [1, 0, 2]], float
        )
        t = [[0, 3, 1], [1, 3, 4], [1, 4, 2], [2, 4, 5]]
        if flip:
            t[2] = [1, 2, 4]
        mesh = rbgen.TriangleMesh(v, np.array(t))
        ridge = [k for k, tri in enumerate(mesh.triangles.tolist()) if {1, 4} <= set(tri)]
        edges = []
        for k in ridge:
            tri = mesh.triangles[k].tolist()
            for e in range(3):
                if {tri[e], tri[(e + 1) % 3]} == {1, 4}:
                    edges.append(bool(mesh.active_edges[k] >> e & 1))
        return edges

    assert fold(1.0) == [True, True]  # 90-degree convex ridge
    assert fold(-1.0) == [False, False]  # concave valley
    assert fold(0.03) == [False, False]  # 3.4-degree convex fold: flat
    assert fold(0.1) == [True, True]  # 11 degrees: sharp
    assert fold(-1.0, flip=True) == [True, True]  # windings disagree: sharp is active


def test_load_mesh_round_trip(tmp_path):
    import trimesh

    box = trimesh.creation.box((1, 2, 3))
    for suffix in ("obj", "stl", "ply"):
        path = tmp_path / f"box.{suffix}"
        box.export(path)
        mesh = rbgen.load_mesh(path)
        assert mesh.triangle_count == 12
        np.testing.assert_allclose(mesh.vertices.min(axis=0), [-0.5, -1, -1.5])
    assert rbgen.TriangleMesh.from_trimesh(box).triangle_count == 12
    with pytest.raises(RbgenError, match="cannot read"):
        rbgen.load_mesh(tmp_path / "missing.obj")


# ------------------------------------------------------------------ physics


@pytest.mark.gpu_shape
@pytest.mark.parametrize("direction", [(1.0, 0.0), (0.8, 0.6), (0.6, -0.8)])
def test_box_slides_across_seams_as_on_a_plane(runtime, direction):
    """A unit box sliding at 4 m/s (friction 0.5 on both sides): on the tessellated floor
    its speed after 0.25 s and 0.5 s is within 2% of the same box's on a plane and of
    4 - mu g t; |v_y| stays below 1 cm/s on the mesh."""
    mu, g, speed = 0.5, 9.81, 4.0
    velocity = (speed * direction[0], 0.0, speed * direction[1])
    speeds = {}
    for ground in ("plane", "mesh"):
        world = rbgen.World(runtime)
        if ground == "plane":
            world.add_static(rbgen.Plane((0, 1, 0), 0.0), friction=mu)
        else:
            world.add_static(floor_mesh(40, 40.0), friction=mu)
        box = world.add_body(
            rbgen.Box((0.5, 0.5, 0.5)),
            mass=1.0,
            position=(-4, 0.5, 0.3),
            linear_velocity=velocity,
            friction=mu,
        )
        history = []
        for _ in range(30):
            world.step(1 / 60)
            history.append(world.linear_velocities[box].astype(np.float64))
        history = np.array(history)
        if ground == "mesh":
            assert np.abs(history[:, 1]).max() < 0.01
        speeds[ground] = np.linalg.norm(history[[14, 29]][:, [0, 2]], axis=1)
    expected = speed - mu * g * np.array([0.25, 0.5])
    np.testing.assert_allclose(speeds["mesh"], speeds["plane"], rtol=0.02)
    np.testing.assert_allclose(speeds["mesh"], expected, rtol=0.02)


def test_sphere_rolls_across_seams(runtime):
    """A sphere launched sliding at 3.2 m/s over 1 m cells rolls across their seams (more
    than 4 m in 2 s) at a constant height (its radius, within 1 mm, |v_y| < 1 cm/s) and
    reaches 5/7 of its speed (rolling without slipping), as on a plane."""
    world = rbgen.World(runtime)
    world.add_static(floor_mesh(40, 40.0), friction=0.5)
    ball = world.add_body(
        rbgen.Sphere(0.5),
        mass=1.0,
        position=(-15, 0.5, 0.2),
        linear_velocity=(3.0, 0.0, 1.0),
        friction=0.5,
    )
    heights, vertical = [], []
    for _ in range(120):
        world.step(1 / 60)
        heights.append(world.positions[ball, 1])
        vertical.append(world.linear_velocities[ball, 1])
    assert np.ptp(heights) < 1e-3 and abs(heights[-1] - 0.5) < 1e-3
    assert np.abs(vertical).max() < 0.01
    v = world.linear_velocities[ball]
    assert np.linalg.norm(v[[0, 2]]) == pytest.approx(5 / 7 * np.sqrt(10.0), rel=0.01)
    assert world.positions[ball, 0] > -11.0  # it crossed the floor's seams


def chair(scale: float = 1.0) -> rbgen.Compound:
    """A seat on four legs with a ball on top: six children of two types."""
    legs = [
        (
            rbgen.Box((0.05 * scale, 0.25 * scale, 0.05 * scale)),
            (x * 0.4 * scale, 0.2 * scale, z * 0.4 * scale),
        )
        for x in (-1, 1)
        for z in (-1, 1)
    ]
    return rbgen.Compound(
        [(rbgen.Box((0.5 * scale, 0.05 * scale, 0.5 * scale)), (0, 0.5 * scale, 0))]
        + legs
        + [(rbgen.Sphere(0.2 * scale), (0, 0.8 * scale, 0))],
        name="chair",
    )


def test_a_hull_rocking_on_a_terrain_ridge_comes_to_rest(runtime, request):
    """A known defect, reproduced: the terrain and hull of seed 775971128 of the test
    below (where 1 run in about 60 fails), the hull set down at rest on a convex ridge
    (an active edge) where that run left it rocking, at that test's solve (one substep of
    10 + 4 sweeps). It should come to rest within 4 s."""
    # (reproduced on CPU plans; a GPU plan takes another path from this state, which
    # may or may not rest: not strict there)
    request.applymarker(
        pytest.mark.xfail(
            strict=not runtime.traits.is_gpu,
            reason=(
                "contact solver owner: the hull, held by a 1 cm edge-edge penetration "
                "on the ridge and a speculative point, rocks in a period-2 cycle at "
                "0.066 m/s for ever; from this state it rests with contact_margin=0, "
                "position_iterations=0 or penetration_recovery=0.1, not with 40 sweeps, "
                "4 substeps, friction 1, the sequential normal solve, no shock sweep, "
                "no warm start or a push target of 0 at separated points: the speculative "
                "points and the push together, mechanism not isolated (CPU plans)"
            ),
        )
    )
    rng = np.random.default_rng(775971128)
    vertices, triangles = reference.terrain(24, 1.0, rng, roughness=0.05)
    hull = rbgen.ConvexHull(rng.normal(size=(12, 3)) * 0.3)
    world = rbgen.World(runtime, substeps=1, iterations=10, position_iterations=4)
    world.add_static(rbgen.TriangleMesh(vertices, triangles))
    body = world.add_body(
        hull,
        mass=1.0,
        position=(18.058926, 0.20587023, 12.547264),
        orientation=(-0.7280135, -0.073194586, -0.072775975, 0.6777481),
    )
    for _ in range(240):
        world.step(1 / 60)
    assert np.linalg.norm(world.linear_velocities[body]) < 0.01


@pytest.mark.gpu_shape
def test_bodies_dropped_on_a_terrain_come_to_rest(runtime, rng):
    """Boxes, hulls and compounds dropped on a rough height field (2 x 24 x 24 triangles,
    heights +-15 cm) rest after 8 s: no NaN, speeds < 5 cm/s, no centre below the terrain
    under it. Spheres and capsules roll without resistance: one that lands on a slope
    rolls on (at most the speed of a fall down the roughness, sqrt(10/7 g 0.3) = 2 m/s),
    so they are held to that and to staying on the terrain while over it (one may roll off
    its edge and fall; at least half stay), in a World of their own (on the same terrain:
    a ball rolling into a resting box would set it moving). The subject is the terrain's
    contacts, so the solve is one substep of 10 + 4 sweeps, where nearly everything rests
    by 5 s and a rocking hull by 8 s (seed 711678375: 0.16 m/s at 5 s, at rest by 5.5 s; at
    the default efforts, 4 of 3 + 1 on CPUs and 8 of 2 + 1 on GPUs, seed 1380154127's chair
    was at 0.09 m/s at 5 s, at rest by 8 s: issue 24's slow settling at few sweeps a
    substep). A hull can also rock for ever on a ridge, a solver defect that
    `test_a_hull_rocking_on_a_terrain_ridge_comes_to_rest` names (about 1 run in 60 here)."""
    vertices, triangles = reference.terrain(24, 1.0, rng, roughness=0.05)
    shapes = [
        rbgen.Box((0.3, 0.2, 0.25)),
        rbgen.Sphere(0.3),
        rbgen.Capsule(0.2, 0.25),
        rbgen.ConvexHull(rng.normal(size=(12, 3)) * 0.3),
        chair(0.6),
    ]
    for rolls, limit in ((False, 0.05), (True, 2.0)):
        world = rbgen.World(runtime, substeps=1, iterations=10, position_iterations=4)
        world.add_static(rbgen.TriangleMesh(vertices, triangles))
        ids, kinds = [], []
        for k, shape in enumerate(shapes):
            if isinstance(shape, (rbgen.Sphere, rbgen.Capsule)) != rolls:
                continue
            grid = np.stack(
                np.meshgrid(np.arange(3, 21, 3.0), [1.5 + 0.8 * k], [4.0 + 3.0 * k], indexing="ij"),
                -1,
            ).reshape(-1, 3)
            ids += list(world.add_bodies(shape, mass=1.0, positions=grid))
            kinds += [type(shape).__name__] * len(grid)
        for _ in range(480):
            world.step(1 / 60)
        p = world.positions[ids]
        speeds = np.linalg.norm(world.linear_velocities[ids], axis=1)
        assert np.all(np.isfinite(p))
        # (a ball may roll off the terrain's edge and fall: only those over it count)
        over = np.all((p[:, [0, 2]] >= 0) & (p[:, [0, 2]] <= 24), axis=1)
        assert over.sum() >= (len(ids) if not rolls else len(ids) // 2), p[~over]
        assert speeds[over].max() < limit, (kinds[int(np.argmax(speeds * over))], speeds.max())
        cell = np.clip(p[over][:, [0, 2]].astype(int), 0, 24)
        ground = vertices[:, 1].reshape(25, 25)[cell[:, 0], cell[:, 1]]
        assert np.all(p[over, 1] > ground - 0.2)


@pytest.mark.gpu_shape
def test_compounds_against_compounds_planes_and_meshes(runtime):
    """Chairs stacked on a chair on a plane and on a mesh floor: at rest after 4 s at the
    heights their geometry gives (legs on the ground: centre of mass 0.576 m up; a chair
    on a chair's seat: 0.599 m higher), on either ground."""
    for ground in ("plane", "mesh"):
        world = rbgen.World(runtime)
        if ground == "plane":
            world.add_static(rbgen.Plane((0, 1, 0), 0.0))
        else:
            world.add_static(floor_mesh(10, 10.0))
        shape = chair()
        com = shape.mass_properties(mass=1.0).com[1]
        ids = world.add_bodies(shape, mass=1.0, positions=[(0, 1, 0), (0, 2.3, 0), (2, 1, 0)])
        for _ in range(240):
            world.step(1 / 60)
        p = world.positions[ids]
        standing = com + 0.05  # the feet are 0.05 below the chair's frame (0.2 - 0.25)
        np.testing.assert_allclose(p[[0, 2], 1], standing, atol=3e-3)
        # the top chair's feet on the seat's top (0.55 in the frame): 0.6 higher
        np.testing.assert_allclose(p[1, 1], standing + 0.6, atol=5e-3)
        assert np.linalg.norm(world.linear_velocities[ids], axis=1).max() < 0.02


# ------------------------------------------------------------------ cost and export


def test_worlds_without_meshes_or_compounds_pay_nothing(runtime):
    """A world of boxes on a plane has no midphase or children stage and no extra shape
    arrays; one with a mesh has the midphase, one with a compound both."""

    def stages(*statics, dynamic=None):
        world = rbgen.World(runtime)
        for shape in statics:
            world.add_static(shape)
        world.add_bodies(dynamic or rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, positions=[(0, 2, 0)])
        world.step(1 / 60)
        return [s.name for s in world._pipeline.stages], world._packed.extra

    names, extra = stages(rbgen.Plane())
    assert "midphase" not in names and "children" not in names and extra == {}
    names, extra = stages(floor_mesh(2, 4.0))
    assert names[:4] == ["prepare", "broadphase", "midphase", "narrowphase"]
    assert "children" not in names and set(extra) == {
        "mesh_vertices",
        "mesh_triangles",
        "bvh_nodes",
    }
    names, extra = stages(rbgen.Plane(), dynamic=chair())
    assert names[:5] == ["prepare", "broadphase", "midphase", "narrowphase", "children"]
    assert set(extra) == {"compound_children"}


def test_a_mesh_worlds_export_builds_standalone(runtime, tmp_path):
    """`rbgen export --world` of a World with a mesh and compounds: the midphase, triangle
    and children kernels are among what it exports, and every file builds outside rbgen."""
    from rbgen.export import export_world

    world = rbgen.World(runtime)
    world.add_static(floor_mesh(4, 8.0))
    world.add_bodies(rbgen.Box((0.3, 0.3, 0.3)), mass=1.0, positions=[(0, 0.5, 0)])
    world.add_bodies(rbgen.Sphere(0.3), mass=1.0, positions=[(1, 0.5, 0)])
    world.add_bodies(chair(0.5), mass=1.0, positions=[(-1, 0.6, 0)])
    for _ in range(3):
        world.step(1 / 60)
    manifest = export_world(world, tmp_path)
    templates = {e["template"] for e in manifest["files"]}
    assert {
        "pipeline/midphase/triangles.cl.mako",
        "pipeline/midphase/children.cl.mako",
        "pipeline/narrowphase/triangles.cl.mako",
    } <= templates
    for entry in manifest["files"]:
        cl.Program(runtime.context, (tmp_path / entry["file"]).read_text()).build(
            options=entry["build_options"]
        )
    header = (tmp_path / "rbgen_layouts.h").read_text()
    assert "BvhNode" in header and "MeshTriangle" in header and "CompoundChild" in header
    assert json.loads((tmp_path / "manifest.json").read_text())["files"]
