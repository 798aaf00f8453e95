"""The runner of method box's pass for the tuner."""
from __future__ import annotations

from clrecon.core.device import Device
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods.box import Box
from clrecon.tune.local import local_size_of
from clrecon.tune.runners.common import PassRunner, PassSpec, synthetic_frame, tunes, wg_items

#: this method's passes, as :func:`tunes` registers their runners
SPECS: list[PassSpec] = []


@tunes(SPECS, Box.TUNABLE)
def box_runner(dev: Device, w: int, h: int, spp: int) -> PassRunner:
    buf = synthetic_frame(w, h, spp)
    s = DeviceSamples.upload(dev.queue, buf, ("color",))
    return PassRunner(dev, lambda c: Box(dev.context, local_size_of(c)),
                      lambda p, q, out: p(q, s["color"], out, w, h, spp), (h, w, 3), wg_items)
