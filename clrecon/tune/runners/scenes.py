"""The runner of the scene generator's ray tracer (pass ``raytrace``) for the tuner."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.device import Device
from clrecon.scenes import get_scene
from clrecon.scenes import render as rt
from clrecon.tune.local import local_size_of
from clrecon.tune.runners.common import PassRunner, PassSpec, tunes, wg_items

#: this method's passes, as :func:`tunes` registers their runners
SPECS: list[PassSpec] = []


@tunes(SPECS, rt.RAYTRACE)
def raytrace_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    scene = get_scene("deep")
    cam, objs, camera, light, bg = rt._common_args(scene, w, h, dev.context)
    n = w * h * spp
    wo = cl.mem_flags.WRITE_ONLY
    fields = [cl.Buffer(dev.context, wo, n * 4 * k) for k in (3, 2, 1, 2, 1, 2)]

    class Launch:
        def __init__(self, config):
            self.local = local_size_of(config)
            self.kernel = cl.Kernel(rt.get_kernel(dev.context, "raytrace", "raytrace_samples")
                                    .get_info(cl.kernel_info.PROGRAM), "raytrace_samples")

    def launch(p, q, out):
        # colour is the checked output; the other fields are written alongside
        p.kernel.set_args(*objs, np.int32(w), np.int32(h), np.int32(spp), np.int32(0),
                          np.uint32(0), *camera, light, bg, out, *fields[1:])
        g, loc = p.local.for_range(w, h)
        return cl.enqueue_nd_range_kernel(q, p.kernel, g, loc)

    return PassRunner(dev, Launch, launch, (h, w, spp, 3), wg_items)
