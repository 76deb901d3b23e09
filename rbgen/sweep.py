"""Parameter sweeps on Dask (`sweep`): one World or WorldBatch per parameter set, each a
Dask task on a `dask.distributed` worker pinned to one OpenCL device.

``sweep(build, params, steps)`` calls ``build(**p)`` for every parameter set ``p`` (a
dict) on a worker, steps the World it returns ``steps`` times by ``dt`` and measures it
(``measure(world)``, a dict; by default the end state), and returns the table: one row
(a dict) per parameter set, in the order given, with the parameters, ``ok``, ``error``
(None, or why the task failed: a raised error with its traceback, a worker that died),
the worker's device, the seconds the run took, and the measurements. A failing task
fails its row only; the others' results are kept.

Timeouts: with ``timeout`` (seconds, default None: no limit), a task that has not
finished that long after it started on its worker (building, stepping and measuring)
fails its row with an error naming its parameter set and the timeout, and the worker
takes the next task. Python cannot stop a thread: the run that overran goes on in the
background of its worker process until it ends (a sweep on its own LocalCluster closes
those processes at the end; with a ``client`` of yours, restart its workers,
``client.restart()``, to reclaim one that hangs for good).

Workers: without a ``client``, a `distributed.LocalCluster` of ``workers`` processes
(default: one per GPU found, else one), closed afterwards. Every worker of the client's
cluster is pinned to a device before the tasks run: the workers of one host are ranked,
and rank r takes ``devices[r % len(devices)]`` (device choices as `RBGEN_DEVICE` takes
them) or, without ``devices``, the r-th GPU of its host (none: the host's default
device); the choice is the worker process's ``RBGEN_DEVICE``. A worker process keeps
its compiled programs between tasks (the program cache), so kernels are built once per
worker. Dask is an optional dependency (``pip install rbgen[sweep]``).
"""

from __future__ import annotations

import math
import os
import threading
import time
import traceback
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from .errors import RbgenError

#: the state fields the default measurement returns
STATE = ("positions", "orientations", "linear_velocities", "angular_velocities")


def end_state(world) -> dict:
    """The default measurement: the end state's arrays (numpy, float32)."""
    return {name: np.array(getattr(world, name)) for name in STATE}


def summary(world) -> dict:
    """A short measurement for tables and JSON: body count, the mean and lowest centre
    height, and the largest speed."""
    positions = np.asarray(world.positions, float).reshape(-1, 3)
    speeds = np.linalg.norm(np.asarray(world.linear_velocities, float).reshape(-1, 3), axis=1)
    return {
        "bodies": len(positions),
        "mean_height": float(positions[:, 1].mean()) if len(positions) else 0.0,
        "min_height": float(positions[:, 1].min()) if len(positions) else 0.0,
        "max_speed": float(speeds.max(initial=0.0)),
    }


def _import_dask():
    try:
        import distributed
    except ImportError:
        raise RbgenError(
            "rbgen.sweep needs dask.distributed: pip install 'rbgen[sweep]' (or "
            "'dask[distributed]')"
        ) from None
    return distributed


def check_params(params) -> list[dict]:
    """The parameter sets as a list of dicts; anything else is refused naming it."""
    if isinstance(params, Mapping) or not isinstance(params, Sequence):
        raise RbgenError(
            f"params must be a sequence of dicts (one parameter set each), got "
            f"{type(params).__name__}"
        )
    checked = []
    for i, p in enumerate(params):
        if not isinstance(p, Mapping) or not all(isinstance(k, str) for k in p):
            raise RbgenError(f"params[{i}] must be a dict of parameter names to values, got {p!r}")
        checked.append(dict(p))
    return checked


def check_timeout(timeout) -> float | None:
    """``timeout`` as seconds (a positive finite number) or None (no limit); anything
    else is refused naming it."""
    if timeout is None:
        return None
    if (
        isinstance(timeout, (bool, np.bool_))
        or not isinstance(timeout, (int, float, np.integer, np.floating))
        or not math.isfinite(timeout)
        or timeout <= 0
    ):
        raise RbgenError(
            f"timeout must be None (no limit) or a positive number of seconds, got {timeout!r}"
        )
    return float(timeout)


def run_one(
    build: Callable,
    param: dict,
    steps: int,
    dt: float = 1 / 60,
    measure=None,
    timeout: float | None = None,
) -> dict:
    """One parameter set, here: ``build(**param)``, ``steps`` steps of ``dt``, and its
    row of the table (see the module docstring). Errors become the row's ``error``.
    ``timeout`` (seconds, None: no limit): a run still going after that long gives a
    failed row naming the parameter set and the timeout, and goes on in a background
    thread until it ends (see the module docstring)."""
    timeout = check_timeout(timeout)
    if timeout is None:
        return _run(build, param, steps, dt, measure)
    done: dict = {}
    thread = threading.Thread(
        target=lambda: done.update(row=_run(build, param, steps, dt, measure)),
        name=f"rbgen sweep {param!r}",
        daemon=True,  # (one that never ends does not hold the process at exit)
    )
    start = time.perf_counter()
    thread.start()
    thread.join(timeout)
    if "row" in done:
        return done["row"]
    return {
        "params": dict(param),
        "ok": False,
        "error": (
            f"parameter set {param!r}: timed out: not finished after {timeout:g} s "
            f"(timeout={timeout:g}); the run goes on in the background of process "
            f"{os.getpid()}"
        ),
        "device": None,
        "seconds": time.perf_counter() - start,
    }


def _run(build: Callable, param: dict, steps: int, dt: float, measure) -> dict:
    """`run_one` without a timeout."""
    from .batch import WorldBatch
    from .world import World

    row: dict = {"params": dict(param), "ok": False, "error": None, "device": None}
    start = time.perf_counter()
    try:
        world = build(**param)
        if not isinstance(world, (World, WorldBatch)):
            raise RbgenError(
                f"build must return an rbgen.World or rbgen.WorldBatch, got {type(world).__name__}"
            )
        row["device"] = world.runtime.traits.device_name
        for _ in range(steps):
            world.step(dt)
        row.update((measure or end_state)(world))
        row["ok"] = True
    except Exception as err:  # noqa: BLE001 -- the row reports it, the sweep goes on
        row["error"] = (
            f"parameter set {param!r}: {type(err).__name__}: {err}\n{traceback.format_exc()}"
        )
    row["seconds"] = time.perf_counter() - start
    return row


def _task(index: int, build, param: dict, steps: int, dt: float, measure, timeout=None) -> dict:
    """A worker's task: `run_one` (its ``timeout`` counted from the task's start on the
    worker, not from its submission) plus where it ran."""
    row = run_one(build, param, steps, dt, measure, timeout)
    row["index"] = index
    row["pid"] = os.getpid()
    row["rbgen_device"] = os.environ.get("RBGEN_DEVICE")
    return row


def _pin(rank: int, devices) -> str | None:
    """(runs on a worker) Set this process's RBGEN_DEVICE for host rank ``rank``."""
    from .device import ENV_DEVICE, build_failure, list_devices

    choice: str | None
    if devices:
        choice = str(devices[rank % len(devices)])
    else:
        import pyopencl as cl

        gpus = [
            e
            for e in list_devices()
            if e.device.type & cl.device_type.GPU and build_failure(e.device) is None
        ]
        choice = gpus[rank % len(gpus)].index if gpus else None
    if choice is None:
        os.environ.pop(ENV_DEVICE, None)
    else:
        os.environ[ENV_DEVICE] = choice
    return choice


def pin_workers(client, devices=None) -> dict:
    """Pin every worker of ``client`` to a device (see the module docstring); returns
    {worker address: device choice or None (the default device)}."""
    workers = sorted(client.scheduler_info(n_workers=-1)["workers"].items())
    by_host: dict[str, list[str]] = {}
    for address, info in workers:
        by_host.setdefault(info.get("host", address.rsplit(":", 1)[0]), []).append(address)
    pinned = {}
    for addresses in by_host.values():
        for rank, address in enumerate(sorted(addresses)):
            pinned.update(client.run(_pin, rank, devices, workers=[address]))
    return pinned


def default_workers() -> int:
    """One LocalCluster worker per GPU here, else one."""
    import pyopencl as cl

    from .device import list_devices

    return max(1, sum(bool(e.device.type & cl.device_type.GPU) for e in list_devices()))


def sweep(
    build: Callable,
    params,
    steps: int,
    client=None,
    *,
    dt: float = 1 / 60,
    measure: Callable | None = None,
    workers: int | None = None,
    devices: Sequence[str] | None = None,
    timeout: float | None = None,
) -> list[dict]:
    """Run ``build(**p)`` for ``steps`` steps for every parameter set ``p`` of ``params``
    as Dask tasks; returns the table (see the module docstring). ``timeout``: seconds a
    task may run on its worker (None: no limit); one that overruns fails its row only,
    naming its parameter set and the timeout. Bad arguments raise `RbgenError` naming
    them before any task is submitted."""
    if not callable(build):
        raise RbgenError(f"build must be a function returning a World, got {build!r}")
    params = check_params(params)
    if isinstance(steps, (bool, np.bool_)) or not isinstance(steps, (int, np.integer)) or steps < 0:
        raise RbgenError(f"steps must be a non-negative integer, got {steps!r}")
    if workers is not None and (not isinstance(workers, int) or workers < 1):
        raise RbgenError(f"workers must be a positive integer, got {workers!r}")
    timeout = check_timeout(timeout)
    distributed = _import_dask()
    cluster = None
    if client is None:
        cluster = distributed.LocalCluster(
            n_workers=workers or default_workers(),
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
        )
        client = distributed.Client(cluster)
    try:
        pin_workers(client, devices)
        futures = [
            client.submit(_task, i, build, p, int(steps), float(dt), measure, timeout, pure=False)
            for i, p in enumerate(params)
        ]
        table = []
        for i, (p, future) in enumerate(zip(params, futures)):
            try:
                table.append(future.result())
            except Exception as err:  # noqa: BLE001 -- a worker died: this row only
                table.append(
                    {
                        "index": i,
                        "params": p,
                        "ok": False,
                        "error": f"parameter set {p!r}: {type(err).__name__}: {err}",
                        "device": None,
                    }
                )
        return table
    finally:
        if cluster is not None:
            client.close()
            cluster.close()
