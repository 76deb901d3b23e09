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
B, then edges, by 1e-4: a tie may legitimately pick either axis).
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen import layouts
from rbgen.pipeline.narrowphase import Narrowphase
from rbgen.shapes import Box, ConvexHull, ShapeTable, Sphere

from .reference import Placed, make_bodies, quat_matrix, random_quaternions, sat

TIE = 3e-4
UNDECIDED = 1e-4
#: float32 rounding of coordinates of magnitude ~4 (positions within +-2, sizes ~1)
FLOAT32_ABS = 4e-6


#: the box-box kernel ignores edge-pair axes within this angle of a face normal
FACE_ALIGNED_DEG = 1.0


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
        )
        if abs(ref.separation) < UNDECIDED:
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
