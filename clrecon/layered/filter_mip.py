"""Pass ``filter_mip``: a MIP pyramid per partition grid and four emulated anisotropic
lookups (section 6.1), read from buffers or, with ``images=True``, from two 2D image atlases
through the device's linear sampler (``kernels/filter_mip_image.cl``)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..pipeline import LocalSize
from .passes import layered_kernel, local_for
from .reference import Layout, mip_atlas, mip_levels


class FilterMip:
    """``kernels/filter_mip.cl``: ``filter_mip_build`` (grids -> pyramid) then
    ``filter_mip_sample`` (-> filtered); with ``images``, ``filter_mip_pack`` (pyramid ->
    atlas images) and ``filter_mip_sample_image`` instead of ``filter_mip_sample``. Returns
    the last event; ``events`` has each kernel's."""

    name = "filter_mip"

    def __init__(self, context: cl.Context, lay: Layout, local: LocalSize | None = None,
                 images: bool = False, nslots: int = 1):
        self.lay = lay
        self.local = local or LocalSize(8, 8)
        self.nlev, self.plane = mip_levels(lay.dmax)
        self.images = bool(images)
        extra = {"NLEV": self.nlev, "PYR_PLANE": self.plane}
        self.kb = layered_kernel(context, "filter_mip", "filter_mip_build", lay, None, **extra)
        if self.images:
            dev = context.devices[0]
            self.atlas = mip_atlas(lay.dmax, self.nlev, nslots, dev.image2d_max_width)
            a = self.atlas
            extra |= {"ATLAS_RW": a["rw"], "ATLAS_RH": a["rh"], "ATLAS_PER_ROW": a["per_row"]}
            self.kp = layered_kernel(context, "filter_mip_image", "filter_mip_pack", lay, None,
                                     **extra)
            self.ks = layered_kernel(context, "filter_mip_image", "filter_mip_sample_image",
                                     lay, self.local, **extra)
        else:
            self.atlas = None
            self.ks = layered_kernel(context, "filter_mip", "filter_mip_sample", lay,
                                     self.local, **extra)
        self.kernel = self.ks  # the one the local size tunes
        self.events: list = []

    def atlas_images(self, context: cl.Context, queue=None) -> tuple:
        """The two atlas images (RGBA float: r, g, b, own weight; R float: behind weight),
        cleared to zero (so no stale NaN ever meets a zero filter weight)."""
        a = self.atlas
        shape = (a["width"], a["height"])
        rw = cl.mem_flags.READ_WRITE
        imgs = tuple(cl.create_image(context, rw, cl.ImageFormat(order, cl.channel_type.FLOAT),
                                     shape=shape)
                     for order in (cl.channel_order.RGBA, cl.channel_order.R))
        if queue is not None:
            zero = np.zeros(4, np.float32)
            for im in imgs:
                cl.enqueue_fill_image(queue, im, zero, (0, 0), shape).wait()
        return imgs

    def __call__(self, queue, params: cl.Buffer, grids: cl.Buffer, pyr: cl.Buffer,
                 filtered: cl.Buffer, nslots: int, wait_for=None, images=None) -> cl.Event:
        wg = 16
        self.kb.set_args(params, grids, pyr)
        eb = cl.enqueue_nd_range_kernel(queue, self.kb, (nslots * wg,), (wg,),
                                        wait_for=wait_for)
        self.events = [("filter_mip_build", eb)]
        if self.images:
            rgbw, behind = images
            self.kp.set_args(params, grids, pyr, rgbw, behind)
            side = self.lay.dmax + 2
            ep = cl.enqueue_nd_range_kernel(queue, self.kp, (side, side, nslots), None,
                                            wait_for=[eb])
            self.events.append(("filter_mip_pack", ep))
            self.ks.set_args(params, rgbw, behind, filtered)
            wait = [ep]
        else:
            self.ks.set_args(params, grids, pyr, filtered)
            wait = [eb]
        g, loc = local_for(self.local, (self.lay.ft, self.lay.ft, nslots))
        es = cl.enqueue_nd_range_kernel(queue, self.ks, g, loc, wait_for=wait)
        self.events.append(("filter_mip_sample", es))
        return es
