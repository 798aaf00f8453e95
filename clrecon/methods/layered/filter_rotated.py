"""Pass ``filter_rotated`` (mode ``lrdm``): separable rotated Gaussian with bilinear taps."""
from __future__ import annotations

import pyopencl as cl

from clrecon.core.pipeline import LocalSize
from clrecon.methods.layered.passes import layered_kernel, local_for
from clrecon.methods.layered.reference import Layout


class FilterRotated:
    """``kernels/filter_rotated.cl``: ``filter_rotated_u`` (grids -> tmp) then
    ``filter_rotated_v`` (tmp -> filtered). Returns the last event; ``events`` has both."""

    name = "filter_rotated"

    def __init__(self, context: cl.Context, lay: Layout, local: LocalSize | None = None):
        self.lay = lay
        self.local = local or LocalSize(8, 8)
        # the local size is a launch parameter only: every configuration shares one program
        self.ku = layered_kernel(context, "filter_rotated", "filter_rotated_u", lay, None)
        self.kv = layered_kernel(context, "filter_rotated", "filter_rotated_v", lay, None)
        self.kernel = self.kv  # the one the tuner queries (both launch with the local size)
        self.events: list = []

    def __call__(self, queue, params: cl.Buffer, grids: cl.Buffer, tmp: cl.Buffer,
                 filtered: cl.Buffer, nslots: int, wait_for=None) -> cl.Event:
        self.ku.set_args(params, grids, tmp)
        g, loc = local_for(self.local, (self.lay.dmax, self.lay.dmax, nslots))
        eu = cl.enqueue_nd_range_kernel(queue, self.ku, g, loc, wait_for=wait_for)
        self.kv.set_args(params, tmp, filtered)
        g, loc = local_for(self.local, (self.lay.ft, self.lay.ft, nslots))
        ev = cl.enqueue_nd_range_kernel(queue, self.kv, g, loc, wait_for=[eu])
        self.events = [("filter_rotated_u", eu), ("filter_rotated_v", ev)]
        return ev
