"""Test fixtures: every test that takes ``runtime`` runs once per OpenCL device.

``RBGEN_TEST_DEVICES`` narrows the set: a comma-separated list of device
choices as accepted by ``rbgen.device.match_devices`` (index ``P:D`` or a
name substring). Programs are cached on disk between runs, so a second run of
the suite skips compilation.
"""
from __future__ import annotations

import os

import numpy as np
import pytest

from rbgen.device import Runtime, list_devices, match_devices

ENV_TEST_DEVICES = "RBGEN_TEST_DEVICES"


def _test_devices():
    choice = os.environ.get(ENV_TEST_DEVICES)
    if choice:
        devices = []
        for part in choice.split(","):
            for d in match_devices(part.strip()):
                if d not in devices:
                    devices.append(d)
        return devices
    return [entry.device for entry in list_devices()]


_DEVICES = _test_devices()
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
