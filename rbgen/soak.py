"""A soak run: a churned scene stepped for a long time, watched for leaks and drift.

The scene (`churned_world`): a ground box and a pile of boxes, spheres, capsules and
hulls. Every ``churn_every`` steps, ``churn`` random bodies are removed and as many new
ones dropped from above (the same palette of shapes, as a game spawns them), so the body
count holds while the indices, the contacts and the warm starts keep changing. The World
starts with tiny pair and manifold buffers, so the first steps overflow and grow them
(forced growth; each growth redoes its step). A run reports, after a warm-up (the growth
and the first churns) and at the end: the bodies, this process's resident memory, the
device bytes the World holds (`rbgen.memory.device_bytes`) and the mean step time of a
window of steps; and a digest of the final state, so that two runs can be compared bit
for bit. `benchmarks/soak.py` is the command; ``tests/test_soak.py`` a short run.
"""

from __future__ import annotations

import dataclasses
import gc
import hashlib
import time

import numpy as np

from . import memory
from .progress import bar
from .shapes import Box, Capsule, ConvexHull, Sphere
from .world import World

FIELDS = ("positions", "orientations", "linear_velocities", "angular_velocities")
DT = 1.0 / 60.0
#: the shapes new bodies are made of (a fixed palette: the shape table does not grow)
PALETTE = (
    Box((0.3, 0.3, 0.3)),
    Sphere(0.3),
    Capsule(0.2, 0.25),
    ConvexHull(np.random.default_rng(1).normal(size=(10, 3)) * 0.3),
)


@dataclasses.dataclass
class SoakResult:
    """What one soak run measured (bytes, milliseconds); ``start`` is after the warm-up."""

    steps: int
    bodies_start: int
    bodies_end: int
    rss_start: int
    rss_end: int
    device_start: int
    device_end: int
    step_ms_start: float
    step_ms_end: float
    overflows: int
    churned: int
    digest: str


def _drop_positions(rng, count, side) -> np.ndarray:
    return np.column_stack(
        [
            rng.uniform(-side, side, count),
            rng.uniform(3.0, 8.0, count),
            rng.uniform(-side, side, count),
        ]
    )


def churned_world(runtime, bodies: int, seed: int, **options) -> tuple[World, float]:
    """The ground and ``bodies`` dynamic bodies (a quarter of each palette shape) in a
    loose pile; returns the World and the half-width of the drop area."""
    rng = np.random.default_rng(seed)
    side = max(2.0, 0.5 * np.sqrt(bodies))
    world = World(runtime, pair_capacity=16, manifold_capacity=16, **options)
    world.add_static(Box((side + 4.0, 0.5, side + 4.0)), position=(0.0, -0.5, 0.0))
    for k, shape in enumerate(PALETTE):
        count = bodies // len(PALETTE) + (k < bodies % len(PALETTE))
        p = _drop_positions(rng, count, side)
        p[:, 1] = 0.5 + rng.uniform(0.0, 0.2 * np.sqrt(bodies), count)
        world.add_bodies(shape, mass=float(rng.uniform(0.5, 2.0)), positions=p)
    return world, side


def churn_step(world: World, rng, side: float, churn: int) -> None:
    """Remove ``churn`` random dynamic bodies and drop as many new ones."""
    dynamic = np.arange(1, world.body_count)
    gone = rng.choice(dynamic, size=min(churn, len(dynamic)), replace=False)
    world.remove_bodies(gone)
    for _ in range(len(gone)):
        shape = PALETTE[int(rng.integers(len(PALETTE)))]
        q = rng.normal(size=4)
        world.add_body(
            shape,
            mass=float(rng.uniform(0.5, 2.0)),
            position=_drop_positions(rng, 1, side)[0],
            orientation=q / np.linalg.norm(q),
            linear_velocity=rng.uniform(-1.0, 1.0, 3),
        )


def state_digest(world: World) -> str:
    """SHA-256 of the four state arrays (bit for bit)."""
    h = hashlib.sha256()
    for field in FIELDS:
        h.update(np.ascontiguousarray(getattr(world, field)).tobytes())
    return h.hexdigest()


def run_soak(
    runtime,
    steps: int,
    bodies: int = 400,
    churn_every: int = 10,
    churn: int = 8,
    seed: int = 0,
    warmup: int | None = None,
    window: int = 50,
    progress: bool = False,
    **options,
) -> SoakResult:
    """Step the churned scene ``steps`` times (see the module docstring). ``warmup``:
    steps before the start measurements (default a tenth, at least two churns);
    ``window``: steps timed at the start and at the end; ``progress``: a bar on stderr
    (a 100,000-step soak takes minutes)."""
    warmup = max(2 * churn_every, steps // 10) if warmup is None else warmup
    if steps < warmup + 2 * window:
        raise ValueError(
            f"steps={steps} must cover the warm-up ({warmup}) and two timing windows of {window}"
        )
    rng = np.random.default_rng(seed + 1)
    world, side = churned_world(runtime, bodies, seed, **options)
    start = {}
    timed: dict[str, list[float]] = {"start": [], "end": []}
    churned = 0
    with bar(total=steps, desc="soak", unit="step", delay=1.0, show=progress) as steps_bar:
        for i in range(steps):
            if i and i % churn_every == 0:
                churn_step(world, rng, side, churn)
                churned += churn
            if i == warmup:
                _ = world.positions  # (waits for the steps in flight)
                gc.collect()
                start = {
                    "bodies": world.body_count,
                    "rss": memory.rss_bytes(),
                    "device": memory.device_bytes(world),
                }
            window_of = (
                "start" if warmup <= i < warmup + window else "end" if i >= steps - window else None
            )
            began = time.perf_counter()
            world.step(DT)
            if window_of:
                _ = world.positions  # (the step's time includes its device work)
                timed[window_of].append(time.perf_counter() - began)
            steps_bar.update(1)
    digest = state_digest(world)
    gc.collect()
    return SoakResult(
        steps=steps,
        bodies_start=start["bodies"],
        bodies_end=world.body_count,
        rss_start=start["rss"],
        rss_end=memory.rss_bytes(),
        device_start=start["device"],
        device_end=memory.device_bytes(world),
        step_ms_start=1e3 * float(np.median(timed["start"])),
        step_ms_end=1e3 * float(np.median(timed["end"])),
        overflows=world.overflows,
        churned=churned,
        digest=digest,
    )


def table(results: list[SoakResult]) -> str:
    """The runs as a Markdown table."""
    rows = [
        "| run | steps | bodies start/end | churned | overflows | RSS start/end (MiB) | "
        "device start/end (MiB) | step start/end (ms) | state digest |",
        "| --- | ---: | --- | ---: | ---: | --- | --- | --- | --- |",
    ]
    mib = 1.0 / 2**20
    for k, r in enumerate(results, 1):
        rows.append(
            f"| {k} | {r.steps:,} | {r.bodies_start} / {r.bodies_end} | {r.churned:,} | "
            f"{r.overflows} | {r.rss_start * mib:.1f} / {r.rss_end * mib:.1f} | "
            f"{r.device_start * mib:.2f} / {r.device_end * mib:.2f} | "
            f"{r.step_ms_start:.2f} / {r.step_ms_end:.2f} | {r.digest[:12]} |"
        )
    return "\n".join(rows)
