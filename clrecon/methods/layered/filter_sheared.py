"""Pass ``filter_sheared``: recursive filter along one grid axis and Gaussian along the sheared
axis (eq. 9-10)."""
from __future__ import annotations

import pyopencl as cl

from clrecon.core.local_size import LocalSize
from clrecon.methods.layered.layout import Layout
from clrecon.methods.layered.passes import layered_kernel, local_for
from clrecon.tune.tunable import Tunable, local_candidates


class FilterSheared:
    """``kernels/filter_sheared.cl``: ``filter_sheared_recursive`` (in place on the grids) then
    ``filter_sheared_gauss`` (into ``filtered``). Returns the last event; ``events`` has both."""

    name = "filter_sheared"
    TUNABLE = Tunable(name, "filter_sheared", {"wg_x": 8, "wg_y": 8}, local_candidates,
                      rtol=1e-4, atol=1e-5)

    def __init__(self, context: cl.Context, layout: Layout, recursions: int = 3,
                 local: LocalSize | None = None):
        self.layout = layout
        self.local = local or LocalSize(8, 8)
        r = {"RECURSIONS": int(recursions)}
        # the local size is a launch parameter only: every configuration shares one program
        self.recursive = layered_kernel(context, "filter_sheared", "filter_sheared_recursive",
                                        layout, None, **r)
        self.gauss = layered_kernel(context, "filter_sheared", "filter_sheared_gauss", layout, None,
                                    **r)
        self.kernel = self.gauss  # the one the local size tunes
        self.events: list = []

    def __call__(self, queue, params: cl.Buffer, grids: cl.Buffer, filtered: cl.Buffer,
                 nslots: int, wait_for=None) -> cl.Event:
        self.recursive.set_args(params, grids)
        er = cl.enqueue_nd_range_kernel(queue, self.recursive, (self.layout.dmax, nslots), None,
                                        wait_for=wait_for)
        self.gauss.set_args(params, grids, filtered)
        side = self.layout.filtered_side
        g, loc = local_for(self.local, (-(-side // 4), side, nslots))
        eg = cl.enqueue_nd_range_kernel(queue, self.gauss, g, loc, wait_for=[er])
        self.events = [("filter_sheared_recursive", er), ("filter_sheared_gauss", eg)]
        return eg
