"""A ragdoll of 11 bodies and 10 joints, added many at a time.

The parts (standing, y up, the pelvis centre at the origin): pelvis and torso boxes, a
head sphere, upper and lower arms and legs as capsules along y. Neighbouring parts are
2-5 cm apart and joined across the gap (joined parts do not collide; the gaps keep the
limbs apart from the torso and each other, which do): ball joints at the spine, neck,
shoulders and hips; hinges with limits at the elbows and knees. Total mass 56 kg,
height 1.8 m.

`add_ragdolls` adds N ragdolls with one `World.add_bodies` call per part and one
`World.add_joints` call per joint kind, so thousands cost a few numpy operations.
"""

from __future__ import annotations

import numpy as np

from .joints import BallJoint, HingeJoint
from .shapes import Box, Capsule, Sphere

#: (name, shape, mass kg, centre relative to the pelvis)
PARTS = (
    ("pelvis", Box((0.15, 0.1, 0.1)), 6.0, (0.0, 0.0, 0.0)),
    ("torso", Box((0.17, 0.2, 0.1)), 10.0, (0.0, 0.35, 0.0)),
    ("head", Sphere(0.1), 4.0, (0.0, 0.7, 0.0)),
    ("upper_arm_l", Capsule(0.05, 0.1), 2.0, (-0.25, 0.37, 0.0)),
    ("upper_arm_r", Capsule(0.05, 0.1), 2.0, (0.25, 0.37, 0.0)),
    ("lower_arm_l", Capsule(0.045, 0.1), 1.5, (-0.25, 0.045, 0.0)),
    ("lower_arm_r", Capsule(0.045, 0.1), 1.5, (0.25, 0.045, 0.0)),
    ("thigh_l", Capsule(0.07, 0.15), 7.0, (-0.09, -0.35, 0.0)),
    ("thigh_r", Capsule(0.07, 0.15), 7.0, (0.09, -0.35, 0.0)),
    ("shin_l", Capsule(0.06, 0.15), 4.0, (-0.09, -0.8, 0.0)),
    ("shin_r", Capsule(0.06, 0.15), 4.0, (0.09, -0.8, 0.0)),
)
PART_INDEX = {name: i for i, (name, *_) in enumerate(PARTS)}

#: (kind, part a, part b, anchor relative to the pelvis, hinge axis, hinge limits,
#: friction torque N m): a is the outer part, b the one nearer the pelvis (hinge angles:
#: a relative to b). Friction (a ball joint's friction, a hinge's motor at speed 0)
#: stops what contacts alone never stop: a limb or the head spinning in place about a
#: ball joint, rolling on the ground.
JOINTS = (
    (BallJoint, "torso", "pelvis", (0.0, 0.125, 0.0), None, None, 5.0),
    (BallJoint, "head", "torso", (0.0, 0.575, 0.0), None, None, 1.0),
    (BallJoint, "upper_arm_l", "torso", (-0.22, 0.52, 0.0), None, None, 1.0),
    (BallJoint, "upper_arm_r", "torso", (0.22, 0.52, 0.0), None, None, 1.0),
    (HingeJoint, "lower_arm_l", "upper_arm_l", (-0.25, 0.2075, 0.0), (1, 0, 0), (-2.0, 0.0), 0.5),
    (HingeJoint, "lower_arm_r", "upper_arm_r", (0.25, 0.2075, 0.0), (1, 0, 0), (-2.0, 0.0), 0.5),
    (BallJoint, "thigh_l", "pelvis", (-0.09, -0.115, 0.0), None, None, 3.0),
    (BallJoint, "thigh_r", "pelvis", (0.09, -0.115, 0.0), None, None, 3.0),
    (HingeJoint, "shin_l", "thigh_l", (-0.09, -0.58, 0.0), (1, 0, 0), (0.0, 2.0), 1.0),
    (HingeJoint, "shin_r", "thigh_r", (0.09, -0.58, 0.0), (1, 0, 0), (0.0, 2.0), 1.0),
)
BODIES_PER_RAGDOLL = len(PARTS)
JOINTS_PER_RAGDOLL = len(JOINTS)
#: from the pelvis centre down to the soles, and up to the top of the head
BELOW_PELVIS, ABOVE_PELVIS = 1.01, 0.8


def add_ragdolls(
    world, origins, friction: float = 0.6, joints: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Add a standing ragdoll with its pelvis at each of ``origins`` ((N, 3)); returns
    (body ids (N, 11) in `PARTS` order, joint ids (N, 10) in `JOINTS` order).
    ``joints=False``: the parts alone (no joint ids: an (N, 0) array)."""
    origins = np.asarray(origins, float).reshape(-1, 3)
    n = len(origins)
    bodies = np.zeros((n, BODIES_PER_RAGDOLL), np.int64)
    for i, (_, shape, mass, offset) in enumerate(PARTS):
        bodies[:, i] = world.add_bodies(
            shape, mass=mass, positions=origins + offset, friction=friction
        )
    made = np.zeros((n, JOINTS_PER_RAGDOLL if joints else 0), np.int64)
    for k, (kind, a, b, anchor, axis, limits, torque) in enumerate(JOINTS if joints else ()):
        fields: dict = {
            "a": bodies[:, PART_INDEX[a]],
            "b": bodies[:, PART_INDEX[b]],
            "anchor": origins + anchor,
        }
        if kind is HingeJoint:
            fields.update(axis=axis, limits=limits, motor=(0.0, torque))
        else:
            fields.update(friction=torque)
        made[:, k] = world.add_joints(kind, **fields)
    return bodies, made
