"""Sub-feature keys: pairs, manifolds, the separating-axis cache and warm starts are keyed
by (body a, body b, sub), so one body pair may have several manifolds (compound children,
mesh triangles) that never mix.

Closed forms: a whole-body pair list from any broadphase has sub = RB_WHOLE_BODY (0)
everywhere; two pairs of the same bodies with different sub ids give the same manifold
(same geometry) carrying their own sub; a constraint is warm-started from the previous
step's constraint with the same (a, b, sub), whatever the order of the manifolds, and a
key absent last step starts from zero.
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

from rbgen import layouts
from rbgen.pipeline.broadphase import BROADPHASES, make_broadphase
from rbgen.pipeline.constraints import ContactConstraints
from rbgen.pipeline.narrowphase import Narrowphase
from rbgen.pipeline.prepare import inertia_records
from rbgen.shapes import Box, Plane, ShapeTable, Sphere

from .narrowphase.reference import make_bodies, pair_records


def test_layouts_carry_the_sub_feature_key():
    assert layouts.WHOLE_BODY == 0
    for layout in (
        layouts.PAIR,
        layouts.CONTACT_MANIFOLD,
        layouts.SAT_CACHE_ENTRY,
        layouts.CONTACT_CONSTRAINT,
    ):
        assert layout.field("sub").kind == "uint"
    # the key fields come last, after the point count (the struct stays 352 bytes)
    c = layouts.CONTACT_CONSTRAINT
    assert c.offset("sub") > c.offset("point_count") > c.offset("body_b")
    assert c.itemsize == 352


@pytest.mark.parametrize("name", sorted(BROADPHASES))
def test_broadphases_write_whole_body_pairs(runtime, rng, name):
    """Every broadphase writes sub = RB_WHOLE_BODY, on a full query and on a second one after
    the boxes moved (sap3: its incremental path, which reads the last query's pairs; the
    others write into a buffer first filled with 0xFF), and keeps the pairs sorted by
    (a, b, sub)."""
    n = 400
    lower = rng.uniform(0, 12, (n, 3)).astype(np.float32)
    broadphase = make_broadphase(runtime, name, capacity=8 * n)
    for _step in range(2):
        aabbs = layouts.AABB.zeros(n)
        aabbs["lower"][:, :3] = lower
        aabbs["upper"][:, :3] = lower + 1.0
        if name != "sap3":
            cl.enqueue_fill_buffer(
                runtime.queue, broadphase.pairs.data, np.uint8(0xFF), 0, broadphase.pairs.nbytes
            )
        count = broadphase.find_pairs(aabbs)
        pairs = broadphase.pairs.get()[:count]
        assert count > n // 2
        assert np.all(pairs["sub"] == layouts.WHOLE_BODY)
        keys = np.stack([pairs["a"], pairs["b"], pairs["sub"]]).astype(np.int64)
        order = np.lexsort(keys[::-1])
        np.testing.assert_array_equal(order, np.arange(count))
        lower = lower + rng.uniform(-0.05, 0.05, lower.shape).astype(np.float32)


def test_manifolds_and_axis_cache_are_keyed_by_sub(runtime):
    """Pairs (0, 1, sub 1), (0, 1, sub 2), (0, 2, whole) of boxes and (3, 4, sub 5) of a
    sphere on a plane: every manifold carries its pair's sub, in pair order, the two
    manifolds of bodies 0 and 1 are equal but for it, and every separating-axis cache entry
    holds its pair's key; with the two sub-feature pairs swapped in the list (a cached
    axis of the other sub at each index), the same manifolds come out."""
    table = ShapeTable()
    cube, ball, ground = table.add(Box((1, 1, 1))), table.add(Sphere(0.5)), table.add(Plane())
    bodies = make_bodies(
        [cube, cube, cube, ball, ground],
        [(0, 0, 0), (0.3, 1.98, 0.1), (1.97, 0.2, 0), (10, 0.49, 0), (0, 0, 0)],
    )
    q = runtime.queue
    narrowphase = Narrowphase(runtime, table)
    packed = table.pack_all().to_device(q)
    d_bodies = cla.to_device(q, bodies)
    records = np.concatenate(
        [
            pair_records([(0, 1)], 1),
            pair_records([(0, 1)], 2),
            pair_records([(0, 2)]),
            pair_records([(3, 4)], 5),
        ]
    )
    found = {}
    for order in ([0, 1, 2, 3], [1, 0, 2, 3]):
        pairs = records[order]
        m = narrowphase.find_contacts(d_bodies, packed, cla.to_device(q, pairs), len(pairs))
        np.testing.assert_array_equal(m["sub"], pairs["sub"])
        np.testing.assert_array_equal(m["body_a"], pairs["a"])
        cache = narrowphase.sat_cache.get()[:3]
        for field in ("a", "b", "sub"):
            np.testing.assert_array_equal(cache[field], pairs[:3][field])
        for record in m:
            found.setdefault(
                (int(record["body_a"]), int(record["body_b"]), int(record["sub"])), []
            ).append(record)
    assert set(found) == {(0, 1, 1), (0, 1, 2), (0, 2, 0), (3, 4, 5)}
    first, second = found[(0, 1, 1)][0], found[(0, 1, 2)][0]
    assert first["point_count"] == 4
    for field in ("points", "normal", "features", "point_count"):
        np.testing.assert_array_equal(first[field], second[field])
    for _key, (m1, m2) in found.items():  # the list's order does not change a manifold
        np.testing.assert_array_equal(m1, m2)


def manifold(a, b, sub, depth):
    """A flat manifold of 4 points under body b, normal +y, features 0..3."""
    m = layouts.CONTACT_MANIFOLD.zeros(1)[0]
    m["body_a"], m["body_b"], m["sub"] = a, b, sub
    m["normal"][:3] = (0, 1, 0)
    m["points"][:, :3] = [(-0.5, 0, -0.5), (0.5, 0, -0.5), (0.5, 0, 0.5), (-0.5, 0, 0.5)]
    m["points"][:, 3] = -depth
    m["features"][:] = np.arange(4)
    m["point_count"] = 4
    m["friction"] = 0.5
    return m


def test_warm_start_is_keyed_by_sub_feature(runtime):
    """Two manifolds of the same bodies (0, 1) with sub 1 and sub 2, same points and
    features: after their impulses are set to 1, 2, 3, 4 (sub 1) and 10, 20, 30, 40
    (sub 2), the next step's constraints, listed as (sub 2, sub 1, sub 3), get exactly
    their own key's impulses (found through the table, not at their old index), and the
    new sub 3 starts from zero."""
    q = runtime.queue
    bodies = make_bodies([0, 0], [(0, -1, 0), (0, 0.5, 0)])
    bodies["inv_mass"][0] = 0.0
    d_bodies = cla.to_device(q, bodies)
    inertia = cla.to_device(q, inertia_records(np.array([[0, 0, 0], [1, 1, 1]])))
    setup = ContactConstraints(runtime, warm_start=True)
    capacity = 8

    def step(manifolds):
        padded = layouts.CONTACT_MANIFOLD.zeros(capacity)
        padded[: len(manifolds)] = manifolds
        setup(
            cla.to_device(q, padded),
            cla.to_device(q, np.array([len(manifolds)], np.uint32)),
            d_bodies,
            inertia,
            capacity,
            1 / 60,
        )
        return setup.constraints

    constraints = step(np.array([manifold(0, 1, 1, 0.01), manifold(0, 1, 2, 0.01)]))
    host = constraints.get()
    assert list(host["sub"][:2]) == [1, 2]
    impulses = {1: np.array([1.0, 2.0, 3.0, 4.0]), 2: np.array([10.0, 20.0, 30.0, 40.0])}
    for k in range(2):
        host["normal_impulse"][k] = impulses[int(host["sub"][k])]
        # (as a load held the substep before: carried whole, not capped as an impact's)
        host["tangent2_impulse"][k][2] = impulses[int(host["sub"][k])].sum()
    constraints.set(host)

    later = step(
        np.array([manifold(0, 1, 2, 0.01), manifold(0, 1, 1, 0.01), manifold(0, 1, 3, 0.01)])
    ).get()[:3]
    assert list(later["sub"]) == [2, 1, 3]
    np.testing.assert_array_equal(later["normal_impulse"][0], impulses[2])
    np.testing.assert_array_equal(later["normal_impulse"][1], impulses[1])
    np.testing.assert_array_equal(later["normal_impulse"][2], 0.0)
