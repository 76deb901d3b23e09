"""What the contact solvers share: the fast-math build, push velocities, sweep checks."""

from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array

from ... import layouts
from ...codegen import Param
from ...device import DeviceTraits, Runtime
from ...errors import RbgenError

#: how a manifold's normal rows are solved (see the template parameter "normal_solve")
NORMAL_SOLVES = ("block", "sequential")
#: the build options of a fast_math solver. The solver relies on no infinity or NaN (a
#: NaN body is caught by the broadphase, which is built without them), and its rows
#: tolerate a few ulps in a reciprocal or a square root.
FAST_MATH_OPTIONS = ("-cl-fast-relaxed-math",)


def fast_math_param() -> Param:
    """The contact solvers' ``fast_math`` parameter (its build options: `fast_math_options`)."""
    return Param(
        "fast_math",
        (False, True),
        "build with -cl-fast-relaxed-math: a lane's constraint is a long chain of "
        "dependent arithmetic, which IEEE division and square root and unfused, "
        "unreordered operations lengthen",
    )


def normal_solve_param() -> Param:
    """The contact solvers' ``normal_solve`` parameter."""
    return Param(
        "normal_solve",
        NORMAL_SOLVES,
        "block: a manifold's normal rows solved together (no point-order bias, so "
        "symmetric stacks stay upright); sequential: one row after another (cheaper)",
    )


def fast_math_options(values: dict) -> tuple[str, ...]:
    """The build options of a solver specialisation (its ``fast_math`` value)."""
    return FAST_MATH_OPTIONS if values["fast_math"] else ()


def default_fast_math(traits: DeviceTraits) -> bool:
    """On GPUs, where a shorter chain of dependent arithmetic per lane makes a batch step
    faster; off on CPUs, where it gains nothing measurable and exact arithmetic keeps the
    CPU results the reference."""
    return traits.kind == "gpu"


def resolve_fast_math(traits: DeviceTraits, fast_math: bool | None) -> bool:
    """A solver's ``fast_math`` argument: None is the device's default; else a bool."""
    if fast_math is None:
        return default_fast_math(traits)
    if not isinstance(fast_math, (bool, np.bool_)):
        raise RbgenError(f"fast_math must be True, False or None, got {fast_math!r}")
    return bool(fast_math)


def shock_sweep(sweeps, joints: bool = False) -> bool:
    """Whether each substep's last velocity sweep is a shock sweep under the step settings
    ``sweeps``: their shock_propagation where it is True or False; where it is None (the
    default), wherever the Gauss-Seidel solve can run one, that is with iterations >= 2
    (a sweep before it carries the loads), in a World without ``joints`` (jointed bodies
    are not held as a unit, and ragdolls dropped on boxes came to rest later with the
    sweep: README, Settings). Solver 'jacobi' runs none: it refuses only an explicit True."""
    value = getattr(sweeps, "shock_propagation", False)
    if value is None:
        return int(sweeps.iterations) >= 2 and not joints
    return bool(value)


def check_sweeps(
    iterations: int, position_iterations: int, relaxation: float, shock: bool = False
) -> None:
    """Refuse sweep settings no solver can run, naming them. With ``shock`` (the setting
    shock_propagation) the last velocity sweep of a substep is a shock sweep, whose
    impulses are not carried: at least one sweep before it must carry the loads."""
    if iterations < 0 or position_iterations < 0 or not 0.0 < relaxation < 2.0:
        raise RbgenError(
            f"need iterations >= 0, position_iterations >= 0 and "
            f"0 < relaxation < 2, got iterations={iterations!r}, "
            f"position_iterations={position_iterations!r}, "
            f"relaxation={relaxation!r}"
        )
    if shock and iterations < 2:
        raise RbgenError(
            f"shock_propagation=True needs iterations >= 2 (the last velocity sweep of a "
            f"substep becomes the shock sweep, whose impulses are not carried; a sweep "
            f"before it must carry the loads), got iterations={iterations!r}"
        )


class PushVelocities:
    """A solver's push velocities (split impulse): zero between steps, grown on demand."""

    runtime: Runtime  # set by the solver that mixes this in
    _split = None

    def split_velocities(self, body_capacity: int):
        """The zeroed push-velocity array (grown to ``body_capacity``)."""
        if self._split is None or len(self._split) < body_capacity:
            self._split = cl_array.zeros(
                self.runtime.queue, max(1, int(body_capacity)), layouts.SPLIT_VELOCITY.dtype
            )
        return self._split
