"""Integrate stage: gravity, damping, positions and orientations of dynamic bodies.

Given the solver's split-impulse push velocities, the same launch also moves
the bodies by them and clears them (what the solver's apply_split_velocities
does in a launch of its own). Given a `BodyDelta` array (the substeps of a step),
it also records how far each body moved since the step began.
"""

from __future__ import annotations

import numpy as np

from ..codegen import KernelTemplate, Param, compile_spec, work_group_size_param
from ..device import DeviceTraits, Runtime
from ..errors import RbgenError

TEMPLATE = KernelTemplate(
    "pipeline/integrate.cl.mako",
    [
        work_group_size_param(
            "bodies per work group; memory-bound, so any size that fills a CU works"
        ),
        Param("damping", (True, False), "emit the damping terms only when a world uses damping"),
        Param(
            "gravity",
            (True, False),
            "True: integrate_bodies adds g dt itself (standalone use); False: a separate "
            "apply_gravity kernel runs before the solver so contacts cancel gravity in the same "
            "step",
        ),
        Param(
            "split",
            (True, False),
            "also apply (and clear) the split-impulse push velocities, saving the World the "
            "solver's apply_split_velocities launch",
        ),
        Param(
            "deltas",
            (False, True),
            "also record each body's motion since the step began (substeps: contacts update "
            "their separations from it)",
        ),
    ],
    doc="Semi-implicit Euler step of body velocities and transforms.",
    roles={"bodies": "inout"},
    defaults=lambda traits: {
        "work_group_size": default_work_group_size(traits),
        "damping": False,
        "gravity": True,
        "split": False,
        "deltas": False,
    },
)

#: Bullet's default clamp: at most a quarter turn per step keeps the
#: axis-angle update accurate and stops tunnelling spins.
DEFAULT_MAX_ANGULAR_STEP = 0.5 * np.pi


def default_work_group_size(traits: DeviceTraits) -> int:
    """128 on GPUs (4 warps / 2 wavefronts per group); 64 on CPUs (PoCL vectorises across items)."""
    return min(128 if traits.is_gpu else 64, traits.max_work_group_size)


class Integrator:
    """Launches `integrate_bodies` over a device array of `Body` records.

    A call given ``split`` (the solver's `SplitVelocity` array) runs the
    variant that also applies and clears the push velocities, one given ``deltas`` (a
    `BodyDelta` array) the variant that records the bodies' motion since the step began
    (each built at its first use).
    """

    def __init__(
        self,
        runtime: Runtime,
        *,
        damping: bool = False,
        gravity: bool = True,
        work_group_size: int | None = None,
    ):
        self.runtime = runtime
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        self.spec = TEMPLATE.spec(
            work_group_size=self.work_group_size,
            damping=bool(damping),
            gravity=bool(gravity),
            split=False,
            deltas=False,
        )
        self.damping, self.gravity = bool(damping), bool(gravity)
        program = compile_spec(runtime, self.spec)
        self.kernel = runtime.bound(program.kernel("integrate_bodies"))
        self.gravity_kernel = None if gravity else runtime.bound(program.kernel("apply_gravity"))
        self._variants: dict = {(False, False): self.kernel}

    def _kernel_for(self, split: bool, deltas: bool):
        kernel = self._variants.get((split, deltas))
        if kernel is None:
            spec = TEMPLATE.spec(**{**self.spec.values, "split": split, "deltas": deltas})
            program = compile_spec(self.runtime, spec)
            kernel = self._variants[split, deltas] = self.runtime.bound(
                program.kernel("integrate_bodies")
            )
        return kernel

    def apply_gravity(
        self, bodies, body_count: int, dt: float, gravity=(0.0, -9.81, 0.0), kicks=None
    ):
        """v += g dt on dynamic bodies (only for an Integrator built with gravity=False),
        and with ``kicks`` (the prepare kernel's, 2 float4 a body) a substep's share of the
        step's external forces."""
        if self.gravity_kernel is None:
            raise RbgenError(
                "this Integrator applies gravity inside integrate_bodies (built with gravity=True)"
            )
        if body_count == 0:
            return None
        return self.gravity_kernel.over(
            body_count,
            self.work_group_size,
            bodies,
            np.uint32(body_count),
            np.float32(dt),
            np.array([*gravity, 0.0], dtype=np.float32),
            bodies if kicks is None else kicks,
            np.uint32(kicks is not None),
        )

    def __call__(
        self,
        bodies,
        body_count: int,
        dt: float,
        gravity=(0.0, -9.81, 0.0),
        linear_damping: float = 0.0,
        angular_damping: float = 0.0,
        max_angular_step: float = DEFAULT_MAX_ANGULAR_STEP,
        split=None,
        deltas=None,
        first_substep: bool = True,
    ):
        """One step of ``body_count`` bodies; ``split``: push velocities to apply and clear
        (at least ``body_count`` `SplitVelocity` records), or None; ``deltas``: `BodyDelta`
        records of the motion since the step began, restarted when ``first_substep``."""
        if not (np.isfinite(dt) and dt > 0):
            raise RbgenError(f"dt must be a positive finite number, got {dt!r}")
        if (linear_damping or angular_damping) and not self.damping:
            raise RbgenError(
                "this Integrator was built with damping=False; "
                "build it with damping=True to use damping"
            )
        for name, value in (
            ("linear_damping", linear_damping),
            ("angular_damping", angular_damping),
        ):
            if not 0.0 <= value < 1.0:
                raise RbgenError(f"{name} must be in [0, 1), got {value!r}")
        if split is not None and len(split) < body_count:
            raise RbgenError(f"split has {len(split)} records for {body_count} bodies")
        if body_count == 0:
            return None
        args = [bodies, np.uint32(body_count), np.float32(dt)]
        if self.gravity:
            args.append(np.array([*gravity, 0.0], dtype=np.float32))
        if self.damping:
            # (1 - damping)^dt is the same for every body
            args += [
                np.float32((1.0 - linear_damping) ** dt),
                np.float32((1.0 - angular_damping) ** dt),
            ]
        if split is not None:
            args.append(split)
        if deltas is not None:
            args += [deltas, np.uint32(bool(first_substep))]
        args.append(np.float32(max_angular_step))
        return self._kernel_for(split is not None, deltas is not None).over(
            body_count, self.work_group_size, *args
        )
