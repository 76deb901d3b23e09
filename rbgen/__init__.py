"""rbgen: a GPU rigid-body pipeline generated as OpenCL kernels.

See DESIGN.md (shared) and README.md. The user-facing names are re-exported here.
"""

from .batch import WorldBatch
from .compound import Compound
from .device import DeviceTraits, Runtime, list_devices, select_device
from .errors import DeviceNotFoundError, KernelBuildError, RbgenError, TemplateParameterError
from .joints import BallJoint, DistanceJoint, FixedJoint, HingeJoint, SliderJoint
from .mesh import TriangleMesh, load_mesh
from .shapes import Box, Capsule, ConvexHull, Plane, Shape, Sphere
from .sweep import sweep
from .world import World

__all__ = [
    "BallJoint",
    "Box",
    "Capsule",
    "Compound",
    "ConvexHull",
    "DeviceNotFoundError",
    "DeviceTraits",
    "DistanceJoint",
    "FixedJoint",
    "HingeJoint",
    "KernelBuildError",
    "Plane",
    "RbgenError",
    "Runtime",
    "Shape",
    "SliderJoint",
    "Sphere",
    "TemplateParameterError",
    "TriangleMesh",
    "World",
    "WorldBatch",
    "list_devices",
    "load_mesh",
    "select_device",
    "sweep",
]

__version__ = "0.1.0"
