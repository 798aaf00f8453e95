"""Passes ``sweep_layer_sums`` and ``sweep_layer_resolve``: the sort-free three-layer
depth-of-field variant (section 3.1)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.device import get_kernel
from clrecon.core.local_size import LocalSize
from clrecon.core.pipeline import DeviceSamples
from clrecon.tune.tunable import DEFAULT_LOCAL, GPU_LOCAL, Tunable, local_candidates


class SweepLayerSums:
    """``kernels/sweep_layer_sums.cl``: per pixel and layer, blend-weighted colour sums."""

    name = "sweep_layer_sums"
    TUNABLE = Tunable(name, "sweep_layer_sums", DEFAULT_LOCAL, local_candidates, gpu=GPU_LOCAL)

    def __init__(self, context: cl.Context, spp: int, local: LocalSize | None = None):
        self.local = local or LocalSize(16, 4)
        self.kernel = get_kernel(context, "sweep_layer_sums", "sweep_layer_sums", {"SPP": spp})

    def __call__(self, queue, samples: DeviceSamples, diameter_scale: float, sums: cl.Buffer,
                 wait_for=None) -> cl.Event:
        c0, c1 = samples.coc
        self.kernel.set_args(samples["color"], samples["depth"], np.int32(samples.width),
                             np.int32(samples.height), np.float32(c0), np.float32(c1),
                             np.float32(diameter_scale), sums)
        g, loc = self.local.for_range(samples.width, samples.height)
        return cl.enqueue_nd_range_kernel(queue, self.kernel, g, loc, wait_for=wait_for)


class SweepLayerResolve:
    """``kernels/sweep_layer_resolve.cl``: 5x5 window sums and the front-to-back combine."""

    name = "sweep_layer_resolve"
    TUNABLE = Tunable(name, "sweep_layer_resolve", DEFAULT_LOCAL, local_candidates,
                      gpu=GPU_LOCAL)

    def __init__(self, context: cl.Context, spp: int, local: LocalSize | None = None):
        self.local = local or LocalSize(16, 4)
        self.kernel = get_kernel(context, "sweep_layer_resolve", "sweep_layer_resolve",
                                 {"SPP": spp})

    def __call__(self, queue, sums: cl.Buffer, width: int, height: int, out: cl.Buffer,
                 wait_for=None) -> cl.Event:
        self.kernel.set_args(sums, np.int32(width), np.int32(height), out)
        g, loc = self.local.for_range(width, height)
        return cl.enqueue_nd_range_kernel(queue, self.kernel, g, loc, wait_for=wait_for)
