"""Plan tuning: the choice among candidates (from recorded summaries, no device) and a
real tuning run on a tiny scene whose winners a new World's plan then takes."""

from __future__ import annotations

import pytest

import rbgen
from rbgen import tuning
from rbgen.plan_tuning import TuningScene, choose, holds, relevant, tune_plan


def summary(ms, displaced=0, sunk=0, nans=0):
    return {"ms_per_step": ms, "displaced": displaced, "sunk": sunk, "nans": nans}


def test_the_fastest_candidate_that_holds_wins():
    reference = summary(1.0)
    results = [
        (2, reference),
        (1, summary(0.8)),
        (3, summary(0.5, displaced=40)),
        (None, summary(0.9)),
    ]
    assert choose(results, reference) == 1  # 3 is faster but displaces boxes


def test_noise_never_moves_away_from_the_default():
    reference = summary(1.0)
    assert choose([(2, reference), (1, summary(0.98))], reference) == 2
    assert choose([(2, reference), (1, summary(0.5, nans=1))], reference) == 2
    assert not holds(summary(0.5, sunk=1), reference)


def test_moot_parameters_are_skipped():
    assert not relevant("ordered_rounds", {"batching": "slabs", "normal_solve": "block"})
    assert not relevant("group_count", {"batching": "global", "normal_solve": "block"})
    assert not relevant("release_sweeps", {"batching": "slabs", "normal_solve": "sequential"})
    assert relevant("batching", {"batching": "slabs", "normal_solve": "sequential"})
    # (the contact geometry: the block solve's serial form or persistent launch)
    lanes = {
        "batching": "cells",
        "normal_solve": "block",
        "solve_form": "lanes",
        "persistent": False,
    }
    assert not relevant("contact_geometry", lanes)
    assert relevant("contact_geometry", {**lanes, "batching": "global", "persistent": True})
    assert relevant("contact_geometry", {**lanes, "batching": "slabs", "solve_form": "serial"})
    assert not relevant(
        "contact_geometry", {**lanes, "solve_form": "serial", "normal_solve": "sequential"}
    )


@pytest.fixture
def cache_root(tmp_path, monkeypatch):
    monkeypatch.setenv("RBGEN_CACHE_DIR", str(tmp_path))
    tuning.forget_loaded()
    yield tmp_path
    tuning.forget_loaded()


def test_a_tuned_plan_reaches_new_worlds(cache_root, runtime):
    """tune_plan on a tiny lattice times every relevant candidate, stores the winners in
    the device's cache, and a World made afterwards plans with them (source "tuned")."""
    lines = []
    entry = tune_plan(runtime, scene=TuningScene("boxbox", 64, 1, 3), progress=lines.append)
    assert set(entry["values"]) == {
        "batching",
        "release_sweeps",
        "ordered_rounds",
        "group_count",
        "contact_geometry",
    }
    assert entry["timings"] and all(t["ms_per_step"] > 0 for t in entry["timings"])
    assert len(lines) == len(entry["timings"])
    assert tuning.lookup_plan(runtime.traits) == entry["values"]
    world = rbgen.World(runtime)
    assert world.plan.sources["batching"] == "tuned"
    assert world.plan.batching == entry["values"]["batching"]
