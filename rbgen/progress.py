"""Progress feedback on a terminal, silent elsewhere.

Bars (tqdm) go to stderr and show only when stderr is a terminal, or when
``RBGEN_PROGRESS=1`` asks for them anyway (``RBGEN_PROGRESS=0`` hides them
everywhere), so tests, CI logs and pipes stay clean. `say` prints a line
above any live bar; `printing_above` sends ``print`` output the same way
while a bar is live; `build_feedback` shows a line while kernel builds
take long (the first, cold run of a kernel compiles it; later runs load
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
#: a burst of kernel builds shows a line once it has taken this long (seconds)
SLOW_BUILD = 1.0


def enabled() -> bool:
    """Whether bars show: ``RBGEN_PROGRESS`` if set, else whether stderr is a terminal."""
    choice = os.environ.get(ENV_PROGRESS, "").strip()
    if choice in ("0", "1"):
        return choice == "1"
    return bool(getattr(sys.stderr, "isatty", lambda: False)())


def bar(
    total=None, desc: str = "", unit: str = "it", delay: float = 0.0, show: bool = True, **options
):
    """A tqdm bar on stderr (a disabled one when bars do not show, or ``show`` is False);
    ``delay``: seconds before it appears, so short work shows none; ``options`` go to tqdm."""
    from tqdm import tqdm

    return tqdm(
        total=total,
        desc=desc,
        unit=unit,
        delay=delay,
        leave=False,
        disable=not (show and enabled()),
        file=sys.stderr,
        dynamic_ncols=True,
        mininterval=0.2,
        **options,
    )


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


class _Builds:
    """One live line for a burst of kernel builds: it appears once the burst has lasted
    `SLOW_BUILD` seconds, counts the programs built, and goes when no build has run for
    half a second (a first run builds dozens of small programs, each quick alone)."""

    def __init__(self):
        self.lock = threading.Lock()
        self.active = self.count = 0
        self.started = self.last_end = None
        self.name = ""
        self.watcher = None

    def begin(self, name: str) -> None:
        with self.lock:
            self.active += 1
            self.name = name
            if self.started is None:
                self.started, self.count = time.perf_counter(), 0
            if self.watcher is None:
                self.watcher = threading.Thread(target=self._watch, daemon=True)
                self.watcher.start()

    def end(self) -> None:
        with self.lock:
            self.active -= 1
            self.count += 1
            self.last_end = time.perf_counter()

    def _watch(self) -> None:
        line = None
        while True:
            time.sleep(0.2)
            with self.lock:
                now = time.perf_counter()
                idle = self.active == 0 and self.last_end is not None and now - self.last_end > 0.5
                if idle:
                    self.started = self.last_end = self.watcher = None
                count, name, started = self.count, self.name, self.started
            if idle:
                if line is not None:
                    line.close()
                return
            if line is None and started is not None and now - started > SLOW_BUILD:
                line = bar(
                    desc="compiling OpenCL kernels (cached on disk for the next run)",
                    unit="program",
                    bar_format="{desc}: {n} built, {elapsed}{postfix}",
                )
            if line is not None:
                line.n = count
                line.set_postfix_str(name, refresh=False)
                line.refresh()


_BUILDS = _Builds()


@contextlib.contextmanager
def build_feedback(name: str):
    """Around one kernel build: when bars show and a burst of builds passes `SLOW_BUILD`
    seconds, a live line counts them and names the one being built (see `_Builds`)."""
    if not enabled():
        yield
        return
    _BUILDS.begin(name)
    try:
        yield
    finally:
        _BUILDS.end()
