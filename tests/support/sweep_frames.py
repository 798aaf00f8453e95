"""Frames shared by the sweep tests and the tests of its tuning and local-memory fits."""
from __future__ import annotations

import numpy as np
from sample_frames import disc_points

from clrecon.core.camera import CocModel
from clrecon.core.samples import SampleBuffer


def frame(rng, h=11, w=13, s=4, motion=True, ties=True):
    """Random valid frame: CoC from -7 to +7 px (D 0..14), optional motion, and depth ties
    (misses at inf and a repeated depth) so that the tie order is exercised."""
    model = CocModel.from_focus(aperture_px=8.0, focus_depth=4.0)
    buf = SampleBuffer.zeros(h, w, s, model)
    buf.position[:] = buf.position - 0.5 + rng.uniform(0.0, 0.999, buf.position.shape)
    buf.depth[:] = rng.uniform(2.2, 40.0, buf.depth.shape)
    if ties:
        buf.depth[rng.uniform(size=buf.depth.shape) < 0.1] = np.inf
        buf.depth[rng.uniform(size=buf.depth.shape) < 0.1] = 4.0  # in focus, all equal
    buf.lens[:] = disc_points(rng, (h, w, s))
    buf.time[:] = rng.uniform(0, 1, buf.time.shape)
    buf.color[:] = rng.exponential(1.0, buf.color.shape)
    if motion:
        moving = rng.uniform(size=buf.depth.shape) < 0.3
        buf.motion[:] = np.where(moving[..., None], rng.normal(0, 4.0, buf.motion.shape), 0.0)
    return buf.validate()
