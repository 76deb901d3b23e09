"""Exceptions raised by rbgen.

`RbgenError` derives from `ValueError` so that callers who validate input with
`except ValueError` keep working; every message names the offending body,
shape, parameter or device so that a user can act on it without a debugger.
"""


class RbgenError(ValueError):
    """Bad input or an unusable configuration; the message names the culprit."""


class DeviceNotFoundError(RbgenError):
    """A device choice matched no OpenCL device; the message lists the devices."""


class TemplateParameterError(RbgenError):
    """A kernel template was given a missing, unknown or disallowed parameter."""


class KernelBuildError(RuntimeError):
    """The OpenCL compiler rejected generated source.

    The message carries the kernel spec, the compiler log and the offending
    lines of generated source with their line numbers.
    """


class MemoryLimitError(RbgenError, MemoryError):
    """A World (or a buffer's growth) would need more host or device memory than there is;
    the message names the need and the limit, and nothing was allocated."""


class CapacityOverflowError(RuntimeError):
    """A device buffer could not be grown enough to hold a result."""
