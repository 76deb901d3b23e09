"""Pictures of rbgen scenes, headless: every shape kind, instanced, lit and shadowed.

    from rbgen.render import Camera, render_world
    render_world(world, "pile.png", camera=Camera(eye=(30, 20, 30), target=(0, 2, 0)))

Modules: `camera` (a validated pinhole camera and `Camera.fit` framing),
`meshes` (a triangle mesh per shape kind), `scene` (what is read of a World:
shapes once, transforms per frame), `renderer` (OpenGL drawing), `usd`
(OpenUSD files). Animations and files of a run: `rbgen.record`.

Why OpenGL through moderngl: a rasteriser with instancing draws thousands of
bodies in a few draw calls, and shadow mapping is a second cheap pass; moderngl
is a maintained, small binding (wheels on PyPI) that makes a context without a
display through EGL, which Mesa's llvmpipe serves on any CPU (Debian's
``libegl1 libegl-mesa0 libgl1-mesa-dri``) and a GPU's driver serves where there
is one. The alternatives weighed: pyrender (OSMesa; unmaintained since 2022,
one node per body), VTK/PyVista (a 100 MB wheel whose headless build needs
OSMesa or EGL all the same, and slower per body without glyph instancing),
Open3D's offscreen renderer (EGL too, heavier, fewer platforms), and a numpy
rasteriser (no shadows at a usable speed).
"""

from __future__ import annotations

from .camera import Camera, coerce_camera
from .meshes import Mesh, mesh_for
from .scene import Bodies, Frame, bodies_of, frame_of

__all__ = [
    "Bodies",
    "Camera",
    "Frame",
    "Mesh",
    "Renderer",
    "bodies_of",
    "coerce_camera",
    "frame_of",
    "mesh_for",
    "render_world",
]


def __getattr__(name):
    # the renderer imports moderngl only when a picture is asked for
    if name == "Renderer":
        from .renderer import Renderer

        return Renderer
    raise AttributeError(name)


def render_world(world, path, camera=None, width: int = 960, height: int = 540, samples: int = 4):
    """Write a picture (PNG, or any `rbgen.record` format as one frame) of ``world`` now.

    ``camera``: a `Camera`, a dict of its fields, or None to frame the dynamic bodies;
    ``samples``: multisamples per pixel (a still can afford smooth edges). Reads the
    World's transforms once; writes ``path`` atomically (a temporary file renamed), so a
    failure leaves no partial file. Returns the path written.
    """
    from ..record import Recorder

    with Recorder(path, camera=camera, width=width, height=height, samples=samples) as recorder:
        recorder.capture(world)
    return recorder.path
