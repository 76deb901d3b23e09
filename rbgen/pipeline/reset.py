"""Resetting environments of a `rbgen.batch.WorldBatch` on the device, between steps.

`EnvironmentReset` writes the new records of the reset environments' bodies (one
non-blocking upload and one launch) and forgets the last step's contacts of those
bodies (one launch over the constraint capacity, the count read on the device): no
blocking read and no re-upload of the other environments, where `World.set_state`
reads every body back and uploads them all again.
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pyopencl.array as cla

from ..codegen import KernelTemplate, compile_spec, work_group_size_param
from ..device import DeviceTraits, Runtime

TEMPLATE = KernelTemplate(
    "pipeline/reset.cl.mako",
    [work_group_size_param("bodies or constraints per work group; memory-bound")],
    doc="A WorldBatch's environment reset: body records written, their contacts forgotten.",
    roles={"bodies": "inout", "constraints": "inout"},
    defaults=lambda traits: {"work_group_size": default_work_group_size(traits)},
)


def default_work_group_size(traits: DeviceTraits) -> int:
    """128 on GPUs; 64 on CPUs (PoCL vectorises across work-items)."""
    return min(128 if traits.is_gpu else 64, traits.max_work_group_size)


class EnvironmentReset:
    """The two kernels of an environment reset (see the module docstring)."""

    def __init__(self, runtime: Runtime, work_group_size: int | None = None):
        self.runtime = runtime
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        self.spec = TEMPLATE.spec(work_group_size=self.work_group_size)
        program = compile_spec(runtime, self.spec)
        self._reset = runtime.bound(program.kernel("reset_bodies"))
        self._forget = runtime.bound(program.kernel("forget_contacts"))
        #: (marker event, arrays) of the uploads still in flight: their host arrays stay
        #: alive until the marker after them completes (checked without waiting)
        self._keep: list[tuple[cl.Event, list]] = []

    def __call__(
        self,
        bodies,
        states: np.ndarray,
        envs: np.ndarray,
        bodies_per_env: int,
        first_env_body: int,
        env_count: int,
        words,
        constraints=None,
    ) -> None:
        """Write ``states`` (Body records, ``bodies_per_env`` per environment of ``envs``,
        distinct) over those environments' bodies in ``bodies`` (body j of environment e
        is ``first_env_body + e * bodies_per_env + j``); then, given ``constraints`` (a
        `ContactConstraints` after a step), forget their contacts (``words``: the bodies'
        collision words)."""
        queue = self.runtime.queue
        count = len(states)
        if count == 0:
            return
        self._keep = [
            (marker, held)
            for marker, held in self._keep
            if marker.command_execution_status != cl.command_execution_status.COMPLETE
        ]
        flags = np.zeros(env_count, np.uint32)
        flags[envs] = 1
        states = np.ascontiguousarray(states)
        env_words = envs.astype(np.uint32)
        d_states = cla.to_device(queue, states, async_=True)
        d_envs = cla.to_device(queue, env_words, async_=True)
        held = [d_states, d_envs, states, env_words, flags]
        wg = self.work_group_size
        self._reset.over(
            count,
            wg,
            bodies,
            d_states,
            d_envs,
            np.uint32(count),
            np.uint32(bodies_per_env),
            np.uint32(first_env_body),
        )
        if constraints is not None and constraints.capacity > 0:
            d_flags = cla.to_device(queue, flags, async_=True)
            held.append(d_flags)
            self._forget.over(
                constraints.capacity,
                wg,
                constraints.constraints,
                constraints.count,
                words,
                d_flags,
            )
        self._keep.append((cl.enqueue_marker(queue), held))
