"""The midphase (`rbgen.pipeline.midphase`) against brute force, on every device.

Triangles: on fresh random height fields and random boxes and spheres (random sizes and
orientations) the output equals `midphase_reference.brute_force` pair for pair: every
body box against every triangle box, in pair order then triangle order, other pairs
copied; for both traversals over their tunable values, over boundary counts of input
pairs (0, 1, 31, 32, 33, 1000: not multiples of the work-group size) and with an output
capacity far too small (every output grows, nothing is lost). Compounds: the children
pairs equal the brute force over the placed children's boxes, and the placed children
sit where the compound's pose times the child's puts them. In a World, a pile on a
dense mesh overflows the candidate buffer: the step is redone and the candidates of the
step equal brute force.
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cla
import pytest

import rbgen
from rbgen import layouts
from rbgen.pipeline import midphase_reference as reference
from rbgen.pipeline.aabbs import WorldAabbs
from rbgen.pipeline.midphase import TRIANGLES, Midphase, default_params, search_space
from rbgen.shapes import ShapeTable

from ..reference import quat_mul, quat_to_matrix

COUNTS = [0, 1, 31, 32, 33, 1000]
PARAMS = [
    {"work_group_size": 16, "traversal": "global", "subtree_nodes": 0},
    {"work_group_size": 64, "traversal": "global", "subtree_nodes": 0},
    {"work_group_size": 16, "traversal": "local", "subtree_nodes": 16},
    {"work_group_size": 32, "traversal": "local", "subtree_nodes": 128},
    {"work_group_size": 64, "traversal": "local", "subtree_nodes": 512},
]


def mesh_scene(runtime, rng, count: int, cells: int = 24):
    """A random height field (body 0) and ``count`` random boxes and spheres around it,
    with their world AABBs on the device."""
    mesh = rbgen.TriangleMesh(*reference.terrain(cells, rng.uniform(0.5, 2.0), rng))
    table = ShapeTable()
    table.add(mesh)
    shapes = [table.add(rbgen.Box(rng.uniform(0.1, 1.0, 3))) for _ in range(3)]
    shapes += [table.add(rbgen.Sphere(rng.uniform(0.1, 1.5))) for _ in range(2)]
    host = reference.bodies_above(count, mesh, shapes[0], rng)
    host["shape"][1:] = rng.choice(shapes, count)
    q = runtime.queue
    packed = table.pack_all().to_device(q)
    bodies = cla.to_device(q, host)
    aabbs = cla.empty(q, len(host), layouts.AABB.dtype)
    margin = float(rng.uniform(0, 0.05))
    WorldAabbs(runtime, table.type_names())(
        bodies, packed.shapes, packed.vertices, aabbs, len(host), margin
    )
    return mesh, table, host, packed, bodies, aabbs


def mesh_pairs(rng, count: int, with_others: bool) -> np.ndarray:
    """Pairs of the mesh (body 0) with each body, and (``with_others``) some pairs of
    bodies without a mesh between them, sorted as the broadphase sorts."""
    pairs = [(0, b) for b in range(1, count + 1)]
    if with_others and count > 1:
        for a in rng.choice(np.arange(1, count), min(count - 1, 20), replace=False):
            pairs.append((int(a), int(a) + 1))
    pairs.sort()
    records = layouts.PAIR.zeros(len(pairs))
    if pairs:
        records["a"], records["b"] = np.array(pairs).T
    return records


@pytest.mark.parametrize("count", COUNTS)
@pytest.mark.parametrize(
    "params", PARAMS, ids=lambda p: f"{p['traversal']}-{p['work_group_size']}-{p['subtree_nodes']}"
)
def test_triangle_candidates_equal_brute_force(runtime, rng, params, count):
    """Both traversals, every tunable point: the output equals brute force, pair order
    then triangle order, pairs without a mesh copied; the output starts at 16 pairs and
    grows to fit (status word = the size needed)."""
    mesh, table, host, packed, bodies, aabbs = mesh_scene(runtime, rng, count)
    pairs = mesh_pairs(rng, count, with_others=True)
    padded = layouts.PAIR.zeros(max(1, len(pairs)) + 5)  # a list longer than its count
    padded[: len(pairs)] = pairs
    midphase = Midphase(runtime, table, params=params, capacity=16)
    found = midphase.find_pairs(
        bodies, len(host), packed, aabbs, cla.to_device(runtime.queue, padded), len(pairs)
    )
    expected = reference.brute_force(mesh, host, aabbs.get(), pairs)
    assert len(found) == len(expected)
    np.testing.assert_array_equal(found, expected)
    if len(expected) > 16:
        assert midphase.triangles.capacity >= len(expected)


def test_device_counts_and_no_blocking_read(runtime, rng):
    """`enqueue` reads nothing back: counts stay on the device, the status word says
    what an overflowed output needs, the count is then the pairs stored (the capacity: a
    count past it had the narrowphase's kernels write past their buffers), and growing it
    makes the redo complete."""
    mesh, table, host, packed, bodies, aabbs = mesh_scene(runtime, rng, 200)
    pairs = mesh_pairs(rng, 200, with_others=False)
    d_pairs = cla.to_device(runtime.queue, pairs)
    count = cla.to_device(runtime.queue, np.array([len(pairs)], np.uint32))
    midphase = Midphase(runtime, table, params=default_params(runtime.traits), capacity=8)
    before = runtime.counters["blocking_reads"]
    midphase.enqueue(bodies, len(host), packed, aabbs, d_pairs, count)
    assert runtime.counters["blocking_reads"] == before
    expected = reference.brute_force(mesh, host, aabbs.get(), pairs)
    status = midphase.status.get()
    assert midphase.problem(status) == {"triangles": len(expected)}
    assert int(midphase.count.get()[0]) == 8
    np.testing.assert_array_equal(midphase.pairs.get()[:8], expected[:8])
    midphase.grow(midphase.problem(status))
    midphase.enqueue(bodies, len(host), packed, aabbs, d_pairs, count)
    assert midphase.problem(midphase.status.get()) is None
    n = int(midphase.count.get()[0])
    np.testing.assert_array_equal(midphase.pairs.get()[:n], expected)


def triangles_touch_box(corners: np.ndarray, lower, upper, slack: float) -> np.ndarray:
    """Which triangles ((T, 3, 3) world corners) intersect the box shrunk by ``slack``: the
    separating-axis test of a triangle and a box (the box's axes, the triangle's normal,
    the nine cross products of their edges), float64."""
    centre, half = 0.5 * (lower + upper), 0.5 * (upper - lower) - slack
    v = corners - centre
    edges = np.stack([v[:, 1] - v[:, 0], v[:, 2] - v[:, 1], v[:, 0] - v[:, 2]], axis=1)
    axes = [np.broadcast_to(np.eye(3)[k], (len(v), 3)) for k in range(3)]
    axes.append(np.cross(edges[:, 0], edges[:, 1]))
    axes += [np.cross(np.eye(3)[k], edges[:, j]) for k in range(3) for j in range(3)]
    touch = np.ones(len(v), bool)
    for axis in axes:
        p = np.einsum("tkd,td->tk", v, axis)
        reach = np.abs(axis) @ half
        touch &= (p.min(axis=1) <= reach) & (p.max(axis=1) >= -reach)
    return touch


def test_rotated_mesh_misses_nothing(runtime, rng):
    """A mesh body turned and moved: its walk uses the box around the rotated query box,
    so the output holds every triangle that intersects a body's AABB (float64 triangle-box
    test, shrunk by float32 rounding), and only triangles whose box in the mesh's frame
    meets that loosened box."""
    mesh = rbgen.TriangleMesh(*reference.terrain(16, 1.0, rng))
    table = ShapeTable()
    table.add(mesh)
    box = table.add(rbgen.Box((0.3, 0.2, 0.4)))
    host = reference.bodies_above(300, mesh, box, rng)
    turn = rng.normal(size=4)
    host["orientation"][0] = turn / np.linalg.norm(turn)
    host["position"][0, :3] = rng.uniform(-3, 3, 3)
    rotation = quat_to_matrix(host["orientation"][0].astype(np.float64))
    host["position"][1:, :3] = (
        host["position"][1:, :3].astype(np.float64) @ rotation.T + host["position"][0, :3]
    )
    q = runtime.queue
    packed = table.pack_all().to_device(q)
    bodies = cla.to_device(q, host)
    aabbs = cla.empty(q, len(host), layouts.AABB.dtype)
    WorldAabbs(runtime, table.type_names())(
        bodies, packed.shapes, packed.vertices, aabbs, len(host)
    )
    pairs = mesh_pairs(rng, 300, with_others=False)
    found = Midphase(runtime, table).find_pairs(
        bodies, len(host), packed, aabbs, cla.to_device(q, pairs), len(pairs)
    )
    world = mesh.vertices.astype(np.float64) @ rotation.T + host["position"][0, :3]
    corners = world[mesh.triangles]
    box_lo = aabbs.get()["lower"][:, :3].astype(np.float64)
    box_hi = aabbs.get()["upper"][:, :3].astype(np.float64)
    got = {(int(p["b"]), int(p["sub"]) - 1) for p in found}
    for body in range(1, len(host)):
        touching = triangles_touch_box(corners, box_lo[body], box_hi[body], 1e-4)
        assert {(body, int(t)) for t in np.flatnonzero(touching)} <= got
    local = mesh.vertices.astype(np.float64)[mesh.triangles]
    for body, t in got:  # the triangle's local box meets the box around the turned query
        centre = rotation.T @ (0.5 * (box_lo[body] + box_hi[body]) - host["position"][0, :3])
        half = np.abs(rotation.T) @ (0.5 * (box_hi[body] - box_lo[body]))
        assert np.all(local[t].min(axis=0) <= centre + half + 1e-3)
        assert np.all(centre - half - 1e-3 <= local[t].max(axis=0))


def compound_scene(runtime, rng, count: int):
    """Random compounds and spheres, each paired with each of a few others."""
    table = ShapeTable()
    compounds = []
    for _ in range(3):
        children = [
            (rbgen.Box(rng.uniform(0.1, 0.5, 3)), rng.uniform(-1, 1, 3), reference_quaternion(rng))
            for _ in range(int(rng.integers(1, 6)))
        ]
        children.append((rbgen.Sphere(0.3), rng.uniform(-1, 1, 3)))
        compounds.append(rbgen.Compound(children))
    indices = [table.add(c) for c in compounds] + [table.add(rbgen.Sphere(0.5))]
    host = layouts.BODY.zeros(count)
    host["shape"] = rng.choice(indices, count)
    host["position"][:, :3] = rng.uniform(-3, 3, (count, 3))
    turns = rng.normal(size=(count, 4))
    host["orientation"] = turns / np.linalg.norm(turns, axis=1, keepdims=True)
    host["inv_mass"] = 1.0
    return table, host


def reference_quaternion(rng):
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


@pytest.mark.parametrize("count", [0, 1, 2, 33, 200])
def test_compound_children_pairs_equal_brute_force(runtime, rng, count):
    """Placed children: the compound's position + R(compound) child position, orientation
    compound * child, the child's shape; their pairs: every overlapping (child, other)
    and (child, child) pair of each input pair, in pair then child order."""
    table, host = compound_scene(runtime, rng, count)
    q = runtime.queue
    packed = table.pack_all().to_device(q)
    bodies = cla.to_device(q, host if count else layouts.BODY.zeros(1))
    aabbs = cla.empty(q, max(1, count), layouts.AABB.dtype)
    WorldAabbs(runtime, table.type_names())(bodies, packed.shapes, packed.vertices, aabbs, count)
    pairs = [(a, b) for a in range(count) for b in range(a + 1, min(count, a + 4))]
    records = layouts.PAIR.zeros(max(1, len(pairs)))
    if pairs:
        records["a"], records["b"] = np.array(pairs).T
    midphase = Midphase(runtime, table, capacity=4)
    found = midphase.find_pairs(
        bodies,
        count,
        packed,
        aabbs,
        cla.to_device(q, records),
        len(pairs),
        shape_indices=host["shape"],
    )
    placed = midphase.placed_bodies.get()[: count + midphase.proxy_count]
    boxes = midphase.placed_aabbs.get()[: count + midphase.proxy_count]
    proxies = midphase.proxies.get()[: midphase.proxy_count]
    # the placed children
    for k, proxy in enumerate(proxies):
        body, child = host[proxy["body"]], proxy["child"]
        compound = table.shapes[body["shape"]]
        rotation = quat_to_matrix(body["orientation"].astype(np.float64))
        expected_position = body["position"][:3] + rotation @ compound.positions[child]
        np.testing.assert_allclose(placed[count + k]["position"][:3], expected_position, atol=2e-5)
        expected_q = quat_mul(body["orientation"].astype(np.float64), compound.orientations[child])
        assert abs(abs(np.dot(placed[count + k]["orientation"], expected_q)) - 1) < 1e-5
        assert placed[count + k]["shape"] == table.index_of(compound.children[child])
    # the pairs
    first = {}
    for k, proxy in enumerate(proxies):
        first.setdefault(int(proxy["body"]), count + k)

    def parts(body):
        shape = table.shapes[host["shape"][body]]
        n = len(shape.children) if isinstance(shape, rbgen.Compound) else 0
        return [first[body] + c for c in range(n)] if n else None

    def overlap(i, j):
        return bool(
            np.all(boxes["lower"][i, :3] <= boxes["upper"][j, :3])
            and np.all(boxes["lower"][j, :3] <= boxes["upper"][i, :3])
        )

    expected = []
    for a, b in pairs:
        pa, pb = parts(a), parts(b)
        if pa is None and pb is None:
            expected.append((a, b, 0))
            continue
        expected += [(i, j, 0) for i in (pa or [a]) for j in (pb or [b]) if overlap(i, j)]
    assert [tuple(int(v) for v in p) for p in found] == expected


def test_world_pile_overflows_and_loses_nothing(runtime, rng):
    """A pile of boxes on a dense mesh: the candidate buffer (its first size far too
    small) overflows, the World grows it and redoes the step, and the candidates of the
    last step equal brute force on that step's AABBs and pairs."""
    world = rbgen.World(runtime)
    vertices, triangles = reference.terrain(40, 0.25, rng, roughness=0.02)
    mesh = rbgen.TriangleMesh(vertices, triangles)
    world.add_static(mesh)
    grid = np.stack(
        np.meshgrid(np.arange(1, 9) * 1.1, [0.5, 1.6, 2.7], np.arange(1, 9) * 1.1, indexing="ij"),
        -1,
    ).reshape(-1, 3)
    world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), mass=1.0, positions=grid)
    world.step(1 / 60)
    stage = world._pipeline["midphase"]
    stage.midphase.triangles.capacity = 0
    stage.midphase.triangles.grow(32)
    before = world.overflows
    for _ in range(3):
        world.step(1 / 60)
    world.statistics()  # (waits for every step)
    assert world.overflows > before
    bp = world._pipeline.broadphase.broadphase
    pairs = bp.pairs.get()[: int(bp.count.get()[0])]
    aabbs = world._pipeline.prepare.aabbs.get()
    mp = stage.midphase
    found = mp.pairs.get()[: int(mp.count.get()[0])]
    host = world._bodies.host  # (the mesh never moves; its pose is all brute force reads)
    expected = reference.brute_force({0: mesh}, host, aabbs, pairs)
    assert len(expected) > 32
    np.testing.assert_array_equal(found, expected)


def test_parameters_are_checked_and_the_space_is_valid(runtime):
    """Every point of the tuner's space is a valid specialisation with the heuristic
    default first; a local walk needs a subtree size, a global one none."""
    space = search_space(runtime.traits)
    assert space[0] == default_params(runtime.traits)
    for params in space:
        TRIANGLES.spec(**params)
    with pytest.raises(rbgen.TemplateParameterError, match="subtree_nodes > 0"):
        TRIANGLES.spec(work_group_size=16, traversal="local", subtree_nodes=0)
    with pytest.raises(rbgen.TemplateParameterError, match="must be 0"):
        TRIANGLES.spec(work_group_size=16, traversal="global", subtree_nodes=64)


def test_the_tuner_times_both_traversals_and_the_midphase_uses_its_winner(
    runtime, tmp_path, monkeypatch
):
    """`rbgen tune`'s family "midphase" runs its candidates on a terrain and checks each
    against brute force; the winner it stores is what a Midphase then uses (an untuned
    device gets the heuristic)."""
    from rbgen import tuning
    from rbgen.pipeline import midphase as module

    monkeypatch.setenv("RBGEN_CACHE_DIR", str(tmp_path))
    tuning.forget_loaded()
    table = ShapeTable()
    table.add(rbgen.TriangleMesh(*reference.terrain(4, 1.0, np.random.default_rng(0))))
    assert Midphase(runtime, table).params_for(300) == default_params(runtime.traits)
    candidates = [
        {"work_group_size": 16, "traversal": "global", "subtree_nodes": 0},
        {"work_group_size": 16, "traversal": "local", "subtree_nodes": 64},
    ]
    monkeypatch.setattr(module, "search_space", lambda traits: candidates)
    entry = tuning.tune(runtime, "midphase", "triangles", 300, repeats=2)
    winner = {k: v for k, v in entry["params"].items() if k != "shape"}
    assert winner in candidates and entry["params"]["shape"] == winner["traversal"]
    tuning.forget_loaded()
    assert Midphase(runtime, table).params_for(300) == winner
    tuning.forget_loaded()


@pytest.mark.parametrize("params", PARAMS[::2], ids=lambda p: p["traversal"])
def test_two_meshes_share_a_work_group(runtime, rng, params):
    """Two meshes of different sizes (their nodes and triangles at different offsets of
    the shared arrays), each paired with every body, the pairs interleaved so that a work
    group walks both: the output equals brute force over each pair's own mesh."""
    meshes = [rbgen.TriangleMesh(*reference.terrain(cells, 1.0, rng)) for cells in (7, 13)]
    table = ShapeTable()
    for mesh in meshes:
        table.add(mesh)
    shapes = [table.add(rbgen.Box(rng.uniform(0.2, 0.8, 3))), table.add(rbgen.Sphere(0.6))]
    count = 97
    host = reference.bodies_above(count + 1, meshes[1], shapes[0], rng)
    host["shape"][:2] = [0, 1]
    host["inv_mass"][:2] = 0.0
    host["orientation"][:2] = (0, 0, 0, 1)
    host["position"][:2] = 0.0
    host["shape"][2:] = rng.choice(shapes, count)
    q = runtime.queue
    packed = table.pack_all().to_device(q)
    bodies = cla.to_device(q, host)
    aabbs = cla.empty(q, len(host), layouts.AABB.dtype)
    WorldAabbs(runtime, table.type_names())(
        bodies, packed.shapes, packed.vertices, aabbs, len(host)
    )
    pairs = layouts.PAIR.zeros(2 * count)
    pairs["a"] = np.tile([0, 1], count)
    pairs["b"] = np.repeat(np.arange(2, count + 2), 2)
    found = Midphase(runtime, table, params=params, capacity=8).find_pairs(
        bodies, len(host), packed, aabbs, cla.to_device(q, pairs), len(pairs)
    )
    expected = reference.brute_force({0: meshes[0], 1: meshes[1]}, host, aabbs.get(), pairs)
    np.testing.assert_array_equal(found, expected)
