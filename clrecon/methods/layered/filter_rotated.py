"""Pass ``filter_rotated`` (mode ``lrdm``): separable rotated Gaussian with bilinear taps."""
from __future__ import annotations

import pyopencl as cl

from clrecon.core.local_size import LocalSize
from clrecon.methods.layered.layout import Layout
from clrecon.methods.layered.passes import layered_kernel, local_for
from clrecon.tune.tunable import Tunable, local_candidates


class FilterRotated:
    """``kernels/filter_rotated.cl``: ``filter_rotated_u`` (grids -> tmp) then
    ``filter_rotated_v`` (tmp -> filtered). Returns the last event; ``events`` has both."""

    name = "filter_rotated"
    TUNABLE = Tunable(name, "filter_rotated", {"wg_x": 8, "wg_y": 8}, local_candidates,
                      rtol=1e-4, atol=1e-5)

    def __init__(self, context: cl.Context, layout: Layout, local: LocalSize | None = None):
        self.layout = layout
        self.local = local or LocalSize(8, 8)
        # the local size is a launch parameter only: every configuration shares one program
        self.ku = layered_kernel(context, "filter_rotated", "filter_rotated_u", layout, None)
        self.kv = layered_kernel(context, "filter_rotated", "filter_rotated_v", layout, None)
        self.kernel = self.kv  # the one the tuner queries (both launch with the local size)
        self.events: list = []

    def __call__(self, queue, params: cl.Buffer, grids: cl.Buffer, tmp: cl.Buffer,
                 filtered: cl.Buffer, nslots: int, wait_for=None) -> cl.Event:
        self.ku.set_args(params, grids, tmp)
        g, loc = local_for(self.local, (self.layout.dmax, self.layout.dmax, nslots))
        eu = cl.enqueue_nd_range_kernel(queue, self.ku, g, loc, wait_for=wait_for)
        self.kv.set_args(params, tmp, filtered)
        side = self.layout.filtered_side
        g, loc = local_for(self.local, (side, side, nslots))
        ev = cl.enqueue_nd_range_kernel(queue, self.kv, g, loc, wait_for=[eu])
        self.events = [("filter_rotated_u", eu), ("filter_rotated_v", ev)]
        return ev
