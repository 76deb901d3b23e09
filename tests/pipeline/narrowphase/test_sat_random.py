"""Randomised cross-check of the convex separating-axis stage against `reference.sat`.

Thousands of random box-box, box-hull and hull-hull pairs (random sizes,
orientations and offsets, about half of them overlapping), margin 0:

* same contact / no-contact decision;
* for overlapping pairs, the axis within 1e-3 rad of the reference's and the
  penetration depth within 1e-4 relative (+ 4e-6 absolute: float32 rounding
  of coordinates of magnitude ~4);
* the manifold's normal is that axis, no point is deeper than the depth, and
  every point lies on B's surface (the ContactManifold convention).

Skipped, by design (documented): pairs whose separation is within 1e-4 of
zero (the float32 decision is a coin toss), and for the axis/depth checks,
pairs whose best and second-best non-parallel axes are within 3e-4, or whose
best face axis and best edge axis are (the kernel prefers faces of A, then of
B, then edges, by 1e-4: a tie may legitimately pick either axis); box-box pairs with
an edge axis within float32 rounding of the kernel's face-aligned limits.
"""

from __future__ import annotations

import re

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen import layouts
from rbgen.codegen import TEMPLATE_DIR
from rbgen.pipeline.narrowphase import Narrowphase
from rbgen.shapes import Box, ConvexHull, ShapeTable, Sphere

from .reference import (
    Placed,
    axis_angle,
    make_bodies,
    quat_matrix,
    random_quaternions,
    sat,
)

TIE = 3e-4
UNDECIDED = 1e-4
#: float32 rounding of coordinates of magnitude ~4 (positions within +-2, sizes ~1)
FLOAT32_ABS = 4e-6


def _box_box_define(name: str) -> float:
    """A constant of the box-box kernel (its face-aligned rule), read from its template."""
    source = (TEMPLATE_DIR / "pipeline/narrowphase/sat_box_box.cl.mako").read_text()
    return float(re.search(rf"#define {name} ([0-9.e+-]+)f", source).group(1))


#: the box-box kernel drops an edge-pair axis within this angle of a face normal when
#: that face is at most FACE_ALIGNED_TOLERANCE deeper (and the edge axis does not
#: separate where the face does not)
FACE_ALIGNED_DEG = float(np.degrees(np.arccos(np.sqrt(_box_box_define("FACE_ALIGNED_COS2")))))
FACE_ALIGNED_TOLERANCE = _box_box_define("FACE_ALIGNED_TOLERANCE")


def random_world(rng, kind: str, n: int, boxes_as_hulls: bool = False):
    """n random pairs of one kind; ``boxes_as_hulls``: the boxes are ConvexHulls of their
    corners (the generic hull-hull test on box geometry)."""
    table = ShapeTable()
    box = (
        (lambda he: ConvexHull(Box(he).local_vertices(), name="box hull"))
        if boxes_as_hulls
        else Box
    )
    boxes = [table.add(box(rng.uniform(0.2, 1.2, 3))) for _ in range(6)]
    hulls = (
        [
            table.add(
                ConvexHull(
                    rng.normal(size=(int(rng.integers(8, 20)), 3)) * rng.uniform(0.3, 1.0, 3),
                    name=f"random hull {k}",
                )
            )
            for k in range(4)
        ]
        if kind != "box_box"
        else []
    )
    first = boxes if kind.startswith("box") else hulls
    second = hulls if kind.endswith("hull") else boxes
    shape_a = rng.choice(first, n)
    shape_b = rng.choice(second, n)
    radius = np.array([np.linalg.norm(s.local_vertices(), axis=1).max() for s in table.shapes])
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    distance = rng.uniform(0.3, 1.0, n) * (radius[shape_a] + radius[shape_b])
    pa = rng.uniform(-2, 2, (n, 3))
    pb = pa + direction * distance[:, None]
    shapes = np.column_stack([shape_a, shape_b]).reshape(-1)
    positions = np.stack([pa, pb], axis=1).reshape(-1, 3)
    bodies = make_bodies(shapes, positions, random_quaternions(rng, 2 * n))
    pairs = layouts.PAIR.zeros(n)
    pairs["a"], pairs["b"] = np.arange(0, 2 * n, 2), np.arange(1, 2 * n, 2)
    return table, bodies, pairs


@pytest.mark.parametrize(
    "kind,n,boxes_as_hulls",
    [
        ("box_box", 2001, False),
        ("box_box", 300, True),
        ("box_hull", 700, False),
        ("hull_hull", 700, False),
    ],
)
def test_sat_matches_reference(runtime, rng, kind, n, boxes_as_hulls):
    """box_box: the closed-form box-box kernel (which takes no edge-pair axis within 1
    degree of a face normal); box_hull: the generic test with closed-form box projection
    and the box's edge directions; hull_hull: the generic test with Gauss-map edge pairs,
    also on boxes cooked as hulls (``boxes_as_hulls``)."""
    closed_form = kind == "box_box" and not boxes_as_hulls
    table, bodies, pairs = random_world(rng, kind, n, boxes_as_hulls)
    q = runtime.queue
    narrowphase = Narrowphase(runtime, table)
    assert (narrowphase.kinds == ("hull_hull",)) if boxes_as_hulls else (kind in narrowphase.kinds)
    packed = table.pack_all().to_device(q)
    d_bodies, d_pairs = cla.to_device(q, bodies), cla.to_device(q, pairs)
    manifolds = narrowphase.find_contacts(d_bodies, packed, d_pairs, n)
    count = int(narrowphase.sat_count.get()[1])
    results = narrowphase.sat_results.get()[:count]
    swapped = (results["pair"] & layouts.PAIR_SWAPPED) != 0
    index = results["pair"] & ~np.uint32(layouts.PAIR_SWAPPED)
    axis = results["axis"].astype(np.float64)
    axis[swapped, :3] *= -1  # to the pair's order, a to b
    by_pair = dict(zip(index.tolist(), axis))
    by_manifold = {int(m["body_a"]) // 2: m for m in manifolds}

    checked = skipped_ties = 0
    for i in range(n):
        a, b = 2 * i, 2 * i + 1
        ref = sat(
            Placed.of(
                table.shapes[bodies["shape"][a]],
                bodies["position"][a, :3],
                bodies["orientation"][a],
            ),
            Placed.of(
                table.shapes[bodies["shape"][b]],
                bodies["position"][b, :3],
                bodies["orientation"][b],
            ),
            face_aligned_deg=FACE_ALIGNED_DEG if closed_form else None,
            face_aligned_tolerance=FACE_ALIGNED_TOLERANCE,
        )
        if abs(ref.separation) < UNDECIDED or ref.aligned_undecided:
            continue
        touching = ref.separation <= 0
        assert (i in by_pair) == touching, f"pair {i}: reference separation {ref.separation}"
        assert (i in by_manifold) == touching, f"pair {i}: reference separation {ref.separation}"
        if not touching:
            continue
        if ref.separation - ref.runner_up < TIE or abs(ref.best_face - ref.best_edge) < TIE:
            skipped_ties += 1
            continue
        got = by_pair[i]
        angle = np.arccos(np.clip(np.dot(got[:3], ref.axis), -1, 1))
        assert angle < 1e-3, f"pair {i}: axis {got[:3]} vs reference {ref.axis}"
        assert abs(got[3] - ref.separation) <= 1e-4 * abs(ref.separation) + FLOAT32_ABS, (
            f"pair {i}: separation {got[3]} vs reference {ref.separation}"
        )
        m = by_manifold[i]
        np.testing.assert_allclose(m["normal"][:3], got[:3], atol=1e-6)
        seps = m["points"][: m["point_count"], 3]
        assert np.all(seps >= ref.separation - 1e-4) and np.all(seps <= 1e-6)
        # the points lie on B's surface: on its boundary, inside all its face planes
        shape_b = table.shapes[bodies["shape"][b]].cooked()
        local = (m["points"][: m["point_count"], :3] - bodies["position"][b, :3]) @ quat_matrix(
            bodies["orientation"][b]
        )
        height = (local @ shape_b.planes[:, :3].T - shape_b.planes[:, 3]).max(axis=1)
        assert np.all(np.abs(height) < 1e-4), f"pair {i}: points off B's surface by {height}"
        checked += 1
    assert checked > n // 10, f"only {checked} of {n} pairs checked ({skipped_ties} ties)"

    # the per-pair axis cache must not change the answer on the next call
    again = narrowphase.find_contacts(d_bodies, packed, d_pairs, n)
    np.testing.assert_array_equal(again["body_a"], manifolds["body_a"])
    np.testing.assert_allclose(again["normal"], manifolds["normal"], atol=1e-6)


def _box_pairs(runtime, half_a, half_b, positions_b, orientations_b):
    """The closed-form kernel on pairs (box A at the origin, unrotated; box B placed):
    (the reference answers without the face-aligned rule, results by pair, manifolds by
    pair)."""
    n = len(positions_b)
    table = ShapeTable()
    shape_a, shape_b = table.add(Box(half_a)), table.add(Box(half_b))
    shapes = np.tile([shape_a, shape_b], n)
    positions = np.stack([np.zeros((n, 3)), positions_b], axis=1).reshape(-1, 3)
    orientations = np.stack([np.tile([0.0, 0, 0, 1], (n, 1)), orientations_b], 1).reshape(-1, 4)
    bodies = make_bodies(shapes, positions, orientations)
    pairs = layouts.PAIR.zeros(n)
    pairs["a"], pairs["b"] = np.arange(0, 2 * n, 2), np.arange(1, 2 * n, 2)
    q = runtime.queue
    narrowphase = Narrowphase(runtime, table)
    packed = table.pack_all().to_device(q)
    d_bodies, d_pairs = cla.to_device(q, bodies), cla.to_device(q, pairs)
    manifolds = narrowphase.find_contacts(d_bodies, packed, d_pairs, n)
    count = int(narrowphase.sat_count.get()[1])
    results = narrowphase.sat_results.get()[:count]
    index = results["pair"] & ~np.uint32(layouts.PAIR_SWAPPED)
    refs = [
        sat(
            Placed.of(table.shapes[shape_a], (0, 0, 0), (0, 0, 0, 1)),
            Placed.of(table.shapes[shape_b], positions_b[i], orientations_b[i]),
        )
        for i in range(n)
    ]
    by_pair = dict(zip(index.tolist(), results))
    return refs, by_pair, {int(m["body_a"]) // 2: m for m in manifolds}


def test_box_on_box_tilted_by_a_few_mrad_gets_the_face_unless_the_edge_is_shallower(runtime, rng):
    """A box resting on another, offset 0.6-1 m and tilted by 1-4 mrad: an edge-pair axis
    along the face normal beats the face by up to about 2.5 mm. Where it beats it by more
    than the edge tolerance (1e-4) but less than FACE_ALIGNED_TOLERANCE, the kernel takes
    a face (the four-point manifold a resting box needs) at its depth; where by more than
    FACE_ALIGNED_TOLERANCE, the edge axis (the rule is no blanket filter)."""
    n = 193
    tilt = rng.uniform(1e-3, 4e-3, n)
    heading = rng.uniform(0, 2 * np.pi, n)
    axes = np.stack([np.cos(heading), np.zeros(n), np.sin(heading)], 1)
    orientations = np.array([axis_angle(a, t) for a, t in zip(axes, tilt)])
    offsets = rng.uniform(0.6, 1.0, (n, 2)) * rng.choice([-1, 1], (n, 2))
    # deep enough that all four corners of the tilted face touch
    depth = 1e-3 + 2.5 * tilt
    positions = np.column_stack([offsets[:, 0], 2 - depth, offsets[:, 1]])
    refs, by_pair, by_manifold = _box_pairs(runtime, (1, 1, 1), (1, 1, 1), positions, orientations)
    faces = edges = 0
    for i, ref in enumerate(refs):
        beats = ref.best_edge - ref.best_face
        if 2e-4 < beats < FACE_ALIGNED_TOLERANCE - 2e-4:
            assert by_pair[i]["feature"] < 12, f"pair {i}: edge axis {by_pair[i]['feature']}"
            assert abs(by_pair[i]["axis"][1]) > np.cos(tilt[i]) - 1e-6  # A's face or B's
            # (A's face unless B's is shallower by more than the kernel's face tolerance)
            gap = by_pair[i]["axis"][3]
            assert ref.best_face - 1e-4 - FLOAT32_ABS <= gap <= ref.best_face + FLOAT32_ABS
            assert by_manifold[i]["point_count"] == 4
            faces += 1
        elif beats > FACE_ALIGNED_TOLERANCE + 2e-4:
            assert by_pair[i]["feature"] >= 12, f"pair {i}: face {by_pair[i]['feature']}"
            assert by_pair[i]["axis"][3] == pytest.approx(ref.best_edge, abs=FLOAT32_ABS)
            edges += 1
    assert faces > n // 10 and edges > n // 50, f"{faces} faces, {edges} edges of {n} pairs"


def test_box_box_separating_edge_axis_near_a_face_normal_is_kept(runtime, rng):
    """A thin rod (turned 20-70 degrees about its length) tilted by 0.3-0.9 degrees,
    beyond the edge of a box: the edge-pair axis (within 1 degree of the box's top face
    normal) separates them by millimetres to centimetres; where every face axis overlaps,
    the pair is not touching."""
    n = 61
    tilt = np.radians(rng.uniform(0.3, 0.9, n))
    roll = np.radians(rng.uniform(20, 70, n))
    # rotate about the rod (x) by roll, then about z by tilt: q_z q_x
    sz, cz, sx, cx = np.sin(tilt / 2), np.cos(tilt / 2), np.sin(roll / 2), np.cos(roll / 2)
    orientations = np.column_stack([cz * sx, -sz * sx, sz * cx, cz * cx])
    overhang = rng.uniform(1.2, 1.8, n)
    # the top face's gap, t_y - 1 - sin(tilt) - 0.05 cos(tilt) (cos(roll) + sin(roll)),
    # made -1 to -5 mm
    reach = np.sin(tilt) + 0.05 * np.cos(tilt) * (np.cos(roll) + np.sin(roll))
    height = 1 + reach - rng.uniform(1e-3, 5e-3, n)
    positions = np.column_stack([-overhang, height, rng.uniform(-0.5, 0.5, n)])
    refs, by_pair, by_manifold = _box_pairs(
        runtime, (1, 1, 1), (1, 0.05, 0.05), positions, orientations
    )
    checked = 0
    for i, ref in enumerate(refs):
        if ref.best_face > -UNDECIDED or ref.separation < UNDECIDED:
            continue  # (a face separates them too, or the edge axis does not)
        assert i not in by_pair and i not in by_manifold, f"pair {i}: apart by {ref.separation}"
        checked += 1
    assert checked > n // 4, f"only {checked} of {n} pairs apart along the edge axis alone"


@pytest.mark.parametrize("boxes_as_hulls", [False, True])
@pytest.mark.parametrize("work_group_size,placement_tile", [(None, None), (64, 256), (1, 1)])
def test_one_kind_reads_the_pair_list_directly(
    runtime, rng, boxes_as_hulls, work_group_size, placement_tile
):
    """A world of boxes only (or hulls only) has one kind: its separating-axis kernel reads
    the pair list and clears the flags itself (no classify_pairs). Same manifolds, in the
    same order, as through the queues (the same table with a sphere that no body uses, so
    that classify_pairs runs), on 1001 random pairs (about half touching), called twice
    (the second call finds flags, counters and the axis cache left by the first)."""
    table, bodies, pairs = random_world(rng, "box_box", 1001, boxes_as_hulls)
    q = runtime.queue
    d_bodies, d_pairs = cla.to_device(q, bodies), cla.to_device(q, pairs)
    results = {}
    for queued in (False, True):
        if queued:
            table.add(Sphere(1.0))
        packed = table.pack_all().to_device(q)
        narrowphase = Narrowphase(
            runtime, table, work_group_size=work_group_size, placement_tile=placement_tile
        )
        assert narrowphase.direct == (not queued)
        first = narrowphase.find_contacts(d_bodies, packed, d_pairs, len(pairs))
        second = narrowphase.find_contacts(d_bodies, packed, d_pairs, len(pairs))
        np.testing.assert_array_equal(second, first)
        results[queued] = first
    assert 200 < len(results[False]) < 900
    np.testing.assert_array_equal(results[False], results[True])
