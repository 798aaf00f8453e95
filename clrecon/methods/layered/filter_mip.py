"""Pass ``filter_mip``: a MIP pyramid per partition grid and four emulated anisotropic
lookups (section 6.1), read from buffers or, with ``images=True``, from two 2D image atlases
through the device's linear sampler (``kernels/filter_mip_image.cl``)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.local_size import LocalSize
from clrecon.methods.layered.layout import Layout, mip_atlas, mip_levels
from clrecon.methods.layered.passes import layered_kernel, local_for
from clrecon.tune.tunable import Tunable, local_candidates


def atlas_layout(device: cl.Device, layout: Layout, nslots: int) -> tuple[dict, bool]:
    """The image atlas for ``nslots`` slots on ``device`` (``layout.mip_atlas``) and
    whether it fits the device's 2D image limits."""
    a = mip_atlas(layout.dmax, mip_levels(layout.dmax)[0], nslots, device.image2d_max_width)
    return a, a["width"] <= device.image2d_max_width and a["height"] <= device.image2d_max_height


class FilterMip:
    """``kernels/filter_mip.cl``: ``filter_mip_build`` (grids -> pyramid) then
    ``filter_mip_sample`` (-> filtered); given an ``atlas`` (``atlas_layout``),
    ``filter_mip_pack`` (pyramid -> two atlas images it owns) and ``filter_mip_sample_image``
    instead of ``filter_mip_sample``. Returns the last event; ``events`` has each kernel's."""

    name = "filter_mip"
    TUNABLE = Tunable(name, "filter_mip", {"wg_x": 8, "wg_y": 8}, local_candidates,
                      rtol=1e-4, atol=1e-5)

    def __init__(self, context: cl.Context, layout: Layout, local: LocalSize | None = None,
                 atlas: dict | None = None):
        self.layout = layout
        self.local = local or LocalSize(8, 8)
        self.nlev, self.plane = mip_levels(layout.dmax)
        self.atlas = atlas
        extra = {"NLEV": self.nlev, "PYR_PLANE": self.plane}
        # the local size is a launch parameter only: every configuration shares one program
        self.kb = layered_kernel(context, "filter_mip", "filter_mip_build", layout, None, **extra)
        if atlas is not None:
            extra |= {"ATLAS_RW": atlas["rw"], "ATLAS_RH": atlas["rh"],
                      "ATLAS_PER_ROW": atlas["per_row"]}
            self.kp = layered_kernel(context, "filter_mip_image", "filter_mip_pack", layout, None,
                                     **extra)
            self.ks = layered_kernel(context, "filter_mip_image", "filter_mip_sample_image",
                                     layout, None, **extra)
            # RGBA float: r, g, b, own weight; R float: behind weight
            shape = (atlas["width"], atlas["height"])
            self.images = tuple(
                cl.create_image(context, cl.mem_flags.READ_WRITE,
                                cl.ImageFormat(order, cl.channel_type.FLOAT), shape=shape)
                for order in (cl.channel_order.RGBA, cl.channel_order.R))
            self._cleared = False
        else:
            self.ks = layered_kernel(context, "filter_mip", "filter_mip_sample", layout, None,
                                     **extra)
            self.images = None
        self.kernel = self.ks  # the one the local size tunes
        self.events: list = []

    def __call__(self, queue, params: cl.Buffer, grids: cl.Buffer, pyr: cl.Buffer,
                 filtered: cl.Buffer, nslots: int, wait_for=None) -> cl.Event:
        wg = 16
        self.kb.set_args(params, grids, pyr)
        eb = cl.enqueue_nd_range_kernel(queue, self.kb, (nslots * wg,), (wg,),
                                        wait_for=wait_for)
        self.events = [("filter_mip_build", eb)]
        wait = [eb]
        if self.images is not None:
            if not self._cleared:  # once: no stale NaN may ever meet a zero filter weight
                shape = (self.atlas["width"], self.atlas["height"])
                zero = np.zeros(4, np.float32)
                wait += [cl.enqueue_fill_image(queue, im, zero, (0, 0), shape)
                         for im in self.images]
                self._cleared = True
            rgbw, behind = self.images
            self.kp.set_args(params, grids, pyr, rgbw, behind)
            side = self.layout.dmax + 2
            ep = cl.enqueue_nd_range_kernel(queue, self.kp, (side, side, nslots), None,
                                            wait_for=wait)
            self.events.append(("filter_mip_pack", ep))
            self.ks.set_args(params, rgbw, behind, filtered)
            wait = [ep]
        else:
            self.ks.set_args(params, grids, pyr, filtered)
        side = self.layout.filtered_side
        g, loc = local_for(self.local, (side, side, nslots))
        es = cl.enqueue_nd_range_kernel(queue, self.ks, g, loc, wait_for=wait)
        self.events.append(("filter_mip_sample", es))
        return es
