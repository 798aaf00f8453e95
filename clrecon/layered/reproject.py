"""Pass ``reproject``: samples of a tile and its guard band splatted into each partition."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..pipeline import DeviceSamples, LocalSize
from .passes import layered_kernel
from .reference import Layout, subsample_cap


class Reproject:
    """``kernels/reproject.cl``: one work-group of ``local.x`` items per (tile, slot); with one
    item the slot's grid is owned (plain adds), otherwise items scatter with atomics."""

    name = "reproject"

    def __init__(self, context: cl.Context, lay: Layout, bilinear: bool = False,
                 local: LocalSize | None = None, subsample: int | bool = True):
        self.lay = lay
        wg = local.x if local and local.x else 1
        self.local = LocalSize(wg, 1)
        self.kernel = layered_kernel(context, "reproject", "reproject", lay, self.local,
                                     SPLAT_BILINEAR=bool(bilinear),
                                     SUBSAMPLE=subsample_cap(subsample))

    def __call__(self, queue, samples: DeviceSamples, kabc, params: cl.Buffer,
                 grids: cl.Buffer, wait_for=None) -> cl.Event:
        ntx, nty = self.lay.tiles(samples.width, samples.height)
        time = samples.buffers.get("time", samples["depth"])
        self.kernel.set_args(samples["color"], samples["position"], samples["depth"],
                             samples["lens"], time, np.int32(samples.width),
                             np.int32(samples.height), np.int32(ntx),
                             *(np.float32(v) for v in kabc), params, grids)
        n = ntx * nty * self.lay.maxp * self.local.x
        return cl.enqueue_nd_range_kernel(queue, self.kernel, (n,), (self.local.x,),
                                          wait_for=wait_for)
