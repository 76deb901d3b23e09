"""Device discovery and choice."""

from __future__ import annotations

import pyopencl as cl
import pytest

from rbgen import device
from rbgen.device import DeviceTraits, Runtime
from rbgen.errors import DeviceNotFoundError, RbgenError


def test_traits_describe_every_device():
    entries = device.list_devices()
    assert entries, "at least the PoCL CPU device"
    for entry in entries:
        t = DeviceTraits.of(entry.device)
        assert t.compute_units >= 1 and t.max_work_group_size >= 1 and t.local_mem_size > 0
        if t.is_gpu and "nvidia" in t.vendor.lower():
            assert t.wavefront == 32
        if t.is_cpu:
            assert t.wavefront == 1
        assert t.fingerprint == DeviceTraits.of(entry.device).fingerprint  # stable
        assert t.driver_version in repr(t)


def test_fingerprint_changes_with_driver():
    t = DeviceTraits.of(device.list_devices()[0].device)
    import dataclasses

    other = dataclasses.replace(t, driver_version=t.driver_version + "-next")
    assert other.fingerprint != t.fingerprint


def test_select_by_index_and_substring(monkeypatch):
    entries = device.list_devices()
    first = entries[0]
    assert device.select_device(first.index) == first.device
    name_part = first.device.name.strip()[:6].upper()
    assert first.device in device.match_devices(name_part)
    monkeypatch.setenv(device.ENV_DEVICE, first.index)
    assert device.select_device(None) == first.device


def test_default_prefers_gpu_else_pocl(monkeypatch):
    monkeypatch.delenv(device.ENV_DEVICE, raising=False)
    chosen = device.select_device(None)
    has_gpu = any(e.device.type & cl.device_type.GPU for e in device.list_devices())
    assert bool(chosen.type & cl.device_type.GPU) == has_gpu
    if not has_gpu:
        assert "portable" in chosen.platform.name.lower() or "pocl" in chosen.platform.name.lower()


def test_unknown_device_lists_available(monkeypatch):
    with pytest.raises(DeviceNotFoundError) as info:
        device.select_device("no-such-accelerator")
    text = str(info.value)
    assert "no-such-accelerator" in text
    assert device.list_devices()[0].index in text
    assert isinstance(info.value, RbgenError) and isinstance(info.value, ValueError)
    monkeypatch.setenv(device.ENV_DEVICE, "9:9")
    with pytest.raises(DeviceNotFoundError, match="9:9"):
        Runtime()


def test_runtime_counts_launches_and_reads(runtime):
    import numpy as np
    import pyopencl.array as cla

    before = dict(runtime.counters)
    arr = cla.zeros(runtime.queue, 4, np.float32)
    runtime.read(arr)
    assert runtime.counters["blocking_reads"] == before["blocking_reads"] + 1


def test_every_test_device_compiles_a_kernel(runtime):
    assert device.build_failure(runtime.device) is None


def test_default_passes_over_a_device_that_cannot_compile(monkeypatch):
    """A listed device whose compiler fails (the bundled PoCL on a CPU its LLVM does not
    know) is skipped with a warning naming it; with none left the error lists each
    device with its compiler's words."""
    monkeypatch.delenv(device.ENV_DEVICE, raising=False)
    entries = device.list_devices()
    broken = entries[0]
    real = device.build_failure
    monkeypatch.setattr(
        device,
        "build_failure",
        lambda d: "unknown target CPU 'x'" if d == broken.device else real(d),
    )
    if len(entries) > 1 and any(real(e.device) is None for e in entries[1:]):
        with pytest.warns(RuntimeWarning, match=broken.index):
            chosen = device.default_device()
        assert chosen != broken.device
    monkeypatch.setattr(device, "build_failure", lambda d: "unknown target CPU 'x'")
    with pytest.raises(DeviceNotFoundError) as info:
        with pytest.warns(RuntimeWarning):
            device.default_device()
    assert broken.index in str(info.value) and "unknown target CPU 'x'" in str(info.value)


def test_a_gpu_shape_is_the_cpu_planned_for_as_the_gpu():
    """``shape:h200`` runs on the CPU device with the H200's traits: the World plans the
    GPU's pipeline (global batching, the lanes form in one persistent launch, fast math),
    the fingerprint is neither the CPU's nor a real H200's, and an unknown shape is refused
    naming the shapes there are."""
    from rbgen.device import GPU_SHAPES, cpu_device
    from rbgen.world import World

    shaped = Runtime("shape:h200")
    assert shaped.device.int_ptr == cpu_device().int_ptr
    assert shaped.traits.is_gpu and shaped.traits.wavefront == 32
    assert shaped.traits.device_name == GPU_SHAPES["h200"]["device_name"]
    assert shaped.traits.fingerprint != DeviceTraits.of(shaped.device).fingerprint
    plan = World(shaped).plan
    assert (plan.batching, plan.solve_form, plan.persistent, plan.fast_math) == (
        "global",
        "lanes",
        True,
        True,
    )
    with pytest.raises(DeviceNotFoundError, match="shape:h200"):
        Runtime("shape:a100")


def test_a_result_file_names_the_shape_it_ran_as():
    """`rbgen.bench.device_record` of ``shape:h200`` (benchmarks record it beside their
    results) names the H200's shape and its fingerprint, not the CPU's."""
    from rbgen.bench import device_record

    record = device_record("shape:h200")
    assert record["name"] == Runtime("shape:h200").traits.device_name
    assert record["type"] == "gpu"
    assert record["fingerprint"] == Runtime("shape:h200").traits.fingerprint
