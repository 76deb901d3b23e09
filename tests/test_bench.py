"""rbgen bench: the JSON it writes follows the schema, its sanity measures are right, and the
README's table is regenerated between its markers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rbgen import bench, sanity
from rbgen.cli import main
from rbgen.errors import RbgenError

from .pipeline.broadphase.test_grid import OWNER_KERNELS


@pytest.fixture(scope="module")
def quick_record(tmp_path_factory):
    """What `rbgen bench --quick` writes (with 20 steps, two a timing block: CI's time is
    short)."""
    out = tmp_path_factory.mktemp("results")
    assert main(["bench", "--quick", "--steps", "20", "--out", str(out)]) == 0
    files = sorted(out.glob("*.json"))
    assert len(files) == 1 and files[0].with_suffix(".md").is_file()
    return out, json.loads(files[0].read_text())


def test_quick_bench_json_follows_the_schema(quick_record):
    _, record = quick_record
    assert bench.validate(record) is record
    assert record["schema"] == bench.SCHEMA and record["kind"] == "scenes"
    assert record["settings"]["quick"] is True
    for key in bench.DEVICE_KEYS:
        assert isinstance(record["device"][key], (str, int)), key
    assert [(r["scene"], r["steps"]) for r in record["results"]] == [
        (scene, 20) for scene, *_ in bench.QUICK_SCENES
    ]
    for r in record["results"]:
        assert r["ms"] > 0 and r["ms_spread"][0] <= r["ms"] <= r["ms_spread"][1]
        assert len(r["ms_blocks"]) == 10
        assert isinstance(r["launches_per_step"], int) and r["blocking_reads_per_step"] == 0
        s = r["sanity"]
        assert set(bench.SANITY_KEYS) <= set(s)
        assert all(isinstance(d, float) for d in s["layer_drop"]) and s["layer_drop"]
        assert r["holds"] is (r["problems"] == [])
        if r["scene"] != "box_pile":  # (20 steps in, the pile is still landing)
            assert s["nans"] == 0 and s["sunk"] == 0
            limit = bench.DISPLACED_FRACTION * r["bodies"]
            assert r["holds"] is (s["displaced"] <= limit and s["moving"] <= limit)
    boxbox = record["results"][0]
    assert boxbox["bodies"] == 1000 and len(boxbox["sanity"]["layer_drop"]) == 10


def test_readme_table_is_regenerated_between_markers(quick_record, tmp_path):
    out, record = quick_record
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\nbefore\n{bench.TABLE_BEGIN}\nold table\n{bench.TABLE_END}\nafter\n")
    assert main(["bench", "--no-run", "--out", str(out), "--readme", str(readme)]) == 0
    text = readme.read_text()
    assert "old table" not in text and text.startswith("# x\n\nbefore\n")
    assert text.endswith(f"{bench.TABLE_END}\nafter\n")
    for r in record["results"]:
        assert f"| {r['scene']} | {r['bodies']:,} | {bench._time(r)} |" in text
    assert bench.update_readme(readme, out) is False  # the same results: unchanged


def test_readme_without_markers_is_refused(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text("# no table here\n")
    with pytest.raises(RbgenError, match="markers"):
        bench.update_readme(readme, tmp_path)


def test_a_scene_that_does_not_hold_has_its_time_struck_out():
    result = {
        "scene": "boxbox",
        "bodies": 8,
        "steps": 100,
        "warmup": 0,
        "ms": 1.5,
        "ms_spread": [1.4, 1.6],
        "launches_per_step": 9,
        "blocking_reads_per_step": 0,
        "sanity": {
            "nans": 0,
            "sunk": 3,
            "displaced": 1,
            "layer_drop": [0.0, 0.05],
            "max_speed": 0.0,
            "overflows": 0,
            "last_box_moved": 0.0,
        },
    }
    ok, problems = bench.holds(result)
    assert not ok and problems == ["3 sunk", "1 displaced", "top layer dropped 5.0 cm"]
    result["holds"], result["problems"] = ok, problems
    assert "~~1.50~~" in bench._time(result) and "does not hold" in bench._sanity(result)


def test_a_dropped_pile_counts_its_bodies_moved_sideways_without_judging_them():
    """Ragdolls dropped on a pile spread as they land: the bodies moved sideways are shown
    as such, not as a displaced count that reads like a failure, and do not fail the
    scene; the same count fails a lattice."""
    sanity = {
        "nans": 0,
        "sunk": 0,
        "displaced": 4642,
        "layer_drop": [],
        "max_speed": 5.7,
        "overflows": 0,
        "last_box_moved": 0.0,
    }
    result = {"scene": "ragdolls", "bodies": 11256, "sanity": sanity, "warmup": 0, "steps": 120}
    result["holds"], result["problems"] = bench.holds(result)
    assert result["holds"]
    text = bench._sanity(result)
    assert "moved sideways 4642 (not judged: dropped)" in text and "displaced" not in text
    lattice = {**result, "scene": "boxbox"}
    lattice["holds"], lattice["problems"] = bench.holds(lattice)
    assert not lattice["holds"] and "displaced 4642" in bench._sanity(lattice)
    # (`rbgen run`'s summary line words it the same way)
    from rbgen.sanity import displaced_text

    assert displaced_text("ragdolls", 7) == "moved sideways 7 (not judged: dropped)"
    assert displaced_text("pyramid", 7) == "displaced 7"


def test_overhanging_boxes_are_those_whose_centre_is_on_the_edge_of_their_support():
    """`sanity.overhanging` against brute force on BoxBox lattices of odd sizes (every pair
    of boxes of adjacent layers, the bounding rectangle of their shared footprints), and
    the closed form: every layer above the ground has one edge row along x and one along
    z whose centres sit on the edge of the layer below, (ny - 1)(nx + nz - 1) boxes."""
    from rbgen import scenes

    for dims in ((1, 1, 1), (3, 4, 2), (5, 3, 7), (1, 6, 1)):
        scene = scenes.boxbox_scene(*dims)
        p = scene.positions.astype(float)
        mask = sanity.overhanging(p, scene.half_extents)
        brute = np.zeros(len(p), bool)
        for i, (x, y, z) in enumerate(p):
            below = [q for q in p if abs(q[1] - (y - 2)) < 1e-6]
            if y < 1.5:
                continue  # (the ground holds the lowest layer)
            shared = [
                (max(x, q[0]) - 1, min(x, q[0]) + 1, max(z, q[2]) - 1, min(z, q[2]) + 1)
                for q in below
            ]
            shared = [r for r in shared if r[1] > r[0] and r[3] > r[2]]
            brute[i] = not shared or not (
                min(r[0] for r in shared) < x < max(r[1] for r in shared)
                and min(r[2] for r in shared) < z < max(r[3] for r in shared)
            )
        nx, ny, nz = dims
        assert np.array_equal(mask, brute), dims
        assert mask.sum() == (ny - 1) * (nx + nz - 1), dims
    assert not sanity.overhanging(np.zeros((0, 3)), np.ones(3)).any()


def test_a_lattice_whose_boxes_keep_moving_does_not_hold():
    """A stack can keep its layers' heights while its boxes fall and are pushed back up
    every substep: more than `DISPLACED_FRACTION` of a lattice's boxes faster than
    `RESTING_SPEED` at the end fails it, where a dropped scene's moving bodies are shown
    but not judged, and a record from before the count (no ``moving``) is judged as it
    was."""
    sanity = {
        "nans": 0,
        "sunk": 0,
        "displaced": 0,
        "layer_drop": [0.0, 0.001],
        "max_speed": 0.3,
        "overflows": 0,
        "last_box_moved": 0.0,
        "moving": 6,
    }
    lattice = {"scene": "boxbox", "bodies": 1000, "sanity": sanity, "warmup": 0, "steps": 120}
    assert bench.holds(lattice) == (False, ["6 moving faster than 0.05 m/s"])
    assert bench.holds({**lattice, "sanity": {**sanity, "moving": 5}}) == (True, [])
    old = {key: value for key, value in sanity.items() if key != "moving"}
    assert bench.holds({**lattice, "sanity": old}) == (True, [])
    assert "moving" not in bench._sanity({**lattice, "sanity": old, "holds": True})
    pile = {**lattice, "scene": "box_pile", "steps": 100}
    pile["holds"], pile["problems"] = bench.holds(pile)
    assert pile["holds"] and "moving 6 (not judged: dropped)" in bench._sanity(pile)


def test_validate_names_what_is_missing():
    with pytest.raises(RbgenError, match="lacks"):
        bench.validate({"schema": bench.SCHEMA})
    record = bench.make_record(
        "benchmarks/render.py",
        [{"name": "x", "ms": 1.0, "ms_spread": [2.0, 1.0], "baseline": None}],
        None,
        {},
    )
    with pytest.raises(RbgenError, match=r"results\[0\].ms_spread"):
        bench.validate(record)


def test_a_record_names_the_commit_the_caller_gives(monkeypatch):
    """RBGEN_GIT_COMMIT names the commit where the copy's own git cannot (taken as given);
    without it the record names this checkout's commit, 12 hex digits (+dirty if edited)."""
    monkeypatch.setenv("RBGEN_GIT_COMMIT", "043beb5a0b1c")
    assert bench.make_record("scenes", [], None, {})["git_commit"] == "043beb5a0b1c"
    monkeypatch.delenv("RBGEN_GIT_COMMIT")
    commit = bench.make_record("scenes", [], None, {})["git_commit"]
    if commit is not None:  # (None outside a git checkout: a copied tree)
        head = commit.removesuffix("+dirty")
        assert len(head) == 12 and int(head, 16) >= 0 and commit != "043beb5a0b1c"


def test_settling_counts_displaced_boxes_and_layer_drops():
    """Two layers (y = 1 and y = 3): one box slides 0.6 m sideways (displaced), one 0.4 m
    (not); the upper layer's boxes fall 0.1 and 0.3 m (median 0.2), the lower's 0."""
    start = np.array([[0, 1, 0], [2, 1, 0], [0, 3, 0], [2, 3, 0]], float)
    end = start + np.array([[0.6, 0, 0], [0, 0, 0.4], [0, -0.1, 0], [0, -0.3, 0]])
    result = sanity.settling(start, end)
    assert result["displaced"] == 1
    assert np.allclose(result["layer_drop"], [0.0, 0.2])
    nan_end = end.copy()
    nan_end[0] = np.nan
    assert sanity.settling(start, nan_end)["displaced"] == 1
    assert sanity.settling(np.zeros((0, 3)), np.zeros((0, 3))) == {"displaced": 0, "layer_drop": []}


def test_settling_counts_the_boxes_that_are_not_at_rest():
    """With the velocities, ``moving`` counts the boxes faster than `RESTING_SPEED` (m/s,
    the length of the velocity): at the speed is at rest, a NaN is moving."""
    start = np.zeros((5, 3))
    r = sanity.RESTING_SPEED
    velocities = np.array(
        [[0, 0, 0], [r, 0, 0], [0.6 * r, 0, 0.81 * r], [0, -1, 0], [np.nan, 0, 0]], float
    )
    result = sanity.settling(start, start, velocities)
    assert result["moving"] == 3  # (0.6^2 + 0.81^2 > 1: the third is just faster)
    assert "moving" not in sanity.settling(start, start)
    resting = np.array([True, True, False, True, False])  # (the others are not judged)
    assert sanity.settling(start, start, velocities, resting)["moving"] == 1
    assert sanity.settling(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)))["moving"] == 0


def test_the_summary_line_shows_the_layer_drops():
    """`rbgen run` / `rbgen demo`'s summary line carries the start layers' median drops in
    mm, as `rbgen bench`'s lines do: every layer up to 12 (bottom first), else the top
    layer's and the largest by size with its layer number; none for a scene without
    layers, nor for a dropped pile (its layers fall by design: `sanity.holding_drops`)."""
    from rbgen.harness import format_summary

    summary = {
        "scene": "boxbox",
        "bodies": 4,
        "ms_per_step": 1.0,
        "launches_per_step": 14,
        "blocking_reads_per_step": 0,
        "pairs": 4,
        "manifolds": 4,
        "contacts": 16,
        "solver": "jacobi",
        "nans": 0,
        "sunk": 0,
        "displaced": 0,
        "max_speed": 0.0,
        "overflows": 0,
        "last_box_moved": 0.0,
    }
    line = format_summary({**summary, "layer_drop": [0.0, 0.002, 0.0135]})
    assert line.endswith("layer drops (mm, bottom to top) 0.0 2.0 13.5")
    assert "moving" not in line  # (not measured)
    assert "displaced 0, moving 2, max speed" in format_summary({**summary, "moving": 2})
    drops = [0.001 * k for k in range(20)]
    drops[7] = -0.05
    line = format_summary({**summary, "layer_drop": drops})
    assert line.endswith("layer drops: top 19.0 mm, largest -50.0 mm (layer 8 of 20)")
    assert "layer drops" not in format_summary({**summary, "layer_drop": []})
    pile = {**summary, "scene": "box_pile", "layer_drop": [1.0, 2.0]}
    assert "layer drops" not in format_summary(pile)


def test_a_timing_block_ends_after_its_steps_have_run(runtime, monkeypatch):
    """`run_scene` stops each timing block's clock only after the queue has finished
    (the steps in flight ran inside the block), so the progress read-back that follows,
    outside the clock, cannot hide their device time: each block's clock read comes
    right after a finish of the queue."""
    from rbgen import harness

    events = []
    world, ids, top, half = harness.build_scene("boxbox", 8, runtime)

    class Queue:
        def finish(self):
            events.append("finish")

    class Runtime:
        queue = Queue()
        traits = runtime.traits
        kernel_launches = None

    class Probe:
        """The World with its queue recorded; its reads and steps are the World's."""

        runtime = Runtime()

        def __getattr__(self, name):
            return getattr(world, name)

    monkeypatch.setattr(harness, "build_scene", lambda *a, **k: (Probe(), ids, top, half))
    clock = iter(range(10_000))
    monkeypatch.setattr(
        harness.time, "perf_counter", lambda: events.append("clock") or float(next(clock))
    )
    harness.run_scene("boxbox", 8, 20, runtime, progress=True)
    reads = [i for i, e in enumerate(events) if e == "clock"][1:]  # (the first starts a block)
    block_ends = [i for i in reads if events[i - 1] == "finish"]
    assert len(block_ends) == harness.TIMING_BLOCKS


def test_benchmark_options_are_a_json_object_or_refused_naming_the_option():
    import argparse

    assert bench.world_options('{"substeps": 2, "iterations": 3}') == {
        "substeps": 2,
        "iterations": 3,
    }
    for bad in ("{bad", "[1, 2]", "3"):
        with pytest.raises(argparse.ArgumentTypeError, match="--options"):
            bench.world_options(bad)


def test_a_scene_records_its_broadphase_and_last_step_launches_by_kernel(runtime, monkeypatch):
    """`run_scene` and the bench result record the broadphase's algorithm, the last step's
    launches by kernel name (adding up to launches_per_step) and which stage asked for each
    redo; a grid that met too many large bodies and left its owner emission for slot
    emission (tens of launches a step more) is a fallback of the plan, printed as one."""
    from rbgen.harness import run_scene
    from rbgen.pipeline.broadphase.grid import LARGE_ROWS, GridBroadphase

    owner = run_scene("boxbox", 8, 3, device=runtime, progress=False)
    assert owner["broadphase"] == "grid, owner emission" and owner["plan_fallbacks"] == []
    counts = owner["launches_by_kernel"]
    assert sum(counts.values()) == owner["launches_per_step"]
    assert all(counts[name] == 1 for name in OWNER_KERNELS)
    assert owner["overflows"] == 0 and owner["overflows_by_stage"] == {}
    # each timing block's last step's colours and manifolds, beside its time
    assert len(owner["batches_blocks"]) == len(owner["ms_per_step_blocks"]) == 3
    assert owner["batches_blocks"][-1] == owner["batches"] > 0
    assert owner["manifolds_blocks"][-1] == owner["manifolds"] > 0
    # every box larger than half the mean size: LARGE_ROWS + 1 large bodies with the ground
    monkeypatch.setitem(GridBroadphase.__init__.__kwdefaults__, "large_factor", 0.5)
    # (6 steps: the retry of the first step is redone during the third, not the last)
    slot = run_scene("boxbox", LARGE_ROWS, 6, device=runtime, progress=False)
    assert slot["plan_fallbacks"] == ["broadphase"]
    assert slot["broadphase"].startswith("grid, slot emission (")
    assert f"since a query met more than {LARGE_ROWS} large bodies" in slot["broadphase"]
    assert slot["overflows"] == 1 and slot["overflows_by_stage"] == {"broadphase": 1}
    counts = slot["launches_by_kernel"]
    assert sum(counts.values()) == slot["launches_per_step"] > owner["launches_per_step"]
    assert counts["write_grid_pairs"] == 1 and not set(OWNER_KERNELS) & set(counts)
    result = bench.scene_result(slot, 1)
    for key in ("broadphase", "launches_by_kernel", "overflows_by_stage"):
        assert result[key] == slot[key]
    for key in ("batches_blocks", "manifolds_blocks"):
        assert result[key] == slot[key] and len(result[key]) == len(result["ms_blocks"])
    assert "[fell back from the plan's broadphase]" in bench.format_result(result)


def cases_record(kind, *cases):
    """A record of ``kind`` whose results are (name, ms, spread, baseline) cases."""
    return {
        "kind": kind,
        "created": "2026-12-05T00:00:00Z",
        "rbgen_version": "0",
        "results": [
            {"name": name, "ms": ms, "ms_spread": list(spread), "baseline": baseline}
            for name, ms, spread, baseline in cases
        ],
    }


def test_case_times_keep_three_significant_digits_below_a_tenth_of_a_millisecond():
    # a device barrier's microsecond must not print as 0.001 beside a 3 ms case
    text = bench.markdown(
        cases_record(
            "device_barrier",
            ("a", 0.0010837, (0.00107, 0.0011), None),
            ("b", 3.0, (2.5, 3.25), {"name": "a", "ms": 2.95e-05}),
        )
    )
    assert "| a | 0.00108 | 0.00107-0.00110 | - |" in text
    assert "| b | 3.000 | 2.500-3.250 | a: 0.0000295 ms |" in text


def test_a_baseline_named_by_a_case_of_the_same_record_is_shown_with_its_time():
    record = cases_record(
        "ragdolls", ("bare", 5.0, (4.0, 6.0), None), ("joints", 9.0, (8.0, 10.0), "bare")
    )
    assert "| joints | 9.000 | 8.000-10.000 | bare: 5.000 ms |" in bench.markdown(record)


def test_every_benchmark_takes_out_through_one_argument_where_empty_writes_nothing():
    """`bench.add_out_argument`: ``--out`` defaults to benchmarks/results and ``--out ''``
    parses to '' (each benchmark writes its records only under a non-empty ``--out``);
    every benchmark script defines its ``--out`` through it, so the two agree."""
    import argparse
    import pathlib
    import re

    parser = argparse.ArgumentParser()
    bench.add_out_argument(parser)
    assert parser.parse_args([]).out == str(bench.RESULTS_DIR)
    assert parser.parse_args(["--out", ""]).out == ""
    scripts = sorted((pathlib.Path(__file__).parents[1] / "benchmarks").glob("*.py"))
    assert len(scripts) > 10
    for script in scripts:
        text = script.read_text()
        assert not re.search(r"add_argument\(\s*\"--out\"", text), script.name
        lines = text.splitlines()
        for i, line in enumerate(lines):
            if "bench.write_results(" not in line:
                continue
            # the block the write is in opens with `if args.out:`
            indent = len(line) - len(line.lstrip())
            opener = next(
                above
                for above in reversed(lines[:i])
                if above.strip() and len(above) - len(above.lstrip()) < indent
            )
            assert opener.strip() == "if args.out:", (script.name, i + 1)
