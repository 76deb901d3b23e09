"""The generated OpenCL parses as OpenCL C 2.0 for NVIDIA's target, where clang is installed.

NVIDIA's OpenCL compiler reads an unqualified pointer as a generic one (OpenCL C 2.0), where
PoCL reads it as a private one (OpenCL C 1.2): a private copy's address handed on through an
unqualified pointer to a ``__private`` parameter builds on PoCL and fails on an NVIDIA GPU
("changes address space of pointer"). clang's OpenCL C 2.0 front end for the nvptx target
rejects the same code, so this machine can see what only a GPU call would otherwise show.
Skipped where no clang is installed (the CI's machines have none; developers' may).
"""

from __future__ import annotations

import shutil
import subprocess

import pytest

from rbgen.device import Runtime
from rbgen.export import default_specs
from tests.pipeline.test_solver import pgs_specs

CLANG = next(
    (
        path
        for name in ("clang", "clang-18", "clang-17", "clang-16", "clang-15", "clang-14")
        if (path := shutil.which(name))
    ),
    None,
)

#: the front end's options: OpenCL C 2.0 for NVIDIA's target, with the 64-bit atomics
#: NVIDIA's driver reports (clang's nvptx target does not declare them by default)
FRONT_END = [
    "-x",
    "cl",
    "-cl-std=CL2.0",
    "-target",
    "nvptx64-nvidia-nvcl",
    "-Xclang",
    "-cl-ext=+cl_khr_int64_base_atomics,+cl_khr_int64_extended_atomics",
    "-fsyntax-only",
]


@pytest.mark.skipif(CLANG is None, reason="needs clang's OpenCL C front end")
def test_generated_opencl_parses_as_opencl_c_2_for_nvptx(tmp_path):
    """Every template's default specialisation for the H200's traits, every persistent PGS
    specialisation at 256 lanes a group (with the support chains' phases and without) and
    every exact PGS specialisation parses as OpenCL C 2.0 for nvptx without an error; the
    failures name the specialisation and the first errors."""
    traits = Runtime("shape:h200").traits
    # (the persistent launches as a GPU's World runs them: 256 lanes, fast math)
    gpu_persistent = pgs_specs(
        forms=("lanes",),
        persistent_choices=(True,),
        normal_solves=("block",),
        lanes_work_group_size=256,
        fast_math=True,
        support_chains=(False, True),
    )
    specs = default_specs(traits) + gpu_persistent + pgs_specs()
    assert len(specs) > 60  # (the three sets, none silently empty)
    failures = []
    for index, spec in enumerate(specs):
        source = tmp_path / f"spec{index}.cl"
        source.write_text(spec.source)
        options = [o for o in spec.build_options if o.startswith(("-D", "-cl-"))]
        result = subprocess.run(
            [CLANG, *FRONT_END, *options, str(source)], capture_output=True, text=True
        )
        errors = [line for line in result.stderr.splitlines() if "error:" in line]
        if result.returncode != 0 or errors:
            failures.append(f"{spec}: {errors[:3] or result.stderr[-500:]}")
    assert not failures, "\n".join(failures)


@pytest.mark.skipif(CLANG is None, reason="needs clang's OpenCL C front end")
def test_the_front_end_sees_the_generic_pointer_error(tmp_path):
    """The check can fail: a private copy's address passed on through an unqualified
    pointer to a ``__private`` parameter (what NVIDIA's compiler refused) is an error for
    this front end, and the same code with a ``__private`` pointer is not."""
    body = """
typedef struct { float4 v; } Record;
float first(const __private Record* r) { return r->v.x; }
__kernel void k(__global const Record* records, __global float* out)
{
    const Record copy = records[get_global_id(0)];
    %s c = &copy;
    out[get_global_id(0)] = first(c);
}
"""
    outcomes = []
    for pointer in ("const Record*", "__private const Record*"):
        source = tmp_path / "probe.cl"
        source.write_text(body % pointer)
        result = subprocess.run([CLANG, *FRONT_END, str(source)], capture_output=True, text=True)
        outcomes.append(result.returncode == 0)
    assert outcomes == [False, True]
