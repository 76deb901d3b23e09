"""The plan: every choice a World makes for its device, derived once, in one place.

`derive_plan` turns (device traits, the World's construction options, the scene's shape
types, the tuning cache) into a `Plan`: which solver, which batching, how the solver walks
its batches, the normal solve, the warm start's form, fast math, and the tunable
parameters. The World builds its step pipeline from the plan, `rbgen export` writes it
beside the kernels, benchmarks print it. A default lives here and nowhere else, with its
one-sentence reason in `Plan.reasons`.

Tunable parameters (`TUNABLES`) are chosen by `rbgen tune` per device and recorded in the
tuning cache (`rbgen.tuning.tune_plan`); a World option ``plan={...}`` overrides them (an
expert's lever, for measurements); an untuned device gets the hand-set value.
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any

from .device import INT64_ATOMICS, DeviceTraits
from .errors import RbgenError
from .pipeline.batching import MODES, SPATIAL_MODES, default_solve_form
from .pipeline.batching.global_colouring import ORDERED_ROUNDS
from .pipeline.batching.spatial import default_group_count, default_spatial_mode
from .pipeline.device_barrier import persistent_launch_validated
from .pipeline.solvers.common import check_sweeps
from .pipeline.solvers.pgs import (
    can_keep_contact_geometry,
    default_contact_geometry,
    default_normal_solve,
    default_values,
)


@dataclasses.dataclass(frozen=True)
class Tunable:
    """A plan parameter `rbgen tune` may choose: its candidates on a device, the hand-set
    default, the check of a value given by hand, and why it is tunable."""

    name: str
    doc: str

    def candidates(self, traits: DeviceTraits) -> list:
        return list(_CANDIDATES[self.name](traits))

    def check(self, value, traits: DeviceTraits):
        # (typed: True is not the candidate 1, nor 1 the candidate True)
        listed = any(type(value) is type(c) and value == c for c in self.candidates(traits))
        if not listed and not _ALSO_ALLOWED[self.name](value):
            raise RbgenError(
                f"plan parameter {self.name}={value!r} is not allowed on "
                f"{traits.device_name}; candidates: {self.candidates(traits)}"
            )
        return value


#: why a device without a persistent launch batches as it does (default_spatial_mode)
SPATIAL_REASONS = {
    "cells": "cells spread any pile over the device's compute units",
    "slabs": "slabs keep stacks whole for a serial solve, over every core",
    "columns": "columns keep stacks whole for a serial solve, with work for many cores",
}


def _batching_candidates(traits: DeviceTraits) -> list:
    """Persistent global batching first where the device is validated for it."""
    first = default_spatial_mode(traits)
    spatial = [first] + [m for m in SPATIAL_MODES if m != first]
    return (["global"] + spatial) if persistent_launch_validated(traits) else spatial


def _contact_geometry_candidates(traits: DeviceTraits) -> list:
    """The solver's default on the device's own solve form first (kept by a CPU's serial
    form, not by a GPU's launch), then the other."""
    kept = bool(default_values(traits)["contact_geometry"])
    return [kept, not kept]


_CANDIDATES = {
    "batching": _batching_candidates,
    "release_sweeps": lambda traits: [2, 1, 3, None],
    "ordered_rounds": lambda traits: [ORDERED_ROUNDS, 32, 128],
    "group_count": lambda traits: [
        default_group_count(traits),
        max(1, default_group_count(traits) // 2),
        2 * default_group_count(traits),
    ],
    "contact_geometry": _contact_geometry_candidates,
}
_ALSO_ALLOWED = {
    "batching": lambda v: v in MODES,
    "release_sweeps": lambda v: (
        v is None or (isinstance(v, int) and not isinstance(v, bool) and v >= 0)
    ),
    "ordered_rounds": lambda v: isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 2**32,
    "group_count": lambda v: isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 4096,
    "contact_geometry": lambda v: isinstance(v, bool),
}

#: plan parameters `rbgen tune` chooses per device (the first candidate is the hand-set
#: default)
TUNABLES = {
    t.name: t
    for t in (
        Tunable("batching", "the colouring a PGS solve runs over; the fastest that holds"),
        Tunable(
            "release_sweeps",
            "the last sweeps that solve each manifold's complete block; "
            "the earlier ones take its cheaper all-pushing solution",
        ),
        Tunable(
            "ordered_rounds",
            "global batching: colouring rounds a step in index order "
            "(fewest colours) before hashed rounds finish the step",
        ),
        Tunable("group_count", "spatial batching: groups per colour (work for every core)"),
        Tunable(
            "contact_geometry",
            "block normal solve, serial form or persistent launch: each contact's face "
            "block and friction rows derived once a step and loaded by every sweep",
        ),
    )
}


@dataclasses.dataclass(frozen=True)
class Plan:
    """Every choice of one World on one device (see the module docstring).

    ``batching`` is None for the Jacobi solver (it colours nothing). ``persistent``: the
    solver runs as one persistent launch (`rbgen.pipeline.device_barrier`).
    ``reasons`` has one sentence per choice; ``sources`` says where each came from
    ("option": the World's options, "tuned": the tuning cache, "default": the device's
    hand-set default, "fallback": a persistent launch gave up on this device).
    """

    device: str
    device_name: str
    solver: str
    batching: str | None
    solve_form: str | None
    persistent: bool
    normal_solve: str
    warm_start_mode: str | None
    fast_math: bool
    release_sweeps: int | None
    ordered_rounds: int
    group_count: int
    broadphase: str
    gyroscopic: bool
    shape_types: tuple[str, ...]
    #: the World has joints: the PGS solve visits joint items too (`rbgen.pipeline.joints`)
    joints: bool = False
    #: bodies at rest fall asleep (`rbgen.pipeline.sleep`; the World option ``sleeping``)
    sleeping: bool = False
    #: the PGS block solve keeps a ContactGeometry record a contact for the step
    #: (`rbgen.pipeline.solvers.pgs`, the template parameter contact_geometry)
    contact_geometry: bool = False
    #: the PGS solve stops bodies sinking into their supports along whole chains after
    #: each substep's sweeps (`rbgen.pipeline.solvers.support`; the World option
    #: ``support_chains``)
    support_chains: bool = False
    reasons: dict = dataclasses.field(compare=False, default_factory=dict)
    sources: dict = dataclasses.field(compare=False, default_factory=dict)

    def check_settings(self, settings) -> None:
        """Refuse step ``settings`` this plan cannot run, naming the setting, before a
        step enqueues anything: shock_propagation=True needs the PGS solver and a velocity
        sweep before the shock sweep (iterations >= 2); None (the default) asks for it only
        where it can run (`rbgen.pipeline.solvers.common.shock_sweep`)."""
        if getattr(settings, "shock_propagation", False) is not True:
            return
        if self.solver != "pgs":
            raise RbgenError(
                f"shock_propagation=True is a sweep of solver 'pgs'; this World's solver is "
                f"{self.solver!r}: set shock_propagation=False or build it with solver='pgs'"
            )
        check_sweeps(
            settings.iterations, settings.position_iterations, settings.relaxation, shock=True
        )

    def choices(self) -> dict[str, Any]:
        """The choices as plain values (no reasons)."""
        return {
            f.name: getattr(self, f.name)
            for f in dataclasses.fields(self)
            if f.name not in ("reasons", "sources")
        }

    def to_json(self) -> str:
        """The plan as JSON: every choice with its source and reason."""
        choices = self.choices()
        choices["shape_types"] = list(self.shape_types)
        return json.dumps(
            {"choices": choices, "sources": self.sources, "reasons": self.reasons}, indent=2
        )

    def describe(self) -> str:
        """One line for logs and benchmarks."""
        if self.solver == "jacobi":
            solve = f"jacobi ({self.normal_solve} normal solve)"
        else:
            solve = (
                f"pgs over {self.batching} batching ({self.solve_form}, "
                f"{self.normal_solve} normal solve, release sweeps "
                f"{self.release_sweeps if self.normal_solve == 'block' else '-'}, "
                f"{self.warm_start_mode} warm start)"
            )
        return (
            f"{solve}{', persistent launch' if self.persistent else ''}, "
            f"{'fast' if self.fast_math else 'exact'} math, {self.broadphase} broadphase"
            f"{', sleeping islands' if self.sleeping else ''}"
            f"{', support chains' if self.support_chains else ''}"
        )


def derive_plan(
    traits: DeviceTraits,
    options: dict,
    shape_types=(),
    *,
    tuned: dict | None = None,
    persistent_failed: bool = False,
    joints: bool = False,
) -> Plan:
    """The plan of a World with construction ``options`` (checked, as `rbgen.settings`
    returns them) whose shapes have ``shape_types``, on a device with ``traits``.

    ``tuned``: the tuning cache's plan entry for this device (None: look it up).
    ``persistent_failed``: a persistent launch gave up on this World's device (its work
    groups did not all run at once), so none is planned.
    ``joints``: the World has joints (only the PGS solver solves them).
    """
    if tuned is None:
        from .tuning import lookup_plan

        tuned = lookup_plan(traits)
    overrides = dict(options.get("plan") or {})
    unknown = sorted(set(overrides) - set(TUNABLES))
    if unknown:
        raise RbgenError(f"unknown plan parameter(s) {unknown}; tunable: {sorted(TUNABLES)}")
    reasons: dict[str, str] = {}
    sources: dict[str, str] = {}

    def pick(name: str, option_value, default, reason: str, *, tunable: bool = False):
        if option_value is not None:
            sources[name], reasons[name] = "option", "set by the World's options"
            return option_value
        if tunable and name in overrides:
            sources[name], reasons[name] = "option", "set by the World's plan overrides"
            return TUNABLES[name].check(overrides[name], traits)
        if tunable and name in tuned:
            sources[name], reasons[name] = "tuned", f"measured fastest on this device; {reason}"
            return tuned[name]
        sources[name], reasons[name] = "default", reason
        return default

    solver = options["solver"]
    if solver == "jacobi" and options["batching"] is not None:
        raise RbgenError(
            f"batching={options['batching']!r} needs solver='pgs': the Jacobi "
            f"solver colours nothing"
        )
    sources["solver"] = "option" if solver != "pgs" else "default"
    reasons["solver"] = (
        "Gauss-Seidel over colours holds stacks at the default sweeps"
        if solver == "pgs"
        else "set by the World's options"
    )
    if joints and solver != "pgs":
        raise RbgenError(
            f"joints need solver='pgs' (the {solver} solver has no joint rows); make the "
            f"World with solver='pgs' or without joints"
        )
    validated = persistent_launch_validated(traits) and not persistent_failed
    batching = solve_form = warm_start_mode = None
    if solver == "pgs":
        capable = persistent_launch_validated(traits)
        batching = pick(
            "batching",
            options["batching"],
            "global" if capable else default_spatial_mode(traits),
            "one colouring and one solver launch a step over every compute unit"
            if capable
            else SPATIAL_REASONS[default_spatial_mode(traits)],
            tunable=True,
        )
        if persistent_failed and batching == "global":
            batching = default_spatial_mode(traits)
            sources["batching"] = "fallback"
            reasons["batching"] = (
                "a persistent launch gave up on this device (its work "
                "groups did not all run at once)"
            )
        solve_form = "lanes" if batching == "global" else default_solve_form(traits)
        reasons["solve_form"] = (
            "a work group's lanes solve a batch together on GPUs; one "
            "work-item walks its group in order on CPUs"
        )
        sources["solve_form"] = "default"
        persistent = batching == "global"
        reasons["persistent"] = "global batching's batches are solved by one persistent launch"
    else:
        persistent = validated
        reasons["persistent"] = (
            "one launch runs every phase where every work group runs at once"
            if validated
            else "one launch per phase"
        )
    sources["persistent"] = "default"
    normal_solve = pick(
        "normal_solve",
        options["normal_solve"],
        "block" if solver == "jacobi" else default_normal_solve(),
        "the block leaves no point-order torque where manifolds are solved "
        "side by side or a column is split between launches"
        if traits.is_gpu or solver == "jacobi" or batching not in ("slabs", "columns")
        else "the block holds a 30-box column that one normal row at a time topples, "
        "and with the CPU's default substeps the lattices",
    )
    if solver == "pgs":
        summed = persistent and traits.has_extension(INT64_ATOMICS)
        warm_start_mode = "summed" if summed else "batched"
        sources["warm_start_mode"] = "default"
        reasons["warm_start_mode"] = (
            "two phases instead of a batch step per colour, order-free integer sums"
            if summed
            else "a batch step per colour (no device-wide barrier or 64-bit atomics)"
        )
    fast_math = pick(
        "fast_math",
        options["fast_math"],
        traits.is_gpu,
        "a shorter dependent chain per lane on GPUs; exact arithmetic keeps CPU "
        "results the reference",
    )
    if solver == "pgs":
        release_sweeps = pick(
            "release_sweeps",
            None,
            2,
            "the last two sweeps remove the rows' point-order residual; the "
            "earlier ones are cheaper",
            tunable=True,
        )
    else:
        release_sweeps = None
        sources["release_sweeps"] = "default"
        reasons["release_sweeps"] = "the Jacobi solver solves the complete block every sweep"
    ordered_rounds = pick(
        "ordered_rounds",
        None,
        ORDERED_ROUNDS,
        "enough index-order rounds to reach the fewest colours over a few steps",
        tunable=True,
    )
    group_count = pick(
        "group_count",
        None,
        default_group_count(traits),
        "two groups per compute unit on GPUs, eight per core on CPUs",
        tunable=True,
    )
    form = {"normal_solve": normal_solve, "solve_form": solve_form, "persistent": persistent}
    can_keep = solver == "pgs" and can_keep_contact_geometry(form)
    not_kept = "only the block solve's serial form or persistent launch keeps it"
    contact_geometry = pick(
        "contact_geometry",
        None,
        can_keep and default_contact_geometry(form),
        "a CPU core loads a contact's face block faster than it derives it; a GPU lane's "
        "visit is the block solve itself, and the records' loads slow large scenes"
        if can_keep
        else not_kept,
        tunable=True,
    )
    if contact_geometry and not can_keep:
        if sources["contact_geometry"] == "option":
            raise RbgenError(
                "plan parameter contact_geometry=True needs the PGS block normal solve in "
                f"the serial form or a persistent launch; this plan solves "
                f"{solver!r} ({normal_solve} normal solve, {solve_form} form, "
                f"{'persistent' if persistent else 'launch per colour'})"
            )
        contact_geometry = False  # (tuned under another batching)
        sources["contact_geometry"], reasons["contact_geometry"] = "default", not_kept
    support_chains = bool(options.get("support_chains", False))
    sources["support_chains"] = "option" if support_chains else "default"
    reasons["support_chains"] = (
        "set by the World's options" if support_chains else "off unless the World's options ask"
    )
    if support_chains and solver != "pgs":
        raise RbgenError(
            f"support_chains=True follows the sweeps of solver 'pgs'; this World's solver is "
            f"{solver!r}: set support_chains=False or build it with solver='pgs'"
        )
    if support_chains and joints:
        support_chains = False
        reasons["support_chains"] = (
            "off in a World with joints: a jointed body is held by its joints too, which "
            "the chains do not see"
        )
    return Plan(
        device=traits.fingerprint,
        device_name=traits.device_name,
        solver=solver,
        batching=batching,
        solve_form=solve_form,
        persistent=persistent,
        normal_solve=normal_solve,
        warm_start_mode=warm_start_mode,
        fast_math=bool(fast_math),
        release_sweeps=None if release_sweeps is None else int(release_sweeps),
        ordered_rounds=int(ordered_rounds),
        group_count=int(group_count),
        broadphase=options["broadphase"],
        gyroscopic=bool(options["gyroscopic"]),
        shape_types=tuple(sorted(shape_types)),
        joints=bool(joints),
        sleeping=bool(options.get("sleeping", False)),
        contact_geometry=bool(contact_geometry),
        support_chains=support_chains,
        reasons=reasons,
        sources=sources,
    )
