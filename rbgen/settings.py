"""Every World option in one table: its default, what it allows, and why.

Two kinds:

* **step settings** (`STEP_SETTINGS`): numbers the step reads each time, changeable
  between steps as World attributes (``world.iterations = 20``);
* **construction options** (`CONSTRUCTION_OPTIONS`): choices that decide which kernels
  run; fixed for a World (its `rbgen.plan.Plan` is derived from them).

A default given as None for a construction option means "the device's choice", which the
plan makes and explains (`Plan.reasons`). A step setting may have its own default on CPUs
(``cpu_default``): the effort that holds the stacks at the least cost differs between a
GPU's side-by-side solve and a CPU's serial one: each default is the least effort at
which the BoxBox lattices hold in `benchmarks/holds.py` (its recorded results compare the
candidates). Every value is checked when set: a bad one
raises `RbgenError` naming the option and what it allows, and leaves the World as it was.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from .errors import RbgenError


@dataclasses.dataclass(frozen=True)
class Option:
    """One World option: name, default, check (returns the normalised value or raises
    RbgenError), what it allows (for errors and the README) and why it exists.

    ``cpu_default``: the default on CPU devices where it differs (None: ``default``
    everywhere). ``literal_none``: a default of None means what ``allowed`` says, not the
    device's choice (the README's table shows it as None)."""

    name: str
    default: Any
    check: Callable[[Any], Any]
    allowed: str
    doc: str
    cpu_default: Any = None
    literal_none: bool = False

    def default_for(self, is_gpu: bool):
        """The default on a GPU (``is_gpu``) or a CPU device."""
        return self.default if is_gpu or self.cpu_default is None else self.cpu_default


def _integer(lo: int, hi: int | None = None) -> Callable[[Any], Any]:
    def check(value):
        if (
            isinstance(value, (bool, np.bool_))
            or not isinstance(value, (int, np.integer))
            or value < lo
            or (hi is not None and value > hi)
        ):
            raise ValueError
        return int(value)

    return check


def _number(
    lo: float, hi: float | None = None, *, open_lo: bool = False, open_hi: bool = False
) -> Callable[[Any], Any]:
    def check(value):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
            raise ValueError
        value = float(value)
        if not math.isfinite(value) or value < lo or (open_lo and value == lo):
            raise ValueError
        if hi is not None and (value > hi or (open_hi and value == hi)):
            raise ValueError
        return value

    return check


def _flag(value):
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError
    return bool(value)


def _choice(*values, none: bool = False) -> Callable[[Any], Any]:
    def check(value):
        if value is None and none:
            return None
        if not isinstance(value, str) or value not in values:
            raise ValueError
        return value

    return check


def _optional(check: Callable[[Any], Any]) -> Callable[[Any], Any]:
    return lambda value: None if value is None else check(value)


def _vector3(value):
    arr = np.asarray(value, float).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError
    return arr


def _plan_overrides(value):
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ValueError
    return dict(value)


#: settings a step reads; attributes of the World, changeable between steps
STEP_SETTINGS = (
    Option(
        "gravity",
        (0.0, -9.81, 0.0),
        _vector3,
        "3 finite numbers (m/s^2)",
        "acceleration of every dynamic body",
    ),
    Option(
        "substeps",
        8,
        _integer(1, 64),
        "an integer from 1 to 64",
        "solver substeps a step on the step's contacts: stiffness from the substep rate "
        "holds tall stacks; each costs the sweeps below, not a collision pass",
        cpu_default=4,
    ),
    Option(
        "iterations",
        2,
        _integer(0, 1000),
        "an integer from 0 to 1000",
        "velocity sweeps of the solver a substep: more hold taller stacks, linearly dearer",
        cpu_default=3,
    ),
    Option(
        "position_iterations",
        1,
        _integer(0, 1000),
        "an integer from 0 to 1000",
        "split-impulse push sweeps a substep: remove penetration without adding momentum",
    ),
    Option(
        "relaxation",
        1.0,
        _number(0.0, 2.0, open_lo=True, open_hi=True),
        "a number in (0, 2)",
        "successive over-relaxation of each row (1: plain "
        "Gauss-Seidel; above 1 makes columns walk sideways)",
    ),
    Option(
        "shock_propagation",
        None,
        _optional(_flag),
        "True, False or None (on wherever it can run: solver 'pgs', iterations >= 2, no joints)",
        "the last velocity sweep of each substep holds the lower body of every contact "
        "that carries a load against gravity still: a stack's velocities agree from the "
        "ground up, so tall stacks come to rest instead of breathing; not "
        "momentum-conserving in that sweep",
        literal_none=True,
    ),
    Option(
        "warm_start",
        True,
        _flag,
        "True or False",
        "start each step from the last step's impulses of the same contact: stacks "
        "converge over steps instead of within one",
    ),
    Option(
        "contact_margin",
        0.02,
        _number(0.0),
        "a finite number >= 0 (m)",
        "contacts are created this far apart, so resting contacts persist between steps",
    ),
    Option(
        "restitution_threshold",
        0.5,
        _number(0.0),
        "a finite number >= 0 (m/s)",
        "slower impacts do not bounce, so resting bodies do not jitter",
    ),
    Option(
        "penetration_slop",
        0.001,
        _number(0.0),
        "a finite number >= 0 (m)",
        "penetration left alone, so resting contacts do not flicker",
    ),
    Option(
        "penetration_recovery",
        0.2,
        _number(0.0, 1.0),
        "a number in [0, 1]",
        "fraction of the penetration the push sweeps remove a step",
    ),
    Option(
        "joint_recovery",
        0.5,
        _number(0.0, 1.0),
        "a number in [0, 1]",
        "fraction of a joint's error (anchors apart, axes turned, a limit crossed) the "
        "push sweeps remove a substep, without adding momentum",
    ),
    Option(
        "linear_damping",
        0.0,
        _number(0.0, 1.0, open_hi=True),
        "a number in [0, 1)",
        "fraction of linear velocity lost per second (v *= (1 - d)^dt)",
    ),
    Option(
        "angular_damping",
        0.0,
        _number(0.0, 1.0, open_hi=True),
        "a number in [0, 1)",
        "fraction of angular velocity lost per second",
    ),
    Option(
        "sleep_threshold",
        0.05,
        _number(0.0, 100.0, open_lo=True),
        "a number in (0, 100] (m/s)",
        "with sleeping on: a body rests while its speed plus its spin times its extent "
        "(its fastest surface point) stays below this (Box2D v3's 0.05 m/s)",
    ),
    Option(
        "sleep_time",
        0.5,
        _number(0.0, 3600.0, open_lo=True),
        "a number in (0, 3600] (seconds)",
        "with sleeping on: an island whose every body has rested this long falls asleep "
        "(Box2D v3's and Jolt's 0.5 s)",
    ),
)

#: choices that decide the kernels; fixed for a World (see `rbgen.plan`)
CONSTRUCTION_OPTIONS = (
    Option(
        "solver",
        "pgs",
        _choice("pgs", "jacobi"),
        "'pgs' or 'jacobi'",
        "pgs: Gauss-Seidel over colours, holds stacks; jacobi: mass splitting, no "
        "colouring, soft in tall stacks at equal sweeps",
    ),
    Option(
        "batching",
        None,
        _choice("global", "cells", "slabs", "columns", none=True),
        "None (the device's choice), 'global', 'cells', 'slabs' or 'columns'",
        "how PGS colours constraints for parallel solving (rbgen.pipeline.batching)",
    ),
    Option(
        "normal_solve",
        None,
        _choice("block", "sequential", none=True),
        "None (the device's choice), 'block' or 'sequential'",
        "a manifold's normal rows solved together (no point-order torque) or one by one",
    ),
    Option(
        "broadphase",
        "grid",
        _choice("grid", "sap", "sap3"),
        "'grid', 'sap' or 'sap3'",
        "grid for similar sizes (a second, coarser level of cells for bodies over twice the "
        "typical size); sap / sap3 (incremental) for widely varying sizes",
    ),
    Option(
        "fast_math",
        None,
        _optional(_flag),
        "None (the device's choice), True or False",
        "build the contact solver with -cl-fast-relaxed-math (a shorter dependent chain)",
    ),
    Option(
        "gyroscopic",
        True,
        _flag,
        "True or False",
        "the implicit gyroscopic term: free spinning bodies keep their angular momentum",
    ),
    Option(
        "sleeping",
        False,
        _flag,
        "True or False",
        "islands of bodies at rest fall asleep (static, no work) until touched, pushed or "
        "set (rbgen.pipeline.sleep)",
    ),
    Option(
        "support_chains",
        False,
        _flag,
        "True or False",
        "after each substep's velocity sweeps of the PGS solver, no body sinks into the "
        "body that holds it up faster than their gap allows, along whole chains of supports "
        "at once (rbgen.pipeline.solvers.support): a tall stack's weight reaches the ground "
        "within the substep instead of a few layers a sweep; not momentum-conserving; off "
        "in a World with joints (the chains do not see them) and without gravity",
    ),
    Option(
        "manifold_capacity",
        None,
        _optional(_integer(1, 1 << 30)),
        "None or an integer from 1 to 2^30",
        "initial manifold buffer (grown on overflow)",
        literal_none=True,
    ),
    Option(
        "pair_capacity",
        None,
        _optional(_integer(1, 1 << 30)),
        "None or an integer from 1 to 2^30",
        "initial pair buffer (grown on overflow)",
        literal_none=True,
    ),
    Option(
        "plan",
        None,
        _plan_overrides,
        "None or a dict of plan parameters",
        "expert overrides of tuned plan parameters (rbgen.plan.TUNABLES)",
        literal_none=True,
    ),
    Option(
        "memory_limit",
        None,
        _optional(_integer(1)),
        "None or a positive integer (bytes)",
        "device memory this World may use (None: the device's global memory; OpenCL "
        "cannot see other processes on a shared GPU); refused before allocating",
        literal_none=True,
    ),
)

STEP = {o.name: o for o in STEP_SETTINGS}
CONSTRUCTION = {o.name: o for o in CONSTRUCTION_OPTIONS}


def check(option: Option, value):
    """``value`` normalised by ``option``'s check, or RbgenError naming both."""
    try:
        return option.check(value)
    except (ValueError, TypeError):
        raise RbgenError(
            f"World option {option.name}={value!r} is not allowed: expected {option.allowed}"
        ) from None


def split_options(options: dict, is_gpu: bool = True) -> tuple[dict, dict]:
    """(step settings, construction options) from World keyword arguments, every value
    checked and every default filled in (a GPU's, or a CPU's where ``is_gpu`` is false);
    an unknown name is refused, listing the known."""
    unknown = sorted(set(options) - set(STEP) - set(CONSTRUCTION))
    if unknown:
        raise RbgenError(
            f"unknown World option(s) {unknown}; known: "
            f"{sorted(STEP)} (step settings) and {sorted(CONSTRUCTION)} "
            f"(construction options)"
        )
    step = {name: check(o, options.get(name, o.default_for(is_gpu))) for name, o in STEP.items()}
    construction = {
        name: check(o, options.get(name, o.default)) for name, o in CONSTRUCTION.items()
    }
    return step, construction


class Settings:
    """The step settings of one World (see `STEP_SETTINGS`): attributes checked on set."""

    __slots__ = tuple(STEP)
    gravity: np.ndarray
    substeps: int
    iterations: int
    position_iterations: int
    relaxation: float
    shock_propagation: bool | None
    warm_start: bool
    contact_margin: float
    restitution_threshold: float
    penetration_slop: float
    penetration_recovery: float
    linear_damping: float
    angular_damping: float
    sleep_threshold: float
    sleep_time: float

    def __init__(self, values: dict):
        for name, value in values.items():
            object.__setattr__(self, name, value)

    def __setattr__(self, name, value):
        option = STEP.get(name)
        if option is None:
            raise RbgenError(f"no step setting {name!r}; settings: {sorted(STEP)}")
        object.__setattr__(self, name, check(option, value))

    def as_dict(self) -> dict:
        return {name: getattr(self, name) for name in STEP}


def options_table() -> str:
    """The options as a Markdown table (the README's settings table)."""
    rows = ["| option | default | allowed | why |", "| --- | --- | --- | --- |"]
    for option in STEP_SETTINGS + CONSTRUCTION_OPTIONS:
        default = (
            "device's choice"
            if option.default is None and not option.literal_none
            else repr(option.default)
        )
        if option.cpu_default is not None:
            default += f" (CPU: {option.cpu_default!r})"
        rows.append(f"| `{option.name}` | {default} | {option.allowed} | {option.doc} |")
    return "\n".join(rows)
