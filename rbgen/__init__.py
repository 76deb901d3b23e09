"""rbgen: a GPU rigid-body pipeline generated as OpenCL kernels.

See DESIGN.md (shared) and README.md. The user-facing names are re-exported here.
"""
from .errors import RbgenError, DeviceNotFoundError, TemplateParameterError, KernelBuildError
from .device import DeviceTraits, Runtime, list_devices, select_device
from .shapes import Box, Capsule, ConvexHull, Plane, Shape, Sphere
from .mesh import TriangleMesh, load_mesh
from .compound import Compound
from .world import World

__version__ = "0.1.0"
