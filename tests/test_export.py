"""Export: the .cl files build and run outside rbgen's loader, as the manifest says."""

from __future__ import annotations

import json

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import pytest

from rbgen import layouts
from rbgen.cli import main
from rbgen.codegen import RESOURCE_QUERIES
from rbgen.device import INT64_ATOMICS
from rbgen.errors import RbgenError
from rbgen.export import default_specs, export_kernels
from rbgen.pipeline.integrate import Integrator
from tests.pipeline.test_integrate import random_bodies


def _scalar(arg, value):
    return {"uint": np.uint32, "float": np.float32, "int": np.int32}[arg["type"].split()[-1]](value)


def _export(out, kernel, device=None, **params):
    """``rbgen export --kernel KERNEL`` into ``out`` (``--device``, one ``--param`` per
    keyword): its exit code, and the manifest's first file entry when it succeeded."""
    argv = ["export", "--out", str(out), "--kernel", kernel]
    argv += ["--device", device] if device else []
    for name, value in params.items():
        argv += ["--param", f"{name}={value}"]
    code = main(argv)
    entry = json.loads((out / "manifest.json").read_text())["files"][0] if code == 0 else None
    return code, entry


def test_exported_integrate_runs_standalone(runtime, rng, tmp_path):
    specs = default_specs(runtime.traits, ["integrate"])
    manifest = export_kernels(specs, tmp_path, runtime.traits)
    reread = json.loads((tmp_path / "manifest.json").read_text())
    assert reread == json.loads(json.dumps(manifest))
    assert reread["device"]["fingerprint"] == runtime.traits.fingerprint
    assert reread["structs"]["Body"]["size"] == layouts.BODY.itemsize
    entry = reread["files"][0]
    kernel = next(k for k in entry["kernels"] if k["name"] == "integrate_bodies")
    assert [a["name"] for a in kernel["args"]] == [
        "bodies",
        "body_count",
        "dt",
        "gravity",
        "max_angular_step",
    ]
    assert kernel["args"][0]["role"] == "inout" and kernel["args"][1]["role"] == "scalar"
    local = kernel["local_size"]
    assert local == entry["params"]["work_group_size"]

    # Plain pyopencl, no rbgen codegen: read the file, build, set args by the manifest.
    source = (tmp_path / entry["file"]).read_text()
    program = cl.Program(runtime.context, source).build(options=entry["build_options"])
    n = 77
    bodies = random_bodies(rng, n)
    d_standalone = cla.to_device(runtime.queue, bodies)
    values = {
        "bodies": d_standalone.data,
        "body_count": n,
        "dt": 1 / 60,
        "gravity": np.array([0, -9.81, 0, 0], np.float32),
        "max_angular_step": np.pi / 2,
    }
    args = [
        values[a["name"]]
        if a["role"] != "scalar" or a["type"].endswith("float4")
        else _scalar(a, values[a["name"]])
        for a in kernel["args"]
    ]
    k = getattr(program, kernel["name"])
    k(runtime.queue, (-(-n // local) * local,), (local,), *args)

    d_rbgen = cla.to_device(runtime.queue, bodies)
    Integrator(runtime)(d_rbgen, n, 1 / 60)
    assert d_standalone.get().tobytes() == d_rbgen.get().tobytes()


def test_a_specs_build_options_reach_its_program_and_the_manifest(runtime, tmp_path):
    """A fast-math solver is built with -cl-fast-relaxed-math by rbgen's loader, and its
    manifest entry says so, so that a host building the file alone builds the same program;
    an exact one has no options."""
    from rbgen.codegen import compile_spec
    from rbgen.pipeline.solvers import pgs

    fast = pgs.TEMPLATE.default_spec(
        runtime.traits, fast_math=True, persistent=False, warm_start_mode="batched"
    )
    exact = pgs.TEMPLATE.default_spec(
        runtime.traits, fast_math=False, persistent=False, warm_start_mode="batched"
    )
    assert fast.build_options == ("-cl-fast-relaxed-math",) and exact.build_options == ()
    built = compile_spec(runtime, fast).program.get_build_info(
        runtime.device, cl.program_build_info.OPTIONS
    )
    assert "-cl-fast-relaxed-math" in built
    manifest = export_kernels([fast, exact], tmp_path, runtime.traits)
    assert [e["build_options"] for e in manifest["files"]] == [["-cl-fast-relaxed-math"], []]
    assert fast.source == exact.source  # (fast math is a build option, not source)
    for entry in manifest["files"]:
        program = cl.Program(runtime.context, (tmp_path / entry["file"]).read_text()).build(
            options=entry["build_options"]
        )
        assert "solve_groups" in {k.function_name for k in program.all_kernels()}


def test_export_all_builds_every_file(runtime, tmp_path):
    assert main(["export", "--out", str(tmp_path), "--device", runtime.device.name.strip()]) == 0
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert (tmp_path / manifest["header"]).is_file()
    names = {e["template"] for e in manifest["files"]}
    assert {"pipeline/integrate.cl.mako", "pipeline/world_aabbs.cl.mako"} <= names
    for entry in manifest["files"]:
        program = cl.Program(runtime.context, (tmp_path / entry["file"]).read_text()).build(
            options=entry["build_options"]
        )
        for k in entry["kernels"]:
            assert getattr(program, k["name"]).num_args == len(k["args"])


def test_export_param_override_and_bad_names(runtime, tmp_path):
    code, entry = _export(tmp_path, "integrate", work_group_size=32, damping=True)
    assert code == 0
    assert entry["params"]["work_group_size"] == 32 and entry["params"]["damping"] is True
    with pytest.raises(RbgenError, match="no template matches 'warp_drive'"):
        default_specs(runtime.traits, ["warp_drive"])
    assert main(["export", "--out", str(tmp_path), "--kernel", "warp_drive"]) == 2


def test_exported_persistent_solver_and_colouring_build_standalone(runtime, tmp_path):
    """Global batching's kernels (the persistent solve and its colouring, the NVIDIA
    default) export like any specialisation: each .cl builds outside rbgen's loader, the
    solver's manifest lists the barrier's words before the relaxation and the bodies' motion
    arguments (it integrates), and a persistent
    solver of the serial form is refused by name."""
    device = runtime.device.name.strip()
    code, entry = _export(
        tmp_path,
        "solvers/pgs",
        device,
        persistent=True,
        solve_form="lanes",
        warm_start_mode="batched",
        work_group_size=32,
    )
    assert code == 0
    assert entry["params"]["persistent"] is True
    program = cl.Program(runtime.context, (tmp_path / entry["file"]).read_text()).build()
    solve = next(k for k in entry["kernels"] if k["name"] == "solve_groups")
    names = [a["name"] for a in solve["args"]]
    assert names.index("sync") < names.index("relaxation")
    # The persistent launch moves the bodies itself between and after its substeps.
    assert {"deltas", "body_count", "substeps", "gravity"} <= set(names)
    assert program.solve_groups.num_args == len(solve["args"])
    code, entry = _export(tmp_path, "global_colouring", device)
    assert code == 0
    program = cl.Program(runtime.context, (tmp_path / entry["file"]).read_text()).build()
    colour = next(k for k in entry["kernels"] if k["name"] == "colour_global")
    assert program.colour_global.num_args == len(colour["args"])
    assert _export(tmp_path, "solvers/pgs", persistent=True, solve_form="serial")[0] == 2


def test_exported_world_specialisations_build_standalone(runtime, tmp_path):
    """What a World on an NVIDIA GPU runs exports on any device: the persistent solve
    with the summed warm start (its manifest lists the per-body sums, an inout buffer, the
    bodies' motion and the body count between the barrier's words and the relaxation; the
    .cl needs 64-bit atomics, so it is built where the device has them) and the body preparation
    that writes the step's backup (an out buffer after the body count)."""
    device = runtime.device.name.strip()
    code, entry = _export(
        tmp_path / "solver",
        "solvers/pgs",
        device,
        persistent=True,
        solve_form="lanes",
        work_group_size=32,
        warm_start_mode="summed",
        normal_solve="block",
    )
    assert code == 0
    assert entry["params"]["warm_start_mode"] == "summed"
    solve = next(k for k in entry["kernels"] if k["name"] == "solve_groups")
    names = [a["name"] for a in solve["args"]]
    at = names.index("relaxation")
    # (deltas: the bodies' motion since the step began, which the fused substeps integrate)
    assert names[at - 4 : at] == ["sync", "warm_sums", "deltas", "body_count"]
    assert next(a for a in solve["args"] if a["name"] == "warm_sums")["role"] == "inout"
    if runtime.has_extension(INT64_ATOMICS):
        program = cl.Program(
            runtime.context, (tmp_path / "solver" / entry["file"]).read_text()
        ).build()
        assert program.solve_groups.num_args == len(solve["args"])
    code, entry = _export(tmp_path / "prepare", "pipeline/prepare", device, backup=True)
    assert code == 0
    prepare = next(k for k in entry["kernels"] if k["name"] == "prepare_bodies")
    names = [a["name"] for a in prepare["args"]]
    assert names[names.index("body_count") + 1] == "backup"
    assert next(a for a in prepare["args"] if a["name"] == "backup")["role"] == "out"
    program = cl.Program(
        runtime.context, (tmp_path / "prepare" / entry["file"]).read_text()
    ).build()
    assert program.prepare_bodies.num_args == len(prepare["args"])


@pytest.mark.parametrize("persistent", [False, True])
def test_exported_jacobi_solver_builds_standalone(runtime, tmp_path, persistent):
    """The Jacobi solver exports in both launch variants: the .cl builds outside rbgen's
    loader; the phase variant's kernels all take one argument list (a C++ caller binds
    the buffers once and launches the phases in order), the persistent variant's one
    kernel takes the barrier's words before the relaxation."""
    code, entry = _export(
        tmp_path, "jacobi", runtime.device.name.strip(), persistent=persistent, work_group_size=32
    )
    assert code == 0
    assert entry["params"]["persistent"] is persistent
    program = cl.Program(runtime.context, (tmp_path / entry["file"]).read_text()).build()
    names = {k["name"]: [a["name"] for a in k["args"]] for k in entry["kernels"]}
    for name, args in names.items():
        assert getattr(program, name).num_args == len(args)
    if persistent:
        assert list(names) == ["solve_jacobi"]
        args = names["solve_jacobi"]
        assert args[args.index("relaxation") - 1] == "sync"
    else:
        assert {"jacobi_clear", "jacobi_sweep", "jacobi_average", "jacobi_push"} <= set(names)
        assert len({tuple(args) for args in names.values()}) == 1


@pytest.mark.parametrize(
    "scene, options",
    [
        ("boxbox", {}),
        ("boxbox", {"solver": "jacobi"}),
        ("boxbox", {"batching": "cells"}),
        ("ragdolls", {}),
        ("ragdolls", {"batching": "global"}),
        ("boxbox", {"sleeping": True}),
        ("boxbox", {"support_chains": True}),
    ],
)
@pytest.mark.gpu_shape
def test_world_export_is_exactly_what_the_world_compiled(runtime, tmp_path, scene, options):
    """`rbgen export --world` = what runs: every source the World handed the compiler
    (recorded as it compiled, through its spec log) is exported byte for byte, with the
    same build options, nothing more, and the exported plan is the World's. A jointed
    scene (ragdolls) exports its joint stage and a solver that visits joints, with the
    joint records among its arguments. A World with support chains exports them: the
    chains' phases in its persistent solve and their records among its arguments, or
    the chains' own kernels beside any other solve."""
    from rbgen.codegen import SpecLog
    from rbgen.export import export_world
    from rbgen.harness import build_scene

    compiled = SpecLog(runtime)
    with compiled:  # an independent record of every compile_spec while the World is made
        world = build_scene(scene, 64 if scene == "boxbox" else 2, runtime, **options)[0]
        world.step(1 / 60)
        world.step(1 / 60)
        world.statistics()
    manifest = export_world(world, tmp_path)
    exported = {
        (json.dumps(e["params"], sort_keys=True), e["template"]): (
            (tmp_path / e["file"]).read_text(),
            tuple(e["build_options"]),
        )
        for e in manifest["files"]
    }
    recorded = {
        (
            json.dumps(
                {k: list(v) if isinstance(v, tuple) else v for k, v in spec.params}, sort_keys=True
            ),
            spec.path,
        ): (spec.source, options)
        for spec, options in compiled.specs()
    }
    assert exported == recorded
    plan = json.loads((tmp_path / "plan.json").read_text())
    assert plan["choices"]["batching"] == world.plan.batching
    assert manifest["plan"]["choices"]["solver"] == world.plan.solver
    assert plan["choices"]["joints"] is (scene == "ragdolls")
    assert plan["choices"]["sleeping"] is bool(options.get("sleeping"))
    if options.get("sleeping"):  # the sleep stage's kernels, and prepare's sleeping inertia
        templates = {e["template"]: e for e in manifest["files"]}
        assert "pipeline/sleep.cl.mako" in templates
        assert templates["pipeline/prepare.cl.mako"]["params"]["sleeping"] is True
    assert plan["choices"]["support_chains"] is bool(options.get("support_chains"))
    if options.get("support_chains"):
        templates = {e["template"]: e for e in manifest["files"]}
        solver = templates["pipeline/solvers/pgs.cl.mako"]
        if world.plan.persistent:
            assert solver["params"]["support_chains"] is True
            solve = next(k for k in solver["kernels"] if k["name"] == "solve_groups")
            assert {"supports", "links", "support_rounds"} <= {a["name"] for a in solve["args"]}
        else:
            assert solver["params"]["support_chains"] is False
            assert "pipeline/solvers/support.cl.mako" in templates
    if scene == "ragdolls":
        templates = {e["template"]: e for e in manifest["files"]}
        assert "pipeline/joints.cl.mako" in templates
        solver = templates["pipeline/solvers/pgs.cl.mako"]
        assert solver["params"]["joints"] is True
        solve = next(k for k in solver["kernels"] if k["name"] == "solve_groups")
        assert {"joints", "inv_h", "joint_recovery"} <= {a["name"] for a in solve["args"]}
    # and every exported file builds standalone, into kernels with the resources the
    # manifest gives them (what the device's compiler made of the World's own build)
    queries = dict(RESOURCE_QUERIES)
    for entry in manifest["files"]:
        program = cl.Program(runtime.context, (tmp_path / entry["file"]).read_text()).build(
            options=entry["build_options"]
        )
        for kernel in entry["kernels"]:
            resources = kernel["resources"]
            assert set(resources) == set(queries), kernel["name"]
            standalone = getattr(program, kernel["name"])
            for key, query in queries.items():
                assert resources[key] == standalone.get_work_group_info(query, runtime.device), (
                    entry["file"],
                    kernel["name"],
                    key,
                )
            # a kernel with a required work-group size must be able to run it
            if kernel["local_size"] is not None:
                assert kernel["local_size"] <= resources["max_work_group_size"], kernel["name"]


def test_export_world_from_the_command_line(runtime, tmp_path):
    """`rbgen export --world SCENE` (a scene name, or a Python file with build(device))
    writes the kernels, plan.json and the manifest; an unknown scene is refused by name."""
    device = runtime.device.name.strip()
    assert (
        main(
            [
                "export",
                "--out",
                str(tmp_path / "a"),
                "--world",
                "pyramid",
                "--n",
                "5",
                "--device",
                device,
            ]
        )
        == 0
    )
    assert (tmp_path / "a" / "plan.json").is_file()
    script = tmp_path / "scene.py"
    script.write_text(
        "import rbgen\n"
        "def build(device):\n"
        "    w = rbgen.World(device)\n"
        "    w.add_static(rbgen.Plane((0, 1, 0)))\n"
        "    w.add_body(rbgen.Sphere(0.5), position=(0, 0.4, 0))\n"
        "    return w\n"
    )
    assert (
        main(["export", "--out", str(tmp_path / "b"), "--world", str(script), "--device", device])
        == 0
    )
    manifest = json.loads((tmp_path / "b" / "manifest.json").read_text())
    assert manifest["plan"]["choices"]["shape_types"] == ["plane", "sphere"]
    assert main(["export", "--out", str(tmp_path / "c"), "--world", "warp_drive"]) == 2
