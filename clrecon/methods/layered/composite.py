"""Pass ``layered_composite``: front-to-back blend of a pixel's filtered partitions."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.device import cpu_context
from clrecon.core.local_size import LocalSize
from clrecon.methods.layered.layout import Layout
from clrecon.methods.layered.passes import layered_kernel, local_for
from clrecon.tune.tunable import DEFAULT_LOCAL, GPU_LOCAL, Tunable, local_candidates


def composite_width(context: cl.Context, tile: int) -> int:
    """Pixels a work-item of ``composite``: 8 on a CPU (the per-slot work, its parameters,
    bounds and addressing, shared by more lanes; PoCL 3.1 does not vectorise across
    work-items a kernel that holds vector values: deep 1280x720 8 spp, the halves' composite
    31-33 -> 28-31 ms, 16 lanes no better), 4 elsewhere; never more than the tile (1 below
    4)."""
    if tile < 4:
        return 1
    cpu = cpu_context(context)
    return min(8 if cpu else 4, tile)


class LayeredComposite:
    """``kernels/layered_composite.cl``: one work-item per ``width`` pixels of a row
    (:func:`composite_width`; per pixel when the tile is narrower than four)."""

    name = "layered_composite"
    TUNABLE = Tunable(name, "layered_composite", DEFAULT_LOCAL, local_candidates, gpu=GPU_LOCAL)

    def __init__(self, context: cl.Context, layout: Layout, local: LocalSize | None = None,
                 width: int | None = None):
        """``width``: pixels a work-item (4, 8 or 16, at most the tile; 1 where the tile is
        narrower than four)."""
        self.layout = layout
        self.width = composite_width(context, layout.tile) if width is None else int(width)
        allowed = (1,) if layout.tile < 4 else tuple(w for w in (4, 8, 16) if w <= layout.tile)
        if self.width not in allowed:
            raise ValueError(f"layered_composite: {width} pixels a work-item with tile "
                             f"{layout.tile} is not one of {allowed}")
        self.local = local or LocalSize(16, 4)
        # the local size is a launch parameter only: every configuration shares one program
        self.kernel = layered_kernel(context, "layered_composite", "composite", layout, None,
                                     CW=max(self.width, 4))

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
        g, loc = local_for(self.local, (-(-width // self.width), height))
        return cl.enqueue_nd_range_kernel(queue, self.kernel, g, loc, wait_for=wait_for)
