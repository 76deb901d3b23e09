"""Many independent environments of one scene in one step pipeline (`WorldBatch`).

A WorldBatch copies a template World (built by a ``build`` function or given) ``envs``
times into one World: the template's static bodies once, as geometry every environment
meets (a ground, walls), then its dynamic bodies once per environment, environment
after environment (body j of environment k is ``shared + k * bodies + j``). One step
is the World's launch sequence, whatever the number of environments.

Environments overlap in space and never see each other: every body carries a collision
word, env << 1 | static (`layouts.SHARED_STATIC`), and the broadphases keep a pair only
when both bodies are in one environment or one is shared geometry (`pair_allowed`, at
the test every broadphase already makes against two static bodies: no extra pass and
no pair ever written for two environments); the grid (the default broadphase) also
files each environment's bodies in cells of their own (`grid_owner.cl.mako`), so
overlapping environments do not crowd one cell. The sweep-and-prune broadphases do not:
with them, overlapping environments cost candidate tests quadratic in their number.

An environment's trajectory does not depend on the number of environments or on the
others, bit for bit, by construction: its bodies keep their relative order whatever
comes before them, and every stage after the broadphase keeps the relative order of
the pairs, manifolds and constraint edges of one environment (pairs sorted by (a, b),
manifolds in pair order, edges in manifold order); its constraints touch none of
another environment's dynamic bodies, so a colouring in index order gives its edges
the colours they get alone, and a serial walk or a colour solved in parallel applies
its impulses in the same order; the batching's cell size and slab axis come from the
template, not from the whole batch. Where a stage orders by something else -- a
hashed priority in the GPU colourings' late rounds (global batching after its
ordered rounds, the lanes form of spatial batching) -- two batch sizes may colour an
environment differently; tests/test_batch.py compares end states across batch sizes
on every device and would show it.

Joints: the template's joints are copied into each environment, their bodies renumbered
(a joint to a static body joins that shared body), environment after environment (joint
j of environment k is ``k * joints + j``). The step's joint edges come before every
contact edge and keep their relative order within an environment, so that the
independence above holds for jointed scenes too. The batch's ``world`` must not add or
remove bodies or joints (its indexing relies on that layout and refuses otherwise).

`reset` restores environments exactly: their bodies' state, their joints as the template
had them (impulses, broken flags), and no warm start of their contacts (as a fresh
start has none). Observations are (envs, bodies, ...) arrays;
`apply_forces` takes (envs, bodies, 3) arrays, for the next step.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np
import pyopencl as cl

from . import history, layouts
from .bodies import STATE_FIELDS, floats, unit_quaternions
from .device import buffer_of
from .errors import RbgenError
from .pipeline.batching.global_colouring import ORDERED_ROUNDS
from .pipeline.reset import EnvironmentReset
from .settings import STEP
from .world import World

#: state fields a reset restores (the initial state's, or those given)
FIELDS = tuple(STATE_FIELDS)


def env_runs(envs) -> list[tuple[int, int]]:
    """The runs of consecutive environment indices in ``envs`` (distinct, any order), as
    (first, end) pairs in increasing order: [3, 0, 1, 5, 4] -> [(0, 2), (3, 6)]."""
    ordered = np.sort(np.asarray(envs, np.int64).reshape(-1))
    if len(ordered) == 0:
        return []
    cuts = np.flatnonzero(np.diff(ordered) != 1) + 1
    firsts = ordered[np.concatenate([[0], cuts])]
    ends = ordered[np.concatenate([cuts - 1, [len(ordered) - 1]])] + 1
    return [(int(a), int(b)) for a, b in zip(firsts, ends)]


def ordered_rounds_for(bodies: int, shared: int, joints: int = 0) -> int:
    """Global batching's index-order colouring rounds for a batch: at least the most
    whole-body pairs one environment can have, and its joints, so that no environment's
    edges are left
    to the hashed rounds, whose priorities would depend on the environments before it
    (a round colours at least one link of every chain of rising indices; the loop ends
    when every edge is coloured, so the bound costs nothing when unreached)."""
    return max(ORDERED_ROUNDS, bodies * (bodies - 1) // 2 + bodies * shared + joints)


class WorldBatch:
    """``envs`` copies of one scene, stepped together (see the module docstring).

    ``WorldBatch(envs, build=None, *, template=None, per_env=False, device=None,
    **options)``: ``build()`` returns the World of one environment (or pass it as
    ``template``); its static bodies are shared by every environment, its dynamic bodies
    are copied into each. With ``per_env=True``, ``build(k)`` returns environment k's
    own World (its masses, materials, shapes, positions), each with as many dynamic
    bodies and the same static bodies; environment 0's settings and options are the
    batch's. ``device`` (None: the template's) and ``options`` (World options: they
    replace the template's) make the batch's World, ``world``, which runs every
    environment (its kernels, plan and statistics are the batch's).
    """

    def __init__(
        self,
        envs: int,
        build: Callable[..., World] | None = None,
        *,
        template: World | None = None,
        per_env: bool = False,
        device=None,
        **options,
    ):
        if isinstance(envs, (bool, np.bool_)) or not isinstance(envs, (int, np.integer)):
            raise RbgenError(f"envs must be a positive integer, got {envs!r}")
        if not 1 <= envs < layouts.SHARED_STATIC >> 1:
            raise RbgenError(
                f"envs must be from 1 to {(layouts.SHARED_STATIC >> 1) - 1}, got {envs}"
            )
        if (build is None) == (template is None):
            raise RbgenError("WorldBatch needs exactly one of build (a function) and template")
        if per_env and build is None:
            raise RbgenError("per_env=True needs build(env), a function of the environment")
        if build is not None and not callable(build):
            raise RbgenError(f"build must be a function returning a World, got {build!r}")
        self.envs = int(envs)
        worlds: list
        if build is None:
            worlds = [template]
        elif per_env:
            worlds = [build(k) for k in range(self.envs)]
        else:
            worlds = [build()]
        for k, world in enumerate(worlds):
            if not isinstance(world, World):
                what = (
                    "template must be"
                    if build is None
                    else (f"build({k}) must return" if per_env else "build must return")
                )
                raise RbgenError(f"{what} an rbgen.World, got {type(world).__name__}")
        template = worlds[0]
        assert template is not None  # (checked above)
        self.template = template
        parts = []
        for world in worlds:
            world._bodies.sync_to_host()
            host = world._bodies.host.copy()
            parts.append((host, world._bodies.inv_inertia.copy(), host["inv_mass"] > 0, world))
        host, inv_inertia, dynamic, _ = parts[0]
        if not np.any(dynamic):
            raise RbgenError("the template World has no dynamic body: nothing to copy")
        #: dynamic bodies per environment, static bodies shared by all
        self.bodies = int(dynamic.sum())
        self.shared = int((~dynamic).sum())
        for k, (_, _, _, world) in enumerate(parts[1:], 1):
            if world.joint_count:
                raise RbgenError(
                    f"build({k}) has {world.joint_count} joints: with per_env=True the "
                    f"joints are environment 0's, copied into each (build(k) for k > 0 "
                    f"must add none)"
                )
        template._joints.sync_to_host()
        #: joints per environment (the template's)
        self.joints = template.joint_count
        merged = {**template.settings.as_dict(), **template.options, **options}
        plan = dict(merged.get("plan") or {})
        plan.setdefault("ordered_rounds", ordered_rounds_for(self.bodies, self.shared, self.joints))
        self.world = World(
            device if device is not None else template.runtime, **{**merged, "plan": plan}
        )
        dynamics, inertias = [], []
        for k, (host_k, inertia_k, dynamic_k, world) in enumerate(parts):
            remap = np.array([self.world.shapes.add(s) for s in world.shapes.shapes], np.uint32)
            records = host_k.copy()
            records["shape"] = remap[records["shape"]]
            if k == 0:
                statics = records[~dynamic_k]
            elif int(dynamic_k.sum()) != self.bodies or not np.array_equal(
                records[~dynamic_k], statics
            ):
                raise RbgenError(
                    f"build({k}): every environment needs {self.bodies} dynamic bodies "
                    f"and the same static bodies as environment 0 (shared), got "
                    f"{int(dynamic_k.sum())} dynamic and {int((~dynamic_k).sum())} static"
                )
            dynamics.append(records[dynamic_k])
            inertias.append(inertia_k[dynamic_k])
        #: initial records: one environment's (a copied scene) or each environment's
        self._initial = dynamics[0] if len(dynamics) == 1 else np.stack(dynamics)
        tiles = 1 if per_env else self.envs
        records = np.concatenate([statics, *(dynamics * tiles)])
        inertia = np.concatenate([inv_inertia[~dynamic], *(inertias * tiles)])
        env_of = np.concatenate(
            [
                np.full(self.shared, layouts.SHARED_STATIC, np.uint32),
                np.repeat(np.arange(self.envs, dtype=np.uint32), self.bodies),
            ]
        )
        first_dynamic = self.world.shapes.shapes[int(dynamics[0]["shape"][0])]
        self.world._memory.check_add(self.world._bodies, len(records), first_dynamic, None)
        self.world._bodies.adopt(records, inertia, env_of)
        self._joint_records = self._copy_joints(template._joints.host, dynamic)
        self._pending_joint_writes: list = []  # (host arrays of enqueued resets, kept alive)
        # spatial batching's cells and slabs from environment 0 alone (not the batch's
        # largest shape or spread, which would change with N)
        self.world._batching_scene = template._bodies
        self._reset: EnvironmentReset | None = None

    def _copy_joints(self, joints: np.ndarray, dynamic: np.ndarray) -> np.ndarray:
        """The template's joint records for every environment, (envs, joints), their bodies
        renumbered (``dynamic``: the template's dynamic-body mask); added to `world`."""
        rank = np.where(dynamic, np.cumsum(dynamic) - 1, np.cumsum(~dynamic) - 1)
        out = np.repeat(joints[None], self.envs, axis=0)  # (C order: see `_reset_joints`)
        for end in ("body_a", "body_b"):
            old = joints[end].astype(np.int64)
            offset = np.where(dynamic[old], self.shared + rank[old], rank[old])
            moved = dynamic[old][None, :] * (np.arange(self.envs)[:, None] * self.bodies)
            out[end] = offset[None, :] + moved
        if len(joints):
            self.world._memory.check_joints(self.world._bodies, out.size, None)
            self.world._joints.add(out.reshape(-1))
        return out

    # ------------------------------------------------------------- settings
    def __getattr__(self, name):
        if name in STEP:
            return getattr(self.world.settings, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def __setattr__(self, name, value):
        if name in STEP:
            setattr(self.world, name, value)  # (the World's: a new gravity wakes islands)
        else:
            object.__setattr__(self, name, value)

    @property
    def runtime(self):
        return self.world.runtime

    @property
    def plan(self):
        return self.world.plan

    @property
    def overflows(self) -> int:
        return self.world.overflows

    @property
    def last_step_counters(self) -> dict:
        return self.world.last_step_counters

    def kernel_specs(self):
        return self.world.kernel_specs()

    def statistics(self) -> dict:
        return {**self.world.statistics(), "envs": self.envs}

    # ------------------------------------------------------------- indices
    def _check_layout(self) -> None:
        """Refuse to index `world` when bodies were added to or removed from it: body j of
        environment k is ``shared + k * bodies + j`` only while it holds exactly the
        bodies the batch laid out (a reset would write over other bodies)."""
        expected = self.shared + self.envs * self.bodies
        if self.world.body_count != expected:
            raise RbgenError(
                f"the batch's world has {self.world.body_count} bodies, not the {expected} "
                f"it laid out ({self.shared} shared + {self.envs} environments x "
                f"{self.bodies}): bodies added to or removed from batch.world break the "
                f"environments' layout (make a new WorldBatch instead)"
            )

    def _check_joint_layout(self) -> None:
        """Refuse a reset when joints were added to or removed from `world` (joint j of
        environment k is ``k * joints + j`` only while it holds the batch's joints)."""
        count = self.world.joint_count
        if count != self.envs * self.joints:
            raise RbgenError(
                f"reset: the batch's world has {count} joints, not {self.joints} a "
                f"environment ({self.envs * self.joints}): joints added to or removed from "
                f"batch.world cannot be reset"
            )

    def env_ids(self, env_ids=None) -> np.ndarray:
        """Environment indices as int64 (None: all); refused naming ``env_ids``."""
        self._check_layout()
        if env_ids is None:
            return np.arange(self.envs)
        arr = np.asarray(env_ids)
        if arr.dtype == object or arr.dtype.kind not in "iu" or arr.ndim > 1:
            raise RbgenError(
                f"env_ids must be an environment index or a 1-D sequence of them (integers "
                f"from 0 to {self.envs - 1}), got {arr.dtype} of shape {arr.shape}"
            )
        arr = arr.reshape(-1).astype(np.int64)
        bad = np.flatnonzero((arr < 0) | (arr >= self.envs))
        if len(bad):
            raise RbgenError(
                f"env_ids: environment {int(arr[bad[0]])} does not exist (environments run "
                f"from 0 to {self.envs - 1})"
            )
        return arr

    def joint_ids(self, env_ids=None) -> np.ndarray:
        """(len(env_ids), joints) indices of the environments' joints in `world`."""
        envs = self.env_ids(env_ids)
        return envs[:, None] * self.joints + np.arange(self.joints)[None, :]

    @property
    def joint_impulses(self) -> np.ndarray:
        """(envs, joints, 6) float32: `World.joint_impulses` by environment."""
        return self.world.joint_impulses.reshape(self.envs, self.joints, 6)

    @property
    def joints_broken(self) -> np.ndarray:
        """(envs, joints) bool: `World.joints_broken` by environment."""
        return self.world.joints_broken.reshape(self.envs, self.joints)

    def body_ids(self, env_ids=None) -> np.ndarray:
        """(len(env_ids), bodies) indices of the environments' bodies in `world`."""
        envs = self.env_ids(env_ids)
        return self.shared + envs[:, None] * self.bodies + np.arange(self.bodies)[None, :]

    # ------------------------------------------------------------- state
    def _field(self, what):
        self._check_layout()
        name, lanes = STATE_FIELDS[what]
        snapshot = self.world._bodies.field(
            name, lanes, f"batch.reset(env_ids, state={{'{what}': ...}})"
        )
        return snapshot[self.shared :].reshape(self.envs, self.bodies, lanes)

    positions = property(
        lambda s: s._field("positions"), doc="(envs, bodies, 3) float32, read-only snapshot"
    )
    orientations = property(
        lambda s: s._field("orientations"), doc="(envs, bodies, 4) float32 quaternions x, y, z, w"
    )
    linear_velocities = property(
        lambda s: s._field("linear_velocities"), doc="(envs, bodies, 3) float32 m/s"
    )
    angular_velocities = property(
        lambda s: s._field("angular_velocities"), doc="(envs, bodies, 3) float32 rad/s"
    )

    @property
    def asleep(self) -> np.ndarray:
        """(envs, bodies) bool: the bodies asleep now (World option ``sleeping``; all False
        without it). A blocking read."""
        return self.world.asleep[self.shared :].reshape(self.envs, self.bodies)

    def _rows(self, value, count: int, lanes: int, what: str, envs: np.ndarray) -> np.ndarray:
        """(count, bodies, lanes) finite numbers, or (bodies, lanes) / (lanes,) for all;
        a bad value names its environment and body."""
        try:
            arr = floats(value)
        except (TypeError, ValueError):
            raise RbgenError(
                f"{what} must be numbers of shape ({count}, {self.bodies}, {lanes}), got "
                f"{type(value).__name__}"
            ) from None
        if arr.shape in ((lanes,), (self.bodies, lanes)):
            arr = np.broadcast_to(arr, (count, self.bodies, lanes))
        if arr.shape != (count, self.bodies, lanes):
            raise RbgenError(
                f"{what} must have shape ({count}, {self.bodies}, {lanes}) (environments, "
                f"bodies, {lanes}), got {arr.shape}"
            )
        if not np.isfinite(arr).all():
            bad = np.argwhere(~np.all(np.isfinite(arr), axis=2))
            e, j = bad[0]
            raise RbgenError(
                f"{what}: environment {int(envs[e])}, body {int(j)} has a NaN or infinite "
                f"value {arr[e, j].tolist()}"
            )
        return arr

    def reset(self, env_ids=None, state=None) -> None:
        """Restore the environments ``env_ids`` (None: all; each at most once) between
        steps: to their initial state, or to ``state``, a dict of the fields given
        (``positions``, ``orientations``, ``linear_velocities``, ``angular_velocities``:
        each (len(env_ids), bodies, k), or one (bodies, k) for them all; a field left out
        takes its initial value; orientations are normalised). Their contacts lose their
        warm start, as at the start, and forces given for them since the last step are
        dropped. Every value is checked first (errors name the environment and body) and
        nothing changes on an error.

        After a step this is done on the device (`rbgen.pipeline.reset`: one upload of
        the new records, two launches, no blocking read; it waits for the steps in flight
        to be checked, since a redone step would overwrite it); before the first step,
        or with host edits pending, on the host copy."""
        envs = self.env_ids(env_ids)
        self._check_joint_layout()
        if len(np.unique(envs)) != len(envs):
            raise RbgenError("env_ids: an environment is listed twice")
        if state is not None and not isinstance(state, Mapping):
            raise RbgenError(
                f"state must be a dict of fields ({list(FIELDS)}) to arrays, got "
                f"{type(state).__name__}"
            )
        records = self._records(envs, {} if state is None else dict(state))
        if len(envs) == 0:
            return
        world, bodies = self.world, self.world._bodies
        ids = self.body_ids(envs).reshape(-1)
        world._finish_pending()
        if world._pipeline is None or world._device is None or bodies.device_stale:
            bodies.sync_to_host()
            bodies.host[ids] = records
            bodies.device_stale = True
            affected = np.zeros(bodies.count, bool)
            affected[ids] = True
            history.forget_bodies(world.runtime, world._pipeline, affected)
            world._wake_islands(affected)
        else:
            with world._spec_log:
                if self._reset is None:
                    self._reset = EnvironmentReset(world.runtime)
                self._reset(
                    world._device.bodies,
                    records,
                    envs,
                    self.bodies,
                    self.shared,
                    self.envs,
                    world._device.static,
                    world._steps.constraints.constraints,
                )
                sleeping = world._sleep_records()
                if sleeping is not None:
                    flags = np.zeros(self.envs, np.uint32)
                    flags[envs] = 1
                    sleeping.wake_environments(world._device.static, flags)
            bodies.host_stale = True  # (the device's records are newer)
        world._forces.resize(world.body_count)
        world._forces.drop(ids)
        self._reset_joints(envs)

    def _reset_joints(self, envs: np.ndarray) -> None:
        """The joints of ``envs`` as the template had them: in the host records when they
        are newer than the device's (or the device has none yet), else by non-blocking
        writes into the device records, one for each run of consecutive environments
        (`env_runs`: a reset of all environments is one write, whatever their number).
        Environment k's joints are records ``k * joints`` to ``(k + 1) * joints`` of both
        the device records and `_joint_records` (C order), so a run's records are one
        contiguous span of each and are written from a view, without a copy."""
        if not self.joints:
            return
        store = self.world._joints
        if store.dirty or store.device is None:
            store.host[self.joint_ids(envs).reshape(-1)] = self._joint_records[envs].reshape(-1)
            store.dirty = True
            return
        queue, size = self.world.runtime.queue, store.device.dtype.itemsize
        records = self._joint_records
        writes: list = [records]  # (the source of the writes, alive until they are done)
        for first, end in env_runs(envs):
            writes.append(
                cl.enqueue_copy(
                    queue,
                    buffer_of(store.device),
                    records[first:end],
                    dst_offset=first * self.joints * size,
                    is_blocking=False,
                )
            )
        self._pending_joint_writes = writes
        store.device_newer = True  # (the host copy is older now)

    def _records(self, envs: np.ndarray, state: dict) -> np.ndarray:
        """The Body records of the environments ``envs`` after a reset to ``state``."""
        unknown = sorted(set(state) - set(FIELDS))
        if unknown:
            raise RbgenError(f"state: unknown field(s) {unknown}; fields: {list(FIELDS)}")
        if self._initial.ndim == 2:  # (each environment its own)
            records = self._initial[envs].reshape(-1)
        else:
            records = np.tile(self._initial, len(envs))
        for what in FIELDS:
            if what not in state:
                continue
            name, lanes = STATE_FIELDS[what]
            rows = self._rows(state[what], len(envs), lanes, what, envs).reshape(-1, lanes)
            if name == "orientation":
                rows = unit_quaternions(rows, len(rows), ids=self.body_ids(envs).reshape(-1))
            records[name][:, :lanes] = rows
        return records

    # ------------------------------------------------------------- forces
    def apply_forces(self, forces, torques=None, points=None, env_ids=None) -> None:
        """Forces (N) on every body of the environments ``env_ids`` (None: all) during
        the next step: ``forces`` (len(env_ids), bodies, 3); ``torques`` (N m) and
        ``points`` (world coordinates of application) likewise or None (see
        `World.apply_forces`). Checked first, naming the argument, environment and body."""
        envs = self.env_ids(env_ids)
        checked = [
            None if v is None else self._rows(v, len(envs), 3, what, envs).reshape(-1, 3)
            for v, what in ((forces, "forces"), (torques, "torques"), (points, "points"))
        ]
        if forces is None:
            raise RbgenError("forces are required (an (envs, bodies, 3) array)")
        # (checked here, so the World's forces take them as they are)
        self.world._forces.resize(self.world.body_count)
        self.world._give_forces()  # (their uploads must fit: MemoryLimitError otherwise)
        self.world._forces.accumulate(self.body_ids(envs).reshape(-1), *checked)

    # ------------------------------------------------------------- stepping
    def step(self, dt: float, substeps: int = 1) -> None:
        """Advance every environment by ``dt`` (`World.step`: no blocking read)."""
        self.world.step(dt, substeps)
