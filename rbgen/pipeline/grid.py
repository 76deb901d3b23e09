"""Launches whose work groups step through dependent phases together.

The `global` batching mode and the solver's grid variant run many phases
(colouring rounds; batches of every sweep) in one launch, with a barrier
across all its work groups between phases (``common/grid_barrier.cl.mako``).
Such a barrier needs every group of the launch running at once, which
OpenCL 1.2 does not promise: it holds when the launch has no more groups
than the device runs side by side. `grid_groups` picks one per compute unit
(the kernels using it need at most one compute unit's registers and local
memory per group), and `sync_buffer` holds the two counters the barrier
keeps, zero between launches.
"""
from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array

from ..device import DeviceTraits, Runtime

#: words of a grid barrier's state: arrivals since the launch began, groups that left
SYNC_WORDS = 2


def grid_groups(traits: DeviceTraits) -> int:
    """Work groups of a grid-synchronised launch: one per compute unit, so that all run at
    once (an NVIDIA SM holds one group of 256 lanes at ~200 registers a lane; PoCL runs
    one group per core thread)."""
    return max(1, int(traits.compute_units))


def grid_validated(traits: DeviceTraits) -> bool:
    """Whether the grid barrier is the default on this device: NVIDIA GPUs, where every
    group of a one-per-compute-unit launch was seen running at once and the memory rules
    of common/grid_barrier.cl.mako were checked (H100, H200). Other GPUs can ask for it
    (batching='global'); AMD's wavefronts and caches have not been tried."""
    return traits.is_gpu and "nvidia" in traits.vendor.lower()


def sync_buffer(runtime: Runtime, extra_words: int = 0):
    """A zeroed uint32 device array: the barrier's SYNC_WORDS, then ``extra_words`` for the
    kernel's own use."""
    return cl_array.zeros(runtime.queue, SYNC_WORDS + int(extra_words), np.uint32)
