"""OpenUSD files of a run: each shape a mesh, each body a prim with time-sampled transforms.

Layout of a stage (Y up, metres, ``timeCodesPerSecond`` = the recording's fps,
frames at time codes 0, 1, 2, ...):

    /World                          Xform, the default prim
    /World/Shapes/<kind>_<k>        Mesh of shape k (rbgen.render.meshes), invisible
    /World/Bodies/body_<i>          Xform: xformOp:translate (double3) and
                                    xformOp:orient (quatf), time-sampled for a
                                    moving body, default values for a static one;
                                    primvars:displayColor; references its shape

Bodies reference their shape's mesh rather than copying it, so a file of 8,000
boxes holds one box. usdview, Blender and Omniverse read it as is. Needs the
``usd-core`` package (module ``pxr``).
"""

from __future__ import annotations

import numpy as np

from ..errors import RbgenError
from ..shapes import Box, Capsule, ConvexHull, Plane, Sphere
from .meshes import mesh_for
from .scene import Bodies, Frame, scene_bounds

#: prim names of the shape kinds
KIND_NAMES = {Box: "box", Sphere: "sphere", Capsule: "capsule", ConvexHull: "hull", Plane: "plane"}


def _pxr():
    try:
        from pxr import Gf, Sdf, Usd, UsdGeom, Vt
    except ImportError:
        raise RbgenError(
            "writing .usd needs OpenUSD's Python module: pip install usd-core "
            "(or pip install 'rbgen[usd]')"
        ) from None
    return Gf, Sdf, Usd, UsdGeom, Vt


def body_path(index: int) -> str:
    """The prim path of body ``index``."""
    return f"/World/Bodies/body_{index:06d}"


class UsdSink:
    """Frames into a USD stage at ``temp``; the stage is written at `finish`."""

    def __init__(self, temp: str, fps: float):
        self.temp, self.fps = temp, fps
        self._frames: list[Frame] = []
        self._bodies: Bodies | None = None
        _pxr()  # fail at the start of a run, not at its end

    def add(self, frame: Frame, bodies: Bodies) -> None:
        if self._bodies is not None and bodies.count != self._bodies.count:
            raise RbgenError(
                f"a USD recording keeps one set of bodies: {self._bodies.count} "
                f"at the first frame, {bodies.count} now"
            )
        self._bodies = bodies
        self._frames.append(Frame(frame.positions.copy(), frame.orientations.copy()))

    def finish(self) -> None:
        assert self._bodies is not None  # set by the first frame; Recorder.close needs one
        write_stage(self.temp, self._bodies, self._frames, self.fps)

    def cancel(self) -> None:
        self._frames.clear()


def write_stage(path: str, bodies: Bodies, frames: list, fps: float) -> None:
    """Write ``frames`` of ``bodies`` as a USD stage at ``path`` (see the module docstring)."""
    Gf, Sdf, Usd, UsdGeom, Vt = _pxr()
    stage = Usd.Stage.CreateNew(path)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(max(0, len(frames) - 1))
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    UsdGeom.Scope.Define(stage, "/World/Shapes")
    UsdGeom.Scope.Define(stage, "/World/Bodies")

    bounds = scene_bounds(bodies, frames[0]) or (np.full(3, -1.0), np.full(3, 1.0))
    plane_size = 2.0 * float(np.linalg.norm(bounds[1] - bounds[0])) + 20.0
    shape_paths = []
    for k, shape in enumerate(bodies.shapes):
        path_k = f"/World/Shapes/{KIND_NAMES.get(type(shape), 'shape')}_{k}"
        mesh = mesh_for(shape, plane_size, (bounds[0] + bounds[1]) / 2)
        prim = UsdGeom.Mesh.Define(stage, path_k)
        prim.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(mesh.vertices))
        prim.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(mesh.normals))
        prim.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        prim.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(mesh.triangles)))
        prim.CreateFaceVertexIndicesAttr(
            Vt.IntArray.FromNumpy(mesh.triangles.reshape(-1).astype(np.int32))
        )
        prim.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        prim.CreateVisibilityAttr(UsdGeom.Tokens.invisible)  # the bodies show it
        shape_paths.append(path_k)

    moving = np.ones(bodies.count, bool) if len(frames) > 1 else np.zeros(bodies.count, bool)
    moving &= ~bodies.static
    positions = np.stack([f.positions for f in frames]).astype(np.float64)  # (F, N, 3)
    orientations = np.stack([f.orientations for f in frames]).astype(np.float64)  # (F, N, 4)
    for i in range(bodies.count):
        xform = UsdGeom.Xform.Define(stage, body_path(i))
        prim = xform.GetPrim()
        child = stage.DefinePrim(body_path(i) + "/geometry")
        child.GetReferences().AddInternalReference(shape_paths[bodies.shape_index[i]])
        UsdGeom.Imageable(child).CreateVisibilityAttr(UsdGeom.Tokens.inherited)
        UsdGeom.PrimvarsAPI(prim).CreatePrimvar(
            "displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.constant
        ).Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, bodies.colours[i]))]))
        translate = xform.AddTranslateOp()
        orient = xform.AddOrientOp()
        if moving[i]:
            for t in range(len(frames)):
                translate.Set(Gf.Vec3d(*positions[t, i]), t)
                x, y, z, w = orientations[t, i]
                orient.Set(Gf.Quatf(float(w), float(x), float(y), float(z)), t)
        else:
            translate.Set(Gf.Vec3d(*positions[0, i]))
            x, y, z, w = orientations[0, i]
            orient.Set(Gf.Quatf(float(w), float(x), float(y), float(z)))
    stage.GetRootLayer().Save()
