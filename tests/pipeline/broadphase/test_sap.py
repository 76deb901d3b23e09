"""SAP specifics: the sweep axis is the axis of largest centre variance."""

from __future__ import annotations

import numpy as np
import pytest

from rbgen.pipeline.broadphase import make_broadphase
from rbgen.pipeline.broadphase.reference import brute_force_pairs

from .conftest import pack


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("shape", ["cpu", "gpu"])
def test_sweeps_along_the_axis_of_largest_variance(runtime, rng, axis, shape):
    n = 500
    spread = np.full(3, 5.0)
    spread[axis] = 40.0
    lower = (rng.uniform(0, 1, (n, 3)) * spread).astype(np.float32)
    aabbs = pack(lower, lower + rng.uniform(0.5, 2, (n, 3)).astype(np.float32))
    broadphase = make_broadphase(runtime, "sap", shape=shape)
    broadphase.find_pairs(aabbs, None)
    centres = 0.5 * (aabbs["lower"][:, :3] + aabbs["upper"][:, :3]).astype(np.float64)
    assert int(broadphase.exact("sweep_axis", 1).get()[0]) == int(np.argmax(centres.var(axis=0)))
    np.testing.assert_array_equal(broadphase.host_pairs(), brute_force_pairs(aabbs))
