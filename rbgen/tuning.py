"""Autotuning of the primitives: search spaces, timing, and a JSON cache.

Each primitive *family* (scan, radix sort, ...) declares in `FAMILIES` its
search space for a device, how to build a candidate, and a benchmark input
with a correctness check. `tune` runs every candidate once on that input and
rejects those whose result is wrong, then times the rest with OpenCL events on
`runtime.profiling_queue`'s timestamps (median of repeated runs) and keeps the
fastest; candidates within `NOISE` of the fastest (or within the fastest's own
measured spread, if larger) count as ties and the one listed first (the
heuristic default leads every space) wins, so noise never flips a result away
from the default.

Winners are stored in ``cache_dir()/"tuning"/<device fingerprint>.json``
(format `CACHE_VERSION`), one entry per family, variant, template source hash
and size bucket (`rbgen.primitives._base.size_bucket`: the even exponent
nearest to log2 of the element count). `lookup` is what primitives call: it
reads the cache once per process and never tunes, so a first run on an
untuned device simply gets the heuristic defaults from `DeviceTraits`. An
entry whose template changed since it was tuned (other source hash) is stale
and ignored; a missing bucket falls back to the nearest tuned bucket of the
same family and variant (ties: the larger). `tune_all` tunes every other
bucket from 2^12 to 2^24 on GPUs (`TUNE_SIZES`).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import os
import statistics
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyopencl as cl

from .codegen import cache_dir
from .device import DeviceTraits, Runtime
from .errors import RbgenError

CACHE_VERSION = 1
#: relative timing difference below which two candidates count as equal
NOISE = 0.03

# --------------------------------------------------------------------------
# The cache


def cache_path(traits: DeviceTraits) -> Path:
    return cache_dir() / "tuning" / f"{traits.fingerprint}.json"


def entry_key(family: str, variant: str, bucket: int) -> str:
    return f"{family}[{variant}]@2^{bucket}"


_LOADED: dict[Path, dict] = {}


def load_cache(traits: DeviceTraits, reload: bool = False) -> dict:
    """The tuning cache of a device: ``{"version", "fingerprint", "entries": {...}}``.

    A missing, unreadable, other-version or other-device file reads as empty.
    """
    path = cache_path(traits)
    if not reload and path in _LOADED:
        return _LOADED[path]
    empty = {"version": CACHE_VERSION, "fingerprint": traits.fingerprint, "entries": {}}
    try:
        data = json.loads(path.read_text())
        ok = (
            isinstance(data, dict)
            and data.get("version") == CACHE_VERSION
            and data.get("fingerprint") == traits.fingerprint
            and isinstance(data.get("entries"), dict)
        )
        cache = data if ok else empty
    except (OSError, ValueError):
        cache = empty
    _LOADED[path] = cache
    return cache


def save_cache(traits: DeviceTraits, cache: dict) -> Path:
    path = cache_path(traits)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps(cache, indent=1, sort_keys=True))
    os.replace(tmp, path)
    _LOADED[path] = cache
    return path


def forget_loaded() -> None:
    """Drop the in-process copies of cache files (tests switch cache dirs)."""
    _LOADED.clear()


def _current_hash(family: str, shape: str) -> str | None:
    fam = FAMILIES.get(family)
    if fam is None:
        return None
    return fam.template_hash(shape)


def lookup(traits: DeviceTraits, family: str, variant: str, bucket: int) -> dict | None:
    """Tuned parameters for a primitive, or None (then the caller uses its heuristic).

    Exact bucket first, else the nearest tuned bucket (ties: the larger);
    entries tuned against another version of the template are ignored.
    """
    entries = load_cache(traits)["entries"]
    best, best_distance = None, None
    for entry in entries.values():
        if entry.get("family") != family or entry.get("variant") != variant:
            continue
        params = entry.get("params") or {}
        if entry.get("source_hash") != _current_hash(family, params.get("shape", "")):
            continue
        distance = (abs(entry["bucket"] - bucket), -entry["bucket"])
        if best_distance is None or distance < best_distance:
            best, best_distance = params, distance
    return dict(best) if best is not None else None


#: the cache entry holding a device's tuned plan parameters (`rbgen.plan.TUNABLES`)
PLAN_ENTRY = "plan"
#: the plan entry's format; an entry of another version is ignored
PLAN_VERSION = 1


def lookup_plan(traits: DeviceTraits) -> dict:
    """The tuned plan parameters of a device (empty when untuned): what `rbgen tune`
    measured fastest among the scenes that held, by parameter name."""
    entry = load_cache(traits)["entries"].get(PLAN_ENTRY)
    if not isinstance(entry, dict) or entry.get("plan_version") != PLAN_VERSION:
        return {}
    values = entry.get("values")
    return dict(values) if isinstance(values, dict) else {}


def describe_cache(traits: DeviceTraits) -> list[str]:
    """One line per tuned entry of a device's cache (``rbgen info`` prints them)."""
    from . import primitives  # noqa: F401 - registers the families

    lines = []
    entries = load_cache(traits, reload=True)["entries"]
    for key in sorted(entries):
        e = entries[key]
        if key == PLAN_ENTRY:
            values = ", ".join(f"{k}={v}" for k, v in sorted((e.get("values") or {}).items()))
            lines.append(f"{key}: {values} (scene {e.get('scene', '?')})")
            continue
        params = dict(e.get("params", {}))
        shape = params.pop("shape", "?")
        stale = e.get("source_hash") != _current_hash(e.get("family", ""), shape)
        text = ", ".join(f"{k}={v}" for k, v in sorted(params.items()))
        timing = f"{e['median_ms']:.3f} ms" if "median_ms" in e else "untimed"
        lines.append(
            f"{key}: {shape} {text} -> {timing}"
            f" ({e.get('candidates', '?')} candidates)" + (" [stale]" if stale else "")
        )
    return lines


# --------------------------------------------------------------------------
# Choosing a winner (pure: tested from recorded timings)


def pick_winner(timings: list[tuple[Any, float | None]], noise: float = NOISE) -> int | None:
    """The index of the winner among ``(params, median_ms or None if incorrect)``.

    The fastest correct candidate wins, except that any candidate listed
    before it within ``noise`` (relative) of its time counts as equal and wins
    instead: the order of the search space (heuristic default first) breaks ties.
    """
    correct = [(i, t) for i, (_, t) in enumerate(timings) if t is not None]
    if not correct:
        return None
    fastest = min(t for _, t in correct)
    for i, t in correct:
        if t <= fastest * (1.0 + noise):
            return i
    return None  # unreachable


# --------------------------------------------------------------------------
# Families and the tuner


@dataclasses.dataclass
class Family:
    """One tunable primitive: how to enumerate, build and check its candidates.

    ``space(traits)`` lists parameter dicts (heuristic default first);
    ``build(runtime, variant, params)`` returns a primitive; ``bench(runtime,
    primitive, n, rng)`` returns ``(run, check)``: ``run()`` enqueues one
    execution on the primitive's queue, ``check()`` says (blocking) whether
    the last run's result is right.
    """

    name: str
    variants: tuple[str, ...]
    space: Callable[[DeviceTraits], list[dict]]
    build: Callable[[Runtime, str, dict], Any]
    bench: Callable[[Runtime, Any, int, np.random.Generator], tuple[Callable, Callable]]
    templates: Callable[[], dict]

    def template_hash(self, shape: str) -> str | None:
        template = self.templates().get(shape)
        return template.source_hash() if template is not None else None


FAMILIES: dict[str, Family] = {}


def register(family: Family) -> Family:
    FAMILIES[family.name] = family
    return family


def profiling_runtime(runtime: Runtime) -> Runtime:
    """A view of ``runtime`` whose queue is its profiling queue (same context)."""
    if runtime.profiling:
        return runtime
    view = copy.copy(runtime)
    view.queue = runtime.profiling_queue
    view.profiling = True
    return view


def time_samples(runtime: Runtime, run: Callable, repeats: int) -> list[float]:
    """Milliseconds of ``repeats`` runs, from OpenCL event timestamps.

    ``run()`` enqueues on ``runtime.queue`` (a profiling queue); markers
    enqueued before and after it on the in-order queue bound the whole run.
    ``run.prepare()``, if present, restores the input first, untimed.
    """
    queue = runtime.queue
    prepare = getattr(run, "prepare", None)
    times = []
    for _ in range(repeats):
        if prepare is not None:
            prepare()
        queue.finish()
        before = cl.enqueue_marker(queue)
        run()
        after = cl.enqueue_marker(queue)
        after.wait()
        times.append((after.profile.end - before.profile.start) * 1e-6)
    return times


def time_runs(runtime: Runtime, run: Callable, repeats: int) -> float:
    """Median milliseconds of ``repeats`` runs (see `time_samples`)."""
    return statistics.median(time_samples(runtime, run, repeats))


def relative_spread(samples: list[float]) -> float:
    """Interquartile range over median: how noisy a candidate's timings were."""
    if len(samples) < 4:
        return 0.0
    q1, _, q3 = statistics.quantiles(samples, n=4)
    return (q3 - q1) / statistics.median(samples)


def tune(
    runtime: Runtime,
    family: str | Family,
    variant: str,
    n: int,
    *,
    repeats: int = 7,
    progress: Callable[[str], None] | None = None,
    seed: int = 0,
    store: bool = True,
) -> dict:
    """Tune one family/variant at size n on ``runtime``; returns the cache entry."""
    from .primitives._base import size_bucket

    fam = FAMILIES[family] if isinstance(family, str) else family
    runtime = profiling_runtime(runtime)
    rng = np.random.default_rng(seed)
    space = fam.space(runtime.traits)
    with warnings.catch_warnings():
        # the profiling view builds its own kernel objects from the shared programs
        warnings.simplefilter("ignore", cl.RepeatedKernelRetrieval)
        results, spreads = _run_candidates(runtime, fam, variant, n, space, rng, repeats, progress)
    # ties: within NOISE, or within the measured spread of the fastest candidate
    timed = [(i, ms) for i, (_, ms) in enumerate(results) if ms is not None]
    fastest = min(timed, key=lambda item: item[1])[0] if timed else None
    noise = max(NOISE, spreads[fastest]) if fastest is not None else NOISE
    winner = pick_winner(results, noise)
    if winner is None:
        raise RbgenError(f"tuning {fam.name}[{variant}]: no candidate gave a correct result")
    params, ms = results[winner]
    bucket = size_bucket(n)
    entry = {
        "family": fam.name,
        "variant": variant,
        "bucket": bucket,
        "n": n,
        "params": params,
        "median_ms": ms,
        "candidates": len(space),
        "source_hash": fam.template_hash(params["shape"]),
        "tuned_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    if store:
        cache = load_cache(runtime.traits, reload=True)
        cache["entries"][entry_key(fam.name, variant, bucket)] = entry
        save_cache(runtime.traits, cache)
    return entry


def _run_candidates(runtime, fam, variant, n, space, rng, repeats, progress):
    """``[(params, median ms or None when wrong or failed)]`` and each one's spread."""
    results: list[tuple[dict, float | None]] = []
    spreads: list[float] = []
    for i, params in enumerate(space):
        label = ", ".join(f"{k}={v}" for k, v in params.items())
        try:
            prim = fam.build(runtime, variant, params)
            run, check = fam.bench(runtime, prim, n, rng)
            if getattr(run, "prepare", None) is not None:
                run.prepare()
            run()
            ok = bool(check())
        except Exception as err:  # noqa: BLE001 - a candidate that fails to build is skipped
            ok, label = False, f"{label} ({type(err).__name__}: {err})"[:200]
        samples = time_samples(runtime, run, repeats) if ok else []
        ms = statistics.median(samples) if ok else None
        results.append((params, ms))
        spreads.append(relative_spread(samples))
        if progress:
            what = f"{ms:.3f} ms" if ms is not None else "REJECTED (wrong result or build error)"
            progress(f"  [{i + 1}/{len(space)}] {fam.name}[{variant}] n={n}: {label}: {what}")
    return results, spreads


#: sizes tuned by `tune_all` on GPUs: the pipeline's arrays (1k-500k elements) up to the
#: 16M of the scan benchmark, every other size bucket (one between two tuned ones picks
#: the nearer, see `lookup`); winners differ across this range (launch count vs bandwidth)
TUNE_SIZES = (1 << 12, 1 << 16, 1 << 20, 1 << 22, 1 << 24)
#: on CPUs (a 2^24 sort takes seconds per run there)
CPU_TUNE_SIZES = (1 << 12, 1 << 16, 1 << 20)
#: ``tune_all(quick=True)``: one size
QUICK_SIZES = (1 << 16,)


def tune_sizes(traits: DeviceTraits, quick: bool = False) -> tuple[int, ...]:
    """The sizes `tune_all` tunes on a device."""
    if quick:
        return QUICK_SIZES
    return TUNE_SIZES if traits.is_gpu else CPU_TUNE_SIZES


def tune_all(runtime: Runtime, progress: bool = True, quick: bool = False) -> list[dict]:
    """Tune every family and variant at `tune_sizes`; lines go to stderr."""
    from . import primitives  # noqa: F401 - registers the families
    from .progress import bar
    from .progress import say as say_above_bar

    say = say_above_bar if progress else None
    sizes = tune_sizes(runtime.traits, quick)
    jobs = [(fam, v, n) for fam in FAMILIES.values() for v in fam.variants for n in sizes]
    entries = []
    with bar(total=len(jobs), desc="tuning", unit="job", show=progress) as jobs_bar:
        for j, (fam, variant, n) in enumerate(jobs):
            if say:
                say(
                    f"[{j + 1}/{len(jobs)}] tuning {fam.name}[{variant}] at n={n} "
                    f"on {runtime.traits.device_name}"
                )
            entries.append(tune(runtime, fam, variant, n, repeats=3 if quick else 7, progress=say))
            jobs_bar.update(1)
    if say:
        say(f"tuning cache: {cache_path(runtime.traits)}")
    return entries
