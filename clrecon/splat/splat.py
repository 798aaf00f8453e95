"""Pass ``splat``: one work-item per sample adds its PSF's spreadlets (or, on the fast track,
its dense PSF) into the images of its depth layer (``kernels/splat.cl``)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from ..device import get_kernel
from ..pipeline import DeviceSamples
from .tables import DeviceTable


class Splat:
    """``kernels/splat.cl`` / ``splat_samples``."""

    name = "splat"

    def __init__(self, context: cl.Context, spp: int, ndim: int, has_motion: bool, nlayers: int,
                 wg: int | None = 64):
        self.wg = wg
        self.kernel = get_kernel(context, "splat", "splat_samples",
                                 {"SPP": spp, "NDIM": ndim, "HAS_MOTION": int(has_motion),
                                  "NLAYERS": nlayers})

    def __call__(self, queue, samples: DeviceSamples, table: DeviceTable, inv_far: float,
                 layer_scale: float, pad: int, reach: int, lap: cl.Buffer, direct: cl.Buffer,
                 wait_for=None) -> cl.Event:
        n = samples.height * samples.width * samples.spp
        c0, c1 = samples.coc
        pw, ph = samples.width + 2 * pad, samples.height + 2 * pad
        self.kernel.set_args(
            samples["color"], samples["position"], samples["depth"], samples["lens"],
            samples["time"], samples["motion"], np.int32(n), np.float32(c0), np.float32(c1),
            np.float32(inv_far), np.float32(layer_scale), np.int32(pad), np.int32(pw),
            np.int32(ph), np.int32(reach), table.pts, table.vals, table.offs, table.dpts,
            table.dvals, table.doffs, table.fast, table.gn, table.gsmax, table.ginvb, table.levels,
            np.int32(table.nlev), lap, direct)
        if self.wg is None:
            return cl.enqueue_nd_range_kernel(queue, self.kernel, (n,), None, wait_for=wait_for)
        g = -(-n // self.wg) * self.wg
        return cl.enqueue_nd_range_kernel(queue, self.kernel, (g,), (self.wg,),
                                          wait_for=wait_for)
