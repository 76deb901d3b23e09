"""Narrowphase: contact manifolds from broadphase pairs (see `narrowphase`; the pair
kernels and the shape-type pairs each handles: `kinds`)."""

from . import triangles  # noqa: F401,E402 - declares the mesh triangle pair kernels
from .kinds import PairKernel, kinds_for, missing_pairs, pair_kernel, pair_kernels
from .narrowphase import Narrowphase, find_contacts

__all__ = [
    "Narrowphase",
    "PairKernel",
    "find_contacts",
    "kinds_for",
    "missing_pairs",
    "pair_kernel",
    "pair_kernels",
]
