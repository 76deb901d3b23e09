"""Data-parallel primitives on device arrays: scan, radix sort, compaction,
fill, reduce and bound search. Each is a class built once for a runtime (and
dtype) and called on pyopencl arrays; counts may live on the device."""
from .scan import Scan
from .radix_sort import RadixSort, float_to_sortable_uint, sortable_uint_to_float
