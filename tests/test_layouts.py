"""Layouts: the numpy dtype, the OpenCL struct and the C header agree."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pyopencl as cl
import pytest

from rbgen import layouts
from rbgen.errors import RbgenError


def offsets_kernel_source() -> str:
    """A kernel that writes sizeof and every field offset, as the device compiler sees them."""
    lines = [
        layouts.cl_constants(),
        layouts.cl_structs(),
        "__kernel void layout_offsets(__global ulong* out) {",
    ]
    k = 0
    for layout in layouts.all_layouts():
        lines.append(f"  {{ __global {layout.name}* p = (__global {layout.name}*)0;")
        lines.append(f"    out[{k}] = sizeof({layout.name});")
        k += 1
        for f in layout.fields:
            lines.append(
                f"    out[{k}] = (ulong)((__global char*)&p->{f.name} - (__global char*)p);"
            )
            k += 1
        lines.append("  }")
    lines.append("}")
    return "\n".join(lines), k


def test_device_offsets_equal_dtype(runtime):
    source, count = offsets_kernel_source()
    program = cl.Program(runtime.context, source).build()
    out = np.zeros(count, np.uint64)
    buf = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, out.nbytes)
    program.layout_offsets(runtime.queue, (1,), None, buf)
    cl.enqueue_copy(runtime.queue, out, buf)
    k = 0
    for layout in layouts.all_layouts():
        assert out[k] == layout.dtype.itemsize == layout.itemsize, f"sizeof({layout.name})"
        k += 1
        for f in layout.fields:
            assert out[k] == layout.dtype.fields[f.name][1] == layout.offset(f.name), (
                f"{layout.name}.{f.name}"
            )
            k += 1


def test_float4_members_are_16_byte_aligned():
    for layout in layouts.all_layouts():
        for f in layout.fields:
            if f.kind.endswith("4"):
                assert layout.offset(f.name) % 16 == 0, f"{layout.name}.{f.name}"
        if any(f.kind.endswith("4") for f in layout.fields):
            assert layout.itemsize % 16 == 0, layout.name


@pytest.mark.parametrize("compiler,flag", [("gcc", "-std=c11"), ("g++", "-std=c++11")])
def test_c_header_compiles_with_static_asserts(tmp_path, compiler, flag):
    if shutil.which(compiler) is None:
        pytest.skip(f"{compiler} not installed")
    header = tmp_path / "rbgen_layouts.h"
    header.write_text(layouts.c_header())
    main = tmp_path / ("main.c" if compiler == "gcc" else "main.cpp")
    main.write_text(
        '#include "rbgen_layouts.h"\nint main(void) { return (int)sizeof(Body) - 80; }\n'
    )
    subprocess.run(
        [compiler, flag, "-Wall", "-Werror", "-o", str(tmp_path / "a.out"), str(main)],
        check=True,
        capture_output=True,
    )
    assert subprocess.run([str(tmp_path / "a.out")]).returncode == 0


def test_header_assert_catches_a_wrong_offset(tmp_path):
    """The header's static asserts really check: a corrupted offset fails to compile."""
    if shutil.which("gcc") is None:
        pytest.skip("gcc not installed")
    text = layouts.c_header().replace(
        "offsetof(Body, inv_mass) == 64", "offsetof(Body, inv_mass) == 60"
    )
    assert "== 60" in text
    (tmp_path / "h.h").write_text(text)
    (tmp_path / "m.c").write_text('#include "h.h"\nint main(void) { return 0; }\n')
    result = subprocess.run(
        ["gcc", "-std=c11", "-c", "-o", str(tmp_path / "m.o"), str(tmp_path / "m.c")],
        capture_output=True,
    )
    assert result.returncode != 0


def test_unknown_names_raise():
    with pytest.raises(RbgenError, match="no layout named 'Bodyy'"):
        layouts.layout("Bodyy")
    with pytest.raises(RbgenError, match="no field 'mass'"):
        layouts.BODY.offset("mass")
    with pytest.raises(RbgenError, match="unknown kind"):
        layouts.Layout("Bad", [layouts.Field("x", "double3")], "bad")


def test_dtype_round_trip_by_field_name():
    bodies = layouts.BODY.zeros(3)
    bodies["position"][:, :3] = np.arange(9).reshape(3, 3)
    raw = bodies.tobytes()
    assert len(raw) == 3 * layouts.BODY.itemsize
    pos = np.frombuffer(raw, np.float32).reshape(3, -1)[:, :3]
    assert np.array_equal(pos, np.arange(9).reshape(3, 3))
