"""The rbgen command."""

from __future__ import annotations

import subprocess
import sys

from rbgen.cli import main


def test_info_names_every_device(capsys):
    from rbgen.device import list_devices

    assert main(["info"]) == 0
    out = capsys.readouterr().out
    for entry in list_devices():
        assert entry.device.name.strip() in out
    assert out.count("*") >= 1


def test_info_lists_devices_that_cannot_compile(monkeypatch, capsys):
    """With no device that compiles a kernel, `rbgen info` still lists every device, each
    with the compiler's words, and exits 1."""
    import warnings

    from rbgen import device
    from rbgen.device import list_devices

    monkeypatch.delenv(device.ENV_DEVICE, raising=False)
    monkeypatch.setattr(device, "build_failure", lambda d: "unknown target CPU 'x'")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert main(["info"]) == 1
    out = capsys.readouterr().out
    assert out.count("cannot compile a kernel: unknown target CPU 'x'") == len(list_devices())
    assert "no device here compiles a kernel" in out


def test_info_unknown_device_exit_code():
    result = subprocess.run(
        [sys.executable, "-m", "rbgen", "export", "--out", "/tmp/x", "--device", "no-such-gpu"],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2
    assert "no-such-gpu" in result.stderr and "available" in result.stderr


def test_integrate_demo_checks_pass(capsys):
    from rbgen.cli import integrate_demo

    assert integrate_demo(5000, 5) == 0
    assert "5,000 boxes" in capsys.readouterr().out


def test_console_script_info_names_the_default_device():
    """After `pip install .` the `rbgen` script is on PATH (CI installs into a fresh venv)."""
    import shutil

    import pytest

    from rbgen.device import default_device

    script = shutil.which("rbgen")
    if script is None:
        pytest.skip("rbgen is not installed as a console script in this environment")
    result = subprocess.run([script, "info"], capture_output=True, text=True, check=True)
    default_line = next(line for line in result.stdout.splitlines() if line.startswith("*"))
    assert default_device().name.strip() in default_line
