"""The launch schedule: what a World's step enqueues, recorded and inferred (rbgen.schedule)."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen import layouts
from rbgen.errors import RbgenError
from rbgen.harness import build_scene
from rbgen.schedule import record_schedule
from rbgen.schedule.drive import Run
from rbgen.schedule.format import FORMAT_VERSION, evaluate
from rbgen.schedule.infer import find_cycle


def test_recorder_sees_every_command_of_a_step_with_its_arguments(runtime):
    """One recorded step of a 64-box BoxBox starts with the prepare launch, binds the bodies
    as their upload made them (the init is the World's host records), ends with the step
    report's copy after the last stage's launch (the integration, or on a plan with a
    persistent launch the solve, which integrates), and every launch's arguments are the
    BoundKernel's values."""
    run = Run(
        lambda: build_scene("boxbox", 64, runtime)[0], 1 / 60, {"pairs": 1024, "manifolds": 512}
    )
    try:
        step = run.step()
    finally:
        run.close()
    rec, world = run.recorder, run.world
    kernels = {k.index: k for k in rec.kernels.values()}
    launches = [c for c in step.commands if c[0] == "launch"]
    assert kernels[launches[0][1]].name == "prepare_bodies"
    last = "solve_groups" if world.plan.persistent else "integrate_bodies"
    assert kernels[launches[-1][1]].name == last
    assert step.commands[-1][0] == "copy"  # the report, gathered after the last stage
    bodies = rec.buffers[world._device.bodies.base_data.int_ptr]
    assert bodies.name == "bodies" and bodies.ctype == "Body"
    assert bodies.init == ("data", world._bodies.host.tobytes())
    first_args = launches[0][2]
    assert first_args[0] == ("buffer", bodies.index)
    assert first_args[2] == ("scalar", np.uint32(world.body_count).tobytes())
    assert step.values["pairs"] == 1024 and step.values["manifolds"] == 512


def test_recorder_refuses_kernels_it_cannot_replay(runtime):
    """An enqueue of pyopencl's own kernels (an Array operation) during a recorded step
    cannot be exported: refused by name, not silently left out."""
    run = Run(
        lambda: build_scene("boxbox", 27, runtime)[0], 1 / 60, {"pairs": 256, "manifolds": 128}
    )
    try:
        array = cla.zeros(runtime.queue, 4, np.float32)
        with pytest.raises(RbgenError, match="did not compile"):
            _ = array + 1
    finally:
        run.close()


def test_find_cycle():
    """The shortest cycle, then the shortest prologue, repeated at least twice; a step that
    changes every time has none."""
    assert find_cycle([1, 2, 3, 4] * 4) == (0, 4)
    assert find_cycle([9, 8] + [1, 2] * 6) == (2, 2)
    assert find_cycle([5] * 8) == (0, 1)
    with pytest.raises(RbgenError, match="period"):
        find_cycle(list(range(16)))


def test_redone_steps_take_the_backup_slots_of_the_steps_they_replace(runtime):
    """After overflows and redos, the guard's step serial (which picks the backup slot) is
    the number of steps kept: a step's slot follows its place in the sequence."""
    world = build_scene("boxbox", 64, runtime, pair_capacity=1, manifold_capacity=1)[0]
    for _ in range(4):
        world.step(1 / 60)
    world.statistics()
    assert world.overflows >= 1
    assert world._guard.serial == 4


@pytest.fixture(scope="module")
def boxbox_schedule(runtime):
    inference, _ = record_schedule(
        lambda: build_scene("boxbox", 64, runtime)[0],
        {"pairs": 1024, "manifolds": 256},
        grow_rungs=1,
    )
    return inference


def test_schedule_of_boxbox_is_four_variants_with_the_ring_as_followers(boxbox_schedule):
    """BoxBox steps repeat with the constraint ring's period (4, no prologue: the ring is
    made whole at the first step); each generation follows the manifold capacity when its
    variant writes it; the undo before a redo restores the bodies and clears one table."""
    inf = boxbox_schedule
    assert (inf.variants.prologue, inf.variants.cycle) == (0, 4)
    assert inf.grown == ["manifolds", "pairs"]
    assert {f: (r["leader"], r["at"]) for f, r in inf.follow.items()} == {
        f"constraints.{k}": ("manifolds", [k]) for k in range(4)
    }
    for v in range(4):
        ops = [key[0] for key, _ in inf.undo[v]]
        assert ops == ["copy", "fill"]


def test_schedule_numbers_follow_their_capacity(boxbox_schedule):
    """The pair buffer's size is a table over the pair capacity's rungs (32 bytes a pair),
    the bodies' a constant; every recorded number reads back from the table."""
    inf = boxbox_schedule
    pairs = next(b.index for b in inf.buffers if b.name == "pairs")
    size = inf.number(("size", pairs))
    assert size["by"] == "pairs"
    assert size["values"] == [layouts.PAIR.itemsize << r for r in range(len(size["values"]))]
    bodies = next(b.index for b in inf.buffers if b.name == "bodies")
    assert inf.number(("size", bodies)) == 65 * layouts.BODY.itemsize
    for key, samples in inf.samples.items():
        number = inf.number(key)
        for value, s in samples[:3]:
            assert evaluate(number, inf.states[s]) == value


def test_export_writes_the_schedule_and_its_data(runtime, tmp_path):
    """`rbgen export --world` writes schedule.json (this format version, this device) and
    data/ with the bodies as the World uploads them, every file listed with its SHA-256."""
    from rbgen.cli import main

    out = tmp_path / "boxbox"
    assert (
        main(
            [
                "export",
                "--world",
                "boxbox",
                "--n",
                "27",
                "--out",
                str(out),
                "--device",
                runtime.device.name.strip(),
                "--grow-rungs",
                "1",
            ]
        )
        == 0
    )
    schedule = json.loads((out / "schedule.json").read_text())
    assert schedule["format"] == "rbgen-schedule" and schedule["version"] == FORMAT_VERSION
    assert schedule["device"]["fingerprint"] == runtime.traits.fingerprint
    assert "rbgen export --world boxbox --n 27" in schedule["command"]
    for name, digest in schedule["files"].items():
        assert hashlib.sha256((out / name).read_bytes()).hexdigest() == digest
    bodies = schedule["buffers"][schedule["bodies"]["buffer"]]
    data = np.fromfile(out / bodies["init"]["file"], layouts.BODY.dtype)
    world = build_scene("boxbox", 27, runtime)[0]
    assert data.tobytes() == world._bodies.host.tobytes()
    assert schedule["bodies"]["count"] == world.body_count
    assert {c["name"] for c in schedule["capacities"]} == {"pairs", "manifolds"}
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["schedule"] == "schedule.json"
    files = {e["file"] for e in manifest["files"]}
    assert {p["file"] for p in schedule["programs"]} <= files
