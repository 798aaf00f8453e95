"""Pass ``tile_stats``: per tile and depth bucket, count and sums of CoC and motion."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.local_size import LocalSize
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods.layered.layout import Layout
from clrecon.methods.layered.passes import layered_kernel, local_for
from clrecon.tune.tunable import GPU_1D, LAYERED_1D, Tunable, layered_1d_candidates


class TileStats:
    """``kernels/tile_stats.cl``: one work-item per tile; ``stride`` 1 = full statistics."""

    name = "tile_stats"
    # float sums in a different order (atomics): relative tolerance
    TUNABLE = Tunable(name, "tile_stats", LAYERED_1D, layered_1d_candidates, rtol=1e-4,
                      atol=1e-4, gpu=GPU_1D)

    def __init__(self, context: cl.Context, layout: Layout, local: LocalSize | None = None):
        self.layout = layout
        self.local = local or LocalSize(8, 1)
        # the local size is a launch parameter only: every configuration shares one program
        self.kernel = layered_kernel(context, "tile_stats", "tile_stats", layout, None)

    def __call__(self, queue, samples: DeviceSamples, bucket_coeffs, stride: int, seed: int,
                 stats: cl.Buffer, wait_for=None) -> cl.Event:
        ntx, nty = self.layout.tiles(samples.width, samples.height)
        c0, c1 = samples.coc
        depth, sstride, soffset = samples.strided("depth")
        motion = samples.strided("motion")[0] if "motion" in samples.buffers else depth
        ka, kb, kc = bucket_coeffs
        self.kernel.set_args(depth, motion, np.int32(sstride), np.int32(soffset),
                             np.int32(samples.width),
                             np.int32(samples.height), np.int32(ntx), np.int32(ntx * nty),
                             np.float32(ka), np.float32(kb), np.float32(kc), np.float32(c0),
                             np.float32(c1), np.int32(stride), np.uint32(seed), stats)
        g, loc = local_for(LocalSize(self.local.x, 1) if self.local.x else None, (ntx * nty,))
        return cl.enqueue_nd_range_kernel(queue, self.kernel, g, loc, wait_for=wait_for)
