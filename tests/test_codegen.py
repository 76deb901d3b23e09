"""Code generation: validation, pure rendering, build errors, program caches."""

from __future__ import annotations

import time

import pytest

from rbgen import codegen
from rbgen.codegen import (
    KernelTemplate,
    Param,
    ProgramCache,
    driver_caches_kernels,
    power_of_two,
)
from rbgen.errors import KernelBuildError, TemplateParameterError
from rbgen.pipeline import integrate


def test_rendering_is_pure_and_deterministic():
    a = integrate.TEMPLATE.spec(
        work_group_size=64, damping=True, gravity=True, split=False, deltas=False
    )
    b = integrate.TEMPLATE.spec(
        damping=True, gravity=True, work_group_size=64, split=False, deltas=False
    )
    assert a == b and hash(a) == hash(b)
    codegen.render.cache_clear()
    first = a.source
    codegen.render.cache_clear()
    assert b.source == first
    assert "linear_damping" in first
    plain = integrate.TEMPLATE.spec(
        work_group_size=64, damping=False, gravity=True, split=False, deltas=False
    ).source
    assert "damping" not in plain.split("__kernel")[1], "no dead damping code when damping=False"


def test_parameter_errors_name_the_parameter():
    t = integrate.TEMPLATE
    with pytest.raises(
        TemplateParameterError, match=r"missing parameter\(s\) \['deltas', 'gravity', 'split'\]"
    ):
        t.spec(work_group_size=64, damping=False)
    with pytest.raises(TemplateParameterError, match=r"unknown parameter\(s\) \['colour'\]"):
        t.spec(work_group_size=64, damping=False, gravity=True, deltas=False, colour=3)
    with pytest.raises(TemplateParameterError, match="work_group_size=48 is not allowed"):
        t.spec(work_group_size=48, damping=False, gravity=True, split=False, deltas=False)
    with pytest.raises(TemplateParameterError, match="damping=1 is not allowed"):
        t.spec(work_group_size=64, damping=1, gravity=True, split=False, deltas=False)


def test_strict_undefined_in_templates(tmp_path, monkeypatch):
    """A template that uses a name nobody passes fails at render time, naming it."""
    (tmp_path / "probe").mkdir()
    (tmp_path / "probe" / "undefined.cl.mako").write_text(
        "__kernel void k() { int x = ${nope}; }\n"
    )
    monkeypatch.setattr(codegen, "TEMPLATE_DIR", tmp_path)
    codegen._lookup.cache_clear()
    codegen.render.cache_clear()
    try:
        t = KernelTemplate("probe/undefined.cl.mako", [])
        with pytest.raises(NameError, match="nope"):
            _ = t.spec().source
    finally:
        codegen.TEMPLATES.pop("probe/undefined.cl.mako", None)
        codegen._lookup.cache_clear()
        codegen.render.cache_clear()


def test_build_error_shows_log_and_numbered_lines(runtime, tmp_path):
    source = "__kernel void broken(__global float* x)\n{\n    x[0] = undefined_name;\n}\n"
    cache = ProgramCache(tmp_path)
    with pytest.raises(KernelBuildError) as info:
        cache.build(runtime, source)
    text = str(info.value)
    assert "undefined_name" in text
    assert ">>    3 |     x[0] = undefined_name;" in text


def test_memory_and_disk_cache(runtime, tmp_path):
    spec = integrate.TEMPLATE.spec(
        work_group_size=32, damping=True, gravity=False, split=False, deltas=False
    )
    first = ProgramCache(tmp_path)
    t0 = time.perf_counter()
    p1 = first.build(runtime, spec.source, (), spec)
    cold = time.perf_counter() - t0
    assert first.stats == {"memory_hits": 0, "disk_hits": 0, "builds": 1}
    assert first.build(runtime, spec.source, (), spec) is p1
    assert first.stats["memory_hits"] == 1
    second = ProgramCache(tmp_path)  # a new process would start like this
    p2 = second.build(runtime, spec.source, (), spec)
    assert p2.integrate_bodies is not None and p2.apply_gravity is not None
    print(f"cold build {cold * 1e3:.0f} ms")
    if driver_caches_kernels(runtime.device):  # (PoCL: its own cache, none of rbgen's)
        assert not list(tmp_path.glob("*.bin")), "no binary of rbgen's for this driver"
        assert second.stats == {"memory_hits": 0, "disk_hits": 0, "builds": 1}
        return
    assert list(tmp_path.glob("*.bin")), "binary written to disk"
    assert second.stats == {"memory_hits": 0, "disk_hits": 1, "builds": 0}
    # options are part of the key
    second.build(runtime, spec.source, ("-cl-fast-relaxed-math",), spec)
    assert second.stats["builds"] == 1


def test_only_pocl_keeps_its_own_kernel_cache():
    """`driver_caches_kernels`, by the platform's name: PoCL's (bundled or the system's)
    yes, NVIDIA's and others' no."""
    from types import SimpleNamespace

    def device(platform):
        return SimpleNamespace(platform=SimpleNamespace(name=platform))

    assert driver_caches_kernels(device("Portable Computing Language"))
    assert not driver_caches_kernels(device("NVIDIA CUDA"))
    assert not driver_caches_kernels(device("AMD Accelerated Parallel Processing"))


def test_corrupt_disk_binary_is_rebuilt(runtime, tmp_path):
    spec = integrate.TEMPLATE.spec(
        work_group_size=16, damping=False, gravity=True, split=False, deltas=False
    )
    cache = ProgramCache(tmp_path)
    key = cache.key(runtime, spec.source, ())
    (tmp_path / f"{key}.bin").write_bytes(b"not a binary")
    cache.build(runtime, spec.source, (), spec)
    assert cache.stats["builds"] == 1


def test_power_of_two_predicate():
    check = power_of_two(1, 256)
    assert [v for v in (0, 1, 2, 3, 64, 256, 512, 2.0) if check(v)] == [1, 2, 64, 256]
    p = Param("tile", check, "why", "a power of two up to 256")
    with pytest.raises(TemplateParameterError, match="a power of two up to 256"):
        p.check(100, "here")
