"""Pass ``sweep_prepare``: denoising diameters and per-pixel depth order."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.device import get_kernel
from clrecon.core.local_size import LocalSize
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods.sweep.reference import DEPTH_KEY_SHIFT
from clrecon.tune.tunable import DEFAULT_LOCAL, GPU_LOCAL, Tunable, local_candidates


class SweepPrepare:
    """``kernels/sweep_prepare.cl``: keys (x, y, order depth, D) and colours, sorted per
    pixel."""

    name = "sweep_prepare"
    TUNABLE = Tunable(name, "sweep_prepare", DEFAULT_LOCAL, local_candidates, gpu=GPU_LOCAL)

    def __init__(self, context: cl.Context, spp: int, smooth_motion: bool,
                 local: LocalSize | None = None, depth_key_shift: int = DEPTH_KEY_SHIFT):
        """``depth_key_shift``: low mantissa bits of a depth the order ignores
        (``kernels/sweep_order.h``; 0: the exact order)."""
        self.local = local or LocalSize(16, 4)
        self.kernel = get_kernel(context, "sweep_prepare", "sweep_prepare",
                                 {"SPP": spp, "SMOOTH_MOTION": smooth_motion,
                                  "DEPTH_KEY_SHIFT": int(depth_key_shift)})

    def __call__(self, queue, samples: DeviceSamples, diameter_scale: float, keys: cl.Buffer,
                 colors: cl.Buffer, wait_for=None) -> cl.Event:
        c0, c1 = samples.coc
        self.kernel.set_args(samples["color"], samples["position"], samples["depth"],
                             samples["motion"], np.int32(samples.width), np.int32(samples.height),
                             np.float32(c0), np.float32(c1), np.float32(diameter_scale), keys,
                             colors)
        g, loc = self.local.for_range(samples.width, samples.height)
        return cl.enqueue_nd_range_kernel(queue, self.kernel, g, loc, wait_for=wait_for)
