"""Launches whose work groups step through dependent phases together.

The `global` batching mode and the solver's grid variant run many phases
(colouring rounds; batches of every sweep) in one launch, with a barrier
across all its work groups between phases (``common/grid_barrier.cl.mako``).
Such a barrier needs every group of the launch running at once, which
OpenCL 1.2 does not promise: it holds when the launch has no more groups
than the device runs side by side. `grid_groups` picks one per compute unit
(the kernels using it need at most one compute unit's registers and local
memory per group), and `sync_buffer` holds the barrier's state: two counters,
zero between launches, the number of polls after which a waiting group gives
up, and the flag it then sets. A launch that gave up did none of its work;
the World reads the flag without blocking and redoes the step without grid
barriers (`rbgen.world`).
"""
from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array

from .. import layouts
from ..device import DeviceTraits, Runtime

#: words of a grid barrier's state: arrivals since the launch began, groups that left,
#: the spin limit, the abandoned flag (layouts.GRID_*)
SYNC_WORDS = layouts.GRID_SYNC_WORDS
#: polls of a waiting work group before it gives up the barrier: a poll is a round trip
#: to the shared cache, estimated (not measured) at ~0.1-0.5 us on an H200 (2^23: ~1-4 s)
#: and ~1-10 ns on a CPU (2^31: seconds); 4,096 polls were shorter than a phase on PoCL
SPIN_LIMIT_GPU, SPIN_LIMIT_CPU = 1 << 23, 1 << 31
#: byte offset of the abandoned flag in a sync buffer (the World copies it each step)
ABANDONED_OFFSET = 4 * layouts.GRID_ABANDONED


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


def spin_limit(traits: DeviceTraits) -> int:
    """Polls before a work group waiting at a grid barrier gives up (seconds of waiting,
    far beyond any phase: a barrier that waits that long has groups that never ran)."""
    return SPIN_LIMIT_GPU if traits.is_gpu else SPIN_LIMIT_CPU


def sync_buffer(runtime: Runtime, extra_words: int = 0):
    """A uint32 device array: the barrier's SYNC_WORDS (counters and flag zero, the spin
    limit set), then ``extra_words`` of zeros for the kernel's own use."""
    words = np.zeros(SYNC_WORDS + int(extra_words), np.uint32)
    words[layouts.GRID_SPIN_LIMIT] = spin_limit(runtime.traits)
    return cl_array.to_device(runtime.queue, words)


def clear_abandoned(runtime: Runtime, sync) -> None:
    """Reset a sync buffer's abandoned flag (after the host has dealt with it)."""
    sync[layouts.GRID_ABANDONED:layouts.GRID_ABANDONED + 1].fill(np.uint32(0),
                                                                  queue=runtime.queue)
