"""Thin-lens camera model shared by every part of clrecon (pure NumPy, no OpenCL).

The signed circle of confusion, in pixels, of a surface at camera-space depth ``w`` is
``coc(w) = C0 / w + C1`` (the TLFR convention): ``C1`` is the aperture radius in pixels as
seen at infinity and ``C0 = -C1 * focus_depth``, so ``coc`` is zero at the focus depth,
negative in front of it and positive behind it. A surface point whose pinhole image at
time ``t`` is ``p(t)`` is seen through lens point ``(u, v)`` (unit disk) at
``p(t) + coc(w) * (u, v)``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CocModel:
    """``coc(w) = c0 / w + c1`` in pixels."""

    c0: float = 0.0
    c1: float = 0.0

    @classmethod
    def from_focus(cls, aperture_px: float, focus_depth: float) -> CocModel:
        """Model with aperture radius ``aperture_px`` (pixels, at infinity) focused at a depth."""
        if not (focus_depth > 0 and math.isfinite(focus_depth)):
            raise ValueError(f"focus_depth must be positive and finite, got {focus_depth}")
        if not math.isfinite(aperture_px):
            raise ValueError(f"aperture_px must be finite, got {aperture_px}")
        return cls(c0=-aperture_px * focus_depth, c1=float(aperture_px))

    @property
    def has_defocus(self) -> bool:
        return self.c0 != 0.0 or self.c1 != 0.0

    @property
    def focus_depth(self) -> float:
        """Depth where ``coc`` is zero (``inf`` for a pinhole)."""
        return -self.c0 / self.c1 if self.c1 != 0.0 else math.inf

    def coc(self, depth):
        """Signed CoC radius in pixels; ``depth`` may be an array (``inf`` gives ``c1``)."""
        depth = np.asarray(depth, dtype=np.float64)
        with np.errstate(divide="ignore"):
            return (self.c0 / depth + self.c1).astype(np.float32)

    def depth_at_coc(self, coc: float) -> float:
        """Inverse of :meth:`coc` (``inf`` where ``coc == c1``)."""
        if coc == self.c1:
            return math.inf
        return self.c0 / (coc - self.c1)


@dataclass(frozen=True)
class ThinLensCamera:
    """A perspective thin-lens camera looking down +z, x right, y down.

    Parameters
    ----------
    width, height : int
        Image size in pixels.
    focal_px : float
        Focal length in pixels (pinhole projection ``x = cx + focal_px * X / Z``).
    focus_depth : float
        Camera-space depth of the plane in focus.
    lens_radius : float
        Lens radius in world units (0 for a pinhole).
    """

    width: int
    height: int
    focal_px: float
    focus_depth: float = 1.0
    lens_radius: float = 0.0

    def __post_init__(self):
        if self.width < 1 or self.height < 1:
            raise ValueError(f"width, height: must be positive, got {self.width}x{self.height}")
        if not (self.focal_px > 0 and math.isfinite(self.focal_px)):
            raise ValueError(f"focal_px: must be positive and finite, got {self.focal_px}")
        if not (self.focus_depth > 0 and math.isfinite(self.focus_depth)):
            raise ValueError(f"focus_depth: must be positive and finite, got {self.focus_depth}")
        if not (self.lens_radius >= 0 and math.isfinite(self.lens_radius)):
            raise ValueError(f"lens_radius: must be >= 0 and finite, got {self.lens_radius}")

    @classmethod
    def from_fov(cls, width: int, height: int, fov_deg: float, **kw) -> ThinLensCamera:
        """Camera whose horizontal field of view is ``fov_deg`` degrees."""
        focal = 0.5 * width / math.tan(math.radians(fov_deg) / 2)
        return cls(width, height, focal, **kw)

    @property
    def centre(self) -> tuple[float, float]:
        return 0.5 * self.width, 0.5 * self.height

    @property
    def coc_model(self) -> CocModel:
        """Derivation: the ray from lens point ``L = R (u, v, 0)`` that lands on sensor point
        ``s`` passes the focus plane at ``(s - c) F / f``; a point ``P`` at depth ``Z`` on it
        therefore images at ``s = c + f P/Z + f R (1/F - 1/Z) (u, v)``, i.e.
        ``coc(Z) = f R / F - f R / Z``: ``C1 = f R / F``, ``C0 = -C1 F``."""
        c1 = self.focal_px * self.lens_radius / self.focus_depth
        return CocModel(c0=-c1 * self.focus_depth, c1=c1)

    def project(self, points) -> np.ndarray:
        """Pinhole image (pixels) of camera-space points of shape (..., 3)."""
        p = np.asarray(points, dtype=np.float64)
        cx, cy = self.centre
        f = self.focal_px
        return np.stack([cx + f * p[..., 0] / p[..., 2], cy + f * p[..., 1] / p[..., 2]], axis=-1)
