"""Test fixtures: every test that takes ``runtime`` runs once per OpenCL device.

By default: every device that compiles a kernel (one PoCL per CPU; pytest's
header names the devices left out and why). ``RBGEN_TEST_DEVICES`` chooses
instead: a comma-separated list of device choices as accepted by
``rbgen.device.match_devices`` (index ``P:D`` or a name substring). Programs
are cached on disk between runs, so a second run of the suite skips
compilation.
"""

from __future__ import annotations

import os

import numpy as np
import pyopencl as cl
import pytest

from rbgen.device import Runtime, build_failure, is_pocl, list_devices, match_devices

ENV_TEST_DEVICES = "RBGEN_TEST_DEVICES"


#: devices left out of the default set, and why (shown in pytest's header)
_LEFT_OUT: list[str] = []


def _test_devices():
    choice = os.environ.get(ENV_TEST_DEVICES)
    if choice:
        devices = []
        for part in choice.split(","):
            for d in match_devices(part.strip()):
                if d not in devices:
                    devices.append(d)
        return devices
    # every device that compiles a kernel; of several PoCL builds of this machine's CPU
    # (pyopencl's bundled one and the system's), the first that works: one CPU, one run
    devices, pocl_cpu = [], False
    for entry in list_devices():
        reason = build_failure(entry.device)
        is_pocl_cpu = bool(entry.device.type & cl.device_type.CPU) and is_pocl(entry)
        if reason is not None:
            _LEFT_OUT.append(f"{entry.index} {entry.label}: cannot compile a kernel ({reason})")
        elif is_pocl_cpu and pocl_cpu:
            _LEFT_OUT.append(f"{entry.index} {entry.label}: a second PoCL on the same CPU")
        else:
            devices.append(entry.device)
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
    lines = [f"rbgen test devices: {', '.join(d.name.strip() for d in _DEVICES) or 'none'}"]
    lines += [f"rbgen left out {line}" for line in _LEFT_OUT]
    return lines


_RUNTIMES: dict[int, Runtime] = {}


def _device_id(device) -> str:
    return "".join(c if c.isalnum() else "_" for c in device.name.strip())[:30]


@pytest.fixture(params=range(len(_DEVICES)), ids=[_device_id(d) for d in _DEVICES], scope="session")
def runtime(request) -> Runtime:
    """A Runtime (context + queue) on each test device, shared by the session."""
    i = request.param
    if i not in _RUNTIMES:
        _RUNTIMES[i] = Runtime(_DEVICES[i])
    return _RUNTIMES[i]


@pytest.fixture
def rng(request) -> np.random.Generator:
    """Fresh random inputs each run; the seed is printed on failure to reproduce."""
    seed = int.from_bytes(os.urandom(4), "little")
    request.node.user_properties.append(("seed", seed))
    print(f"rng seed {seed}")
    return np.random.default_rng(seed)


#: Boundary sizes every data-parallel kernel is tested over (issue 2).
SIZES = [0, 1, 31, 32, 33, 1000, 2**16 + 3]
