"""The sample buffer: one frame of stochastic samples as a structure of float32 arrays.

Field layout (``S`` samples per pixel, sample ``(py, px, i)``):

========== ============== ==============================================================
field      shape          meaning
========== ============== ==============================================================
color      (H, W, S, 3)   linear radiance (HDR values far above 1 are normal), <= 1e30
position   (H, W, S, 2)   sensor position in pixels (x right, y down), inside its pixel
depth      (H, W, S)      camera-space depth ``w >= 1e-20``; ``inf`` (or >= 1e30): a miss
lens       (H, W, S, 2)   lens coordinates ``(u, v)`` in the unit disk
time       (H, W, S)      shutter time in [0, 1]
motion     (H, W, S, 2)   pinhole screen displacement (pixels) from t=0 to t=1
========== ============== ==============================================================

The thin-lens model is :class:`clrecon.core.camera.CocModel`; the centre of a sample (its
reprojection to ``(u, v, t) = (0, 0, 0.5)``) is
``position - coc(depth) * lens - (time - 0.5) * motion``.

Value bounds: :mod:`clrecon.core.limits` (checked by :meth:`SampleBuffer.validate` on
the host, :mod:`clrecon.core.validate`, and by :mod:`clrecon.core.inspect` on the device,
same rules and messages).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# the frame's description, value limits and validation rules live in their own modules; they
# are re-exported here, where the frame is (``X as X``: an explicit re-export)
from clrecon.core.camera import CocModel
from clrecon.core.frame_info import FrameInfo as FrameInfo
from clrecon.core.frame_info import inspect_arrays, inspect_blocks
from clrecon.core.limits import C0_MAX as C0_MAX
from clrecon.core.limits import COC_MAX as COC_MAX
from clrecon.core.limits import COLOR_MAX as COLOR_MAX
from clrecon.core.limits import LENS_TOLERANCE as LENS_TOLERANCE
from clrecon.core.limits import MIN_DEPTH as MIN_DEPTH
from clrecon.core.limits import MISS_DEPTH as MISS_DEPTH
from clrecon.core.limits import MOTION_MAX as MOTION_MAX
from clrecon.core.limits import POSITION_TOLERANCE as POSITION_TOLERANCE
from clrecon.core.validate import RULE_NAMES as RULE_NAMES
from clrecon.core.validate import bad_sample_message as bad_sample_message
from clrecon.core.validate import check_values
from clrecon.core.validate import coc_min_depth as coc_min_depth
from clrecon.core.validate import coc_model_error as coc_model_error
from clrecon.core.validate import rule_text as rule_text

#: field name -> trailing shape after (H, W, S)
FIELDS: dict[str, tuple[int, ...]] = {
    "color": (3,),
    "position": (2,),
    "depth": (),
    "lens": (2,),
    "time": (),
    "motion": (2,),
}


@dataclass(eq=False)
class SampleBuffer:
    """One frame of samples; see the module docstring for the fields.

    Arrays are converted to C-contiguous float32 on construction; shapes are checked by
    :meth:`validate` (called by every consumer at its boundary), not here, so that a
    loader can build a buffer and report every problem through one path.
    """

    color: np.ndarray
    position: np.ndarray
    depth: np.ndarray
    lens: np.ndarray
    time: np.ndarray
    motion: np.ndarray
    coc_model: CocModel = field(default_factory=CocModel)

    def __post_init__(self):
        for name in FIELDS:
            setattr(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.float32))
        if not isinstance(self.coc_model, CocModel):
            raise TypeError(f"coc_model must be a CocModel, got {type(self.coc_model).__name__}")

    # -- shape -----------------------------------------------------------------------------
    @property
    def height(self) -> int:
        return self.depth.shape[0]

    @property
    def width(self) -> int:
        return self.depth.shape[1]

    @property
    def spp(self) -> int:
        return self.depth.shape[2]

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(H, W, S)``."""
        return tuple(self.depth.shape)

    @property
    def nbytes(self) -> int:
        return sum(getattr(self, n).nbytes for n in FIELDS)

    def arrays(self) -> dict[str, np.ndarray]:
        return {n: getattr(self, n) for n in FIELDS}

    # -- constructors ----------------------------------------------------------------------
    @classmethod
    def zeros(cls, height: int, width: int, spp: int, coc_model: CocModel | None = None):
        """A buffer of the given shape, samples at pixel centres, lens 0, time 0.5, depth 1."""
        hws = (height, width, spp)
        buf = cls(
            color=np.zeros(hws + (3,), np.float32),
            position=pixel_centres(height, width, spp),
            depth=np.ones(hws, np.float32),
            lens=np.zeros(hws + (2,), np.float32),
            time=np.full(hws, 0.5, np.float32),
            motion=np.zeros(hws + (2,), np.float32),
            coc_model=coc_model or CocModel(),
        )
        return buf

    @classmethod
    def pinhole(cls, color, depth, motion=None, coc_model: CocModel | None = None):
        """Synthesis input from a pinhole frame: S = 1, lens 0, time 0.5, pixel centres.

        ``color`` is (H, W, 3), ``depth`` (H, W), ``motion`` (H, W, 2) or None.
        """
        color = np.asarray(color, np.float32)
        if color.ndim != 3 or color.shape[2] != 3:
            raise ValueError(f"color: expected shape (H, W, 3), got {color.shape}")
        h, w = color.shape[:2]
        buf = cls.zeros(h, w, 1, coc_model)
        buf.color[:] = color[:, :, None, :]
        buf.depth[:] = np.asarray(depth, np.float32).reshape(h, w, 1)
        if motion is not None:
            buf.motion[:] = np.asarray(motion, np.float32).reshape(h, w, 1, 2)
        return buf

    # -- convention ------------------------------------------------------------------------
    def coc(self) -> np.ndarray:
        """Signed CoC radius of every sample, pixels, (H, W, S)."""
        return self.coc_model.coc(self.depth)

    def centre(self) -> np.ndarray:
        """Each sample reprojected to ``(u, v, t) = (0, 0, 0.5)``: (H, W, S, 2) pixels.

        Misses (depth >= MISS_DEPTH) have ``coc = C1``; their centre is still defined.
        """
        coc = self.coc()[..., None]
        shutter = (self.time[..., None] - 0.5) * self.motion
        return (self.position - coc * self.lens - shutter).astype(np.float32)

    def inspect(self) -> FrameInfo:
        """One pass over the frame: the facts that decide which terms a kernel needs.

        Scans the frame in blocks that stay in cache; a frame the block scan does not cover
        (not validated: non-positive or NaN depths, another layout, a subclassed or
        non-finite CoC model) is described by the plain whole-array formulas instead, with
        the same results.
        """
        with np.errstate(over="ignore", invalid="ignore"):  # float32 squares may overflow
            info = inspect_blocks(self)
        return info if info is not None else inspect_arrays(self)

    # -- validation ------------------------------------------------------------------------
    def check_layout(self, fields=None) -> SampleBuffer:
        """Check what the kernels read of memory, without looking at values: each field of
        ``fields`` (default: all) is a C-contiguous float32 array of the frame's shape.
        Raises ``ValueError`` naming the field. Cheap: the values are checked by
        :meth:`validate` on the host or by the device inspection pass."""
        if not isinstance(self.depth, np.ndarray) or self.depth.ndim != 3:
            raise ValueError(f"depth: expected shape (H, W, S), got "
                             f"{getattr(self.depth, 'shape', type(self.depth).__name__)}")
        hws = self.depth.shape
        if min(hws) < 1:
            raise ValueError(f"depth: empty frame of shape {hws}")
        for name in fields or FIELDS:
            arr = getattr(self, name)
            if not isinstance(arr, np.ndarray):
                raise ValueError(f"{name}: expected a numpy array, got {type(arr).__name__}")
            if arr.dtype != np.float32:
                raise ValueError(f"{name}: expected float32, got {arr.dtype}")
            if arr.shape != hws + FIELDS[name]:
                raise ValueError(f"{name}: expected shape {hws + FIELDS[name]}, got {arr.shape}")
            if not arr.flags.c_contiguous:
                raise ValueError(f"{name}: expected a C-contiguous array")
        return self

    def validate(self, allow_negative: bool = False) -> SampleBuffer:
        """Check layout (:meth:`check_layout`) and value ranges (module docstring); raise
        ``ValueError`` naming the field and, for a value, the first bad sample in C order
        and the number of bad samples.

        Order: the rules of depth, color, motion, time, lens and position, then the
        ``coc_model`` coefficients, then each hit's CoC (rule ``coc``). Negative colours
        are refused unless ``allow_negative``. Returns ``self`` so that
        ``buf.validate()`` can be used inline.
        """
        self.check_layout()
        with np.errstate(over="ignore", invalid="ignore"):  # float32 squares may overflow
            check_values(self, bool(allow_negative))
        return self


def pixel_centres(height: int, width: int, spp: int) -> np.ndarray:
    """Positions at pixel centres, (H, W, S, 2)."""
    ys, xs = np.meshgrid(np.arange(height, dtype=np.float32) + 0.5,
                         np.arange(width, dtype=np.float32) + 0.5, indexing="ij")
    pos = np.stack([xs, ys], -1)[:, :, None, :]
    # a real copy: a broadcast view would be read-only (and shared by every sample)
    return np.array(np.broadcast_to(pos, (height, width, spp, 2)), dtype=np.float32)
