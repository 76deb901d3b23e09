"""Support chains: after a substep's velocity sweeps, no body sinks into what holds it up.

A stack's weight reaches the ground through its contacts a few layers a sweep, so a tall
stack whose loads are not yet known (a stack just built or landed on) sinks while they
propagate: about g (T h)^2 / 2 for T substeps of h, T growing with the stack's height;
and once sunk it stays (the push leaves the penetration within the slop alone, a
millimetre a contact). After the sweeps of every substep, each dynamic body that a
contact holds up against gravity takes one such contact as its support (one of those
touching, as the substep's targets say: chosen once a step, a support that rocked apart
left the body free to sink, and a lattice breathed), and a
body approaching its support faster than the contact's gap allows takes the velocity
along the normal that stops it, its support's own gain included: the chains are solved
whole by pointer jumping, `ROUNDS` rounds of one pass over the bodies each
(pipeline/solvers/support_chains.cl.mako has the arithmetic). A persistent PGS launch
runs the pass between its sweeps and the bodies' move (`rbgen.pipeline.solvers.pgs`);
every other PGS solve runs these kernels between the solver and the integrator
(`SupportChains`).
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cl_array
import pyopencl.cltypes as cltypes

from ...codegen import KernelTemplate, compile_spec, work_group_size_param
from ...device import Runtime
from .substeps import default_work_group_size  # (the same rule: per constraint or body)

#: rounds of pointer jumping a substep: chains of up to 2^ROUNDS bodies are solved whole
#: (a 55-layer lattice's in 6), a deeper one from its lowest 2^ROUNDS links up
ROUNDS = 6
#: a body's entry in `supports` between passes: no support (the template keeps the
#: complement of a support's key)
NO_SUPPORT = 0
#: the template's RB_SUPPORT_SLACK (the launches pass it times |g| h)
SLACK = 0.5
#: an odd substep's `flip` (RB_SUPPORT_INDEX: offer_support takes the highest index);
#: a support's contact index has 30 bits
FLIP = 0x3FFFFFFF

TEMPLATE = KernelTemplate(
    "pipeline/solvers/support.cl.mako",
    [work_group_size_param("constraints or bodies per work group; memory-bound")],
    doc="Support chains: bodies stop sinking into their supports, along whole chains.",
    roles={"supports": "inout", "links": "inout", "bodies": "inout"},
    defaults=lambda traits: {"work_group_size": default_work_group_size(traits)},
)


class SupportBuffers:
    """The per-body records of the chains: `supports` (one uint a body: its support's key,
    written by a substep's offers and cleared again as the body takes its gain, so that
    every body is without one between passes) and `links` (two float4 a body: the links
    of one round and of the next). Grown on demand, `supports` zero (`NO_SUPPORT`)."""

    def __init__(self, runtime: Runtime):
        self.runtime = runtime
        self.supports: cl_array.Array | None = None
        self.links: cl_array.Array | None = None

    def grow(self, body_count: int) -> None:
        n = max(1, int(body_count))
        if self.supports is None or len(self.supports) < n:
            self.supports = cl_array.zeros(self.runtime.queue, n, np.uint32)
            self.links = cl_array.empty(self.runtime.queue, 2 * n, cltypes.float4)


class SupportChains(SupportBuffers):
    """Launches the support chains' kernels (a solve that does not run its substeps
    itself): `propagate` after each substep's sweeps."""

    def __init__(self, runtime: Runtime, work_group_size: int | None = None):
        super().__init__(runtime)
        self.work_group_size = work_group_size or default_work_group_size(runtime.traits)
        self.spec = TEMPLATE.spec(work_group_size=self.work_group_size)
        program = compile_spec(runtime, self.spec)
        self.kernels = {
            name: runtime.bound(program.kernel(name))
            for name in ("offer_supports", "link_supports", "jump_supports", "apply_supports")
        }

    def propagate(
        self,
        constraints,
        constraint_count,
        capacity: int,
        bodies,
        body_count: int,
        gravity,
        h: float,
        substep: int = 0,
        rounds: int = ROUNDS,
    ) -> None:
        """After a substep of ``h`` seconds' sweeps (under ``gravity``): the supports
        offered by min(``constraint_count[0]``, ``capacity``) constraints (the lowest index
        of a body's on even ``substep`` s, the highest on odd ones), then every body of a
        chain takes its gain."""
        n, wg = max(1, int(body_count)), self.work_group_size
        g = np.asarray(gravity, float)
        if not np.linalg.norm(g) > 0:  # (nothing to hold up against)
            return
        self.grow(n)
        k, links = self.kernels, self.links
        flip = np.uint32(FLIP if substep % 2 else 0)
        if capacity > 0:
            k["offer_supports"].over(
                capacity,
                wg,
                constraints,
                constraint_count,
                np.uint32(capacity),
                flip,
                self.supports,
            )
        up = np.array([*(-g / np.linalg.norm(g)), 0.0], np.float32)
        slack = np.float32(SLACK * np.linalg.norm(g) * h)
        k["link_supports"].over(
            n, wg, constraints, bodies, self.supports, flip, links, np.uint32(n), up, slack
        )
        for r in range(rounds):
            k["jump_supports"].over(n, wg, links, np.uint32(n), np.uint32(r))
        k["apply_supports"].over(
            n, wg, bodies, self.supports, links, np.uint32(n), up, np.uint32(rounds)
        )
