"""rbgen.progress: bars and build lines show on a terminal (or when asked) and nowhere else."""

from __future__ import annotations

import time

from rbgen import progress


def test_nothing_is_printed_off_a_terminal(monkeypatch, capsys):
    monkeypatch.delenv(progress.ENV_PROGRESS, raising=False)
    assert not progress.enabled()  # (pytest captures stderr: not a terminal)
    with progress.bar(total=3, desc="steps") as steps:
        steps.update(3)
    with progress.build_feedback("slow.cl.mako"):
        time.sleep(0.01)
    captured = capsys.readouterr()
    assert captured.err == "" and captured.out == ""


def test_a_burst_of_slow_builds_shows_a_line_when_asked(monkeypatch, capsys):
    """With RBGEN_PROGRESS=1 a burst of builds longer than SLOW_BUILD shows one line that
    counts them; it is gone (cleared) once the builds stop."""
    monkeypatch.setenv(progress.ENV_PROGRESS, "1")
    monkeypatch.setattr(progress, "SLOW_BUILD", 0.05)
    for k in range(4):
        with progress.build_feedback(f"k{k}.cl.mako"):
            time.sleep(0.12)
    time.sleep(0.9)  # the watcher closes the line after half a second without builds
    err = capsys.readouterr().err
    assert "compiling OpenCL kernels" in err and "built" in err
    assert progress._BUILDS.watcher is None


def test_printing_above_passes_lines_through(monkeypatch, capsys):
    monkeypatch.setenv(progress.ENV_PROGRESS, "1")
    with progress.printing_above():
        print("a line", flush=True)
        print("partial", end="")
    assert "a line" in capsys.readouterr().out
