"""Pass ``partition_setup``: layer merging and each partition's reprojection and filter."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.local_size import LocalSize
from clrecon.methods.layered.layout import Layout
from clrecon.methods.layered.passes import layered_kernel, local_for
from clrecon.tune.tunable import GPU_1D, LAYERED_1D, Tunable, layered_1d_candidates


class PartitionSetup:
    """``kernels/partition_setup.cl``: one work-item per tile; ``threshold < 0``: no merging."""

    name = "partition_setup"
    TUNABLE = Tunable(name, "partition_setup", LAYERED_1D, layered_1d_candidates, gpu=GPU_1D)

    def __init__(self, context: cl.Context, layout: Layout, local: LocalSize | None = None):
        self.layout = layout
        self.local = LocalSize(local.x, 1) if local and local.x else (local or LocalSize(8, 1))
        # the local size is a launch parameter only: every configuration shares one program
        self.kernel = layered_kernel(context, "partition_setup", "partition_setup", layout, None)

    def __call__(self, queue, stats: cl.Buffer, ntiles: int, sigma_x: float, threshold: float,
                 params: cl.Buffer, wait_for=None) -> cl.Event:
        self.kernel.set_args(stats, np.int32(ntiles), np.float32(sigma_x),
                             np.float32(threshold), params)
        g, loc = local_for(self.local, (ntiles,))
        return cl.enqueue_nd_range_kernel(queue, self.kernel, g, loc, wait_for=wait_for)
