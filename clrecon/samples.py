"""The sample buffer: one frame of stochastic samples as a structure of float32 arrays.

Field layout (``S`` samples per pixel, sample ``(py, px, i)``):

========== ============== ==============================================================
field      shape          meaning
========== ============== ==============================================================
color      (H, W, S, 3)   linear radiance (HDR values far above 1 are normal)
position   (H, W, S, 2)   sensor position in pixels (x right, y down), inside its pixel
depth      (H, W, S)      camera-space depth ``w > 0``; ``inf`` (or >= 1e30) for a miss
lens       (H, W, S, 2)   lens coordinates ``(u, v)`` in the unit disk
time       (H, W, S)      shutter time in [0, 1]
motion     (H, W, S, 2)   pinhole screen displacement (pixels) from t=0 to t=1
========== ============== ==============================================================

The thin-lens model is :class:`clrecon.camera.CocModel`; the centre of a sample (its
reprojection to ``(u, v, t) = (0, 0, 0.5)``) is
``position - coc(depth) * lens - (time - 0.5) * motion``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .camera import CocModel

#: field name -> trailing shape after (H, W, S)
FIELDS: dict[str, tuple[int, ...]] = {
    "color": (3,),
    "position": (2,),
    "depth": (),
    "lens": (2,),
    "time": (),
    "motion": (2,),
}

#: depths at or beyond this are misses (background)
MISS_DEPTH = 1e30

LENS_TOLERANCE = 1e-4
POSITION_TOLERANCE = 1e-4


@dataclass(frozen=True)
class FrameInfo:
    """What one look at a frame says it needs (used to specialise kernels)."""

    width: int
    height: int
    spp: int
    max_abs_coc: float  # pixels, over every sample (misses: |C1|)
    max_abs_motion: float  # pixels, longest motion vector
    min_depth: float
    max_depth: float
    miss_fraction: float

    @property
    def has_motion(self) -> bool:
        return self.max_abs_motion > 0.0

    @property
    def has_defocus(self) -> bool:
        return self.max_abs_coc > 0.0


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
        """One pass over the frame: the facts that decide which terms a kernel needs."""
        hit = self.depth < MISS_DEPTH
        # misses keep their lens term: coc(inf) = C1 (the background is defocused too)
        coc = np.abs(self.coc())
        hit_depth = self.depth[hit] if hit.any() else np.array([np.inf], np.float32)
        motion = np.sqrt((self.motion.astype(np.float64) ** 2).sum(-1))
        return FrameInfo(
            width=self.width,
            height=self.height,
            spp=self.spp,
            max_abs_coc=float(coc.max(initial=0.0)),
            max_abs_motion=float(motion.max(initial=0.0)),
            min_depth=float(hit_depth.min()),
            max_depth=float(hit_depth.max()),
            miss_fraction=float(1.0 - hit.mean()),
        )

    # -- validation ------------------------------------------------------------------------
    def validate(self) -> SampleBuffer:
        """Check shapes and value ranges; raise ``ValueError`` naming the field and sample.

        Returns ``self`` so that ``buf.validate()`` can be used inline.
        """
        if self.depth.ndim != 3:
            raise ValueError(f"depth: expected shape (H, W, S), got {self.depth.shape}")
        hws = self.depth.shape
        if min(hws) < 1:
            raise ValueError(f"depth: empty frame of shape {hws}")
        for name, tail in FIELDS.items():
            arr = getattr(self, name)
            if arr.shape != hws + tail:
                raise ValueError(f"{name}: expected shape {hws + tail}, got {arr.shape}")
        _first_bad("depth", np.isnan(self.depth) | (self.depth <= 0), self.depth,
                   "must be positive (inf for a miss), got")
        _first_bad("color", ~np.isfinite(self.color).all(-1), self.color, "must be finite, got")
        _first_bad("motion", ~np.isfinite(self.motion).all(-1), self.motion, "must be finite, got")
        _first_bad("time", ~((self.time >= 0) & (self.time <= 1)), self.time,
                   "must lie in [0, 1], got")
        r2 = (self.lens.astype(np.float64) ** 2).sum(-1)
        _first_bad("lens", ~(r2 <= (1 + LENS_TOLERANCE) ** 2), self.lens,
                   "must lie in the unit disk, got")
        h, w, _ = hws
        px = np.arange(w, dtype=np.float32)[None, :, None]
        py = np.arange(h, dtype=np.float32)[:, None, None]
        x, y = self.position[..., 0], self.position[..., 1]
        tol = POSITION_TOLERANCE
        outside = ~((x >= px - tol) & (x <= px + 1 + tol) & (y >= py - tol) & (y <= py + 1 + tol))
        _first_bad("position", outside, self.position, "must lie inside its pixel, got")
        if not (np.isfinite(self.coc_model.c0) and np.isfinite(self.coc_model.c1)):
            raise ValueError(f"coc_model: coefficients must be finite, got {self.coc_model}")
        return self


def _first_bad(name: str, bad: np.ndarray, values: np.ndarray, what: str) -> None:
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        py, px, s = idx
        count = int(bad.sum())
        raise ValueError(
            f"{name}: sample (y={py}, x={px}, i={s}) {what} {values[idx].tolist()} "
            f"({count} bad sample{'s' if count != 1 else ''})"
        )


def pixel_centres(height: int, width: int, spp: int) -> np.ndarray:
    """Positions at pixel centres, (H, W, S, 2)."""
    ys, xs = np.meshgrid(np.arange(height, dtype=np.float32) + 0.5,
                         np.arange(width, dtype=np.float32) + 0.5, indexing="ij")
    pos = np.stack([xs, ys], -1)[:, :, None, :]
    # a real copy: a broadcast view would be read-only (and shared by every sample)
    return np.array(np.broadcast_to(pos, (height, width, spp, 2)), dtype=np.float32)
