"""The rbgen command."""

from __future__ import annotations

import subprocess
import sys

import pytest

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


def _starred(out: str) -> list[str]:
    return [line for line in out.splitlines() if line.startswith("*")]


def test_info_marks_a_gpu_shape_choice_as_chosen(monkeypatch, capsys):
    """`rbgen info --device shape:h200` marks the CPU device that stands in for the H200
    (as a Runtime of that choice uses it), not the default device, and shows the GPU
    traits it is planned for; the footer names the choice. (The default is made another
    device here where there is one, so that a fallback to it shows.)"""
    from rbgen import device
    from rbgen.device import DeviceTraits, cpu_device, list_devices, shaped_traits

    cpu = cpu_device()
    others = [e.device for e in list_devices() if e.device != cpu]
    if others:
        monkeypatch.setattr(device, "default_device", lambda: others[0])
    monkeypatch.delenv(device.ENV_DEVICE, raising=False)
    assert main(["info", "--device", "shape:h200"]) == 0
    out = capsys.readouterr().out
    index = next(e.index for e in list_devices() if e.device == cpu)
    assert _starred(out) == [f"* {index}  {DeviceTraits.of(cpu).describe()}"]
    shaped = shaped_traits(DeviceTraits.of(cpu), "h200")
    assert f"        chosen as shape:h200: planned for as {shaped.describe()}" in out
    assert f"fingerprint {shaped.fingerprint}" in out
    assert out.rstrip().endswith("(* = the device rbgen uses: --device shape:h200)")


def test_info_marks_a_device_choice_and_names_it(monkeypatch, capsys):
    """A real device choice (its index) is marked the same way, the footer names it, and
    no GPU traits are shown for it."""
    from rbgen import device
    from rbgen.device import DeviceTraits, cpu_device, list_devices

    cpu = cpu_device()
    index = next(e.index for e in list_devices() if e.device == cpu)
    monkeypatch.delenv(device.ENV_DEVICE, raising=False)
    assert main(["info", "--device", index]) == 0
    out = capsys.readouterr().out
    assert _starred(out) == [f"* {index}  {DeviceTraits.of(cpu).describe()}"]
    assert "chosen as" not in out
    assert out.rstrip().endswith(f"(* = the device rbgen uses: --device {index})")


@pytest.mark.parametrize(
    "choice, match",
    [("no-such-gpu", "matches no OpenCL device"), ("shape:a100", "no GPU shape 'a100'")],
)
def test_info_with_a_device_choice_that_names_nothing_says_so(monkeypatch, capsys, choice, match):
    """A choice that names no device is not replaced by the default: every device is
    listed unmarked, and the error names the choice (exit 2)."""
    from rbgen import device
    from rbgen.device import list_devices

    monkeypatch.delenv(device.ENV_DEVICE, raising=False)
    assert main(["info", "--device", choice]) == 2
    captured = capsys.readouterr()
    assert _starred(captured.out) == []
    assert all(entry.index in captured.out for entry in list_devices())
    assert captured.err.startswith(f"rbgen: error: --device {choice!r}: ")
    assert match in captured.err


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
