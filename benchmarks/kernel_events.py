"""Every kernel launch of a stretch of steps with its profiling event, for the benchmarks
that split a World's device time by kernel (kernel_times.py, cpu_solve.py).

It imports nothing of rbgen, so that cpu_solve.py's worker, which runs another tree's
rbgen, can use it too. The queue must have been made with profiling on.
"""

from __future__ import annotations

from collections import Counter, defaultdict

import numpy as np
import pyopencl as cl


class KernelEvents:
    """``with KernelEvents() as launches:`` records each `cl.enqueue_nd_range_kernel` call
    (``launches.step``: the step it belongs to, set by the caller before each step) until
    the block ends; read the times only after the queue has finished."""

    def __init__(self):
        self.step = 0
        self.events: list[tuple[int, str, cl.Event]] = []
        self._original = None

    def __enter__(self) -> KernelEvents:
        self._original = original = cl.enqueue_nd_range_kernel

        def recording(queue, kernel, *rest, **kw):
            event = original(queue, kernel, *rest, **kw)
            self.events.append((self.step, kernel.function_name, event))
            return event

        cl.enqueue_nd_range_kernel = recording
        return self

    def __exit__(self, *exc) -> None:
        cl.enqueue_nd_range_kernel = self._original

    def per_step_ms(self, steps: int) -> dict[str, np.ndarray]:
        """Each kernel's device time (ms) in each of ``steps`` steps."""
        per_step: dict[str, np.ndarray] = defaultdict(lambda: np.zeros(steps))
        for step, name, event in self.events:
            per_step[name][step] += 1e-6 * (event.profile.end - event.profile.start)
        return dict(per_step)

    def counts(self) -> Counter:
        """Launches of each kernel over the whole block."""
        return Counter(name for _, name, _ in self.events)
