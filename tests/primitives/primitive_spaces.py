"""Shared by the primitive tests: boundary sizes and search-space points.

Every point of the test device's own search space is tested (on a GPU: all
GPU-shape points; on PoCL: all CPU-shape points). On a CPU device we also
test GPU-shape kernels, which are plain OpenCL and run there too, but only at
the heuristic defaults of two reference GPUs (NVIDIA, wavefront 32; AMD,
wavefront 64) plus the extra points a test names: PoCL needs 10-30 s to
compile each barrier-heavy GPU-shape program (mostly spent producing the
binary for the disk cache), so the whole GPU spaces would cost CI minutes.
"""

from __future__ import annotations

import dataclasses

from rbgen.device import DeviceTraits

#: the full boundary list (run on the heuristic default point)
FULL_SIZES = [0, 1, 31, 32, 33, 63, 64, 65, 1000, 2**16 - 1, 2**16 + 1, 2**20 + 3]
#: reduced list for every other point: empty, one, odd, non-multiples of any
#: work-group size, and one size larger than the largest tile (32 * 1024 keys)
REDUCED_SIZES = [0, 1, 33, 1000, 40_009]

NVIDIA = DeviceTraits(
    "NVIDIA CUDA",
    "reference NVIDIA GPU",
    "NVIDIA Corporation",
    True,
    132,
    32,
    65536,
    1024,
    "test",
    "OpenCL 3.0",
)
AMD = dataclasses.replace(
    NVIDIA,
    platform_name="AMD APP",
    device_name="reference AMD GPU",
    vendor="Advanced Micro Devices, Inc.",
    wavefront=64,
)


def all_points(search_space, traits: DeviceTraits, extra=lambda params: False) -> list[dict]:
    """The device's whole search space; on a CPU device also the reference
    GPUs' default points and those of their points that ``extra`` selects."""
    points = list(search_space(traits))
    if not traits.is_gpu:
        for t in (NVIDIA, AMD):
            space = search_space(t)
            points += [p for i, p in enumerate(space) if i == 0 or extra(p)]
    unique = []
    for p in points:
        if p not in unique:
            unique.append(p)
    return unique


def label(params: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in params.items())
