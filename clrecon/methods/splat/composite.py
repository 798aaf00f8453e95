"""Pass ``splat_composite``: back-to-front composition of the layers
(``kernels/splat_composite.cl``; ``layered`` has its own ``layered_composite``)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.device import get_kernel
from clrecon.core.local_size import LocalSize
from clrecon.tune.tunable import DEFAULT_LOCAL, GPU_LOCAL, Tunable, local_candidates


class SplatComposite:
    """``kernels/splat_composite.cl`` / ``splat_composite``."""

    name = "splat_composite"
    TUNABLE = Tunable(name, "splat_composite", DEFAULT_LOCAL, local_candidates, gpu=GPU_LOCAL)

    def __init__(self, context: cl.Context, nlayers: int, use_lap: bool,
                 local: LocalSize | None = None):
        self.local = local or LocalSize(16, 4)
        self.kernel = get_kernel(context, "splat_composite", "splat_composite",
                                 {"NLAYERS": nlayers, "USE_LAP": int(use_lap)})

    def __call__(self, queue, b: cl.Buffer, direct: cl.Buffer, ring: cl.Buffer, width: int,
                 height: int, pad: int, out: cl.Buffer, wait_for=None,
                 color: cl.Buffer | None = None, spp: int = 0, stride: int | None = None,
                 offset: int = 0) -> cl.Event:
        """``color`` and ``spp``: the frame's samples, whose per-pixel mean fills a pixel no
        layer covers (without them such a pixel is 0); ``stride`` and ``offset``: where they
        are in ``color`` (default a whole frame: ``spp`` per pixel from 0; a view's
        ``DeviceSamples.strided``)."""
        if color is None:
            color, spp = b, 0
        stride = spp if stride is None else stride
        self.kernel.set_args(b, direct, ring, np.int32(width), np.int32(height), np.int32(pad),
                             np.int32(width + 2 * pad), np.int32(height + 2 * pad), color,
                             np.int32(spp), np.int32(stride), np.int32(offset), out)
        g, loc = self.local.for_range(width, height)
        return cl.enqueue_nd_range_kernel(queue, self.kernel, g, loc, wait_for=wait_for)
