"""Mass properties of shapes: mass, centre of mass, principal inertia and frame.

Why a module of its own: the World needs, per body, a mass, the inertia
diagonal in the body's principal frame and where that frame sits in the
user's frame. Spheres, boxes and capsules have closed forms; convex hulls use
trimesh's exact volume integrals over the closed triangle surface (divergence
theorem), and are then re-centred and rotated into their principal frame at
cooking time, so every shape's local frame *is* its principal frame.

`MassProperties.rotation` is the unit quaternion (x, y, z, w) that turns the
shape's stored (principal) frame into the frame the user gave the points in,
and `com` is the centre of mass in that user frame: a point p stored in the
shape is at ``rotate(rotation, p) + com`` in the user's frame.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .errors import RbgenError

IDENTITY_QUATERNION = (0.0, 0.0, 0.0, 1.0)


@dataclasses.dataclass(frozen=True)
class MassProperties:
    """Mass, centre of mass (user frame), principal inertia diagonal, principal rotation."""

    mass: float
    com: tuple
    inertia: tuple
    rotation: tuple = IDENTITY_QUATERNION

    @property
    def inverse_mass(self) -> float:
        return 1.0 / self.mass

    @property
    def inverse_inertia(self) -> tuple:
        return tuple(1.0 / i for i in self.inertia)


def resolve_mass(volume: float, density: float | None, mass: float | None, what: str) -> float:
    """The mass from exactly one of ``density`` and ``mass``; ``what`` names the shape."""
    if (density is None) == (mass is None):
        raise RbgenError(
            f"{what}: give exactly one of density and mass (got density={density!r}, mass={mass!r})"
        )
    given = mass if mass is not None else density
    assert given is not None  # exactly one of density and mass is None (checked above)
    value = mass if mass is not None else given * volume
    name = "mass" if mass is not None else "density"
    if not (np.isfinite(given) and given > 0):
        raise RbgenError(f"{what}: {name} must be a positive finite number, got {given!r}")
    return float(value)


def sphere_unit_inertia(radius: float) -> tuple:
    """Inertia per unit mass of a solid sphere: 2/5 r^2 on every axis."""
    i = 0.4 * radius * radius
    return (i, i, i)


def box_unit_inertia(half_extents) -> tuple:
    """Inertia per unit mass of a solid box: (b^2 + c^2) / 3 with half extents a, b, c."""
    a2, b2, c2 = (float(h) ** 2 for h in half_extents)
    return ((b2 + c2) / 3.0, (a2 + c2) / 3.0, (a2 + b2) / 3.0)


def capsule_volume(radius: float, half_height: float) -> float:
    return math.pi * radius * radius * (2.0 * half_height + 4.0 / 3.0 * radius)


def capsule_unit_inertia(radius: float, half_height: float) -> tuple:
    """Inertia per unit mass of a solid capsule along y (cylinder + two hemispheres).

    Hemisphere of mass m_h about its own centre of mass (3/8 r from the flat
    face) is 83/320 m_h r^2 across; moved to the capsule centre by the parallel
    axis theorem with distance h + 3/8 r.
    """
    r, h = float(radius), float(half_height)
    v_cyl = math.pi * r * r * 2.0 * h
    v_hemi = 2.0 / 3.0 * math.pi * r**3
    total = v_cyl + 2.0 * v_hemi
    m_cyl, m_hemi = v_cyl / total, v_hemi / total
    axial = m_cyl * r * r / 2.0 + 2.0 * m_hemi * 0.4 * r * r
    cyl_across = m_cyl * (3.0 * r * r + 4.0 * h * h) / 12.0
    d = h + 3.0 / 8.0 * r
    hemi_across = m_hemi * (83.0 / 320.0 * r * r + d * d)
    across = cyl_across + 2.0 * hemi_across
    return (across, axial, across)


def quaternion_from_matrix(rot: np.ndarray) -> tuple:
    """Unit quaternion (x, y, z, w) of a proper rotation matrix (Shepperd's method)."""
    m = np.asarray(rot, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = (0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s)
    quat = np.array(q)
    quat /= np.linalg.norm(quat)
    if quat[3] < 0:
        quat = -quat
    return tuple(float(c) for c in quat)


def principal_frame(inertia_tensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(principal moments, rotation matrix with det +1 whose columns are the axes)."""
    tensor = 0.5 * (np.asarray(inertia_tensor, np.float64) + np.asarray(inertia_tensor).T)
    off_diagonal = tensor - np.diag(np.diag(tensor))
    if np.max(np.abs(off_diagonal)) <= 1e-9 * np.trace(tensor):
        # already principal (boxes, symmetric solids): keep the user's axes rather than
        # an arbitrary basis of a repeated eigenvalue
        return np.diag(tensor).copy(), np.eye(3)
    moments, axes = np.linalg.eigh(tensor)
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return moments, axes


@dataclasses.dataclass(frozen=True)
class SolidIntegrals:
    """Volume, centroid and inertia tensor (about the centroid) of a unit-density solid."""

    volume: float
    centroid: np.ndarray
    inertia: np.ndarray


def mesh_integrals(vertices: np.ndarray, triangles: np.ndarray, what: str) -> SolidIntegrals:
    """Exact volume integrals of a closed, outward-oriented triangle surface (via trimesh)."""
    import trimesh

    mesh = trimesh.Trimesh(
        vertices=np.asarray(vertices, np.float64),
        faces=np.asarray(triangles, np.int64),
        process=False,
    )
    props = mesh.mass_properties  # density 1: mass == volume
    volume = float(props["volume"])
    if not (np.isfinite(volume) and volume > 0):
        raise RbgenError(f"{what}: enclosed volume is {volume!r}; the hull is degenerate")
    return SolidIntegrals(
        volume,
        np.asarray(props["center_mass"], np.float64),
        np.asarray(props["inertia"], np.float64),
    )
