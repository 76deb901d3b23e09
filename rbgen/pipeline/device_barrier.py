"""Persistent launches: work groups that step through dependent phases together.

The `global` batching mode and the PGS solver's persistent launch run many phases
(colouring rounds; batches of every sweep) in one launch, with a barrier
across all its work groups between phases (``common/device_barrier.cl.mako``).
Such a barrier needs every group of the launch running at once, which
OpenCL 1.2 does not promise: it holds when the launch has no more groups
than the device runs side by side. `persistent_groups` picks one per compute unit
(the kernels using it need at most one compute unit's registers and local
memory per group), and `barrier_buffer` holds the barrier's state: two counters,
zero between launches, the number of polls after which a waiting group gives
up, and the flag it then sets. A launch that gave up did none of its work;
the World reads the flag without blocking and redoes the step without persistent
launches (`rbgen.world`). "Persistent launch" and "device-wide barrier" are the names
for this everywhere; "grid" means only the broadphase's uniform grid.
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array

from .. import layouts
from ..device import DeviceTraits, Runtime

#: words of a device-wide barrier's state: arrivals since the launch began, groups that left,
#: the spin limit, the abandoned flag (layouts.BARRIER_*)
SYNC_WORDS = layouts.BARRIER_WORDS
#: polls of a waiting work group before it gives up the barrier: seconds of waiting on
#: either kind of device (a poll is a round trip to the shared cache: far slower on a GPU)
SPIN_LIMIT_GPU, SPIN_LIMIT_CPU = 1 << 23, 1 << 31
#: byte offset of the abandoned flag in a sync buffer (the World copies it each step)
ABANDONED_OFFSET = 4 * layouts.BARRIER_ABANDONED


def persistent_groups(traits: DeviceTraits) -> int:
    """Work groups of a persistent launch: one per compute unit, so that all run at
    once (the kernels that use it need at most one compute unit's registers and local
    memory per group)."""
    return max(1, int(traits.compute_units))


def persistent_launch_validated(traits: DeviceTraits) -> bool:
    """Whether the device-wide barrier is the default on this device: NVIDIA GPUs, where every
    group of a one-per-compute-unit launch was seen running at once and the memory rules
    of common/device_barrier.cl.mako were checked. Other GPUs can ask for it
    (batching='global'); AMD's wavefronts and caches have not been tried."""
    return traits.is_gpu and "nvidia" in traits.vendor.lower()


def spin_limit(traits: DeviceTraits) -> int:
    """Polls before a work group waiting at a device-wide barrier gives up (seconds of waiting,
    far beyond any phase: a barrier that waits that long has groups that never ran)."""
    return SPIN_LIMIT_GPU if traits.is_gpu else SPIN_LIMIT_CPU


def barrier_buffer(runtime: Runtime, extra_words: int = 0):
    """A uint32 device array: the barrier's SYNC_WORDS (counters and flag zero, the spin
    limit set), then ``extra_words`` of zeros for the kernel's own use."""
    words = np.zeros(SYNC_WORDS + int(extra_words), np.uint32)
    words[layouts.BARRIER_SPIN_LIMIT] = spin_limit(runtime.traits)
    return cl_array.to_device(runtime.queue, words)


def clear_abandoned(runtime: Runtime, sync) -> None:
    """Reset a sync buffer's abandoned flag (after the host has dealt with it)."""
    sync[layouts.BARRIER_ABANDONED : layouts.BARRIER_ABANDONED + 1].fill(
        np.uint32(0), queue=runtime.queue
    )
