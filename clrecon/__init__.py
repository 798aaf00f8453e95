"""clrecon: OpenCL reconstruction of depth of field and motion blur from stochastic samples."""
__version__ = "0.1.0"

from clrecon.core.camera import CocModel, ThinLensCamera
from clrecon.core.errors import ClreconError, DeviceError, KernelBuildError
from clrecon.core.samples import SampleBuffer

__all__ = [
    "CocModel", "ThinLensCamera", "ClreconError", "DeviceError", "KernelBuildError",
    "SampleBuffer", "make_pipeline", "reconstruct", "run",
]

#: the entry points of clrecon.api, loaded on first use: ``import clrecon.tune.runtime`` (or
#: any other light module) then imports no method
_API = ("make_pipeline", "reconstruct", "run")


def __getattr__(name: str):
    if name in _API:
        from clrecon import api

        return getattr(api, name)
    raise AttributeError(f"module 'clrecon' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))
