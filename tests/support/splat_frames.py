"""Frames shared by the splat tests."""
from __future__ import annotations

import numpy as np

from clrecon.core.camera import CocModel
from clrecon.core.samples import SampleBuffer


def frame(rng, h=11, w=13, s=4, motion=True, aperture=8.0, misses=True):
    """Random valid frame: CoC up to ~|aperture| px, optional motion up to ~20 px, misses."""
    model = CocModel.from_focus(aperture_px=aperture, focus_depth=4.0)
    buf = SampleBuffer.zeros(h, w, s, model)
    buf.position[:] = buf.position - 0.5 + rng.uniform(0.0, 0.999, buf.position.shape)
    buf.depth[:] = rng.uniform(2.2, 40.0, buf.depth.shape)
    if misses:
        buf.depth[rng.uniform(size=buf.depth.shape) < 0.1] = np.inf
    r = np.sqrt(rng.uniform(0, 1, (h, w, s)))
    a = rng.uniform(0, 2 * np.pi, (h, w, s))
    buf.lens[:] = np.stack([r * np.cos(a), r * np.sin(a)], -1)
    buf.time[:] = rng.uniform(0, 1, buf.time.shape)
    buf.color[:] = rng.exponential(1.0, buf.color.shape)
    if motion:
        moving = rng.uniform(size=buf.depth.shape) < 0.5
        buf.motion[:] = np.where(moving[..., None], rng.normal(0, 8.0, buf.motion.shape), 0.0)
    return buf.validate()
