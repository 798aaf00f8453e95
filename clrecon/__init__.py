"""clrecon: OpenCL reconstruction of depth of field and motion blur from stochastic samples."""
__version__ = "0.1.0"

from .camera import CocModel, ThinLensCamera
from .errors import ClreconError, DeviceError, KernelBuildError
from .pipeline import reconstruct, run
from .samples import SampleBuffer

__all__ = [
    "CocModel", "ThinLensCamera", "ClreconError", "DeviceError", "KernelBuildError",
    "SampleBuffer", "reconstruct", "run",
]
