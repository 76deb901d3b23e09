"""Triangle pair kernels (sphere, capsule, box and hull against one mesh triangle) against
float64 references, on every device.

Random triangles (each its own, so every edge is open, hence active) and random shapes
near them, about half touching, margin 0:

* sphere: the triangle's closest point to the centre (float64, Ericson's regions): same
  contact decision, separation = distance - radius, normal along the closest points,
  the point on the sphere;
* capsule: the segment-triangle distance (float64: ends against the triangle, the
  segment against each edge, a crossing): same decision, the deepest point's separation
  = distance - radius and on the capsule's surface, no point outside the capsule
  (crossings, whose depth is not a distance, only touch);
* box and hull: `reference.sat` with the triangle as a two-sided polygon (normals n and
  -n, its three edges): same decision, normal = the reference axis (within 1e-3 rad), no
  point deeper than the reference depth, every point on the shape's surface.
  Pairs whose two best axes are within 3e-4 are skipped for the axis (either is right).

Pairs whose separation is within 1e-4 of 0 are skipped (a float32 coin toss). Then the
internal edges: on a flat square of two triangles (its diagonal inactive) each shape
over the seam gets the face normal from both triangles, and a sharp convex ridge keeps
its tilted normals.
"""

from __future__ import annotations

import numpy as np
import pytest

import rbgen
from rbgen import layouts
from rbgen.pipeline.narrowphase import Narrowphase, find_contacts
from rbgen.shapes import Box, Capsule, ConvexHull, ShapeTable, Sphere

from .reference import Placed, make_bodies, quat_matrix, random_quaternions, sat

UNDECIDED = 1e-4
TIE = 3e-4


def random_triangles(rng, n: int) -> np.ndarray:
    """(n, 3, 3) random triangles about the origin (a mesh may hold overlapping triangles:
    a pair names its own), none thin."""
    out = []
    while len(out) < n:
        t = rng.uniform(-1.5, 1.5, (3, 3))
        n_ = np.cross(t[1] - t[0], t[2] - t[0])
        longest = max(
            np.linalg.norm(t[1] - t[0]), np.linalg.norm(t[2] - t[1]), np.linalg.norm(t[0] - t[2])
        )
        if np.linalg.norm(n_) / longest > 0.3 * longest:
            out.append(t)
    return np.array(out)


def inside_prism(t: np.ndarray, p: np.ndarray) -> float:
    """How far p's projection on triangle t's plane lies inside it (< 0: beside it),
    in float64."""
    normal = np.cross(t[1] - t[0], t[2] - t[0])
    normal /= np.linalg.norm(normal)
    return min(
        float(np.cross(normal, t[(k + 1) % 3] - t[k]) @ (p - t[k]))
        / np.linalg.norm(t[(k + 1) % 3] - t[k])
        for k in range(3)
    )


def triangle_world(rng, n: int, shapes: list):
    """A mesh of n separate random triangles (body 0) and one body per triangle, of a
    random shape of ``shapes``, placed about its triangle (half of them touching)."""
    triangles = random_triangles(rng, n)
    mesh = rbgen.TriangleMesh(triangles.reshape(-1, 3), np.arange(3 * n).reshape(n, 3))
    table = ShapeTable()
    index = [table.add(mesh)] + [table.add(s) for s in shapes]
    stored = mesh.vertices.astype(np.float64)[mesh.triangles]  # in the mesh's order
    body_shapes = rng.integers(1, len(index), n)
    w = rng.dirichlet(np.ones(3), n)
    on = np.einsum("tk,tkd->td", w, stored)
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    radius = np.array([0.0] + [s.bounding_radius() for s in shapes])[body_shapes]
    position = on + direction * (radius * rng.uniform(0.2, 1.3, n))[:, None]
    bodies = make_bodies(
        [0] + [index[k] for k in body_shapes],
        np.concatenate([[np.zeros(3)], position]),
        np.concatenate([[[0, 0, 0, 1]], random_quaternions(rng, n)]),
    )
    bodies["inv_mass"][0] = 0.0
    pairs = layouts.PAIR.zeros(n)
    pairs["a"], pairs["b"], pairs["sub"] = 0, np.arange(1, n + 1), np.arange(1, n + 1)
    return mesh, table, bodies, pairs, stored, [shapes[k - 1] for k in body_shapes]


def closest_on_triangle(t: np.ndarray, p: np.ndarray) -> np.ndarray:
    """float64 closest point of triangle t (3, 3) to p (Ericson 5.1.5)."""
    a, b, c = t
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab @ ap, ac @ ap
    if d1 <= 0 and d2 <= 0:
        return a
    bp = p - b
    d3, d4 = ab @ bp, ac @ bp
    if d3 >= 0 and d4 <= d3:
        return b
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        return a + ab * d1 / (d1 - d3)
    cp = p - c
    d5, d6 = ab @ cp, ac @ cp
    if d6 >= 0 and d5 <= d6:
        return c
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        return a + ac * d2 / (d2 - d6)
    va = d3 * d6 - d5 * d4
    if va <= 0 and d4 - d3 >= 0 and d5 - d6 >= 0:
        return b + (c - b) * (d4 - d3) / ((d4 - d3) + (d5 - d6))
    s = 1.0 / (va + vb + vc)
    return a + ab * vb * s + ac * vc * s


def closest_on_segment(s0, s1, x):
    """float64 closest point of the segment [s0, s1] to x."""
    d = s1 - s0
    return s0 + d * np.clip((x - s0) @ d / (d @ d), 0, 1) if d @ d > 0 else s0


def closest_segments(p0, p1, q0, q1):
    """float64 closest points of two segments (Ericson 5.1.9; p0 != p1, q0 != q1 or
    the point cases below)."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    if a == 0:
        return p0, closest_on_segment(q0, q1, p0)
    if e == 0:
        return closest_on_segment(p0, p1, q0), q0
    c, b = d1 @ r, d1 @ d2
    denom = a * e - b * b
    s = np.clip((b * f - c * e) / denom, 0, 1) if denom > 1e-12 else 0.0
    t = (b * s + f) / e
    if t < 0:
        t, s = 0.0, np.clip(-c / a, 0, 1)
    elif t > 1:
        t, s = 1.0, np.clip((b - c) / a, 0, 1)
    return p0 + d1 * s, q0 + d2 * t


def segment_triangle_distance(t, s0, s1):
    """(distance, point on segment, point on triangle), float64."""
    n = np.cross(t[1] - t[0], t[2] - t[0])
    h0, h1 = n @ (s0 - t[0]), n @ (s1 - t[0])
    if (h0 <= 0) != (h1 <= 0):
        hit = s0 + (s1 - s0) * h0 / (h0 - h1)
        p = closest_on_triangle(t, hit)
        if np.linalg.norm(p - hit) < 1e-12:
            return 0.0, hit, hit
    best = (np.inf, s0, s0)
    for end in (s0, s1):
        p = closest_on_triangle(t, end)
        best = min(best, (np.linalg.norm(p - end), end, p), key=lambda x: x[0])
    for k in range(3):
        p, q = closest_segments(s0, s1, t[k], t[(k + 1) % 3])
        best = min(best, (np.linalg.norm(p - q), p, q), key=lambda x: x[0])
    return best


def contacts_by_body(runtime, table, bodies, pairs):
    found = find_contacts(runtime, table, bodies, pairs)
    assert np.all(found["body_a"] == 0)
    return {int(m["body_b"]): m for m in found}


def test_sphere_triangle_matches_reference(runtime, rng):
    """Sphere: closest point, distance - radius, normal along the closest points."""
    n = 600
    mesh, table, bodies, pairs, stored, shapes = triangle_world(
        rng, n, [Sphere(r) for r in (0.3, 0.7, 1.1)]
    )
    found = contacts_by_body(runtime, table, bodies, pairs)
    checked = 0
    for i in range(n):
        c = bodies["position"][i + 1, :3].astype(np.float64)
        p = closest_on_triangle(stored[i], c)
        distance = np.linalg.norm(c - p)
        separation = distance - shapes[i].radius
        if abs(separation) < UNDECIDED:
            continue
        assert (i + 1 in found) == (separation <= 0), (i, separation)
        if i + 1 not in found or distance < 1e-3:
            continue
        m = found[i + 1]
        normal = (c - p) / distance  # from the mesh (body a) to the sphere
        assert m["point_count"] == 1
        np.testing.assert_allclose(m["normal"][:3], normal, atol=2e-4)
        assert m["points"][0, 3] == pytest.approx(separation, abs=2e-5)
        np.testing.assert_allclose(m["points"][0, :3], c - normal * shapes[i].radius, atol=5e-5)
        assert m["sub"] == i + 1
        checked += 1
    assert checked > n // 5


def test_capsule_triangle_matches_reference(runtime, rng):
    """Capsule: the deepest point at distance - radius, the normal along the closest
    points (or the face's, for a face contact), points on the capsule."""
    n = 600
    mesh, table, bodies, pairs, stored, shapes = triangle_world(
        rng, n, [Capsule(0.2, 0.5), Capsule(0.5, 0.3), Capsule(0.3, 0.0)]
    )
    found = contacts_by_body(runtime, table, bodies, pairs)
    checked = 0
    for i in range(n):
        capsule = shapes[i]
        r = quat_matrix(bodies["orientation"][i + 1])
        c = bodies["position"][i + 1, :3].astype(np.float64)
        s0, s1 = c - r[:, 1] * capsule.half_height, c + r[:, 1] * capsule.half_height
        distance, on_segment, on_triangle = segment_triangle_distance(stored[i], s0, s1)
        separation = distance - capsule.radius
        if abs(separation) < UNDECIDED:
            continue
        assert (i + 1 in found) == (separation <= 0), (i, separation)
        if i + 1 not in found or distance < 1e-3:
            continue
        m = found[i + 1]
        points = m["points"][: m["point_count"]]
        assert points[:, 3].min() == pytest.approx(separation, abs=5e-5)
        normal = (on_segment - on_triangle) / distance
        face = np.cross(stored[i][1] - stored[i][0], stored[i][2] - stored[i][0])
        face /= np.linalg.norm(face)
        along = abs(normal @ face)
        if along < 1 - 1e-4:  # an edge or vertex contact: the closest-point direction
            np.testing.assert_allclose(m["normal"][:3], normal, atol=5e-4)
        else:
            assert abs(m["normal"][:3] @ face) > 1 - 1e-4
        # the points are on the capsule (body b) below its segment along the normal: the
        # deepest on its surface, none outside it
        reach = [
            np.linalg.norm(p[:3] - closest_on_segment(s0, s1, p[:3].astype(np.float64)))
            for p in points
        ]
        assert max(reach) <= capsule.radius + 1e-4
        assert reach[int(np.argmin(points[:, 3]))] == pytest.approx(capsule.radius, abs=1e-4)
        checked += 1
    assert checked > n // 5


@pytest.mark.parametrize("kind", ["box", "hull"])
def test_convex_triangle_matches_reference(runtime, rng, kind):
    """Box or hull: the separating-axis answer with the triangle as a two-sided polygon,
    except that a penetrating axis pushing the shape through the triangle, away from the
    side its centre is on, while the centre lies over the triangle, gives way to the
    triangle's normal facing the centre (a separating axis, or a shape beside the
    triangle, keeps the answer: `test_a_hull_beside_a_convex_fold_keeps_its_gap`)."""
    n = 500
    shapes = (
        [Box(rng.uniform(0.2, 0.9, 3)) for _ in range(3)]
        if kind == "box"
        else [
            ConvexHull(
                rng.normal(size=(int(rng.integers(8, 20)), 3)) * rng.uniform(0.3, 0.9, 3),
                name=f"random hull {k}",
            )
            for k in range(3)
        ]
    )
    mesh, table, bodies, pairs, stored, body_shapes = triangle_world(rng, n, shapes)
    assert f"{kind}_triangle" in Narrowphase(runtime, table).kinds
    found = contacts_by_body(runtime, table, bodies, pairs)
    checked = turned = 0
    for i in range(n):
        t = stored[i]
        normal = np.cross(t[1] - t[0], t[2] - t[0])
        normal /= np.linalg.norm(normal)
        triangle = Placed(t, np.array([normal, -normal]), t[[1, 2, 0]] - t)
        shape = Placed.of(
            body_shapes[i], bodies["position"][i + 1, :3], bodies["orientation"][i + 1]
        )
        answer = sat(shape, triangle)
        if abs(answer.separation) < UNDECIDED:
            continue
        # the centre's side; the axis runs from the shape to the triangle
        height = normal @ (bodies["position"][i + 1, :3] - t[0])
        facing = normal if height >= 0 else -normal
        through = answer.axis @ facing
        over = inside_prism(t, bodies["position"][i + 1, :3])
        if abs(height) < 1e-4 or abs(through) < 1e-4 or abs(over) < 1e-4:
            continue  # (a float32 coin toss)
        axis, separation = answer.axis, answer.separation
        if through > 0 and answer.separation < 0 and over > 0:
            axis = -facing
            separation = float((t @ axis).min() - (shape.vertices @ axis).max())
        assert (i + 1 in found) == (answer.separation <= 0), (i, answer.separation)
        if i + 1 not in found:
            continue
        m = found[i + 1]
        points = m["points"][: m["point_count"]]
        assert 1 <= len(points) <= 4
        assert np.all(points[:, 3] >= separation - 1e-4) and np.all(points[:, 3] <= 1e-6)
        # (a tie may pick either axis, one that pushes through or one that does not)
        if (
            answer.runner_up < answer.separation - TIE
            and abs(answer.best_face - answer.best_edge) > TIE
        ):
            # the manifold's normal runs from the mesh (a) to the shape (b)
            angle = np.arccos(np.clip(-m["normal"][:3] @ axis, -1, 1))
            assert angle < 1e-3, (i, m["normal"][:3], axis)
            turned += through > 0
        # every point lies on the shape's surface (body b's, by convention)
        cooked = body_shapes[i].cooked()
        rotation = quat_matrix(bodies["orientation"][i + 1])
        local = (points[:, :3] - bodies["position"][i + 1, :3]) @ rotation
        outside = (local @ cooked.planes[:, :3].T - cooked.planes[:, 3]).max(axis=1)
        np.testing.assert_allclose(outside, 0.0, atol=1e-4)
        checked += 1
    assert checked > n // 5 and turned > 0, (checked, turned)


# --------------------------------------------------------------- internal edges


def flat_square(size: float = 2.0):
    """Two triangles making the square [0, size]^2 at y = 0; the diagonal from (size, 0, 0)
    to (0, 0, size) is shared (inactive), the four sides open (active)."""
    v = np.array([[0, 0, 0], [0, 0, size], [size, 0, 0], [size, 0, size]], float)
    return rbgen.TriangleMesh(v, np.array([[0, 1, 2], [2, 1, 3]]))


@pytest.mark.parametrize(
    "shape,orientation",
    [
        (Sphere(0.5), (0, 0, 0, 1)),
        (Capsule(0.25, 0.4), (0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4))),
        (Box((0.4, 0.25, 0.3)), (0, np.sin(0.3), 0, np.cos(0.3))),
    ],
)
def test_no_bump_over_an_inactive_edge(runtime, shape, orientation):
    """A shape pressed 1 cm into a flat square right over its diagonal: both triangles
    give the face normal (+y) and a separation of -1 cm, none a tilted normal."""
    mesh = flat_square()
    assert sorted(mesh.active_edges.tolist()) == [5, 6]  # one edge inactive in each
    table = ShapeTable()
    index = [table.add(mesh), table.add(shape)]
    bottom = (
        -min((shape.local_vertices() @ quat_matrix(orientation).T)[:, 1])
        if isinstance(shape, Box)
        else (shape.radius if isinstance(shape, Sphere) else shape.radius)
    )
    centre = np.array([1.05, bottom - 0.01, 0.98])  # near the diagonal x + z = 2
    bodies = make_bodies(index, [np.zeros(3), centre], [(0, 0, 0, 1), orientation])
    pairs = layouts.PAIR.zeros(2)
    pairs["a"], pairs["b"], pairs["sub"] = 0, 1, [1, 2]
    found = find_contacts(runtime, table, bodies, pairs)
    assert len(found) == 2
    for m in found:
        np.testing.assert_allclose(m["normal"][:3], (0, 1, 0), atol=1e-5)
        points = m["points"][: m["point_count"]]
        assert points[:, 3].min() == pytest.approx(-0.01, abs=1e-4)


def test_a_sharp_ridge_keeps_its_edge_normal(runtime):
    """A 90-degree convex ridge (active edge): a sphere resting on the ridge line gets
    the normal from the ridge to its centre, not a face normal."""
    v = np.array([[-1, 0, 0], [0, 1, 0], [1, 0, 0], [-1, 0, 2], [0, 1, 2], [1, 0, 2]], float)
    mesh = rbgen.TriangleMesh(v, np.array([[0, 3, 1], [1, 3, 4], [1, 4, 2], [2, 4, 5]]))
    ridge = np.flatnonzero([{1, 4} <= set(t) for t in mesh.triangles.tolist()])
    table = ShapeTable()
    index = [table.add(mesh), table.add(Sphere(0.5))]
    bodies = make_bodies(index, [np.zeros(3), (0.0, 1.49, 1.0)])
    pairs = layouts.PAIR.zeros(len(ridge))
    pairs["a"], pairs["b"], pairs["sub"] = 0, 1, ridge + 1
    found = find_contacts(runtime, table, bodies, pairs)
    assert len(found) == len(ridge) == 2
    for m in found:
        np.testing.assert_allclose(m["normal"][:3], (0, 1, 0), atol=1e-5)
        assert m["points"][0, 3] == pytest.approx(-0.01, abs=1e-5)


@pytest.mark.parametrize("kind", ["box", "hull"])
@pytest.mark.parametrize("gap", [0.02, -0.005])
def test_a_hull_beside_a_convex_fold_keeps_its_gap(runtime, kind, gap):
    """A box (or the same box as a hull) lying on a slope that falls away 15 degrees
    from a flat plateau (a convex, active fold), its side ``gap`` from the fold line
    (sunk by as much where the gap is negative). Its centre lies above the plateau's
    plane but beside the plateau, and the slope runs under that plane extended: the
    plateau's contacts, if any, are as deep as the true overlap (gap, if < 0), never the
    depth below the plane extended (16 cm), which kicked a resting hull up by decimetres
    on a terrain."""
    slope = np.radians(15.0)
    c, s = np.cos(slope), np.sin(slope)
    v = np.array(
        [[-2, 0, 0], [-2, 0, 2], [0, 0, 0], [0, 0, 2], [2, -2 * s / c, 0], [2, -2 * s / c, 2]],
        float,
    )
    mesh = rbgen.TriangleMesh(v, np.array([[0, 1, 2], [2, 1, 3], [2, 3, 4], [4, 3, 5]]))
    half = np.array([0.3, 0.2, 0.3])
    corners = np.array(np.meshgrid(*[(-h, h) for h in half], indexing="ij")).reshape(3, -1).T
    shape = Box(half) if kind == "box" else ConvexHull(corners, name="box hull")
    table = ShapeTable()
    index = [table.add(mesh), table.add(shape)]
    down, up = np.array([c, -s, 0.0]), np.array([s, c, 0.0])  # along and off the slope
    sink = min(gap, 0.0)
    centre = (half[0] + gap) * down + (half[1] + sink) * up + (0.0, 0.0, 1.0)
    assert centre[1] > 0.0 and centre[0] > 0.0  # above the plateau's plane, beside it
    turn = (0.0, 0.0, -np.sin(slope / 2), np.cos(slope / 2))  # lies flat on the slope
    bodies = make_bodies(index, [np.zeros(3), centre], [(0, 0, 0, 1), turn])
    pairs = layouts.PAIR.zeros(4)
    pairs["a"], pairs["b"], pairs["sub"] = 0, 1, np.arange(1, 5)
    found = find_contacts(runtime, table, bodies, pairs, margin=0.05)
    deepest = min(float(m["points"][: m["point_count"], 3].min()) for m in found)
    assert len(found) >= 2  # the slope holds the box
    assert deepest == pytest.approx(sink, abs=2e-3)


@pytest.mark.parametrize("n", [0, 1, 17])
def test_few_or_no_triangle_pairs(runtime, rng, n):
    """Lists of 0, 1 and 17 triangle pairs of every kind (fewer than a work group): as
    many manifolds as touching pairs, each keyed by its pair's sub-feature."""
    shapes = [
        Sphere(0.5),
        Capsule(0.3, 0.3),
        Box((0.4, 0.3, 0.5)),
        ConvexHull(rng.normal(size=(10, 3)) * 0.4, name="pebble"),
    ]
    mesh, table, bodies, pairs, stored, body_shapes = triangle_world(rng, max(n, 1), shapes)
    found = find_contacts(runtime, table, bodies, pairs[:n])
    assert len(found) <= n
    assert set(found["sub"].tolist()) <= set(pairs[:n]["sub"].tolist())
    assert np.array_equal(found["sub"] - 1, found["body_b"] - 1)
