"""The World's bodies: the host mirror, input checks, and the device arrays.

Every body, static or dynamic, has an index (returned by the World's ``add_*``) into the
state arrays. A body's frame is its shape's principal frame (centre of mass): for
spheres, boxes and capsules the shape's own frame, for hulls the cooked (re-centred)
frame. The host copy and the device copy are kept apart: the host copy is authoritative
after an add or a set (``device_stale``), the device copy after a step (``host_stale``);
each side is brought up to date only when the other is read.

Input checks (errors name the body index and the field, and leave the store as it was):
NaN/inf positions, velocities, orientations; non-positive or non-finite mass of a dynamic
body; friction < 0; restitution outside [0, 1]; a static-only shape (a plane) as a dynamic
body; a shape that is not a registered shape type, or whose pairs with the world's other
types have no narrowphase kernel (`supported_shapes`); body ids that are not integers in
range; a velocity set on a static body; numbers given as text or booleans. Orientations
are normalised; one whose norm is off by more than 1e-3 is normalised with a warning, a
zero one is refused.

State read back (`field`) is a read-only `StateArray` snapshot: an edit raises, naming the
setter, because an edit of a copy would be lost without a word. Removal compacts the
records in order (`remove` returns the old-to-new index mapping).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np
import pyopencl.array as cla

from . import layouts
from .errors import RbgenError
from .pipeline.narrowphase.kinds import missing_pairs
from .pipeline.prepare import inertia_records
from .shapes import Shape, ShapeTable, registered_type, shape_type_names, shape_types


def supported_shapes() -> tuple[type[Shape], ...]:
    """The registered shape types that have a narrowphase kernel for their pairs with every
    registered type (so a World may mix them freely)."""
    names = shape_type_names()
    return tuple(
        t for t in shape_types() if not any(t.type_name in pair for pair in missing_pairs(names))
    )


def check_supported(shape: Shape, world_types) -> None:
    """Refuse a shape a World cannot simulate beside shapes of ``world_types`` (names): one
    that is no registered shape type, or whose pairs with them have no kernel."""
    cls = registered_type(shape)
    if cls is None:
        raise RbgenError(
            f"shape {type(shape).__name__} has no narrowphase kernels; "
            f"supported: {', '.join(c.__name__ for c in supported_shapes())}"
        )
    missing = [
        pair for pair in missing_pairs({*world_types, cls.type_name}) if cls.type_name in pair
    ]
    if missing:
        # the narrowphase has kernels for declared pairs only: fail here, not mid-step
        raise RbgenError(
            f"shape {type(shape).__name__} has no narrowphase kernel for the "
            f"shape-type pairs {missing} of this World"
        )


class StateArray(np.ndarray):
    """A read-only snapshot of one state field (an (N, lanes) float32 array).

    Writing into it raises `RbgenError` naming the setter: the World's state lives on the
    device, so an edit of this copy would be silently lost. ``.copy()`` is writeable;
    arithmetic on it gives plain numpy arrays."""

    #: the setter named in the error (set by `BodyStore.field`)
    setter = "World.set_state"

    def __array_finalize__(self, obj):
        self.setter = getattr(obj, "setter", StateArray.setter)

    def __array_wrap__(self, result, context=None, return_scalar=False):
        result = np.asarray(result)
        return result[()] if return_scalar else result

    def __setitem__(self, key, value):
        if not self.flags.writeable:
            raise RbgenError(
                f"this array is a read-only snapshot of the World's state (an "
                f"edit would be lost): use {self.setter}"
            )
        super().__setitem__(key, value)


def collision_words(host: np.ndarray, envs: np.ndarray) -> np.ndarray:
    """Each body's collision word (`layouts.GROUP_STATIC`): env << 1 | static, or
    RB_SHARED_STATIC for a static body of environment RB_SHARED_STATIC (shared geometry)."""
    static = (host["inv_mass"] == 0).astype(np.uint32)
    words = (envs.astype(np.uint32) << np.uint32(1)) | static
    return np.where(envs == layouts.SHARED_STATIC, np.uint32(layouts.SHARED_STATIC), words)


class DeviceBodies:
    """The device arrays of one upload: bodies, their backups (one per step in flight: a
    redone step starts from one), inertia records and collision words (``static``: the
    broadphase's per-body word, env << 1 | static; see `collision_words`)."""

    def __init__(
        self, queue, host: np.ndarray, inv_inertia: np.ndarray, backups: int, envs: np.ndarray
    ):
        n = len(host)
        self.count = n
        self.bodies = cla.to_device(queue, host if n else layouts.BODY.zeros(1))
        self.backups = [cla.empty_like(self.bodies) for _ in range(backups)]
        self.inertia = cla.to_device(queue, inertia_records(inv_inertia if n else np.zeros((1, 3))))
        self.static = cla.to_device(
            queue, collision_words(host, envs) if n else np.zeros(1, np.uint32)
        )
        #: each body's shape index (host copy: the midphase places compound children by it)
        self.shape_indices = host["shape"].copy()

    def refill(self, queue, host: np.ndarray, inv_inertia: np.ndarray, envs: np.ndarray) -> None:
        """Copy a host copy of the same body count into these arrays (a set or a removal
        followed by as many adds: no new allocation)."""
        self.bodies.set(host, queue=queue)
        self.inertia.set(inertia_records(inv_inertia), queue=queue)
        self.static.set(collision_words(host, envs), queue=queue)
        self.shape_indices = host["shape"].copy()


class BodyStore:
    """Host records of every body (`layouts.BODY`) and their inverse inertia diagonals.

    ``finish``: called before the host copy is read or changed (the World's: check every
    step in flight); ``read_device``: returns the device's records (after a step).
    """

    def __init__(
        self, shapes: ShapeTable, finish: Callable[[], None], read_device: Callable[[], np.ndarray]
    ):
        self.shapes = shapes
        self._finish = finish
        self._read_device = read_device
        self.host = layouts.BODY.zeros(0)
        self.inv_inertia = np.zeros((0, 3), np.float32)
        #: each body's environment (uint32; a World's are 0; `rbgen.batch` sets them)
        self.envs = np.zeros(0, np.uint32)
        self.has_dynamic = False
        self.device_stale = True  # host copy newer than the device
        self.host_stale = False  # device newer than the host copy

    @property
    def count(self) -> int:
        return len(self.host)

    def sync_to_host(self) -> None:
        """Bring the host copy up to date (waits for the steps in flight)."""
        self._finish()
        if self.host_stale:
            fresh = self._read_device()[: self.count]
            # (the host's own inverse masses: the device zeroes a sleeping body's,
            # rbgen.pipeline.sleep, and nothing else on the device changes them)
            fresh["inv_mass"] = self.host["inv_mass"]
            self.host = fresh
            self.host_stale = False

    def add(
        self,
        shape: Shape,
        positions,
        orientations,
        masses,
        friction,
        restitution,
        linear_velocities,
        angular_velocities,
    ) -> np.ndarray:
        """Append bodies of one shape (``masses`` None: static); returns their indices."""
        if isinstance(shape, (int, np.integer)):
            # shapes are values, never indices: an index means one World's table
            raise RbgenError(
                f"shape must be an rbgen shape object (e.g. rbgen.Box(...)), got "
                f"the index {int(shape)}: shape indices belong to one World's "
                f"table, while a shape object can be added to any World"
            )
        if not isinstance(shape, Shape):
            raise RbgenError(f"shape must be an rbgen shape, got {type(shape).__name__}")
        check_supported(shape, self.shapes.type_names())
        if masses is not None and type(shape).static_only:
            raise RbgenError(
                f"shape: a {type(shape).__name__} can only be static (use "
                f"add_static)" + type(shape).static_only_hint
            )
        n = len(positions)
        first = self.count
        positions = rows(positions, n, 3, "positions", first)
        orientations = unit_quaternions(orientations, n, first)
        lin = rows(
            np.zeros((n, 3)) if linear_velocities is None else linear_velocities,
            n,
            3,
            "linear_velocities",
            first,
        )
        ang = rows(
            np.zeros((n, 3)) if angular_velocities is None else angular_velocities,
            n,
            3,
            "angular_velocities",
            first,
        )
        friction = per_body(friction, n, "friction")
        restitution = per_body(restitution, n, "restitution")
        for values, name, ok in (
            (friction, "friction", friction >= 0),
            (restitution, "restitution", (restitution >= 0) & (restitution <= 1)),
        ):
            bad = np.flatnonzero(~(np.isfinite(values) & ok))
            if len(bad):
                raise RbgenError(
                    f"body {first + bad[0]}: {name}={float(values[bad[0]])!r} is out of range"
                )
        records = layouts.BODY.zeros(n)
        inv_inertia = np.zeros((n, 3), np.float32)
        if masses is not None:
            bad = np.flatnonzero(~(np.isfinite(masses) & (masses > 0)))
            if len(bad):
                raise RbgenError(
                    f"body {first + bad[0]}: mass must be positive and finite "
                    f"for a dynamic body, got {masses[bad[0]]!r}"
                )
            unit = shape.mass_properties(mass=1.0)
            records["inv_mass"] = 1.0 / masses
            inv_inertia[:] = 1.0 / (masses[:, None] * np.asarray(unit.inertia)[None, :])
        self.sync_to_host()
        shape_index = self.shapes.add(shape)
        records["position"][:, :3] = positions
        records["orientation"] = orientations
        records["linear_velocity"][:, :3] = lin
        records["angular_velocity"][:, :3] = ang
        records["shape"] = shape_index
        records["friction"], records["restitution"] = friction, restitution
        if masses is None:
            records["linear_velocity"] = 0
            records["angular_velocity"] = 0
        self.host = np.concatenate([self.host, records])
        self.has_dynamic = bool(np.any(self.host["inv_mass"] > 0))
        self.inv_inertia = np.concatenate([self.inv_inertia, inv_inertia])
        self.envs = np.concatenate([self.envs, np.zeros(n, np.uint32)])
        self.device_stale = True
        return np.arange(first, first + n)

    def adopt(self, host: np.ndarray, inv_inertia: np.ndarray, envs: np.ndarray) -> None:
        """Replace every body by checked records (a `rbgen.batch.WorldBatch` copies its
        template's, already checked, and numbers their environments)."""
        self.sync_to_host()
        self.host = np.ascontiguousarray(host)
        self.inv_inertia = np.ascontiguousarray(inv_inertia, np.float32)
        self.envs = np.ascontiguousarray(envs, np.uint32)
        self.has_dynamic = bool(np.any(self.host["inv_mass"] > 0))
        self.device_stale = True

    def field(self, name: str, lanes: int, setter: str) -> StateArray:
        """A read-only snapshot of one state field of every body, (N, lanes) float32
        (``setter`` is named by the error an edit raises)."""
        self.sync_to_host()
        snapshot = self.host[name][:, :lanes].copy().view(StateArray)
        snapshot.setter = setter
        snapshot.flags.writeable = False
        return snapshot

    def set_field(self, name: str, values, lanes: int, what: str) -> np.ndarray:
        """Replace one state field of every body (static bodies keep zero velocities);
        returns the mask of the bodies whose value changed."""
        self.sync_to_host()
        values = rows(values, self.count, lanes, what, 0)
        if name == "orientation":
            values = unit_quaternions(values, self.count, 0)
        dynamic = self.host["inv_mass"] > 0
        if name in ("linear_velocity", "angular_velocity"):
            values = np.where(dynamic[:, None], values, 0.0)
        new = values.astype(np.float32)
        changed = np.any(self.host[name][:, :lanes] != new, axis=1)
        self.host[name][:, :lanes] = new
        self.device_stale = True
        return changed

    def set_rows(self, ids, fields: dict) -> np.ndarray:
        """Set some fields of the bodies ``ids``: ``fields`` maps a state field name
        (``positions``, ``orientations``, ``linear_velocities``, ``angular_velocities``) to
        one row per id or one row for all (None: unchanged). Every value is checked
        before any is written. Returns the ids (int64)."""
        self.sync_to_host()
        ids = body_ids(ids, self.count, "ids")
        if len(np.unique(ids)) != len(ids):
            values, counts = np.unique(ids, return_counts=True)
            raise RbgenError(
                f"ids: body {int(values[counts > 1][0])} is listed twice (each "
                f"body's new state must be given once)"
            )
        checked = {}
        for what, value in fields.items():
            if value is None:
                continue
            name, lanes = STATE_FIELDS[what]
            try:
                arr = floats(value)
            except (TypeError, ValueError):
                raise RbgenError(
                    f"{what} must be numbers of shape ({len(ids)}, {lanes}) or "
                    f"({lanes},), got {type(value).__name__}"
                ) from None
            if arr.shape == (lanes,):
                arr = np.broadcast_to(arr, (len(ids), lanes))
            arr = rows(arr, len(ids), lanes, what, ids=ids)
            if name == "orientation":
                arr = unit_quaternions(arr, len(ids), ids=ids)
            if name in ("linear_velocity", "angular_velocity"):
                static = (self.host["inv_mass"][ids] == 0) & np.any(arr != 0, axis=1)
                if np.any(static):
                    body = int(ids[np.flatnonzero(static)[0]])
                    raise RbgenError(
                        f"body {body} is static: {what} must stay zero, got "
                        f"{arr[np.flatnonzero(static)[0]].tolist()}"
                    )
            checked[name] = (arr, lanes)
        for name, (arr, lanes) in checked.items():
            self.host[name][ids, :lanes] = arr
        if checked:
            self.device_stale = True
        return ids

    def remove(self, ids) -> np.ndarray:
        """Remove the bodies ``ids`` (each at most once is needed; repeats are allowed);
        the others keep their order. Returns the mapping from old index to new index
        (-1 for a removed body)."""
        self.sync_to_host()
        ids = body_ids(ids, self.count, "ids")
        keep = np.ones(self.count, bool)
        keep[ids] = False
        mapping = np.full(self.count, -1, np.int64)
        mapping[keep] = np.arange(int(keep.sum()))
        self.host = self.host[keep]
        self.inv_inertia = self.inv_inertia[keep]
        self.envs = self.envs[keep]
        self.has_dynamic = bool(np.any(self.host["inv_mass"] > 0))
        self.device_stale = True
        return mapping

    def upload(self, queue, backups: int, previous: DeviceBodies | None = None) -> DeviceBodies:
        """The device arrays of the host copy (after adds, sets or removals): ``previous``
        refilled when it holds as many bodies, else new ones."""
        if (
            previous is not None
            and previous.count == self.count > 0
            and len(previous.backups) == backups
        ):
            previous.refill(queue, self.host, self.inv_inertia, self.envs)
            arrays = previous
        else:
            arrays = DeviceBodies(queue, self.host, self.inv_inertia, backups, self.envs)
        self.device_stale = False
        return arrays

    def dynamic_shapes(self) -> list[Shape]:
        """The distinct shapes of the dynamic bodies."""
        indices = np.unique(self.host["shape"][self.host["inv_mass"] > 0])
        return [self.shapes.shapes[int(i)] for i in indices]

    def dynamic_positions(self) -> np.ndarray:
        """(N, 3) positions of the dynamic bodies (host copy)."""
        return self.host["position"][self.host["inv_mass"] > 0, :3]


# ----------------------------------------------------------------- checks


def per_body(value, n, what):
    """A scalar or one value per body, as n floats; a wrong shape is refused, naming it."""
    try:
        arr = floats(value)
    except (TypeError, ValueError):
        raise RbgenError(
            f"{what} must be a number or one number per body ({n}), got {type(value).__name__}"
        ) from None
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.shape != (n,):
        raise RbgenError(
            f"{what} must be a scalar or one value per body ({n}), got shape {arr.shape}"
        )
    return arr.astype(float)


def floats(value) -> np.ndarray:
    """``value`` as a float64 array; text and booleans are refused (numpy would read "1"
    as 1.0 and True as 1.0, and either given for a number is a mistake): raises TypeError
    or ValueError, which callers turn into an RbgenError naming the argument."""
    arr = np.asarray(value)
    if arr.dtype.kind in "USVb":
        raise TypeError("not a number")
    return arr.astype(float, copy=False)


#: the settable state fields: argument name -> (record field, lanes)
STATE_FIELDS = {
    "positions": ("position", 3),
    "orientations": ("orientation", 4),
    "linear_velocities": ("linear_velocity", 3),
    "angular_velocities": ("angular_velocity", 3),
}


def _body(i, first, ids) -> int:
    return int(first + i if ids is None else ids[i])


def rows(values, n, lanes, what, first=0, ids=None):
    """An (n, lanes) array of finite numbers; the first bad body is named (row i is body
    ``first + i``, or ``ids[i]``)."""
    try:
        arr = floats(values)
    except (TypeError, ValueError):
        raise RbgenError(
            f"{what} must be numbers of shape ({n}, {lanes}), got {type(values).__name__}"
        ) from None
    if arr.shape != (n, lanes):
        raise RbgenError(f"{what} must have shape ({n}, {lanes}), got {arr.shape}")
    bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
    if len(bad):
        raise RbgenError(
            f"body {_body(bad[0], first, ids)}: {what} has a NaN or infinite "
            f"value {arr[bad[0]].tolist()}"
        )
    return arr


def unit_quaternions(values, n, first=0, ids=None):
    """(n, 4) unit quaternions (identity when None); see the module docstring."""
    if values is None:
        out = np.zeros((n, 4))
        out[:, 3] = 1.0
        return out
    q = rows(values, n, 4, "orientations", first, ids)
    norms = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(norms < 1e-6)
    if len(bad):
        raise RbgenError(f"body {_body(bad[0], first, ids)}: orientations has a zero quaternion")
    off = np.flatnonzero(np.abs(norms - 1) > 1e-3)
    if len(off):
        warnings.warn(
            f"body {_body(off[0], first, ids)}: orientations not unit (norm "
            f"{norms[off[0]]:.4g}); normalised ({len(off)} bodies)",
            stacklevel=4,
        )
    return q / norms[:, None]


def one_row(value, lanes: int, what: str, body: int) -> np.ndarray:
    """One body's ``lanes`` finite numbers as a (1, lanes) array (``what`` names the
    argument in errors, ``body`` the index the body would get)."""
    try:
        arr = floats(value)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != (lanes,):
        raise RbgenError(f"body {body}: {what} must be {lanes} numbers, got {value!r}")
    return rows(arr[None], 1, lanes, what, body)


def body_ids(ids, count: int, what: str) -> np.ndarray:
    """Body indices as int64: an integer or a 1-D sequence of integers in [0, count)."""
    arr = np.asarray(ids)
    if arr.dtype == object or arr.dtype.kind not in "iu" or arr.ndim > 1:
        if arr.size == 0 and arr.ndim == 1:
            return np.zeros(0, np.int64)
        raise RbgenError(
            f"{what} must be a body index or a 1-D sequence of body indices "
            f"(integers from 0 to {count - 1}), got "
            f"{arr.dtype if arr.dtype != object else type(ids).__name__} "
            f"of shape {arr.shape}"
        )
    arr = arr.reshape(-1).astype(np.int64)
    bad = np.flatnonzero((arr < 0) | (arr >= count))
    if len(bad):
        raise RbgenError(
            f"{what}: body {int(arr[bad[0]])} does not exist (body indices run "
            f"from 0 to {count - 1})"
        )
    return arr


def bounding_radius(shape: Shape) -> float:
    """Radius of a sphere about the body's origin that holds the shape (its type's
    `Shape.bounding_radius`)."""
    return shape.bounding_radius()
