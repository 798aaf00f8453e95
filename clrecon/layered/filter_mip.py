"""Pass ``filter_mip``: a MIP pyramid per partition grid and four emulated anisotropic
lookups (section 6.1). Buffers only: no OpenCL image objects."""
from __future__ import annotations

import pyopencl as cl

from ..pipeline import LocalSize
from .passes import layered_kernel, local_for
from .reference import Layout, mip_levels


class FilterMip:
    """``kernels/filter_mip.cl``: ``filter_mip_build`` (grids -> pyramid) then
    ``filter_mip_sample`` (-> filtered). Returns the last event; ``events`` has both."""

    name = "filter_mip"

    def __init__(self, context: cl.Context, lay: Layout, local: LocalSize | None = None):
        self.lay = lay
        self.local = local or LocalSize(8, 8)
        self.nlev, self.plane = mip_levels(lay.dmax)
        extra = {"NLEV": self.nlev, "PYR_PLANE": self.plane}
        self.kb = layered_kernel(context, "filter_mip", "filter_mip_build", lay, None, **extra)
        self.ks = layered_kernel(context, "filter_mip", "filter_mip_sample", lay, self.local,
                                 **extra)
        self.kernel = self.ks  # the one the local size tunes
        self.events: list = []

    def __call__(self, queue, params: cl.Buffer, grids: cl.Buffer, pyr: cl.Buffer,
                 filtered: cl.Buffer, nslots: int, wait_for=None) -> cl.Event:
        wg = 16
        self.kb.set_args(params, grids, pyr)
        eb = cl.enqueue_nd_range_kernel(queue, self.kb, (nslots * wg,), (wg,),
                                        wait_for=wait_for)
        self.ks.set_args(params, grids, pyr, filtered)
        g, loc = local_for(self.local, (self.lay.ft, self.lay.ft, nslots))
        es = cl.enqueue_nd_range_kernel(queue, self.ks, g, loc, wait_for=[eb])
        self.events = [("filter_mip_build", eb), ("filter_mip_sample", es)]
        return es
