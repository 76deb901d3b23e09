"""Data-parallel primitives on device arrays.

Scan, radix sort, stream compaction, fill, reduce and bound search. Each is a
class built once for a runtime (and dtype/options) and called on pyopencl
arrays; element counts may be host ints or device uint32 counts, so a
pipeline can chain them without reading sizes back. Every class accepts
``params=`` to override the tuned or heuristic kernel parameters.
"""

from .bound_search import BoundSearch
from .compact import Compact
from .fill import Fill
from .radix_sort import RadixSort, float_to_sortable_uint, sortable_uint_to_float
from .reduce import Reduce
from .scan import Scan

__all__ = [
    "BoundSearch",
    "Compact",
    "Fill",
    "RadixSort",
    "Reduce",
    "Scan",
    "float_to_sortable_uint",
    "sortable_uint_to_float",
]
from . import families  # noqa: F401 - importing it registers the tuning families
