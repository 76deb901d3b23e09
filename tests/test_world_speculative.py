"""Speculative contacts (created up to contact_margin apart) must not hold bodies up."""

from __future__ import annotations

import numpy as np
import pytest

import rbgen


@pytest.mark.parametrize("gap", [0.005, 0.015])
def test_box_released_inside_the_margin_lands(runtime, gap):
    """Two boxes (half extent 0.5) released `gap` apart, inside the 2 cm margin, above the
    ground (top y = 0): after 2 s at rest the centres are at 0.5 and 1.5 within 2 mm
    (the slop leaves < 2 mm), not hovering at 0.5 + gap and 1.5 + 2 gap."""
    world = rbgen.World(runtime)
    world.add_static(rbgen.Box(half_extents=(50, 1, 50)), position=(0, -1, 0))
    ids = world.add_bodies(
        rbgen.Box(half_extents=(0.5, 0.5, 0.5)),
        mass=1.0,
        positions=np.array([[0, 0.5 + gap, 0], [0, 1.5 + 2 * gap, 0]]),
    )
    for _ in range(120):
        world.step(1 / 60)
    y = world.positions[ids][:, 1]
    np.testing.assert_allclose(y, [0.5, 1.5], atol=2e-3)
    assert np.abs(world.linear_velocities[ids]).max() < 0.02
