"""Pass ``tile_stats``: per tile and depth bucket, count and sums of CoC and motion."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.pipeline import DeviceSamples, LocalSize
from clrecon.methods.layered.passes import layered_kernel, local_for
from clrecon.methods.layered.reference import Layout


class TileStats:
    """``kernels/tile_stats.cl``: one work-item per tile; ``stride`` 1 = full statistics."""

    name = "tile_stats"

    def __init__(self, context: cl.Context, lay: Layout, local: LocalSize | None = None):
        self.lay = lay
        self.local = local or LocalSize(8, 1)
        # the local size is a launch parameter only: every configuration shares one program
        self.kernel = layered_kernel(context, "tile_stats", "tile_stats", lay, None)

    def __call__(self, queue, samples: DeviceSamples, kabc, stride: int, seed: int,
                 stats: cl.Buffer, wait_for=None) -> cl.Event:
        ntx, nty = self.lay.tiles(samples.width, samples.height)
        c0, c1 = samples.coc
        motion = samples.buffers.get("motion", samples["depth"])
        ka, kb, kc = kabc
        self.kernel.set_args(samples["depth"], motion, np.int32(samples.width),
                             np.int32(samples.height), np.int32(ntx), np.int32(ntx * nty),
                             np.float32(ka), np.float32(kb), np.float32(kc), np.float32(c0),
                             np.float32(c1), np.int32(stride), np.uint32(seed), stats)
        g, loc = local_for(LocalSize(self.local.x, 1) if self.local.x else None, (ntx * nty,))
        return cl.enqueue_nd_range_kernel(queue, self.kernel, g, loc, wait_for=wait_for)
