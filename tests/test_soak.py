"""A short soak (issue 30, item 6; `benchmarks/soak.py` is the long one): a churned scene
with forced buffer growth holds its device bytes and resident memory after the warm-up,
keeps its step time, and two runs end bit for bit equal."""

from __future__ import annotations

from rbgen import soak


def test_short_soak_holds_memory_and_is_deterministic(runtime):
    runs = [
        soak.run_soak(runtime, 600, bodies=100, churn_every=10, churn=8, warmup=300)
        for _ in range(2)
    ]
    print("\n" + soak.table(runs))
    first, second = runs
    assert first.digest == second.digest  # bit for bit
    for run in runs:
        assert run.overflows >= 1  # the growth was forced
        assert run.churned == 59 * 8 and run.bodies_end == run.bodies_start == 101
        assert run.device_end <= run.device_start
        assert run.rss_end - run.rss_start < 16 * 2**20
        # (a shared CPU is noisy: only a drift far beyond noise fails)
        assert run.step_ms_end < 4 * run.step_ms_start + 2.0
