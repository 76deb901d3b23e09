"""Pair kernels ("kinds"): which narrowphase kernel handles which pair of shape types.

A `PairKernel` is one kernel with one queue. It declares the (first, second)
pairs of shape type names it handles, in the kernel's own shape order (a pair
of bodies whose types come the other way round is queued with its bodies
swapped), the `KernelTemplate` of its program with that template's parameters
for this kernel, and whether it stores manifolds itself or appends touching
convex pairs to the clipping queue (``separating_axis``). Its arguments are
bound by name (`Narrowphase`): its C signature says which shape arrays it reads.

Everything that lists kinds is derived from these declarations and the
shape-type registry (`rbgen.shapes`): the dispatch kernel's classification,
the programs a `Narrowphase` builds, which shapes a World accepts
(`missing_pairs`). The built-in kernels are declared beside their templates
(`templates`).
"""

from __future__ import annotations

import dataclasses
import itertools
import re
from typing import Any

from ...codegen import KernelTemplate
from ...errors import RbgenError
from ...shapes import shape_type, shape_type_names


@dataclasses.dataclass(frozen=True)
class PairKernel:
    """One narrowphase kernel and the shape-type pairs it handles (see the module docstring).

    ``name``: the kind (queue) name, e.g. "sphere_convex"; ``pairs``: (first, second)
    type names; ``template``: its program's template, given ``params`` (name, value)
    besides the shared ones (``work_group_size``, ``placement_tile``, ``direct``,
    ``kinds`` where the template declares them); ``kernel``: the kernel's name in the
    program (default: ``name``); ``separating_axis``: it writes `SatResult` records for
    ``clip_incident_face`` instead of manifolds.
    """

    name: str
    pairs: tuple[tuple[str, str], ...]
    template: KernelTemplate
    params: tuple[tuple[str, Any], ...] = ()
    kernel: str = ""
    separating_axis: bool = False

    def __post_init__(self):
        object.__setattr__(self, "pairs", tuple(tuple(p) for p in self.pairs))
        object.__setattr__(self, "params", tuple(sorted(dict(self.params).items())))
        if not self.kernel:
            object.__setattr__(self, "kernel", self.name)

    def handles(self, types) -> list[tuple[str, str]]:
        """Its type pairs whose two types are both among ``types``."""
        return [(f, s) for f, s in self.pairs if f in types and s in types]


_KINDS: dict[str, PairKernel] = {}


def register_pair_kernel(kind: PairKernel) -> PairKernel:
    """Declare a pair kernel; no type pair (in either order) may have two kernels."""
    if not re.fullmatch(r"[a-z][a-z0-9_]*", kind.name) or kind.name in _KINDS:
        raise RbgenError(
            f"pair kernel {kind.name!r}: the name must be new and a C identifier "
            f"(declared: {list(_KINDS)})"
        )
    if not kind.pairs:
        raise RbgenError(f"pair kernel {kind.name!r} handles no shape-type pair")
    for first, second in kind.pairs:
        shape_type(first), shape_type(second)  # registered types only
        other = kernel_for(first, second)
        if other is not None:
            raise RbgenError(
                f"pair kernel {kind.name!r}: the pair ({first}, {second}) is "
                f"already handled by {other[0].name!r}"
            )
    _KINDS[kind.name] = kind
    return kind


def pair_kernels() -> tuple[PairKernel, ...]:
    """Every declared pair kernel, in declaration order (the order of queues and launches)."""
    return tuple(_KINDS.values())


def pair_kernel(name: str) -> PairKernel:
    try:
        return _KINDS[name]
    except KeyError:
        raise RbgenError(f"no pair kernel named {name!r}; declared: {list(_KINDS)}") from None


def kernel_for(first: str, second: str) -> tuple[PairKernel, bool] | None:
    """The kernel of a pair of bodies with these types and whether the bodies are swapped
    for it (the kernel's first type is the second body's), or None."""
    for kind in _KINDS.values():
        if (first, second) in kind.pairs:
            return kind, False
        if (second, first) in kind.pairs:
            return kind, True
    return None


def missing_pairs(type_names) -> list[tuple[str, str]]:
    """Pairs of these (registered) types that no kernel handles; a pair of two static-only
    types needs none (such bodies never touch), nor a pair with a composite type (the
    midphase turns it into pairs of its children, whose types are among the world's)."""
    types = sorted(set(type_names))
    return [
        (a, b)
        for a, b in itertools.combinations_with_replacement(types, 2)
        if not (shape_type(a).static_only and shape_type(b).static_only)
        and not (shape_type(a).composite or shape_type(b).composite)
        and kernel_for(a, b) is None
    ]


def kinds_for(type_names) -> tuple[str, ...]:
    """The kinds a world with these shape types needs, in declaration order; raises for a
    type that is not registered or a pair of types without a kernel."""
    types = set(type_names)
    unknown = sorted(types - set(shape_type_names()))
    if unknown:
        raise RbgenError(
            f"narrowphase: shape type(s) {unknown} are not supported "
            f"(registered: {list(shape_type_names())})"
        )
    missing = missing_pairs(types)
    if missing:
        raise RbgenError(
            f"narrowphase: no pair kernel handles {missing} (declared: {list(_KINDS)})"
        )
    return tuple(kind.name for kind in _KINDS.values() if kind.handles(types))


def kinds_param_check(template_path: str | None):
    """The check of a template's ``kinds`` parameter: a non-empty tuple of distinct names of
    kernels declared with that template (any template: None), in declaration order."""

    def allowed(value) -> bool:
        names = [
            k.name
            for k in _KINDS.values()
            if template_path is None or k.template.path == template_path
        ]
        return (
            isinstance(value, tuple)
            and len(value) > 0
            and set(value) <= set(names)
            and tuple(sorted(set(value), key=names.index)) == value
        )

    return allowed
