"""The runners of method splat's passes for the tuner."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.api import make_pipeline
from clrecon.core.device import Device
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods.splat.composite import SplatComposite
from clrecon.methods.splat.integrate import SplatIntegrate
from clrecon.methods.splat.splat import Splat
from clrecon.tune.local import local_size_of
from clrecon.tune.runners.common import PassRunner, PassSpec, synthetic_frame, tunes, wg_items

#: this method's passes, as :func:`tunes` registers their runners
SPECS: list[PassSpec] = []


def _splat_frame_pipeline(dev, w, h, spp):
    buf = synthetic_frame(w, h, spp)
    s = DeviceSamples.upload(dev.queue, buf)
    return make_pipeline("splat", dev.context, buf.inspect(), psf="combined", layers=2,
                         mip_radius=0, safeguard=False), s


def _group(config: dict | None) -> int | None:
    return None if config is None else int(config["wg"])


@tunes(SPECS, Splat.TUNABLE)
def splat_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    pipe, s = _splat_frame_pipeline(dev, w, h, spp)
    n = pipe.layers * pipe.shape[0] * pipe.shape[1] * 4

    def launch(p, q, out):
        # accumulating pass: clear first (fast-track cells go to pipe.direct, not checked)
        ev = cl.enqueue_fill_buffer(q, out, np.float32(0), 0, n * 4)
        return p(q, s, pipe.device_table, pipe.inv_far, pipe.layer_scale, pipe.pad, pipe.reach,
                 out, pipe.direct, [ev])

    return PassRunner(dev, lambda c: Splat(dev.context, spp, 2, True, pipe.layers, _group(c)),
                      launch, (n,), _group)


@tunes(SPECS, SplatIntegrate.TUNABLE)
def integrate_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    pipe, s = _splat_frame_pipeline(dev, w, h, spp)
    q = dev.queue
    size = pipe.layers * pipe.shape[0] * pipe.shape[1] * 16
    evs = [cl.enqueue_fill_buffer(q, b, np.float32(0), 0, size) for b in (pipe.lap, pipe.direct)]
    pipe.splat(q, s, pipe.device_table, pipe.inv_far, pipe.layer_scale, pipe.pad, pipe.reach,
               pipe.lap, pipe.direct, evs).wait()
    ring = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, pipe.layers * 16)
    return PassRunner(dev, lambda c: SplatIntegrate(dev.context, *pipe.shape, "f5",
                                                    local_size_of(c)),
                      lambda p, q, out: p(q, pipe.lap, 0, out, ring),
                      (*pipe.shape, 4), wg_items)  # layer 0 only


@tunes(SPECS, SplatComposite.TUNABLE)
def composite_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    pipe, s = _splat_frame_pipeline(dev, w, h, spp)
    out = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, w * h * 12)
    pipe(dev.queue, s, out).wait()
    return PassRunner(dev, lambda c: SplatComposite(dev.context, pipe.layers, True,
                                                    local_size_of(c)),
                      lambda p, q, o: p(q, pipe.prim, pipe.direct, pipe.ring, w, h, pipe.pad, o),
                      (h, w, 3), wg_items)
