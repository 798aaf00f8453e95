"""Error families: ``ValueError``/``TypeError`` for bad input, ``ClreconError`` for the device."""
from __future__ import annotations


class ClreconError(RuntimeError):
    """Base class of errors raised by the OpenCL side of clrecon."""


class DeviceError(ClreconError):
    """No usable OpenCL device, or the requested one does not exist."""


class KernelBuildError(ClreconError):
    """An OpenCL program failed to build.

    Attributes
    ----------
    source : str
        Kernel file (or description) that was built.
    options : list of str
        Build options passed to the compiler.
    log : str
        The compiler's build log.
    """

    def __init__(self, source: str, options: list[str], log: str):
        self.source = source
        self.options = list(options)
        self.log = log
        super().__init__(
            f"failed to build {source} with options {' '.join(self.options)!r}:\n{log.strip()}"
        )


class DeviceMemoryError(ClreconError):
    """A plan needs more device memory than the device (or, for a CPU device, the process's
    address-space limit) allows; raised before anything is allocated."""
