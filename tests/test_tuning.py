"""The tuner's cache and selection logic, from recorded JSON fixtures (no timing),
plus one real tuning run of a cheap family and one with a wrong candidate.

Fixtures (tests/fixtures/tuning/):
  recorded_gpu_cache.json  a tuning cache recorded for a GPU; ``"@current"``
                           source hashes are replaced by the current template
                           hashes at load, any other hash is stale.
  recorded_timings.json    candidate timings (None: wrong result) and the
                           winner the tie rule must pick.
"""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pyopencl.array as cla
import pytest

from rbgen import tuning
from rbgen.device import DeviceTraits
from rbgen.errors import RbgenError
from rbgen.primitives import Fill, Scan
from rbgen.primitives._base import size_bucket
from rbgen.primitives.fill import search_space as fill_space

FIXTURES = Path(__file__).parent / "fixtures" / "tuning"
GPU = DeviceTraits(
    "NVIDIA CUDA",
    "NVIDIA H200 (recorded)",
    "NVIDIA Corporation",
    True,
    132,
    32,
    49152,
    1024,
    "550.54.15",
    "OpenCL 3.0 CUDA",
)


@pytest.fixture
def cache_root(tmp_path, monkeypatch):
    """An empty cache directory for the test; in-process cache copies dropped."""
    monkeypatch.setenv("RBGEN_CACHE_DIR", str(tmp_path))
    tuning.forget_loaded()
    yield tmp_path
    tuning.forget_loaded()


def install_fixture(traits, name="recorded_gpu_cache.json", **changes):
    data = json.loads((FIXTURES / name).read_text())
    data["fingerprint"] = traits.fingerprint
    for entry in data["entries"].values():
        if entry["source_hash"] == "@current":
            entry["source_hash"] = tuning.FAMILIES[entry["family"]].template_hash(
                entry["params"]["shape"]
            )
    data.update(changes)
    path = tuning.cache_path(traits)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data))
    tuning.forget_loaded()
    return data


def test_lookup_exact_bucket(cache_root):
    data = install_fixture(GPU)
    assert tuning.lookup(GPU, "scan", "uint", 22) == data["entries"]["scan[uint]@2^22"]["params"]
    assert tuning.lookup(GPU, "scan", "uint", 16) == data["entries"]["scan[uint]@2^16"]["params"]
    assert tuning.lookup(GPU, "scan", "float", 22)["work_group_size"] == 256


def test_lookup_nearest_bucket(cache_root):
    data = install_fixture(GPU)
    e = data["entries"]
    assert tuning.lookup(GPU, "scan", "uint", 20) == e["scan[uint]@2^22"]["params"]  # 2 vs 4 away
    assert tuning.lookup(GPU, "scan", "uint", 18) == e["scan[uint]@2^16"]["params"]  # 2 vs 4 away
    assert tuning.lookup(GPU, "scan", "uint", 19) == e["scan[uint]@2^22"]["params"]  # tie: larger
    assert tuning.lookup(GPU, "scan", "uint", 10) == e["scan[uint]@2^12"]["params"]
    assert tuning.lookup(GPU, "scan", "uint", 26) == e["scan[uint]@2^24"]["params"]
    assert tuning.lookup(GPU, "scan", "float", 12) == e["scan[float]@2^22"]["params"]


def test_size_bucket_is_the_nearest_even_exponent():
    """Bucket b serves 2^(b-1) <= n < 2^(b+1) (log scale), clamped to 10..26."""
    cases = {
        0: 10,
        1: 10,
        2**11 - 1: 10,
        2**11: 12,
        3000: 12,
        2**16: 16,
        2**17 - 1: 16,
        2**17: 18,
        2**22: 22,
        2**22 + 1: 22,
        2**23 - 1: 22,
        2**23: 24,
        12_000_000: 24,
        2**24: 24,
        2**25: 26,
        2**31: 26,
    }
    assert {n: size_bucket(n) for n in cases} == cases


def test_sizes_between_tuned_buckets(cache_root):
    """A count picks the tuned size nearest on a log scale: just over 4M takes
    the 2^22 winner (not 2^24's), 12M the 2^24 one, beyond 2^24 the 2^24 one."""
    data = install_fixture(GPU)
    e = data["entries"]

    def params_for(n):
        return tuning.lookup(GPU, "scan", "uint", size_bucket(n))

    assert params_for(2**22 + 1) == e["scan[uint]@2^22"]["params"]
    assert params_for(2**23 - 1) == e["scan[uint]@2^22"]["params"]
    assert params_for(12_000_000) == e["scan[uint]@2^24"]["params"]
    assert params_for(2**26) == e["scan[uint]@2^24"]["params"]
    assert params_for(3000) == e["scan[uint]@2^12"]["params"]
    assert params_for(2**14) == e["scan[uint]@2^16"]["params"]  # 2^14: tie 12/16, the larger
    assert (
        tuning.lookup(GPU, "scan_chained", "uint", size_bucket(2**20))
        == e["scan_chained[uint]@2^24"]["params"]
    )  # its only tuned bucket


def test_tune_sizes_cover_every_other_bucket_to_2_24():
    sizes = tuning.tune_sizes(GPU)
    assert max(sizes) == 2**24 and [size_bucket(n) for n in sizes] == [12, 16, 20, 22, 24]
    cpu = dataclasses.replace(GPU, is_gpu=False)
    assert max(tuning.tune_sizes(cpu)) < 2**22
    assert tuning.tune_sizes(GPU, quick=True) == tuning.tune_sizes(cpu, quick=True) == (2**16,)


def test_lookup_misses(cache_root):
    install_fixture(GPU)
    assert tuning.lookup(GPU, "scan", "int", 22) is None  # variant never tuned
    assert tuning.lookup(GPU, "reduce", "sum-float", 22) is None  # family never tuned
    assert tuning.lookup(GPU, "radix_sort", "kv", 22) is None  # only a stale entry
    assert tuning.lookup(GPU, "radix_sort", "keys", 22)["radix_bits"] == 4
    other = dataclasses.replace(GPU, driver_version="560.1")  # same GPU, new driver
    assert other.fingerprint != GPU.fingerprint
    assert tuning.lookup(other, "scan", "uint", 22) is None


@pytest.mark.parametrize("damage", ["version", "fingerprint", "corrupt"])
def test_unusable_cache_files_read_as_empty(cache_root, damage):
    if damage == "version":
        install_fixture(GPU, version=tuning.CACHE_VERSION + 1)
    elif damage == "fingerprint":
        install_fixture(GPU, fingerprint="someone-else")
    else:
        install_fixture(GPU)
        tuning.cache_path(GPU).write_text("{not json")
        tuning.forget_loaded()
    assert tuning.lookup(GPU, "scan", "uint", 22) is None
    assert tuning.describe_cache(GPU) == []


def test_describe_cache(cache_root):
    data = install_fixture(GPU)
    lines = tuning.describe_cache(GPU)
    assert len(lines) == len(data["entries"])
    stale = [line for line in lines if line.endswith("[stale]")]
    assert len(stale) == 1 and stale[0].startswith("radix_sort[kv]@2^22")
    scan_line = next(line for line in lines if line.startswith("scan[uint]@2^22"))
    assert "work_group_size=512" in scan_line and "0.118 ms" in scan_line


def test_pick_winner_recorded_timings():
    recorded = json.loads((FIXTURES / "recorded_timings.json").read_text())
    for case in recorded["cases"]:
        timings = [({"i": i}, ms) for i, ms in enumerate(case["ms"])]
        assert tuning.pick_winner(timings, recorded["noise"]) == case["winner"], case["doc"]


def test_primitive_uses_tuned_params(cache_root, runtime, rng):
    """A tuned entry for this device is used (and computes right); an entry that
    no longer fits the template falls back to the heuristic default."""
    tuned = (
        {"shape": "cpu", "work_items": 3}
        if not runtime.traits.is_gpu
        else {"shape": "gpu", "work_group_size": 64, "items_per_thread": 2, "wavefront": 64}
    )
    entry = {
        "family": "scan",
        "variant": "int",
        "bucket": 10,
        "params": tuned,
        "source_hash": tuning.FAMILIES["scan"].template_hash(tuned["shape"]),
        "median_ms": 0.01,
        "candidates": 5,
    }
    broken = dict(entry, variant="uint", params=dict(tuned, shape="gpu", work_group_size=3))
    broken["source_hash"] = tuning.FAMILIES["scan"].template_hash("gpu")
    tuning.save_cache(
        runtime.traits,
        {
            "version": tuning.CACHE_VERSION,
            "fingerprint": runtime.traits.fingerprint,
            "entries": {"a": entry, "b": broken},
        },
    )
    tuning.forget_loaded()
    scan = Scan(runtime, np.int32, inclusive=True)
    assert scan.program(1000)[0] == tuned
    x = rng.integers(-5, 5, 1000).astype(np.int32)
    src, dst = cla.to_device(runtime.queue, x), cla.empty(runtime.queue, 1000, np.int32)
    scan(src, dst)
    assert np.array_equal(dst.get(), np.cumsum(x))
    fallback = Scan(runtime, np.uint32)
    assert fallback.program(1000)[0] == Scan.default_params(runtime.traits)


def test_tuned_chained_scan_is_used(cache_root, runtime, rng, monkeypatch):
    """A chained winner of family "scan" is used by a plain Scan (the tuner
    opted in); if its guard fails on this device the scan falls back."""
    from rbgen.primitives import scan as scan_module

    tuned = Scan.default_params(runtime.traits, "chained")
    entry = {
        "family": "scan",
        "variant": "uint",
        "bucket": 16,
        "params": tuned,
        "source_hash": tuning.FAMILIES["scan"].template_hash("chained"),
        "median_ms": 0.01,
        "candidates": 9,
    }
    tuning.save_cache(
        runtime.traits,
        {
            "version": tuning.CACHE_VERSION,
            "fingerprint": runtime.traits.fingerprint,
            "entries": {"scan[uint]@2^16": entry},
        },
    )
    tuning.forget_loaded()
    x = rng.integers(0, 100, 70_001).astype(np.uint32)
    src, dst = cla.to_device(runtime.queue, x), cla.empty(runtime.queue, x.size, np.uint32)
    scan = Scan(runtime, np.uint32)
    assert scan.program(x.size)[0] == tuned
    launches = runtime.counters["launches"]
    scan(src, dst)
    assert runtime.counters["launches"] == launches + 1
    assert np.array_equal(dst.get(), np.concatenate([[0], np.cumsum(x)[:-1]]))
    monkeypatch.setattr(scan_module, "chained_scan_works", lambda rt, params: False)
    assert Scan(runtime, np.uint32).program(x.size)[0] == Scan.default_params(runtime.traits)


def test_tune_stores_a_correct_winner(cache_root, runtime):
    entry = tuning.tune(runtime, "fill", "uint", 5000, repeats=2)
    assert entry["params"] in fill_space(runtime.traits)
    assert entry["bucket"] == size_bucket(5000) and entry["median_ms"] > 0
    tuning.forget_loaded()
    assert tuning.lookup(runtime.traits, "fill", "uint", size_bucket(5000)) == entry["params"]
    assert len(tuning.describe_cache(runtime.traits)) == 1


class WrongFill(Fill):
    """A fast but wrong candidate: writes value + 1."""

    def __call__(self, array, value, n=None):
        return super().__call__(array, value + 1, n)


def test_tune_rejects_wrong_candidates(cache_root, runtime):
    good = Fill.default_params(runtime.traits)
    bad = dict(good, items_per_thread=1 if good["items_per_thread"] != 1 else 4)
    base = tuning.FAMILIES["fill"]
    family = dataclasses.replace(
        base,
        space=lambda traits: [bad, good],
        build=lambda rt, v, p: (WrongFill if p == bad else Fill)(rt, np.uint32, params=p),
    )
    lines = []
    entry = tuning.tune(
        runtime, family, "uint", 3000, repeats=1, progress=lines.append, store=False
    )
    assert entry["params"] == good
    assert "REJECTED" in lines[0] and "REJECTED" not in lines[1]
    all_wrong = dataclasses.replace(family, space=lambda traits: [bad])
    with pytest.raises(RbgenError, match="no candidate gave a correct result"):
        tuning.tune(runtime, all_wrong, "uint", 3000, repeats=1, store=False)
    assert not tuning.cache_path(runtime.traits).exists()


def test_relative_spread():
    """Interquartile range over median; too few samples count as no spread."""
    assert tuning.relative_spread([1.0, 1.0, 1.0]) == 0.0
    assert tuning.relative_spread([2.0] * 8) == 0.0
    samples = [1.0, 1.0, 1.2, 1.2, 1.2, 1.4, 1.4]
    q1, _, q3 = np.quantile(samples, [0.25, 0.5, 0.75], method="weibull")
    assert tuning.relative_spread(samples) == pytest.approx((q3 - q1) / np.median(samples))
