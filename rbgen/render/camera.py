"""A pinhole camera: where it stands, what it looks at, and how it projects.

`Camera` is a small validated value (eye, target, up, vertical field of view);
the renderer asks it for the view and projection matrices of an image size.
The matrices follow OpenGL's conventions (right-handed eye space looking down
-z, clip space in [-1, 1]), so `project` maps a world point to the pixel
whose row 0 is the top of the image, as PNG files store it. `Camera.fit`
frames a box of the world from a direction, so a caller that knows nothing
about the scene still gets a useful picture.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..errors import RbgenError

#: default viewing direction of `Camera.fit` (from the target towards the eye): a
#: three-quarter view from above, which shows a pile's top and two of its sides
DEFAULT_DIRECTION = (1.0, 0.75, 1.35)


def _vector3(value, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise RbgenError(f"camera {name} must be 3 finite numbers, got {value!r}") from None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise RbgenError(f"camera {name} must be 3 finite numbers, got {value!r}")
    return arr


@dataclasses.dataclass(frozen=True)
class Camera:
    """A perspective camera at ``eye`` looking at ``target``.

    ``up`` only orients the picture (it need not be orthogonal to the view
    direction, but must not be parallel to it); ``fov`` is the vertical field
    of view in degrees, in (0, 180). ``near`` and ``far`` are the clip
    distances; None lets the renderer choose them from the scene's extent.
    Raises `RbgenError` naming the field for NaNs, a zero view direction
    (eye == target) or an ``up`` parallel to it.
    """

    eye: tuple = (10.0, 8.0, 14.0)
    target: tuple = (0.0, 0.0, 0.0)
    up: tuple = (0.0, 1.0, 0.0)
    fov: float = 40.0
    near: float | None = None
    far: float | None = None

    def __post_init__(self):
        eye, target, up = (_vector3(getattr(self, k), k) for k in ("eye", "target", "up"))
        view = target - eye
        if np.linalg.norm(view) < 1e-9:
            raise RbgenError(
                f"camera view direction is zero: eye {tuple(eye)} equals target {tuple(target)}"
            )
        if np.linalg.norm(up) < 1e-9:
            raise RbgenError("camera up must not be the zero vector")
        if np.linalg.norm(np.cross(view / np.linalg.norm(view), up / np.linalg.norm(up))) < 1e-6:
            raise RbgenError(
                f"camera up {tuple(up)} is parallel to the view direction {tuple(view)}"
            )
        fov = float(self.fov) if _is_number(self.fov) else float("nan")
        if not (0.0 < fov < 180.0):
            raise RbgenError(f"camera fov must be in (0, 180) degrees, got {self.fov!r}")
        for name in ("near", "far"):
            value = getattr(self, name)
            if value is not None and not (_is_number(value) and 0 < float(value) < math.inf):
                raise RbgenError(
                    f"camera {name} must be a positive finite number or None, got {value!r}"
                )
        if self.near is not None and self.far is not None and float(self.far) <= float(self.near):
            raise RbgenError(f"camera far ({self.far!r}) must exceed near ({self.near!r})")
        for name, value in (("eye", eye), ("target", target), ("up", up)):
            object.__setattr__(self, name, tuple(float(v) for v in value))
        object.__setattr__(self, "fov", fov)

    # ------------------------------------------------------------- framing
    @classmethod
    def fit(
        cls,
        lower,
        upper,
        direction=DEFAULT_DIRECTION,
        up=(0.0, 1.0, 0.0),
        fov: float = 40.0,
        aspect: float = 16 / 9,
        margin: float = 1.05,
    ) -> Camera:
        """A camera that sees the box [lower, upper] whole from ``direction``.

        The eye lies along ``direction`` (target to eye) from the box's centre, at the
        least distance at which all eight corners project inside an image of ``aspect``
        (width / height), times ``margin``.
        """
        lo, hi = _vector3(lower, "lower bound"), _vector3(upper, "upper bound")
        d = _vector3(direction, "direction")
        if np.linalg.norm(d) < 1e-9:
            raise RbgenError("camera direction must not be the zero vector")
        centre = (lo + hi) / 2
        d = d / np.linalg.norm(d)
        probe = cls(eye=tuple(centre + d), target=tuple(centre), up=up, fov=fov)
        right, upv, back = probe.basis()
        corners = (
            np.array(
                [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
            )
            - centre
        )
        tan_y = math.tan(math.radians(float(fov)) / 2)
        tan_x = tan_y * float(aspect)
        # the eye at distance D along ``back`` sees a corner (x, y, z) of the camera's basis
        # at depth D - z: it is inside the picture when |x| <= (D - z) tan_x, |y| likewise
        need = corners @ back + np.maximum(
            np.abs(corners @ right) / tan_x, np.abs(corners @ upv) / tan_y
        )
        distance = max(float(need.max()) * margin, 1e-3 + float((corners @ back).max()))
        eye = centre + d * distance
        return cls(eye=tuple(eye), target=tuple(centre), up=up, fov=fov)

    # ------------------------------------------------------------- matrices
    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, back) unit vectors of eye space in world coordinates."""
        eye, target = np.asarray(self.eye), np.asarray(self.target)
        back = eye - target
        back /= np.linalg.norm(back)
        right = np.cross(np.asarray(self.up), back)
        right /= np.linalg.norm(right)
        return right, np.cross(back, right), back

    def view_matrix(self) -> np.ndarray:
        """4x4 float64 world -> eye matrix (column vectors: p_eye = V @ p)."""
        right, up, back = self.basis()
        eye = np.asarray(self.eye)
        view = np.eye(4)
        view[0, :3], view[1, :3], view[2, :3] = right, up, back
        view[:3, 3] = -view[:3, :3] @ eye
        return view

    def projection_matrix(self, aspect: float, near: float, far: float) -> np.ndarray:
        """4x4 float64 OpenGL perspective matrix for ``aspect`` = width / height."""
        f = 1.0 / math.tan(math.radians(self.fov) / 2)
        proj = np.zeros((4, 4))
        proj[0, 0], proj[1, 1] = f / aspect, f
        proj[2, 2] = (far + near) / (near - far)
        proj[2, 3] = 2 * far * near / (near - far)
        proj[3, 2] = -1.0
        return proj

    def clip_range(self, lower, upper) -> tuple[float, float]:
        """(near, far) that hold the box [lower, upper], unless the camera fixes them."""
        lo, hi = np.asarray(lower, float), np.asarray(upper, float)
        corners = np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        )
        depth = -(self.view_matrix()[:3, :3] @ corners.T + self.view_matrix()[:3, 3:4])[2]
        far = float(self.far) if self.far is not None else max(float(depth.max()) * 1.01, 1e-2)
        near = (
            float(self.near)
            if self.near is not None
            else max(float(depth.min()) * 0.99, far * 1e-4)
        )
        return near, max(far, near * 1.001)

    def project(self, points, width: int, height: int) -> np.ndarray:
        """(N, 2) pixel coordinates (x right, y down, pixel centres at +0.5) of world points."""
        p = np.asarray(points, float).reshape(-1, 3)
        eye = (self.view_matrix() @ np.c_[p, np.ones(len(p))].T)[:3]
        f = 1.0 / math.tan(math.radians(self.fov) / 2)
        ndc_x = f / (width / height) * eye[0] / -eye[2]
        ndc_y = f * eye[1] / -eye[2]
        return np.stack([(ndc_x + 1) / 2 * width, (1 - ndc_y) / 2 * height], axis=1)


def _is_number(value) -> bool:
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False


def coerce_camera(camera) -> Camera | None:
    """``camera`` as a `Camera`: None (frame the scene), a Camera, or a mapping of its fields."""
    if camera is None or isinstance(camera, Camera):
        return camera
    if isinstance(camera, dict):
        unknown = set(camera) - {f.name for f in dataclasses.fields(Camera)}
        if unknown:
            raise RbgenError(f"camera: unknown field(s) {sorted(unknown)}")
        return Camera(**camera)
    raise RbgenError(
        f"camera must be an rbgen.render.Camera, a dict of its fields or None, "
        f"got {type(camera).__name__}"
    )
