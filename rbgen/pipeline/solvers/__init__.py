"""Contact solvers: one module per algorithm behind one small interface.

``pgs`` (pgs.py)
    Projected Gauss-Seidel over a batcher's colours (`rbgen.pipeline.batching`): the
    default, the solver that holds stacks.
``jacobi`` (jacobi.py)
    Jacobi sweeps with mass splitting (Tonge et al. 2012): no colouring, fewer batch
    steps, but a push travels one body down a stack per sweep.

Both take the step's constraints, bodies and sweep settings through `Solver.solve` and
leave the push velocities (split impulse) for the integrator.
"""

from __future__ import annotations

from typing import Protocol

#: solver algorithms by name
SOLVERS = ("pgs", "jacobi")


class Sweeps(Protocol):
    """The per-step sweep settings a solver reads (the World's settings object)."""

    iterations: int
    position_iterations: int
    relaxation: float
    warm_start: bool


class Solver(Protocol):
    """What the World's solve stage needs from a contact solver."""

    #: the device-wide barrier words of its persistent launch, or None when it makes none
    def barrier_state(self):
        """The barrier buffer its persistent launch shares (None: no persistent launch)."""

    def solve(
        self,
        constraints,
        constraint_count,
        constraint_capacity: int,
        bodies,
        inertia,
        body_count: int,
        sweeps: Sweeps,
        restitution: bool = True,
        same_geometry: bool = False,
    ) -> None:
        """Warm start and sweep the step's constraints (no blocking read).
        ``restitution``: the last velocity sweep applies the contacts' restitution (the
        step's last substep). ``same_geometry``: the constraints' lever arms and normals
        and the bodies' world inverse inertias are those of the previous call (a later
        substep of the same step; the restitution changes none of them), so what the
        solver derived from them then still holds."""

    def split_velocities(self, body_capacity: int):
        """The push velocities the integrator applies (zero between steps)."""
