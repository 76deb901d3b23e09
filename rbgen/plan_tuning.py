"""Tuning the plan: the batching and solver parameters measured per device.

`tune_plan` times whole World steps of a standard scene (BoxBox from the lattice's start)
for the candidates of each tunable plan parameter (`rbgen.plan.TUNABLES`), one parameter
at a time in that order (coordinate descent: a later parameter is tuned under the winners
of the earlier ones), skipping a parameter the current choice makes moot (ordered rounds
need global batching, group counts spatial batching, release sweeps a block normal
solve). A candidate counts only if its scene holds at least as well as the hand-set
default's (no NaN, nothing sunk, no more boxes displaced): a time counts only for a scene
that holds. Among those, the fastest wins, except that a candidate listed earlier within
the timing noise wins instead (the hand-set default is listed first, so noise never moves
a device away from it). The winners go to the device's tuning cache (entry "plan"), which
`rbgen.plan.derive_plan` reads.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

from .device import Runtime
from .pipeline.batching import SPATIAL_MODES
from .pipeline.solvers.pgs import can_keep_contact_geometry
from .plan import TUNABLES, derive_plan
from .settings import split_options
from .tuning import NOISE, PLAN_ENTRY, PLAN_VERSION, load_cache, pick_winner, save_cache


@dataclasses.dataclass(frozen=True)
class TuningScene:
    """The scene a plan is tuned on: a harness scene, its size, warm-up and timed steps."""

    name: str
    size: int
    warmup: int
    steps: int


#: GPUs: a lattice big enough that batching and solve dominate; CPUs: one that a 2-core
#: machine times in seconds
GPU_SCENE = TuningScene("boxbox", 8000, 10, 100)
CPU_SCENE = TuningScene("boxbox", 1000, 5, 40)
QUICK_SCENE = TuningScene("boxbox", 1000, 3, 10)


def relevant(name: str, values: dict) -> bool:
    """Whether tunable ``name`` matters under the plan ``values`` chosen so far."""
    if name == "ordered_rounds":
        return values["batching"] == "global"
    if name == "group_count":
        return values["batching"] in SPATIAL_MODES
    if name == "release_sweeps":
        return values["normal_solve"] == "block"
    if name == "contact_geometry":
        return can_keep_contact_geometry(values)
    return True


def holds(summary: dict, reference: dict) -> bool:
    """A candidate's scene holds when it has no NaN, nothing sunk, and no more boxes
    displaced than the hand-set default's run of the same scene."""
    return (
        summary["nans"] == 0
        and summary["sunk"] == 0
        and summary.get("displaced", 0) <= reference.get("displaced", 0)
    )


def choose(results: list[tuple[object, dict]], reference: dict, noise: float = NOISE):
    """The winning candidate value among ``(value, run summary)``, listed default first:
    the fastest that holds, ties within ``noise`` to the earlier one."""
    timed = [
        (value, summary["ms_per_step"] if holds(summary, reference) else None)
        for value, summary in results
    ]
    winner = pick_winner(timed, noise)
    return results[0][0] if winner is None else timed[winner][0]


def tune_plan(
    runtime: Runtime,
    *,
    quick: bool = False,
    scene: TuningScene | None = None,
    progress: Callable[[str], None] | None = None,
    store: bool = True,
) -> dict:
    """Tune the plan parameters of ``runtime``'s device (see the module docstring);
    returns the cache entry (stored unless ``store`` is False)."""
    from .harness import run_scene

    traits = runtime.traits
    scene = scene or (QUICK_SCENE if quick else GPU_SCENE if traits.is_gpu else CPU_SCENE)
    options = split_options({})[1]
    default = derive_plan(traits, options, ("box",), tuned={})
    chosen = {name: getattr(default, name) for name in TUNABLES}

    def run(values: dict) -> dict:
        return run_scene(
            scene.name,
            scene.size,
            scene.steps,
            device=runtime,
            progress=False,
            warmup=scene.warmup,
            plan=values,
        )

    reference = run(chosen)
    timings = []
    for name, tunable in TUNABLES.items():
        plan = derive_plan(traits, {**options, "plan": chosen}, ("box",), tuned={})
        if not relevant(
            name,
            {
                **chosen,
                "normal_solve": plan.normal_solve,
                "solve_form": plan.solve_form,
                "persistent": plan.persistent,
            },
        ):
            continue
        results = []
        for value in tunable.candidates(traits):
            summary = reference if value == chosen[name] else run({**chosen, name: value})
            results.append((value, summary))
            timings.append(
                {
                    "parameter": name,
                    "value": value,
                    "ms_per_step": summary["ms_per_step"],
                    "holds": holds(summary, reference),
                }
            )
            if progress:
                progress(
                    f"  plan {name}={value!r}: {summary['ms_per_step']:.3f} ms/step"
                    + ("" if holds(summary, reference) else " (does not hold)")
                )
        chosen[name] = choose(results, reference)
    entry = {
        "plan_version": PLAN_VERSION,
        "values": chosen,
        "scene": f"{scene.name} {scene.size}, {scene.steps} steps",
        "timings": timings,
        "tuned_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    if store:
        cache = load_cache(traits, reload=True)
        cache["entries"][PLAN_ENTRY] = entry
        save_cache(traits, cache)
    return entry
