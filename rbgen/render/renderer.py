"""Draw a frame of bodies into an RGB image with OpenGL, without a display.

`Renderer` owns an OpenGL context made through EGL (Mesa's llvmpipe on a
machine without a GPU, the vendor's driver where there is one), the shader
programs, and one instanced draw per distinct shape: every body of a shape
is one instance of that shape's mesh (`rbgen.render.meshes`), so thousands of
bodies cost a handful of draw calls. A frame is two passes: depth from the
sun into a shadow map fitted to the dynamic bodies, then colour with
percentage-closer filtered shadows, a hemisphere ambient and multisampling.
Why OpenGL through moderngl: see `rbgen.render`.
"""

from __future__ import annotations

import math
from importlib import resources

import numpy as np

from ..errors import RbgenError
from ..shapes import Plane
from .camera import Camera
from .meshes import mesh_for
from .scene import Bodies, Frame, rotate, scene_bounds

#: background colour (sRGB, 0-1): a light sky grey that boxes of every palette colour stand out on
BACKGROUND = (0.86, 0.89, 0.93)
#: direction towards the sun, before normalisation (y is up): high and from one side,
#: so a box's top and one side are lit and the other side reads as shade
SUN = (-0.45, 1.0, 0.3)
#: shadow-map size (texels a side; each lookup filters 2 x 2 texels four times): a
#: box of a 40 x 40 pile spans ~12 texels
SHADOW_SIZE = 1024
#: multisamples per pixel; none by default, as llvmpipe shades every sample (stills
#: for documents ask for 4)
SAMPLES = 0
#: bytes of one instance: position (3 floats), quaternion (4), colour with static flag (4)
_INSTANCE_FLOATS = 11

_CONTEXT = None


def gl_context():
    """This process's headless OpenGL context (made once; EGL first)."""
    global _CONTEXT
    if _CONTEXT is None:
        try:
            import moderngl
        except ImportError as err:
            raise RbgenError(f"rendering needs moderngl ({err}); pip install moderngl") from None
        errors = []
        for backend in ("egl", None):
            try:
                kwargs = {"backend": backend} if backend else {}
                _CONTEXT = moderngl.create_standalone_context(require=330, **kwargs)
                break
            except Exception as err:  # noqa: BLE001 - try the next backend, report all
                errors.append(f"{backend or 'default'}: {err}")
        else:
            raise RbgenError(
                "no headless OpenGL context could be made ("
                + "; ".join(errors)
                + "). On Debian/Ubuntu: apt-get install libegl1 libegl-mesa0 "
                "libgl1-mesa-dri (Mesa's EGL and its llvmpipe CPU renderer)"
            )
    return _CONTEXT


def _shader(name: str) -> str:
    return resources.files("rbgen.render").joinpath("shaders").joinpath(name).read_text()


def _program(ctx, vertex: str, fragment: str):
    common = _shader("common.glsl")
    return ctx.program(
        vertex_shader="#version 330\n" + common + _shader(vertex),
        fragment_shader="#version 330\n" + _shader(fragment),
    )


class Renderer:
    """Renders `Frame`s of `Bodies` to (height, width, 3) uint8 sRGB images.

    ``width`` and ``height`` in pixels (1 to 8192); ``samples`` multisamples (0 or 1:
    none); ``shadows`` toggles the shadow pass. One Renderer can draw frames of
    any bodies; meshes are built once per shape (planes once per size of scene).
    """

    def __init__(
        self,
        width: int = 640,
        height: int = 360,
        samples: int = SAMPLES,
        shadows: bool = True,
        shadow_size: int = SHADOW_SIZE,
    ):
        for name, value in (("width", width), ("height", height)):
            if not isinstance(value, (int, np.integer)) or not 1 <= value <= 8192:
                raise RbgenError(f"image {name} must be an integer in [1, 8192], got {value!r}")
        if not isinstance(samples, (int, np.integer)) or samples < 0 or samples > 16:
            raise RbgenError(f"samples must be an integer in [0, 16], got {samples!r}")
        self.width, self.height = int(width), int(height)
        self.shadows = bool(shadows)
        ctx = self.ctx = gl_context()
        samples = min(int(samples), ctx.max_samples) if samples > 1 else 0
        size = (self.width, self.height)
        self._msaa = ctx.framebuffer(
            ctx.renderbuffer(size, 4, samples=samples),
            ctx.depth_renderbuffer(size, samples=samples),
        )
        self._resolved = ctx.framebuffer(ctx.renderbuffer(size, 4)) if samples else self._msaa
        self._shadow_tex = ctx.depth_texture((shadow_size, shadow_size))
        self._shadow_tex.compare_func = "<="
        self._shadow_tex.filter = (ctx.LINEAR, ctx.LINEAR)  # each tap a 2 x 2 filtered compare
        self._shadow_tex.repeat_x = self._shadow_tex.repeat_y = False
        self._shadow_fbo = ctx.framebuffer(depth_attachment=self._shadow_tex)
        self._shade = _program(ctx, "shade.vert", "shade.frag")
        self._depth = _program(ctx, "shadow.vert", "shadow.frag")
        self._meshes: dict = {}  # shape key (planes: with size) -> buffers, vertex arrays

    # ------------------------------------------------------------- drawing
    def render(self, bodies: Bodies, frame: Frame, camera: Camera | None = None) -> np.ndarray:
        """The image of ``frame`` seen by ``camera`` (None: `Camera.fit` to the dynamic
        bodies, or all bodies when none moves)."""
        if frame.positions.shape[0] != bodies.count:
            raise RbgenError(
                f"frame has {frame.positions.shape[0]} bodies, bodies has {bodies.count}"
            )
        bounds = scene_bounds(bodies, frame, dynamic_only=True) or scene_bounds(bodies, frame)
        if bounds is None:
            bounds = (np.full(3, -1.0), np.full(3, 1.0))
        lower, upper = bounds
        if camera is None:
            camera = Camera.fit(lower, upper, aspect=self.width / self.height)
        everything = scene_bounds(bodies, frame) or bounds
        plane_size, plane_centre = self._plane_extent(lower, upper, camera)
        groups = self._groups(bodies, frame, plane_size, plane_centre)
        all_lower = np.minimum(everything[0], plane_centre - plane_size)
        all_upper = np.maximum(everything[1], plane_centre + plane_size)
        near, far = camera.clip_range(all_lower, all_upper)
        near = max(near, far * 1e-4)
        view_proj = (
            camera.projection_matrix(self.width / self.height, near, far) @ camera.view_matrix()
        )
        light_dir = np.asarray(SUN, float) / np.linalg.norm(SUN)
        light_view_proj, texel = _light_matrix(light_dir, lower, upper, self._shadow_tex.size[0])

        ctx = self.ctx
        ctx.enable(ctx.DEPTH_TEST | ctx.CULL_FACE)  # meshes are closed; a plane is seen from above
        if self.shadows:
            self._shadow_fbo.use()
            self._shadow_fbo.clear(depth=1.0)
            ctx.polygon_offset = (2.0, 4.0)
            self._depth["light_view_proj"].write(_gl(light_view_proj))
            for vao, _count, instances in groups:
                if instances:
                    vao["depth"].render(instances=instances)
            ctx.polygon_offset = (0.0, 0.0)
        self._msaa.use()
        self._msaa.clear(*BACKGROUND, 1.0, depth=1.0)
        shade = self._shade
        shade["view_proj"].write(_gl(view_proj))
        shade["light_view_proj"].write(_gl(light_view_proj))
        shade["light_dir"].value = tuple(light_dir)
        shade["up"].value = tuple(np.asarray(camera.up) / np.linalg.norm(camera.up))
        shade["eye"].value = tuple(camera.eye)
        shade["shadow_texel"].value = float(texel)
        shade["shadows"].value = int(self.shadows)
        self._shadow_tex.use(location=0)
        shade["shadow_map"].value = 0
        for vao, _count, instances in groups:
            if instances:
                vao["shade"].render(instances=instances)
        if self._resolved is not self._msaa:
            ctx.copy_framebuffer(self._resolved, self._msaa)
        data = self._resolved.read(components=3, alignment=1)
        image = np.frombuffer(data, np.uint8).reshape(self.height, self.width, 3)
        return image[::-1].copy()

    def _plane_extent(self, lower, upper, camera):
        """Half size and centre of the square that stands for a plane: well past what
        the camera sees around the bodies."""
        centre = (lower + upper) / 2
        reach = float(np.linalg.norm(upper - lower)) + float(
            np.linalg.norm(np.asarray(camera.eye) - centre)
        )
        return 4.0 * reach + 10.0, centre

    def _groups(self, bodies: Bodies, frame: Frame, plane_size: float, plane_centre):
        """[(vertex arrays by pass, index count, instances)] for one frame; each shape's
        instances (position, rotation, colour and static flag) go into its own buffer."""
        data = np.empty((bodies.count, _INSTANCE_FLOATS), np.float32)
        data[:, 0:3] = frame.positions
        data[:, 3:7] = frame.orientations
        data[:, 7:10] = bodies.colours
        data[:, 10] = ~bodies.static
        order = np.argsort(bodies.shape_index, kind="stable")
        data = data[order]
        counts = np.bincount(bodies.shape_index, minlength=len(bodies.shapes))
        starts = np.concatenate([[0], np.cumsum(counts)])
        groups = []
        # dynamic shapes first: the ground drawn last loses its hidden fragments to the depth test
        for k in sorted(
            range(len(bodies.shapes)),
            key=lambda k: bool(bodies.static[bodies.shape_index == k].all()),
        ):
            count = int(counts[k])
            if count:
                centre = plane_centre
                if isinstance(bodies.shapes[k], Plane):
                    # the square's centre in the plane body's frame (of its first body: a
                    # World has one body per plane)
                    first = order[starts[k]]
                    q = frame.orientations[first].astype(float)
                    conjugate = np.r_[-q[:3], q[3]]
                    centre = rotate(conjugate, np.asarray(plane_centre) - frame.positions[first])
                entry = self._mesh(bodies.shapes[k], plane_size, centre)
                chunk = data[starts[k] : starts[k] + count]
                if entry["instances"].size < chunk.nbytes:
                    entry["instances"].orphan(max(chunk.nbytes, 2 * entry["instances"].size))
                entry["instances"].write(chunk.tobytes())
                groups.append((entry["vaos"], entry["indices"], count))
        return groups

    def _mesh(self, shape, plane_size, plane_centre) -> dict:
        """A shape's mesh buffers, instance buffer and vertex arrays (made once)."""
        mesh_args: tuple[float, np.ndarray] | tuple[()]
        if isinstance(shape, Plane):
            # a plane's square follows the scene; quantised so a settling scene reuses it
            size = 2.0 ** math.ceil(math.log2(plane_size))
            centre = np.round(np.asarray(plane_centre) / (size / 8)) * (size / 8)
            key = (shape.key(), size, tuple(centre))
            mesh_args = (size, centre)
        else:
            key, mesh_args = shape.key(), ()
        entry = self._meshes.get(key)
        if entry is None:
            mesh = mesh_for(shape, *mesh_args)
            ctx = self.ctx
            interleaved = np.hstack([mesh.vertices, mesh.normals]).astype(np.float32)
            vbo, ibo = ctx.buffer(interleaved.tobytes()), ctx.buffer(mesh.triangles.tobytes())
            inst = ctx.buffer(reserve=_INSTANCE_FLOATS * 4 * 64, dynamic=True)
            vaos = {
                "shade": ctx.vertex_array(
                    self._shade,
                    [
                        (vbo, "3f 3f", "in_vert", "in_norm"),
                        (inst, "3f 4f 4f/i", "in_pos", "in_rot", "in_color"),
                    ],
                    index_buffer=ibo,
                    index_element_size=4,
                ),
                "depth": ctx.vertex_array(
                    self._depth,
                    [(vbo, "3f 3x4", "in_vert"), (inst, "3f 4f 4x4/i", "in_pos", "in_rot")],
                    index_buffer=ibo,
                    index_element_size=4,
                ),
            }
            entry = {
                "buffers": (vbo, ibo, inst),
                "instances": inst,
                "vaos": vaos,
                "indices": mesh.triangles.size,
            }
            self._meshes[key] = entry
        return entry

    def release(self) -> None:
        """Free this renderer's GL objects (the context stays for the next renderer)."""
        for entry in self._meshes.values():
            for vao in entry["vaos"].values():
                vao.release()
            for buffer in entry["buffers"]:
                buffer.release()
        self._meshes.clear()
        for obj in (
            self._shadow_fbo,
            self._shadow_tex,
            self._msaa,
            self._resolved,
            self._shade,
            self._depth,
        ):
            obj.release()


def _gl(matrix: np.ndarray) -> bytes:
    """A row-major numpy matrix as the column-major float32 bytes GLSL expects."""
    return np.ascontiguousarray(matrix.T, np.float32).tobytes()


def _light_matrix(light_dir, lower, upper, size):
    """The sun's orthographic view-projection around the box [lower, upper], and the world
    size of one shadow texel."""
    centre = (np.asarray(lower) + np.asarray(upper)) / 2
    radius = max(float(np.linalg.norm(np.asarray(upper) - np.asarray(lower))) / 2, 1e-3) * 1.05
    back = light_dir
    helper = np.array([0.0, 0.0, 1.0]) if abs(back[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    right = np.cross(helper, back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    eye = centre + back * 2 * radius
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = right, up, back
    view[:3, 3] = -view[:3, :3] @ eye
    # casters lie within the sphere about the bodies; receivers (a ground) may lie far beyond
    near, far = radius * 0.5, radius * 12.0 + 100.0
    proj = np.diag([1 / radius, 1 / radius, -2 / (far - near), 1.0])
    proj[2, 3] = -(far + near) / (far - near)
    return proj @ view, 2 * radius / size
