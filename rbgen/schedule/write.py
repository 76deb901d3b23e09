"""`write_schedule`: a World's kernels, header, plan and schedule in one directory."""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import RbgenError
from . import GROW_RUNGS, record_schedule
from .format import assemble, sha256

SCHEDULE_NAME = "schedule.json"


def grown_capacities(world) -> dict[str, int]:
    """The capacities ``world``'s stages grow on overflow, with their values now."""
    found: dict[str, int] = {}
    for stage in world._steps.stages:
        grown = stage.report_protocol().get("capacities", {})
        found.update({k: v for k, v in stage.capacities().items() if k in grown})
    return found


def write_schedule(
    world,
    build,
    out_dir,
    *,
    dt: float = 1 / 60,
    grow_rungs: int = GROW_RUNGS,
    command: str | None = None,
) -> dict:
    """Export ``world`` (stepped once, so that its kernels and capacities are known) with
    its schedule, recorded from fresh Worlds that ``build()`` returns (the same scene,
    unstepped). Writes the kernels, ``rbgen_layouts.h``, ``plan.json``, ``manifest.json``,
    ``schedule.json`` and ``data/`` (the buffers' initial contents: bodies, shapes, ...).
    ``command``: how to make this export again (a host names it when the export does not
    fit its device). Returns the manifest."""
    from ..export import export_kernels

    if world._pipeline is None:
        raise RbgenError("export: the World has not stepped yet; step it once first")
    initial = {name: max(1, value) for name, value in grown_capacities(world).items()}

    def like_world():
        fresh = build()
        # (a World whose persistent launch gave up plans without one from then on)
        fresh._persistent_failed = world._persistent_failed
        return fresh

    inference, runs = record_schedule(like_world, initial, dt=dt, grow_rungs=grow_rungs)
    try:
        if runs[0].world.plan != world.plan:
            raise RbgenError(
                f"export: the schedule's World planned "
                f"{runs[0].world.plan.describe()}, the exported World "
                f"{world.plan.describe()} (build() must make the same World)"
            )
        specs = list(world.kernel_specs())
        for kernel in inference.kernels:
            if (kernel.spec, kernel.options) not in specs:
                specs.append((kernel.spec, kernel.options))
        out = Path(out_dir)
        manifest = export_kernels(
            specs, out, world.runtime.traits, plan=world.plan, runtime=world.runtime
        )
        files = {spec_options: entry for spec_options, entry in zip(specs, manifest["files"])}
        programs: list[dict] = []
        program_index: dict = {}
        for kernel in inference.kernels:
            key = (kernel.spec, kernel.options)
            if key not in program_index:
                entry = files[key]
                program_index[key] = len(programs)
                programs.append({"file": entry["file"], "build_options": entry["build_options"]})
        schedule, data = assemble(inference, program_index)
    finally:
        for run in runs:
            run.close()
    schedule["programs"] = programs
    schedule["command"] = command or (
        "rbgen.export.export_world(world, DIR, build=...) with the scene's World"
    )
    for name, content in data.items():
        path = out / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(content)
    checked = [p["file"] for p in programs] + sorted(data)
    schedule["files"] = {name: sha256((out / name).read_bytes()) for name in checked}
    (out / SCHEDULE_NAME).write_text(json.dumps(schedule, separators=(",", ":")) + "\n")
    manifest["schedule"] = SCHEDULE_NAME
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest
