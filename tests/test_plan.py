"""The plan: the documented default of every choice per device class, where each came
from, the fallback after a persistent launch gave up, and overrides (no device needed:
plans are derived from traits)."""

from __future__ import annotations

import json

import pytest

from rbgen import RbgenError
from rbgen.device import INT64_ATOMICS, DeviceTraits
from rbgen.plan import TUNABLES, derive_plan
from rbgen.settings import split_options


def traits(vendor: str, gpu: bool, extensions=(INT64_ATOMICS,)) -> DeviceTraits:
    return DeviceTraits(
        platform_name="p",
        device_name=f"{vendor} device",
        vendor=vendor,
        is_gpu=gpu,
        compute_units=8,
        wavefront=32 if gpu else 1,
        local_mem_size=48 * 1024,
        max_work_group_size=1024,
        driver_version="1",
        opencl_version="OpenCL 3.0",
        extensions=tuple(extensions),
    )


NVIDIA = traits("NVIDIA Corporation", True)
AMD = traits("Advanced Micro Devices, Inc.", True)
CPU = traits("GenuineIntel", False)


def plan(device, tuned=None, **options):
    return derive_plan(device, split_options(options)[1], ("box",), tuned=tuned or {})


# device -> the README's table of defaults
EXPECTED = {
    "nvidia": (
        NVIDIA,
        dict(
            solver="pgs",
            batching="global",
            solve_form="lanes",
            persistent=True,
            normal_solve="block",
            warm_start_mode="summed",
            fast_math=True,
            release_sweeps=2,
            contact_geometry=False,
        ),
    ),
    "other gpu": (
        AMD,
        dict(
            solver="pgs",
            batching="cells",
            solve_form="lanes",
            persistent=False,
            normal_solve="block",
            warm_start_mode="batched",
            fast_math=True,
            release_sweeps=2,
            contact_geometry=False,
        ),
    ),
    "cpu": (
        CPU,
        dict(
            solver="pgs",
            batching="slabs",
            solve_form="serial",
            persistent=False,
            normal_solve="block",
            warm_start_mode="batched",
            fast_math=False,
            release_sweeps=2,
            contact_geometry=True,
        ),
    ),
}


# device kind -> the README's step defaults (substeps, velocity and push sweeps a substep):
# the GPU's stay those the GPU plan was measured with; a CPU's serial solve holds the
# lattices, a 30-box column and a 20-row pyramid at 4 substeps of 3 + 1
# (benchmarks/holds.py, benchmarks/stacking.py)
#: (substeps, iterations, position_iterations) a GPU and a CPU default to (rbgen.settings)
STEP_DEFAULTS = {True: (8, 2, 1), False: (4, 3, 1)}


@pytest.mark.parametrize("gpu", [True, False])
def test_step_defaults_per_device_kind(gpu):
    step = split_options({}, gpu)[0]
    assert (step["substeps"], step["iterations"], step["position_iterations"]) == (
        STEP_DEFAULTS[gpu]
    )
    # a setting given is the setting, on either kind
    given = split_options({"substeps": 2, "iterations": 7, "position_iterations": 0}, gpu)[0]
    assert (given["substeps"], given["iterations"], given["position_iterations"]) == (2, 7, 0)


def test_the_batching_names_are_one_list():
    """The option's choices, the batchers and the spatial colours name the same algorithms."""
    from rbgen.pipeline.batching import MODES, SPATIAL_MODES
    from rbgen.pipeline.batching.spatial import COLOURS
    from rbgen.settings import CONSTRUCTION, check

    assert all(check(CONSTRUCTION["batching"], mode) == mode for mode in MODES)
    with pytest.raises(RbgenError, match="batching"):
        check(CONSTRUCTION["batching"], "hexagons")
    assert tuple(COLOURS) == SPATIAL_MODES and MODES == ("global", *SPATIAL_MODES)


def test_cpus_with_many_cores_batch_over_columns():
    """A CPU's serial solve keeps whole stacks in a group: slabs up to 8 cores, columns
    beyond (slabs give a 20-stack lattice 10 groups a colour). The normal-solve reason of
    a column's serial solve is the slabs'."""
    import dataclasses

    many = dataclasses.replace(CPU, compute_units=16)
    assert plan(CPU).batching == "slabs" and plan(many).batching == "columns"
    assert "many cores" in plan(many).reasons["batching"]
    assert "30-box column" in plan(many).reasons["normal_solve"]
    assert TUNABLES["batching"].candidates(many)[0] == "columns"


def test_normal_solve_reasons():
    """A GPU's reason for the block is the one it always had; a CPU's names the column."""
    for device in (NVIDIA, AMD):
        assert plan(device).reasons["normal_solve"].startswith("the block leaves no point-order")
    assert "30-box column" in plan(CPU).reasons["normal_solve"]
    assert plan(CPU, normal_solve="sequential").sources["normal_solve"] == "option"


@pytest.mark.parametrize("name", list(EXPECTED))
def test_defaults_per_device_class(name):
    device, expected = EXPECTED[name]
    p = plan(device)
    assert {k: getattr(p, k) for k in expected} == expected
    assert set(p.sources.values()) == {"default"}
    assert all(p.reasons[k] for k in expected)  # a reason for every choice
    choices = json.loads(p.to_json())["choices"]
    assert choices["batching"] == expected["batching"] and choices["shape_types"] == ["box"]


def test_a_persistent_launch_without_64_bit_atomics_warm_starts_batched():
    p = plan(traits("NVIDIA Corporation", True, extensions=()))
    assert (p.batching, p.persistent, p.warm_start_mode) == ("global", True, "batched")


def test_fallback_after_a_persistent_launch_gave_up():
    """No persistent launch is planned on a device where one gave up: GPUs fall back to
    cells, and an explicit batching='global' is overruled, saying why."""
    for options in ({}, {"batching": "global"}):
        p = derive_plan(
            NVIDIA, split_options(options)[1], ("box",), tuned={}, persistent_failed=True
        )
        assert (p.batching, p.persistent) == ("cells", False)
        assert p.sources["batching"] == "fallback"
    jacobi = derive_plan(
        NVIDIA, split_options({"solver": "jacobi"})[1], (), tuned={}, persistent_failed=True
    )
    assert jacobi.persistent is False and jacobi.batching is None


def test_options_tuned_values_and_overrides_in_that_order():
    """A World option beats a plan override, which beats the tuning cache, which beats the
    hand-set default; each choice records its source."""
    tuned = {"batching": "cells", "release_sweeps": 1}
    p = plan(NVIDIA, tuned=tuned)
    assert (p.batching, p.release_sweeps) == ("cells", 1)
    assert p.sources["batching"] == p.sources["release_sweeps"] == "tuned"
    p = plan(NVIDIA, tuned=tuned, plan={"release_sweeps": 3})
    assert p.release_sweeps == 3 and p.sources["release_sweeps"] == "option"
    p = plan(NVIDIA, tuned=tuned, batching="slabs")
    assert p.batching == "slabs" and p.sources["batching"] == "option"
    assert p.solve_form == "lanes"  # the device's form for spatial batching on a GPU


def test_bad_plan_overrides_name_the_parameter():
    with pytest.raises(RbgenError, match="unknown plan parameter"):
        plan(CPU, plan={"colours": 4})
    with pytest.raises(RbgenError, match="ordered_rounds"):
        plan(NVIDIA, plan={"ordered_rounds": -1})


def test_every_tunable_lists_its_default_first():
    """The hand-set default is the first candidate, so that an untuned device and a tie in
    `rbgen tune` both keep it."""
    for device in (NVIDIA, AMD, CPU):
        p = plan(device)
        for name, tunable in TUNABLES.items():
            assert tunable.candidates(device)[0] == getattr(p, name), (device.vendor, name)


def test_contact_geometry_where_the_block_solve_can_keep_it():
    """The block solve keeps its contacts' geometry for the step in the CPU's serial form
    by default, not in a GPU's persistent launch (the default there: off); a plan override
    turns it on where the launch can keep it, and is refused, naming it, where it cannot
    (a launch per colour, the sequential normal solve, Jacobi), while a tuned value that no
    longer applies is dropped."""
    assert plan(CPU).contact_geometry and not plan(NVIDIA).contact_geometry
    on = plan(NVIDIA, plan={"contact_geometry": True})
    assert on.contact_geometry and on.persistent and on.sources["contact_geometry"] == "option"
    assert not plan(CPU, plan={"contact_geometry": False}).contact_geometry
    for options in (
        {"batching": "cells"},
        {"normal_solve": "sequential"},
        {"solver": "jacobi"},
    ):
        with pytest.raises(RbgenError, match="contact_geometry=True needs"):
            plan(NVIDIA, plan={"contact_geometry": True}, **options)
    dropped = plan(NVIDIA, tuned={"contact_geometry": True}, batching="cells")
    assert not dropped.contact_geometry and dropped.sources["contact_geometry"] == "default"
    with pytest.raises(RbgenError, match="contact_geometry"):
        plan(CPU, plan={"contact_geometry": 1})
    with pytest.raises(RbgenError, match="release_sweeps"):  # (not the candidate 1)
        plan(CPU, plan={"release_sweeps": True})


def test_jacobi_plans_no_batching():
    p = plan(NVIDIA, solver="jacobi")
    assert p.batching is None and p.persistent and p.normal_solve == "block"
    assert plan(CPU, solver="jacobi").persistent is False
