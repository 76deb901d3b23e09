"""Sweeps on Dask (issue 29, item 3): `rbgen.sweep` on a LocalCluster of 2 worker
processes gives, bit for bit, the results of the same runs done one after another
here; a failing parameter set reports which and why, and the others' rows are kept."""

from __future__ import annotations

import time

import numpy as np
import pytest

import rbgen
from rbgen import RbgenError
from rbgen.sweep import STATE, check_params, run_one

distributed = pytest.importorskip("distributed")

DT = 1 / 60


def sliding_box(friction, speed=2.0):
    """A box sliding along x on the ground (friction: the box's and the ground's)."""
    world = rbgen.World()
    world.add_static(rbgen.Plane((0, 1, 0), 0.0), friction=friction)
    world.add_body(
        rbgen.Box((0.5, 0.5, 0.5)),
        position=(0.0, 0.5, 0.0),
        linear_velocity=(speed, 0.0, 0.0),
        friction=friction,
    )
    return world


def not_a_world(friction):
    return {"friction": friction}


def slow_box(friction, sleep=0.0):
    """`sliding_box` after ``sleep`` seconds (a task that hangs, for the timeout)."""
    time.sleep(sleep)
    return sliding_box(friction)


@pytest.fixture(scope="module")
def client():
    """Two worker processes, one thread each (each pinned to this machine's default
    device: no GPU here)."""
    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        yield client


def test_sweep_equals_serial_runs_bit_for_bit(client):
    params = [{"friction": f} for f in (0.0, 0.2, 0.5, 0.8)] + [{"friction": -1.0}]
    table = rbgen.sweep(sliding_box, params, steps=30, client=client)
    assert [row["params"] for row in table] == params
    assert len({row["pid"] for row in table}) == 2  # both workers ran tasks
    for row, p in zip(table[:4], params):
        assert row["ok"] and row["error"] is None, row["error"]
        serial = run_one(sliding_box, p, 30, DT)
        for name in STATE:
            assert np.array_equal(row[name], serial[name]), (p, name)
    # friction slows the box: more friction, less distance
    distances = [row["positions"][1, 0] for row in table[:4]]
    assert all(a > b for a, b in zip(distances, distances[1:]))
    failed = table[4]
    assert not failed["ok"] and failed["params"] == {"friction": -1.0}
    assert failed["error"].startswith("parameter set {'friction': -1.0}: RbgenError: body 0:")
    assert "friction=-1.0 is out of range" in failed["error"]


def test_a_build_that_is_not_a_world_fails_its_row(client):
    table = rbgen.sweep(not_a_world, [{"friction": 0.1}], steps=1, client=client)
    assert not table[0]["ok"]
    assert "build must return an rbgen.World or rbgen.WorldBatch, got dict" in table[0]["error"]


def test_workers_are_pinned_to_a_device(client):
    """Given devices, worker rank r of a host gets devices[r % len]: its RBGEN_DEVICE."""
    from rbgen.sweep import pin_workers

    choice = rbgen.list_devices()[0].index
    pinned = pin_workers(client, devices=[choice])
    assert sorted(pinned.values()) == [choice, choice]
    table = rbgen.sweep(
        sliding_box, [{"friction": 0.3}] * 2, steps=1, client=client, devices=[choice]
    )
    assert {row["rbgen_device"] for row in table} == {choice}
    assert all(row["ok"] for row in table)
    pin_workers(client)  # (back to the default: no GPU here)


@pytest.mark.parametrize(
    "params, match",
    [
        ({"friction": 0.1}, r"params must be a sequence of dicts"),
        ([0.1, 0.2], r"params\[0\] must be a dict"),
    ],
)
def test_bad_params_are_refused_before_any_task(params, match):
    with pytest.raises(RbgenError, match=match):
        check_params(params)
    with pytest.raises(RbgenError, match=match):
        rbgen.sweep(sliding_box, params, steps=1)


def test_batch_runs_in_a_sweep_too():
    """A WorldBatch per parameter set, here (run_one is the task's body)."""
    row = run_one(lambda envs: rbgen.WorldBatch(envs, lambda: sliding_box(0.3)), {"envs": 3}, 5)
    assert row["ok"], row["error"]
    assert row["positions"].shape == (3, 1, 3)


def test_command_line_sweep_on_its_own_local_cluster(tmp_path, capsys):
    """`rbgen sweep SCENE --param ...` (no scheduler: a LocalCluster of its own) runs every
    combination; its JSON table equals serial runs; a bad value fails its row only."""
    import json

    from rbgen.cli import main
    from rbgen.cli_extras import parse_params, scene_world

    assert parse_params(["iterations=4,8", "fast_math=false"]) == [
        {"iterations": 4, "fast_math": False},
        {"iterations": 8, "fast_math": False},
    ]
    with pytest.raises(RbgenError, match="--param must be NAME=V1,V2"):
        parse_params(["iterations"])
    out = tmp_path / "table.json"
    argv = ["sweep", "pyramid", "--n", "3", "--steps", "10", "--workers", "2"]
    code = main([*argv, "--param", "iterations=4,10,-1", "--out", str(out)])
    assert code == 1  # iterations=-1 is refused
    table = json.loads(out.read_text())
    assert [row["ok"] for row in table] == [True, True, False]
    assert "World option iterations=-1 is not allowed" in table[2]["error"]
    for row in table[:2]:
        serial = run_one(lambda **o: scene_world("pyramid", 3, **o), row["params"], 10)
        assert summary_of(serial) == {k: row[k] for k in summary_of(serial)}
    assert "FAILED" in capsys.readouterr().out


def summary_of(row):
    from rbgen.sweep import summary

    class State:  # (the end state as a World shows it, for `summary`)
        positions = row["positions"]
        linear_velocities = row["linear_velocities"]

    return summary(State)


def test_a_task_past_the_timeout_fails_its_row_and_the_others_come_back(client):
    """timeout=10: the parameter set that sleeps 60 s fails its row, naming itself and
    the timeout, about 10 s after it started (the sweep does not wait the 60 s); the
    others' rows are the serial runs' bit for bit."""
    params = [{"friction": 0.3}, {"friction": 0.3, "sleep": 60.0}, {"friction": 0.6}]
    start = time.perf_counter()
    table = rbgen.sweep(slow_box, params, steps=20, client=client, timeout=10)
    elapsed = time.perf_counter() - start
    assert 10 <= elapsed < 45, elapsed
    assert [row["ok"] for row in table] == [True, False, True], [r["error"] for r in table]
    hung = table[1]
    assert hung["params"] == params[1]
    assert hung["error"].startswith(
        "parameter set {'friction': 0.3, 'sleep': 60.0}: timed out: not finished after 10 s "
        "(timeout=10)"
    )
    assert 10 <= hung["seconds"] < 20
    for row in (table[0], table[2]):
        serial = run_one(sliding_box, row["params"], 20, DT)
        for name in STATE:
            assert np.array_equal(row[name], serial[name]), (row["params"], name)


def test_run_one_times_out_and_a_fast_run_is_unchanged():
    """run_one (a task's body) with a timeout: a run past it gives a failed row at once;
    one within it gives the row it gives without a timeout."""
    start = time.perf_counter()
    row = run_one(slow_box, {"friction": 0.2, "sleep": 30.0}, 1, timeout=0.25)
    assert time.perf_counter() - start < 5
    assert not row["ok"] and row["device"] is None
    assert row["error"].startswith(
        "parameter set {'friction': 0.2, 'sleep': 30.0}: timed out: not finished after 0.25 s"
    )
    timed = run_one(sliding_box, {"friction": 0.2}, 10, timeout=120)
    plain = run_one(sliding_box, {"friction": 0.2}, 10)
    assert timed["ok"], timed["error"]
    for name in STATE:
        assert np.array_equal(timed[name], plain[name])


@pytest.mark.parametrize("timeout", [0, -1.0, float("nan"), float("inf"), "5", True])
def test_bad_timeouts_are_refused_before_any_task(timeout):
    with pytest.raises(RbgenError, match=r"timeout must be None \(no limit\) or a positive"):
        rbgen.sweep(sliding_box, [{"friction": 0.1}], steps=1, timeout=timeout)
