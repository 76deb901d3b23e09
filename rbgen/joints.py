"""Joints: the public joint kinds, their checks, and the World's joint records.

A joint holds two bodies together by rows the solver solves with the contacts, in the
same colours and launches (`rbgen.pipeline.joints`, ``solvers/joint_rows.cl.mako``).
Anchors and axes are given in world coordinates when the joint is made; the joint keeps
them in each body's frame (``b=None``: the world, where they stay in world coordinates).

Kinds (every one takes ``break_impulse``: None, or the reaction impulse over one step,
N s, above which the joint breaks and acts no more):

* ``BallJoint(a, b, anchor, friction=None)``: the anchor points of both bodies coincide;
  ``friction`` (N m): the largest torque that resists the relative rotation (a
  ragdoll's joints settle with it);
* ``FixedJoint(a, b, anchor=None)``: the relative pose stays that of creation (anchor:
  where the point rows act; None: B's centre, A's when B is the world);
* ``HingeJoint(a, b, anchor, axis, limits=None, motor=None)``: rotation about the axis
  only; ``limits`` (lower, upper) radians of the angle turned since creation, ``motor``
  (target speed rad/s, maximum torque N m);
* ``SliderJoint(a, b, anchor, axis, limits=None)``: translation along the axis only;
  ``limits`` (lower, upper) metres of the offset since creation;
* ``DistanceJoint(a, b, anchor_a, anchor_b, min_length=None, max_length=None)``: the
  anchors' distance stays in [min_length, max_length] (None: the distance at creation).

`JointStore` is the World's copy: numpy `layouts.JOINT_CONSTRAINT` records, checked and
packed by `pack_joints` (vectorised: thousands of joints in a few numpy operations), and
their device array, uploaded only when joints were added or removed. The solver updates
the impulses and the broken flags on the device; they are read back only when asked
(`World.joint_impulses`, `World.joints_broken`) or before the records change.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pyopencl as cl
import pyopencl.array as cl_array

from . import layouts
from .device import buffer_of
from .errors import RbgenError
from .guard import STEPS_IN_FLIGHT

#: the largest float32: a break impulse never reached (the kernels avoid infinities)
UNBREAKABLE = float(np.finfo(np.float32).max)


@dataclasses.dataclass(frozen=True)
class BallJoint:
    """The anchor (world point at creation) of both bodies stays one point; ``friction``
    (N m, None: none) resists the relative rotation up to that torque."""

    a: int
    b: int | None
    anchor: tuple = (0.0, 0.0, 0.0)
    friction: float | None = None
    break_impulse: float | None = None


@dataclasses.dataclass(frozen=True)
class FixedJoint:
    """B keeps its pose relative to A (anchor None: B's centre, A's if B is the world)."""

    a: int
    b: int | None
    anchor: tuple | None = None
    break_impulse: float | None = None


@dataclasses.dataclass(frozen=True)
class HingeJoint:
    """B turns about ``axis`` through ``anchor`` relative to A; optional angle limits
    (lower, upper, radians from creation) and motor (target speed rad/s, max torque N m)."""

    a: int
    b: int | None
    anchor: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (0.0, 0.0, 1.0)
    limits: tuple | None = None
    motor: tuple | None = None
    break_impulse: float | None = None


@dataclasses.dataclass(frozen=True)
class SliderJoint:
    """B slides along ``axis`` relative to A without turning; optional offset limits
    (lower, upper, metres from creation)."""

    a: int
    b: int | None
    anchor: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (1.0, 0.0, 0.0)
    limits: tuple | None = None
    break_impulse: float | None = None


@dataclasses.dataclass(frozen=True)
class DistanceJoint:
    """The distance between A's ``anchor_a`` and B's ``anchor_b`` stays within
    [min_length, max_length] (None: the distance at creation)."""

    a: int
    b: int | None
    anchor_a: tuple = (0.0, 0.0, 0.0)
    anchor_b: tuple = (0.0, 0.0, 0.0)
    min_length: float | None = None
    max_length: float | None = None
    break_impulse: float | None = None


#: joint class -> kind code
KINDS = {
    BallJoint: layouts.JOINT_BALL,
    FixedJoint: layouts.JOINT_FIXED,
    HingeJoint: layouts.JOINT_HINGE,
    SliderJoint: layouts.JOINT_SLIDER,
    DistanceJoint: layouts.JOINT_DISTANCE,
}
#: the per-joint fields each kind takes besides a, b and break_impulse
FIELDS = {
    BallJoint: ("anchor", "friction"),
    FixedJoint: ("anchor",),
    HingeJoint: ("anchor", "axis", "limits", "motor"),
    SliderJoint: ("anchor", "axis", "limits"),
    DistanceJoint: ("anchor_a", "anchor_b", "min_length", "max_length"),
}
JOINT_TYPES = tuple(KINDS)


def joint_fields(joint) -> tuple[type, dict]:
    """(kind, fields) of a joint object, as `pack_joints` takes them (one row each)."""
    kind = type(joint)
    if kind not in KINDS:
        raise RbgenError(
            f"a joint must be one of {[k.__name__ for k in JOINT_TYPES]}, got {kind.__name__}"
        )
    fields: dict = {"a": [joint.a], "b": [joint.b], "break_impulse": [joint.break_impulse]}
    for name in FIELDS[kind]:
        value = getattr(joint, name)
        fields[name] = None if value is None else [value]
    return kind, fields


def _quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    pv, pw, qv, qw = p[:, :3], p[:, 3:], q[:, :3], q[:, 3:]
    return np.concatenate(
        [pw * qv + qw * pv + np.cross(pv, qv), pw * qw - np.sum(pv * qv, 1, keepdims=True)], 1
    )


def _conj(q: np.ndarray) -> np.ndarray:
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def _to_local(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """conj(q) v q: world vectors into the frames of orientations q."""
    qv, qw = -q[:, :3], q[:, 3:]
    t = 2.0 * np.cross(qv, v)
    return v + qw * t + np.cross(qv, t)


class _Rows:
    """Per-joint input rows of one `pack_joints` call, checked with the joint's id."""

    def __init__(self, kind: type, n: int, first: int):
        self.kind, self.n, self.first = kind, n, first

    def name(self, i: int) -> str:
        return f"joint {self.first + i} ({self.kind.__name__})"

    def vectors(self, values, lanes: int, what: str) -> np.ndarray:
        try:
            arr = np.asarray(values, float)
        except (TypeError, ValueError):
            raise RbgenError(f"{self.name(0)}: {what} must be numbers, {lanes} per joint") from None
        if arr.ndim == 1 and arr.shape == (lanes,):
            arr = np.broadcast_to(arr, (self.n, lanes))
        if arr.shape != (self.n, lanes):
            raise RbgenError(
                f"{self.name(0)}: {what} must be {lanes} numbers or ({self.n}, {lanes}), "
                f"got shape {arr.shape}"
            )
        bad = ~np.all(np.isfinite(arr), axis=1)
        if np.any(bad):
            raise RbgenError(f"{self.name(int(np.argmax(bad)))}: {what} must be finite numbers")
        return arr

    def scalars(self, values, what: str, default=None) -> np.ndarray:
        """One optional number per joint (None entries: ``default``, NaN if None)."""
        if values is None:
            values = [None]
        seq = list(values) if np.ndim(values) else [values]
        if len(seq) == 1:
            seq = seq * self.n
        if len(seq) != self.n:
            raise RbgenError(f"{self.name(0)}: {what} must be one value or {self.n}")
        out = np.empty(self.n)
        for i, v in enumerate(seq):
            if v is None:
                out[i] = np.nan if default is None else default
                continue
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.number)):
                raise RbgenError(f"{self.name(i)}: {what} must be a number or None, got {v!r}")
            if not np.isfinite(v):
                raise RbgenError(f"{self.name(i)}: {what} must be finite, got {v!r}")
            out[i] = float(v)
        return out

    def pairs(self, values, what: str) -> tuple[np.ndarray, np.ndarray]:
        """Optional (x, y) per joint: (present mask, (n, 2) values)."""
        present = np.zeros(self.n, bool)
        out = np.zeros((self.n, 2))
        if values is None:
            return present, out
        seq = list(values)
        if len(seq) == 2 and all(
            v is not None and not np.ndim(v) and not isinstance(v, (tuple, list)) for v in seq
        ):
            seq = [tuple(seq)] * self.n  # one pair for all
        if len(seq) == 1:
            seq = seq * self.n
        if len(seq) != self.n:
            raise RbgenError(f"{self.name(0)}: {what} must be one pair or {self.n}")
        for i, v in enumerate(seq):
            if v is None:
                continue
            try:
                pair = np.asarray(v, float).reshape(2)
            except (TypeError, ValueError):
                raise RbgenError(f"{self.name(i)}: {what} must be a pair of numbers") from None
            if not np.all(np.isfinite(pair)):
                raise RbgenError(f"{self.name(i)}: {what} must be finite, got {v!r}")
            present[i], out[i] = True, pair
        return present, out


def _unit_axes(rows: _Rows, axis) -> np.ndarray:
    axes = rows.vectors(axis, 3, "axis")
    norms = np.linalg.norm(axes, axis=1)
    small = norms < 1e-9
    if np.any(small):
        raise RbgenError(f"{rows.name(int(np.argmax(small)))}: axis must be non-zero")
    return axes / norms[:, None]


def pack_joints(
    kind: type,
    fields: dict,
    first: int,
    positions: np.ndarray,
    orientations: np.ndarray,
    dynamic: np.ndarray,
) -> np.ndarray:
    """Checked `layouts.JOINT_CONSTRAINT` records of joints of one ``kind`` (a joint class)
    numbered from ``first``; ``fields``: ``a``, ``b`` (None or -1: the world),
    ``break_impulse`` and the kind's `FIELDS`, each one value for all or one per joint;
    the bodies' ``positions``, ``orientations`` and ``dynamic`` flags now. A bad value
    raises `RbgenError` naming the joint (its would-be id) and the field."""
    if kind not in KINDS:
        raise RbgenError(
            f"a joint kind must be one of {[k.__name__ for k in JOINT_TYPES]}, got {kind!r}"
        )
    unknown = set(fields) - {"a", "b", "break_impulse", *FIELDS[kind]}
    if unknown:
        raise RbgenError(
            f"{kind.__name__}: unknown field(s) {sorted(unknown)}; it takes a, b, "
            f"break_impulse and {list(FIELDS[kind])}"
        )
    if "a" not in fields:
        raise RbgenError(f"{kind.__name__}: the bodies `a` are required")
    a_values = np.atleast_1d(np.asarray(fields["a"], dtype=object))
    n = len(a_values)
    rows = _Rows(kind, n, first)
    count = len(positions)

    def bodies(values, what: str, world_ok: bool) -> np.ndarray:
        seq = np.atleast_1d(np.asarray(values, dtype=object))
        if len(seq) == 1:
            seq = np.repeat(seq, n)
        if len(seq) != n:
            raise RbgenError(f"{rows.name(0)}: {what} must be one body or {n}")
        out = np.empty(n, np.int64)
        for i, v in enumerate(seq):
            if v is None and world_ok:
                out[i] = -1
                continue
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
                raise RbgenError(
                    f"{rows.name(i)}: {what} must be a body index"
                    f"{' or None (the world)' if world_ok else ''}, got {v!r}"
                )
            if world_ok and v == -1:
                out[i] = -1
                continue
            if not 0 <= v < count:
                raise RbgenError(
                    f"{rows.name(i)}: {what}={v} is not a body (the World has {count}: "
                    f"0 .. {count - 1})"
                )
            out[i] = int(v)
        return out

    a = bodies(fields["a"], "a", False)
    b = bodies(fields.get("b"), "b", True)
    world = b < 0
    same = ~world & (a == b)
    if np.any(same):
        raise RbgenError(
            f"{rows.name(int(np.argmax(same)))}: a and b are the same body {a[same][0]}"
        )
    still = ~dynamic[a] & (world | ~dynamic[np.maximum(b, 0)])
    if np.any(still):
        raise RbgenError(
            f"{rows.name(int(np.argmax(still)))}: both ends are static (a body a or b must "
            f"be dynamic)"
        )
    breaking = rows.scalars(fields.get("break_impulse"), "break_impulse", UNBREAKABLE)
    if np.any(breaking <= 0):
        raise RbgenError(
            f"{rows.name(int(np.argmax(breaking <= 0)))}: break_impulse must be > 0 or None"
        )

    xa, qa = positions[a].astype(float), orientations[a].astype(float)
    bb = np.maximum(b, 0)
    xb = np.where(world[:, None], 0.0, positions[bb])
    qb = np.where(world[:, None], np.array([0.0, 0.0, 0.0, 1.0]), orientations[bb])
    out = layouts.JOINT_CONSTRAINT.zeros(n)
    out["body_a"] = a
    out["body_b"] = np.where(world, a, b)
    out["kind"] = KINDS[kind]
    flags = np.where(world, layouts.JOINT_WORLD, 0)
    axis_world = np.tile([1.0, 0.0, 0.0], (n, 1))
    lower = upper = np.zeros(n)
    if kind is DistanceJoint:
        pa = rows.vectors(fields.get("anchor_a", (0, 0, 0)), 3, "anchor_a")
        pb = rows.vectors(fields.get("anchor_b", (0, 0, 0)), 3, "anchor_b")
        distance = np.linalg.norm(pb - pa, axis=1)
        shortest = rows.scalars(fields.get("min_length"), "min_length")
        longest = rows.scalars(fields.get("max_length"), "max_length")
        shortest = np.where(np.isnan(shortest), distance, shortest)
        longest = np.where(np.isnan(longest), distance, longest)
        bad = shortest < 0
        if np.any(bad):
            raise RbgenError(f"{rows.name(int(np.argmax(bad)))}: min_length must be >= 0")
        bad = shortest > longest
        if np.any(bad):
            i = int(np.argmax(bad))
            raise RbgenError(f"{rows.name(i)}: min_length {shortest[i]} > max_length {longest[i]}")
        direction = pb - pa
        apart = distance > 1e-9
        axis_world[apart] = direction[apart] / distance[apart, None]
    else:
        anchor = fields.get("anchor")
        if kind is FixedJoint and anchor is None:
            anchor = np.where(world[:, None], xa, xb)
        pa = pb = rows.vectors(anchor if anchor is not None else (0, 0, 0), 3, "anchor")
        if kind in (HingeJoint, SliderJoint):
            axis_world = _unit_axes(rows, fields.get("axis", (0, 0, 1)))
            present, limits = rows.pairs(fields.get("limits"), "limits")
            bad = present & (limits[:, 0] > limits[:, 1])
            if np.any(bad):
                i = int(np.argmax(bad))
                raise RbgenError(
                    f"{rows.name(i)}: limits lower {limits[i, 0]} > upper {limits[i, 1]}"
                )
            if kind is HingeJoint:
                outside = present & ((limits[:, 0] < -np.pi) | (limits[:, 1] > np.pi))
                if np.any(outside):
                    raise RbgenError(
                        f"{rows.name(int(np.argmax(outside)))}: hinge limits must lie in "
                        f"[-pi, pi] (radians from the pose of creation)"
                    )
            flags = flags | np.where(present, layouts.JOINT_LIMITS, 0)
            lower, upper = limits[:, 0], limits[:, 1]
        if kind is HingeJoint:
            present, motor = rows.pairs(fields.get("motor"), "motor")
            bad = present & (motor[:, 1] < 0)
            if np.any(bad):
                i = int(np.argmax(bad))
                raise RbgenError(
                    f"{rows.name(i)}: motor maximum torque must be >= 0, got {motor[i, 1]}"
                )
            flags = flags | np.where(present, layouts.JOINT_MOTOR, 0)
            out["motor"][:, 0] = motor[:, 0]
            out["motor"][:, 1] = motor[:, 1]
    if kind is BallJoint:
        friction = rows.scalars(fields.get("friction"), "friction")
        bad = friction < 0
        if np.any(bad):
            i = int(np.argmax(bad))
            raise RbgenError(f"{rows.name(i)}: friction must be >= 0 (N m), got {friction[i]}")
        present = ~np.isnan(friction)
        flags = flags | np.where(present, layouts.JOINT_MOTOR, 0)
        out["motor"][:, 1] = np.where(present, friction, 0.0)
    out["anchor_a"][:, :3] = _to_local(qa, pa - xa)
    out["anchor_b"][:, :3] = _to_local(qb, pb - xb)
    out["axis_a"][:, :3] = _to_local(qa, axis_world)
    out["axis_b"][:, :3] = _to_local(qb, axis_world)
    if kind is DistanceJoint:
        out["anchor_a"][:, 3], out["anchor_b"][:, 3] = shortest, longest
    out["axis_a"][:, 3], out["axis_b"][:, 3] = lower, upper
    out["reference"] = _quat_mul(_conj(qa), qb)
    out["motor"][:, 2] = breaking
    out["flags"] = flags
    return out


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    qv, qw = q[:, :3], q[:, 3:]
    t = 2.0 * np.cross(qv, v)
    return v + qw * t + np.cross(qv, t)


def joint_reactions(
    records: np.ndarray, positions: np.ndarray, orientations: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(linear, angular) impulse of each joint record on its body b in the last substep,
    world frame: the blocks' totals plus the axial rows' scalars along the axial direction
    of the bodies' poses now (as the solver's warm start applies them)."""
    records = records.astype(records.dtype)
    a, b = records["body_a"].astype(np.int64), records["body_b"].astype(np.int64)
    world = (records["flags"] & layouts.JOINT_WORLD) != 0
    qa = orientations[a].astype(float)
    qb = np.where(world[:, None], [0.0, 0.0, 0.0, 1.0], orientations[b].astype(float))
    xb = np.where(world[:, None], 0.0, positions[b].astype(float))
    pa = positions[a].astype(float) + _rotate(qa, records["anchor_a"][:, :3].astype(float))
    pb = xb + _rotate(qb, records["anchor_b"][:, :3].astype(float))
    axis = _rotate(qa, records["axis_a"][:, :3].astype(float))
    separation = pb - pa
    length = np.linalg.norm(separation, axis=1)
    kind = records["kind"]
    along = -axis
    distance = (kind == layouts.JOINT_DISTANCE) & (length > 1e-6)
    along[distance] = separation[distance] / length[distance, None]
    along[(kind == layouts.JOINT_DISTANCE) & ~distance] = axis[
        (kind == layouts.JOINT_DISTANCE) & ~distance
    ]
    axial = records["axial_impulse"].astype(float)
    linear = records["linear_impulse"][:, :3].astype(float)
    angular = records["angular_impulse"][:, :3].astype(float)
    hinge = kind == layouts.JOINT_HINGE
    ball = kind == layouts.JOINT_BALL
    angular[ball] += axial[ball, :3]
    straight = (kind == layouts.JOINT_SLIDER) | (kind == layouts.JOINT_DISTANCE)
    angular[hinge] += along[hinge] * (axial[hinge, 0] - axial[hinge, 1] + axial[hinge, 2])[:, None]
    linear[straight] += along[straight] * (axial[straight, 0] - axial[straight, 1])[:, None]
    return linear, angular


class JointStore:
    """The World's joints: host records and their device array (see the module
    docstring). ``version`` counts changes of the joint list (the step's edges inherit
    colours only while it holds)."""

    def __init__(self, runtime):
        self.runtime = runtime
        self.host = layouts.JOINT_CONSTRAINT.zeros(0)
        self.device: cl_array.Array | None = None
        #: one copy of the device records per step slot (`rbgen.guard.STEPS_IN_FLIGHT`),
        #: written by the step's joint launch as the step found them: a redone step's
        #: records are restored from its slot's (`restore`)
        self.backups: list[cl_array.Array] = []
        self.dirty = False  # host records newer than the device
        self.device_newer = False  # the solver changed impulses or flags since the upload
        self.version = 0
        #: the joined body pairs (sorted, lower body first; joints to the world left out)
        #: as a device uint2 array, and their count (`pipeline.constraints` filters them)
        self.pairs: cl_array.Array | None = None
        self.pair_count = 0

    @property
    def count(self) -> int:
        return len(self.host)

    def sync_to_host(self) -> None:
        """Read the solver's impulses and broken flags back (a blocking read)."""
        if self.device_newer and self.device is not None and self.count:
            self.host = self.runtime.read(self.device)[: self.count].copy()
        self.device_newer = False

    def add(self, records: np.ndarray) -> np.ndarray:
        self.sync_to_host()
        first = self.count
        self.host = np.concatenate([self.host, records])
        self.dirty = True
        self.version += 1
        return np.arange(first, first + len(records), dtype=np.int64)

    def remove(self, ids) -> np.ndarray:
        """Remove joints ``ids``; returns the mapping old id -> new id (-1 removed)."""
        ids = joint_ids(ids, self.count)
        self.sync_to_host()
        keep = np.ones(self.count, bool)
        keep[ids] = False
        mapping = np.where(keep, np.cumsum(keep) - 1, -1).astype(np.int64)
        self.host = self.host[keep]
        self.dirty = True
        self.version += 1
        return mapping

    def renumber_bodies(self, mapping: np.ndarray) -> np.ndarray:
        """Bodies were removed (``mapping``: old body -> new, -1 removed): joints of a
        removed body go (at either end), the others follow their bodies, in order, with
        their impulses and broken flags. Returns the joints' mapping, old id -> new id
        (-1 removed)."""
        if not self.count:
            return np.zeros(0, np.int64)
        self.sync_to_host()
        a = mapping[self.host["body_a"].astype(np.int64)]
        b = mapping[self.host["body_b"].astype(np.int64)]
        keep = (a >= 0) & (b >= 0)
        joints = np.where(keep, np.cumsum(keep) - 1, -1).astype(np.int64)
        if (
            np.all(keep)
            and np.array_equal(a, self.host["body_a"])
            and np.array_equal(b, self.host["body_b"])
        ):
            return joints  # (no joint moved)
        self.host = self.host[keep]
        self.host["body_a"], self.host["body_b"] = a[keep], b[keep]
        self.dirty = True
        self.version += 1
        return joints

    def forget_bodies(self, affected: np.ndarray) -> None:
        """The state of bodies ``affected`` (a mask) was set: their joints lose their
        warm start."""
        if not self.count:
            return
        hit = affected[self.host["body_a"]] | affected[self.host["body_b"]]
        if not np.any(hit):
            return
        self.sync_to_host()
        for name in ("linear_impulse", "angular_impulse", "axial_impulse"):
            self.host[name][hit] = 0
        self.dirty = True

    def upload(self) -> None:
        """Send the host records (only after a change)."""
        if not self.dirty:
            return
        records = self.host if self.count else layouts.JOINT_CONSTRAINT.zeros(1)
        if self.device is not None and len(self.device) == len(records):
            self.device.set(records)
        else:
            self.device = cl_array.to_device(self.runtime.queue, records)
            self.backups = [cl_array.empty_like(self.device) for _ in range(STEPS_IN_FLIGHT)]
        on_world = (self.host["flags"] & layouts.JOINT_WORLD) != 0
        a, b = self.host["body_a"][~on_world], self.host["body_b"][~on_world]
        pairs = np.unique(np.stack([np.minimum(a, b), np.maximum(a, b)], 1), axis=0)
        self.pair_count = len(pairs)
        words = np.zeros((max(1, len(pairs)), 2), np.uint32)
        words[: len(pairs)] = pairs
        self.pairs = cl_array.to_device(self.runtime.queue, words)
        self.dirty = False
        self.device_newer = False

    def restore(self, slot: int) -> None:
        """A step is redone: the records go back to the backup its joint launch wrote in
        step slot ``slot`` (the joint list has not changed since: the World checks every
        step in flight before changing it)."""
        if self.count and self.device is not None and self.backups:
            cl.enqueue_copy(
                self.runtime.queue, buffer_of(self.device), buffer_of(self.backups[slot])
            )


def joint_ids(ids, count: int) -> np.ndarray:
    """Checked joint indices (an index or a sequence)."""
    arr = np.atleast_1d(np.asarray(ids, dtype=object))
    out = np.empty(len(arr), np.int64)
    for i, v in enumerate(arr):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
            raise RbgenError(f"joint ids must be integers, got {v!r}")
        if not 0 <= v < count:
            raise RbgenError(f"joint {v} does not exist (the World has {count} joints)")
        out[i] = int(v)
    return out
