"""BoxBox scene: positions from the closed-form lattice, standard sizes, AABBs."""

from __future__ import annotations

import numpy as np
import pytest

from rbgen.errors import RbgenError
from rbgen.pipeline.broadphase.reference import brute_force_pairs
from rbgen.scenes import (
    STANDARD_BOXBOX_DIMS,
    boxbox_scene,
    scene_aabbs,
    standard_boxbox_dims,
    standard_boxbox_scene,
)


def test_boxbox_positions_follow_the_formula():
    nx, ny, nz = 3, 4, 2
    scene = boxbox_scene(nx, ny, nz)
    assert scene.count == nx * ny * nz and scene.positions.dtype == np.float32
    expected = {
        (((j + 1) % 2) + 2.2 * i, 1 + 2 * j, ((j + 1) % 2) + 2.2 * k)
        for i in range(nx)
        for j in range(ny)
        for k in range(nz)
    }
    got = {tuple(p) for p in scene.positions.astype(np.float64)}
    assert len(got) == len(expected)
    for p in expected:  # float32 rounding of 2.2 i
        assert min(np.abs(np.array(list(got)) - p).max(axis=1)) < 1e-5
    np.testing.assert_array_equal(scene.half_extents, 1.0)
    assert scene.mass == 1.0


def test_ground_top_face_is_y0_and_covers_the_lattice():
    scene = boxbox_scene(4, 3, 5)
    top = scene.ground_position[1] + scene.ground_half_extents[1]
    assert top == 0.0 and scene.ground_offset == 0.0
    np.testing.assert_array_equal(scene.ground_normal, (0, 1, 0))
    lower = scene.ground_position - scene.ground_half_extents
    upper = scene.ground_position + scene.ground_half_extents
    box_lower = scene.positions.min(axis=0) - 1
    box_upper = scene.positions.max(axis=0) + 1
    assert np.all(lower[[0, 2]] < box_lower[[0, 2]]) and np.all(upper[[0, 2]] > box_upper[[0, 2]])
    assert box_lower[1] == 0.0  # the bottom layer rests on the ground


@pytest.mark.parametrize("count", sorted(STANDARD_BOXBOX_DIMS))
def test_standard_sizes(count):
    dims = standard_boxbox_dims(count)
    assert int(np.prod(dims)) == count
    assert standard_boxbox_scene(count).count == count


def test_bad_sizes():
    with pytest.raises(RbgenError, match="no standard BoxBox size 1234"):
        standard_boxbox_dims(1234)
    with pytest.raises(RbgenError, match="ny"):
        boxbox_scene(2, -1, 2)


def test_scene_aabbs_pairs_have_the_lattice_count():
    """Each box touches the ground (bottom layer) or the 4 boxes it rests on.

    Layers alternate between offsets 0 and 1 with pitch 2.2, so a box overlaps
    the boxes i-1..i or i..i+1 of the next layer along x and z (when they
    exist), and exactly touches their faces along y.
    """
    nx, ny, nz = 4, 3, 5
    aabbs, static = scene_aabbs(boxbox_scene(nx, ny, nz))
    assert len(aabbs) == nx * ny * nz + 1 and static[0] == 1 and not static[1:].any()
    per_layer_pair = (2 * nx - 1) * (2 * nz - 1)  # overlapping columns between two layers
    expected = nx * nz + (ny - 1) * per_layer_pair
    assert len(brute_force_pairs(aabbs, static)) == expected
    no_ground, flags = scene_aabbs(boxbox_scene(nx, ny, nz), ground=False)
    assert len(no_ground) == nx * ny * nz and not flags.any()
