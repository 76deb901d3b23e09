"""Progress feedback on a terminal, silent elsewhere.

Bars (tqdm) go to stderr and show only when stderr is a terminal, or when
``RBGEN_PROGRESS=1`` asks for them anyway (``RBGEN_PROGRESS=0`` hides them
everywhere), so tests, CI logs and pipes stay clean. `say` prints a line
above any live bar; `printing_above` sends ``print`` output the same way
while a bar is live; `build_feedback` shows a line while a kernel build
takes long (the first, cold run of a kernel compiles it; later runs load
the binary from the disk cache).
"""
from __future__ import annotations

import contextlib
import os
import sys
import threading
import time

#: environment variable: "1" shows bars even off a terminal, "0" hides them
ENV_PROGRESS = "RBGEN_PROGRESS"
#: a kernel build shows a line once it has taken this long (seconds)
SLOW_BUILD = 1.0


def enabled() -> bool:
    """Whether bars show: ``RBGEN_PROGRESS`` if set, else whether stderr is a terminal."""
    choice = os.environ.get(ENV_PROGRESS, "").strip()
    if choice in ("0", "1"):
        return choice == "1"
    return bool(getattr(sys.stderr, "isatty", lambda: False)())


def bar(total=None, desc: str = "", unit: str = "it", delay: float = 0.0, show: bool = True):
    """A tqdm bar on stderr (a disabled one when bars do not show, or ``show`` is False);
    ``delay``: seconds before it appears, so short work shows none."""
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, delay=delay, leave=False,
                disable=not (show and enabled()), file=sys.stderr, dynamic_ncols=True,
                mininterval=0.2)


def say(line: str) -> None:
    """Print ``line`` to stderr above any live bar."""
    from tqdm import tqdm

    tqdm.write(line, file=sys.stderr)


class _AboveBars:
    """A stdout stand-in that writes whole lines through tqdm.write."""

    def __init__(self, target):
        self._target, self._pending = target, ""

    def write(self, text: str) -> int:
        from tqdm import tqdm

        self._pending += text
        while "\n" in self._pending:
            line, self._pending = self._pending.split("\n", 1)
            tqdm.write(line, file=self._target)
        return len(text)

    def flush(self) -> None:
        self._target.flush()


@contextlib.contextmanager
def printing_above(active: bool = True):
    """While inside, ``print`` to stdout goes above live bars (when bars show)."""
    if not (active and enabled()):
        yield
        return
    target = sys.stdout
    with contextlib.redirect_stdout(_AboveBars(target)) as proxy:
        try:
            yield
        finally:
            if proxy._pending:
                target.write(proxy._pending)


_builds = {"count": 0}


@contextlib.contextmanager
def build_feedback(name: str):
    """Around one kernel build: when bars show and the build passes `SLOW_BUILD`
    seconds, a live line names it with its elapsed time, cleared when it ends."""
    if not enabled():
        yield
        return
    _builds["count"] += 1
    done = threading.Event()
    start = time.perf_counter()
    label = (f"compiling OpenCL program {_builds['count']} ({name}; cached on disk for the "
             f"next run)")

    def show():
        if done.wait(SLOW_BUILD):
            return
        with bar(desc=label, unit="s", show=True) as line:
            line.bar_format = "{desc}: {elapsed}"
            while not done.wait(0.5):
                line.refresh()
            line.set_postfix_str(f"{time.perf_counter() - start:.1f} s")

    watcher = threading.Thread(target=show, daemon=True)
    watcher.start()
    try:
        yield
    finally:
        done.set()
        watcher.join()
