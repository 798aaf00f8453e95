"""clrecon: OpenCL reconstruction of depth of field and motion blur from stochastic samples."""
__version__ = "0.1.0"

from clrecon.api import make_pipeline, reconstruct, run
from clrecon.core.camera import CocModel, ThinLensCamera
from clrecon.core.errors import ClreconError, DeviceError, KernelBuildError
from clrecon.core.samples import SampleBuffer

__all__ = [
    "CocModel", "ThinLensCamera", "ClreconError", "DeviceError", "KernelBuildError",
    "SampleBuffer", "make_pipeline", "reconstruct", "run",
]
