"""Test fixtures: every test that takes ``runtime`` runs once per OpenCL device.

By default: every device that compiles a kernel (one PoCL per CPU; pytest's
header names the devices left out and why). ``RBGEN_TEST_DEVICES`` chooses
instead: a comma-separated list of device choices as accepted by
``rbgen.device.match_devices`` (index ``P:D`` or a name substring), or
``shape:h200``: this machine's PoCL CPU device standing in for the H200 (its
traits are the H200's, so every plan, template and launch is the GPU's, built
by the CPU's compiler; see `rbgen.device.GPU_SHAPES`). Programs are cached on disk between
runs, so a second run of the suite skips compilation.
"""

from __future__ import annotations

import functools
import os

import numpy as np
import pyopencl as cl
import pytest

from rbgen.device import (
    GPU_SHAPES,
    Runtime,
    build_failure,
    cpu_device,
    is_pocl,
    list_devices,
    match_devices,
    shaped_traits,
)

ENV_TEST_DEVICES = "RBGEN_TEST_DEVICES"
#: a failing test's printed seed, to run it again on the same inputs
ENV_TEST_SEED = "RBGEN_TEST_SEED"


#: devices left out of the default set, and why (shown in pytest's header)
_LEFT_OUT: list[str] = []


@functools.cache
def _cpu_device():
    """The CPU device a GPU shape runs on: the test devices' CPU if there is one."""
    for device, shape in globals().get("_DEVICES", ()):
        if shape is None and device.type & cl.device_type.CPU:
            return device
    return cpu_device()


def _test_devices():
    """(device, GPU shape name or None) pairs to test on."""
    choice = os.environ.get(ENV_TEST_DEVICES)
    if choice:
        devices: list = []
        for part in choice.split(","):
            part = part.strip()
            if part.startswith("shape:"):
                name = part.removeprefix("shape:")
                if name not in GPU_SHAPES:
                    raise pytest.UsageError(
                        f"{ENV_TEST_DEVICES}: unknown GPU shape {name!r}; choose one of "
                        f"{sorted(GPU_SHAPES)}"
                    )
                devices.append((_cpu_device(), name))
                continue
            for d in match_devices(part):
                if (d, None) not in devices:
                    devices.append((d, None))
        return devices
    # every device that compiles a kernel; of several PoCL builds of this machine's CPU
    # (pyopencl's bundled one and the system's), the first that works: one CPU, one run
    devices, pocl_cpu = [], False
    for entry in list_devices():
        reason = build_failure(entry.device)
        is_pocl_cpu = bool(entry.device.type & cl.device_type.CPU) and is_pocl(entry.device)
        if reason is not None:
            _LEFT_OUT.append(f"{entry.index} {entry.label}: cannot compile a kernel ({reason})")
        elif is_pocl_cpu and pocl_cpu:
            _LEFT_OUT.append(f"{entry.index} {entry.label}: a second PoCL on the same CPU")
        else:
            devices.append((entry.device, None))
            pocl_cpu = pocl_cpu or is_pocl_cpu
    return devices


_DEVICES = _test_devices()
if not _DEVICES:  # fail loudly: a suite whose device tests are all skipped proves nothing
    _reasons = "\n  ".join(_LEFT_OUT or ["none listed"])
    raise pytest.UsageError(
        f"no OpenCL device to test on:\n  {_reasons}\n(install the "
        f"system's PoCL, e.g. Debian's pocl-opencl-icd)"
    )


def pytest_report_header(config):
    lines = [f"rbgen test devices: {', '.join(_device_id(d) for d in _DEVICES) or 'none'}"]
    lines += [f"rbgen left out {line}" for line in _LEFT_OUT]
    return lines


_RUNTIMES: dict[tuple, Runtime] = {}


def _device_id(entry) -> str:
    device, shape = entry
    name = "".join(c if c.isalnum() else "_" for c in device.name.strip())[:30]
    return name if shape is None else f"{shape}_shape_on_{name}"


def _entries_for(definition) -> list:
    """The test devices of one test: every test device; for a test marked ``gpu_shape``,
    when no test device is a GPU, also the H200's shape on the CPU (see `GPU_SHAPES`), so
    that the GPU plans' kernels of the scenes those tests cover build and run in every
    suite, CI's included."""
    entries = list(_DEVICES)
    if definition.get_closest_marker("gpu_shape") is not None and not any(
        shape is not None or device.type & cl.device_type.GPU for device, shape in entries
    ):
        entries.append((_cpu_device(), "h200"))
    return entries


def pytest_generate_tests(metafunc):
    if "runtime" in metafunc.fixturenames:
        entries = _entries_for(metafunc.definition)
        metafunc.parametrize(
            "runtime", entries, ids=[_device_id(e) for e in entries], indirect=True, scope="session"
        )


@pytest.fixture(scope="session")
def runtime(request) -> Runtime:
    """A Runtime (context + queue) on each test device, shared by the session; for a
    GPU shape, a Runtime on the CPU device whose traits are the GPU's."""
    device, shape = request.param
    key = (device.int_ptr, shape)
    if key not in _RUNTIMES:
        runtime = Runtime(device)
        if shape is not None:
            runtime.traits = shaped_traits(runtime.traits, shape)
        _RUNTIMES[key] = runtime
    return _RUNTIMES[key]


@pytest.fixture
def rng(request) -> np.random.Generator:
    """Fresh random inputs each run; the seed is printed on failure, and
    RBGEN_TEST_SEED=<seed> reproduces them."""
    fixed = os.environ.get(ENV_TEST_SEED)
    seed = int(fixed) if fixed else int.from_bytes(os.urandom(4), "little")
    request.node.user_properties.append(("seed", seed))
    print(f"rng seed {seed}")
    return np.random.default_rng(seed)


#: Boundary sizes every data-parallel kernel is tested over (issue 2).
SIZES = [0, 1, 31, 32, 33, 1000, 2**16 + 3]


@pytest.fixture(scope="session")
def headless_gl():
    """Skips a test that draws when this machine cannot make a headless OpenGL context (a
    GPU server without Mesa's or the driver's libGL/libEGL), naming what is missing; where
    a context can be made (CI installs Mesa), the test runs."""
    from rbgen.errors import RbgenError
    from rbgen.render.renderer import gl_context

    try:
        return gl_context()
    except RbgenError as err:
        pytest.skip(str(err))
