"""Pass ``layered_composite``: front-to-back blend of a pixel's filtered partitions."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.local_size import LocalSize
from clrecon.methods.layered.layout import Layout
from clrecon.methods.layered.passes import layered_kernel, local_for
from clrecon.tune.tunable import DEFAULT_LOCAL, GPU_LOCAL, Tunable, local_candidates


class LayeredComposite:
    """``kernels/layered_composite.cl``: one work-item per four pixels of a row (per pixel when the
    tile is narrower than four)."""

    name = "layered_composite"
    TUNABLE = Tunable(name, "layered_composite", DEFAULT_LOCAL, local_candidates, gpu=GPU_LOCAL)

    def __init__(self, context: cl.Context, layout: Layout, local: LocalSize | None = None):
        self.layout = layout
        self.local = local or LocalSize(16, 4)
        # the local size is a launch parameter only: every configuration shares one program
        self.kernel = layered_kernel(context, "layered_composite", "composite", layout, None)

    def __call__(self, queue, color: cl.Buffer, params: cl.Buffer, filtered: cl.Buffer,
                 width: int, height: int, out: cl.Buffer, wait_for=None,
                 sample_stride: int | None = None, sample_offset: int = 0) -> cl.Event:
        """``sample_stride`` / ``sample_offset``: the samples per pixel in ``color`` and the
        first of this frame's (``DeviceSamples.strided``; default: a whole frame)."""
        ntx, _ = self.layout.tiles(width, height)
        if sample_stride is None:
            sample_stride = self.layout.spp
        self.kernel.set_args(color, np.int32(sample_stride), np.int32(sample_offset), params,
                             filtered, np.int32(width), np.int32(height),
                             np.int32(ntx), out)
        per = 4 if self.layout.tile >= 4 else 1
        g, loc = local_for(self.local, (-(-width // per), height))
        return cl.enqueue_nd_range_kernel(queue, self.kernel, g, loc, wait_for=wait_for)
