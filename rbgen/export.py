"""Export generated kernels for programs that do not run Python.

`export_kernels` writes, into one directory (`export_world`: a World's own kernels and
its plan, exactly what it compiled):

* one ``.cl`` file per specialisation: self-contained OpenCL C (structs and
  constants included), exactly the source rbgen builds;
* ``rbgen_layouts.h``: the C/C++ header of every host/device struct, with
  static asserts on sizes and offsets;
* ``manifest.json``: for every file its template, specialisation parameters,
  build options, source hash, and per kernel the argument names, C types and
  roles (input / output / inout / scalar / local) and the recommended local size,
  and (a World's export) what the device's compiler made of it
  (`rbgen.codegen.kernel_resources`: the largest work group it runs, private memory
  a work-item, local memory a work group); plus the fingerprint of the device the
  specialisations were chosen for;
* ``plan.json`` (a World's export): its `rbgen.plan.Plan`, every choice with its source
  and reason;
* ``schedule.json`` and ``data/`` (a World's export with ``build``): its step as a launch
  schedule and its buffers' initial contents, which the C++ runtime in ``rbgen/host``
  replays (`rbgen.schedule`; ``rbgen/host/SCHEDULE.md`` describes the format).

A C++ host reads the manifest, builds the ``.cl`` with ``clBuildProgram`` and
sets arguments in the listed order using the structs of the header.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import pkgutil
import re
from collections.abc import Iterable
from pathlib import Path

from . import __version__, layouts
from .codegen import TEMPLATES, KernelSpec, KernelTemplate, kernel_resources, kernel_signatures
from .device import DeviceTraits
from .errors import RbgenError

MANIFEST_VERSION = 1
HEADER_NAME = "rbgen_layouts.h"


def load_all_templates() -> dict[str, KernelTemplate]:
    """Import every rbgen module that declares templates; return the registry."""
    import rbgen

    for info in pkgutil.walk_packages(rbgen.__path__, "rbgen."):
        if info.name.endswith(("__main__", ".cli")):
            continue
        importlib.import_module(info.name)
    return dict(TEMPLATES)


def _json_value(value):
    if isinstance(value, tuple):
        return [_json_value(v) for v in value]
    return value


def _file_name(spec: KernelSpec, options: tuple[str, ...], taken: set[str]) -> str:
    stem = spec.path.removesuffix(".cl.mako").replace("/", "_")
    name = f"{stem}.cl"
    if name in taken:
        digest = hashlib.sha256(repr((spec.params, options)).encode()).hexdigest()[:8]
        name = f"{stem}_{digest}.cl"
    taken.add(name)
    return name


def _local_sizes(source: str) -> dict[str, int]:
    pattern = re.compile(r"reqd_work_group_size\(\s*(\d+)[^)]*\)\s*\)\)\s*void\s+(\w+)")
    return {m.group(2): int(m.group(1)) for m in pattern.finditer(source)}


def export_kernels(
    specs: Iterable,
    out_dir: str | Path,
    traits: DeviceTraits | None = None,
    build_options: Iterable[str] = (),
    plan=None,
    runtime=None,
) -> dict:
    """Write the specs' sources, the layouts header and the manifest; return the manifest.

    ``specs``: `KernelSpec`s, or (spec, build options) pairs as a World compiled them
    (the options then replace the spec's own plus ``build_options``). ``plan``: a
    `rbgen.plan.Plan` to write as plan.json and into the manifest. ``runtime``: the
    `rbgen.device.Runtime` the specs were built on; given, each kernel's entry carries
    ``resources`` on its device (`rbgen.codegen.kernel_resources`)."""
    specs = list(specs)
    if not specs:
        raise RbgenError("export: no kernel specs given")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / HEADER_NAME).write_text(layouts.c_header())
    taken: set[str] = set()
    entries = []
    for item in specs:
        spec, options = item if isinstance(item, tuple) else (item, None)
        if not isinstance(spec, KernelSpec):
            raise RbgenError(f"export: expected KernelSpec, got {type(spec).__name__}")
        if options is None:
            options = (
                *spec.build_options,
                *(o for o in build_options if o not in spec.build_options),
            )
        source = spec.source
        fname = _file_name(spec, tuple(options), taken)
        (out / fname).write_text(source)
        roles = spec.template.roles if spec.template is not None else {}
        local = _local_sizes(source)
        resources = {} if runtime is None else kernel_resources(runtime, spec, options)
        entries.append(
            {
                "file": fname,
                "template": spec.path,
                "params": {k: _json_value(v) for k, v in spec.params},
                "build_options": list(options),
                "source_sha256": hashlib.sha256(source.encode()).hexdigest(),
                "kernels": [
                    {
                        "name": name,
                        "args": args,
                        "local_size": local.get(name),
                        **({"resources": resources[name]} if name in resources else {}),
                    }
                    for name, args in kernel_signatures(source, roles).items()
                ],
            }
        )
    manifest = {
        "manifest_version": MANIFEST_VERSION,
        "rbgen_version": __version__,
        "header": HEADER_NAME,
        "device": None
        if traits is None
        else {
            "fingerprint": traits.fingerprint,
            "name": traits.device_name,
            "platform": traits.platform_name,
            "driver_version": traits.driver_version,
            "wavefront": traits.wavefront,
        },
        "structs": {
            layout.name: {
                "size": layout.itemsize,
                "fields": {f.name: layout.offset(f.name) for f in layout.fields},
            }
            for layout in layouts.all_layouts()
        },
        "files": entries,
    }
    if plan is not None:
        manifest["plan"] = json.loads(plan.to_json())
        (out / "plan.json").write_text(plan.to_json() + "\n")
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest


def export_world(
    world,
    out_dir: str | Path,
    *,
    build=None,
    dt: float = 1 / 60,
    grow_rungs: int | None = None,
    command: str | None = None,
) -> dict:
    """Write every kernel specialisation ``world`` compiled, with the build options it used,
    its plan, the header and the manifest (what a C++ host needs to run what the World runs).
    The World must have stepped once (its kernels are built at its first step).

    ``build``: a function returning a fresh, unstepped World of the same scene; given, the
    export also holds the step's launch schedule at ``dt`` (`rbgen.schedule.write`),
    covering each capacity up to ``2 ** grow_rungs`` times its value in ``world``;
    ``command`` says how to make it again (a C++ host prints it for another device)."""
    specs = world.kernel_specs()
    if not specs:
        raise RbgenError(
            "export: the World has compiled no kernels yet; step it once first "
            "(kernels are built for its scene at the first step)"
        )
    if build is not None:
        from .batch import WorldBatch
        from .schedule import GROW_RUNGS
        from .schedule.write import write_schedule

        if isinstance(world, WorldBatch):
            raise RbgenError(
                "export: a WorldBatch's kernels export (build=None), but not a C++ schedule: "
                "the C++ host replays one World's steps, not a batch's resets and forces"
            )

        return write_schedule(
            world,
            build,
            out_dir,
            dt=dt,
            command=command,
            grow_rungs=GROW_RUNGS if grow_rungs is None else grow_rungs,
        )
    return export_kernels(
        specs, out_dir, world.runtime.traits, plan=world.plan, runtime=world.runtime
    )


def default_specs(traits: DeviceTraits, names: Iterable[str] | None = None) -> list[KernelSpec]:
    """The heuristic specialisation of each named template (all when none named).

    A name matches a template path exactly or as a substring ("integrate").
    """
    registry = load_all_templates()
    if names:
        chosen = []
        for name in names:
            hits = [t for p, t in sorted(registry.items()) if p == name or name in p]
            if not hits:
                raise RbgenError(
                    f"export: no template matches {name!r}; templates: {sorted(registry)}"
                )
            chosen += [t for t in hits if t not in chosen]
    else:
        chosen = [t for _, t in sorted(registry.items())]
    specs = []
    for template in chosen:
        try:
            specs.append(template.default_spec(traits))
        except RbgenError:
            if names:
                raise
    return specs
