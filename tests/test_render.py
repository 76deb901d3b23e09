"""rbgen.render: what a camera sees is where the geometry projects, for every shape kind.

The projection in these tests is written out from the pinhole model (look-at
basis, perspective divide, pixel rows from the top), independently of
`rbgen.render.camera`, so a wrong matrix in the renderer fails them.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from scipy.spatial import ConvexHull as Hull2d

from rbgen.errors import RbgenError
from rbgen.render import Bodies, Camera, Frame
from rbgen.shapes import Box, Capsule, ConvexHull, Plane, Sphere

W, H = 160, 120


@pytest.fixture(scope="module")
def renderer(headless_gl):
    from rbgen.render.renderer import Renderer

    r = Renderer(W, H, samples=0, shadows=True)
    yield r
    r.release()


def background_mask(image):
    from rbgen.render.renderer import BACKGROUND

    bg = np.round(np.asarray(BACKGROUND) * 255).astype(int)
    return np.all(np.abs(image.astype(int) - bg) <= 1, axis=-1)


def quat_matrix(q):
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def project(points, eye, target, up, fov_deg, width, height):
    """Pinhole projection to pixel coordinates (x right, y down, pixel centres at k + 0.5)."""
    eye, target, up = (np.asarray(v, float) for v in (eye, target, up))
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    rel = np.asarray(points, float) - eye
    depth = rel @ forward
    t = math.tan(math.radians(fov_deg) / 2)
    sx = (rel @ right) / depth / (t * width / height)
    sy = (rel @ true_up) / depth / t
    return np.stack([(sx + 1) / 2 * width, (1 - sy) / 2 * height], axis=1)


def polygon_mask_and_distance(polygon, width, height):
    """Which pixel centres lie inside a convex polygon, and their distance to its boundary."""
    hull = Hull2d(polygon)
    ys, xs = np.mgrid[0:height, 0:width]
    centres = np.stack([xs + 0.5, ys + 0.5], axis=-1).reshape(-1, 2)
    # hull.equations: n . p + d <= 0 inside, n unit
    signed = centres @ hull.equations[:, :2].T + hull.equations[:, 2]
    inside = np.all(signed <= 0, axis=1)
    distance = np.min(np.abs(signed), axis=1)  # (to the nearest edge line: a lower bound)
    return inside.reshape(height, width), distance.reshape(height, width)


def test_box_covers_the_pixels_its_projected_corners_bound(renderer):
    """A rotated box alone in view: the pixels it covers are those inside the convex hull of
    its eight projected corners, except within 2 pixels of that outline (edge pixels)."""
    half = np.array([1.0, 0.5, 0.75])
    angle = 0.6
    axis = np.array([0.3, 1.0, 0.2]) / np.linalg.norm([0.3, 1.0, 0.2])
    q = np.r_[axis * math.sin(angle / 2), math.cos(angle / 2)]
    centre = np.array([0.4, 0.3, -0.2])
    eye, target, up, fov = (4.0, 3.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 35.0
    bodies = Bodies.make([Box(half)], [0])
    image = renderer.render(
        bodies, Frame.make([centre], [q], 1), Camera(eye=eye, target=target, up=up, fov=fov)
    )
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half
    world = corners @ quat_matrix(q).T + centre
    inside, distance = polygon_mask_and_distance(project(world, eye, target, up, fov, W, H), W, H)
    drawn = ~background_mask(image)
    clear = distance > 2.0
    assert inside.sum() > 500  # the box is well in view
    assert np.array_equal(drawn[clear], inside[clear]), (
        f"{np.sum(drawn[clear] != inside[clear])} pixels off the outline disagree"
    )


@pytest.mark.parametrize(
    "shape",
    [
        Sphere(0.6),
        Box((0.5, 0.4, 0.3)),
        Capsule(0.3, 0.5),
        ConvexHull(np.random.default_rng(3).normal(size=(24, 3)) * 0.5),
    ],
    ids=["sphere", "box", "capsule", "hull"],
)
def test_every_shape_kind_draws_inside_its_bounding_sphere(renderer, shape):
    """Each kind covers pixels, all of them inside the projected disc of its bounding sphere."""
    eye, target, up, fov = (3.0, 2.0, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0
    image = renderer.render(
        Bodies.make([shape], [0]),
        Frame.make([[0, 0, 0]], [[0, 0, 0, 1]], 1),
        Camera(eye=eye, target=target, up=up, fov=fov),
    )
    drawn = ~background_mask(image)
    assert drawn.sum() > 200
    # the sphere's outline is within its projected radius of the projected centre (+ margin)
    r = {
        Sphere: lambda s: s.radius,
        Capsule: lambda s: s.radius + s.half_height,
        Box: lambda s: float(np.linalg.norm(s.half_extents)),
        ConvexHull: lambda s: float(np.linalg.norm(s.vertices, axis=1).max()),
    }[type(shape)](shape)
    dist = np.linalg.norm(eye)
    radius_px = math.tan(math.asin(r / dist)) / math.tan(math.radians(fov) / 2) * H / 2
    centre = project([[0, 0, 0]], eye, target, up, fov, W, H)[0]
    ys, xs = np.nonzero(drawn)
    far = np.hypot(xs + 0.5 - centre[0], ys + 0.5 - centre[1])
    assert far.max() <= radius_px * 1.15 + 2


def test_plane_fills_below_the_horizon_and_boxes_cast_shadows(renderer):
    """Looking level-ish over a ground plane: the bottom rows are ground, the top rows sky;
    a box above the ground darkens some grey ground pixels (its shadow) against no box."""
    camera = Camera(eye=(0.0, 3.0, 8.0), target=(0.0, 0.0, 0.0), fov=50.0)
    plane = Bodies.make([Plane((0, 1, 0), 0.0)], [0], static=[True])
    ground = renderer.render(plane, Frame.make([[0, 0, 0]], [[0, 0, 0, 1]], 1), camera)
    sky = background_mask(ground)
    assert not sky[-5:].any() and sky[:3].all()
    both = Bodies.make([Plane((0, 1, 0), 0.0), Box((0.5, 0.5, 0.5))], [0, 1], static=[True, False])
    with_box = renderer.render(
        both, Frame.make([[0, 0, 0], [0, 1.5, 0]], [[0, 0, 0, 1]] * 2, 2), camera
    )
    darker = with_box.astype(int).sum(-1) < ground.astype(int).sum(-1) - 60
    grey = np.ptp(with_box.astype(int), axis=-1) < 24  # ground, not the coloured box
    assert (darker & grey).sum() >= 10


def test_thousands_of_bodies_render(renderer):
    """2,000 bodies of four kinds (instanced) give an image of the requested size."""
    rng = np.random.default_rng(0)
    n = 2000
    shapes = [Box((0.3, 0.3, 0.3)), Sphere(0.3), Capsule(0.2, 0.3), Plane((0, 1, 0), 0)]
    index = np.r_[rng.integers(0, 3, n), 3]
    positions = np.c_[
        rng.uniform(-10, 10, n + 1), rng.uniform(0.3, 5, n + 1), rng.uniform(-10, 10, n + 1)
    ]
    q = rng.normal(size=(n + 1, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    positions[n], q[n] = (1.0, -0.5, 2.0), (0.0, 0.0, 0.0, 1.0)  # the ground plane
    image = renderer.render(
        Bodies.make(shapes, index, static=index == 3), Frame.make(positions, q, n + 1)
    )
    assert image.shape == (H, W, 3) and image.dtype == np.uint8
    assert (~background_mask(image)).mean() > 0.6  # bodies and the ground below the horizon


@pytest.mark.parametrize(
    "fields, named",
    [
        ({"eye": (float("nan"), 1, 1)}, "eye"),
        ({"eye": (1, 2, 3), "target": (1, 2, 3)}, "view direction is zero"),
        ({"eye": (0, 5, 0), "target": (0, 0, 0), "up": (0, 1, 0)}, "parallel"),
        ({"target": (0, float("inf"), 0)}, "target"),
        ({"fov": 0.0}, "fov"),
        ({"fov": float("nan")}, "fov"),
        ({"near": -1.0}, "near"),
    ],
)
def test_bad_camera_is_refused_naming_the_field(fields, named):
    with pytest.raises(RbgenError, match=named):
        Camera(**fields)


def test_camera_fit_keeps_the_box_in_the_picture():
    lower, upper = np.array([-3.0, 0.0, -1.0]), np.array([5.0, 2.0, 4.0])
    camera = Camera.fit(lower, upper, aspect=W / H)
    corners = np.array(
        [
            [x, y, z]
            for x in (lower[0], upper[0])
            for y in (lower[1], upper[1])
            for z in (lower[2], upper[2])
        ]
    )
    px = project(corners, camera.eye, camera.target, camera.up, camera.fov, W, H)
    assert np.all(px >= -1e-6) and np.all(px[:, 0] <= W + 1e-6) and np.all(px[:, 1] <= H + 1e-6)
    # and it is tight along one of the two axes (within the 5 % margin)
    spans = (px.max(0) - px.min(0)) / np.array([W, H])
    assert spans.max() > 0.85


def test_bad_image_size_is_refused_naming_it():
    from rbgen.render.renderer import Renderer

    with pytest.raises(RbgenError, match="width"):
        Renderer(0, 10)
    with pytest.raises(RbgenError, match="height"):
        Renderer(10, 100000)


def test_render_world_writes_a_png_of_a_world(tmp_path, headless_gl):
    """A World's picture (render_world, World.render): a PNG of the size asked, the bodies
    in view; a bad path or camera leaves nothing behind."""
    import warnings

    from PIL import Image

    import rbgen
    from rbgen.render import render_world

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        world = rbgen.World()
    world.add_static(rbgen.Plane((0, 1, 0), 0.0))
    world.add_bodies(rbgen.Box((0.5, 0.5, 0.5)), positions=[[0, 0.5, 0], [0, 1.5, 0]])
    path = render_world(world, tmp_path / "w.png", width=96, height=64)
    assert world.render(tmp_path / "m.png", width=96, height=64) == tmp_path / "m.png"
    with Image.open(path) as image:
        assert image.size == (96, 64)
        assert (~background_mask(np.asarray(image.convert("RGB")))).mean() > 0.3
    with pytest.raises(RbgenError, match="view direction is zero"):
        render_world(world, tmp_path / "v.png", camera={"eye": (1, 1, 1), "target": (1, 1, 1)})
    with pytest.raises(RbgenError, match="missing"):
        render_world(world, tmp_path / "missing" / "w.png")
    assert sorted(os.listdir(tmp_path)) == ["m.png", "w.png"]
