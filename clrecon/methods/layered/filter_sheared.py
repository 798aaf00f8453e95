"""Pass ``filter_sheared``: recursive x filter and Gaussian along the sheared axis (eq. 9-10)."""
from __future__ import annotations

import pyopencl as cl

from clrecon.core.pipeline import LocalSize
from clrecon.methods.layered.passes import layered_kernel, local_for
from clrecon.methods.layered.reference import Layout


class FilterSheared:
    """``kernels/filter_sheared.cl``: ``filter_sheared_x`` (in place on the grids) then
    ``filter_sheared_y`` (into ``filtered``). Returns the last event; ``events`` has both."""

    name = "filter_sheared"

    def __init__(self, context: cl.Context, lay: Layout, recursions: int = 3,
                 local: LocalSize | None = None):
        self.lay = lay
        self.local = local or LocalSize(8, 8)
        r = {"RECURSIONS": int(recursions)}
        # the local size is a launch parameter only: every configuration shares one program
        self.kx = layered_kernel(context, "filter_sheared", "filter_sheared_x", lay, None, **r)
        self.ky = layered_kernel(context, "filter_sheared", "filter_sheared_y", lay, None, **r)
        self.kernel = self.ky  # the one the local size tunes
        self.events: list = []

    def __call__(self, queue, params: cl.Buffer, grids: cl.Buffer, filtered: cl.Buffer,
                 nslots: int, wait_for=None) -> cl.Event:
        self.kx.set_args(params, grids)
        ex = cl.enqueue_nd_range_kernel(queue, self.kx, (self.lay.dmax, nslots), None,
                                        wait_for=wait_for)
        self.ky.set_args(params, grids, filtered)
        g, loc = local_for(self.local, (-(-self.lay.ft // 4), self.lay.ft, nslots))
        ey = cl.enqueue_nd_range_kernel(queue, self.ky, g, loc, wait_for=[ex])
        self.events = [("filter_sheared_x", ex), ("filter_sheared_y", ey)]
        return ey
