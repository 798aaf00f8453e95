"""Method ``box``: the per-pixel average of a pixel's samples (the baseline of every report)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from .device import get_kernel
from .pipeline import DeviceSamples, LocalSize, Pipeline, register


class Box:
    """Pass ``box``: ``kernels/box.cl`` / ``box_average``."""

    name = "box"

    def __init__(self, context: cl.Context, local: LocalSize | None = None):
        self.local = local or LocalSize(16, 4)
        defines = {} if self.local.x is None else {"WG_X": self.local.x, "WG_Y": self.local.y}
        self.kernel = get_kernel(context, "box", "box_average", defines)

    def __call__(self, queue, color: cl.Buffer, out: cl.Buffer, width: int, height: int,
                 spp: int, wait_for=None) -> cl.Event:
        gsize, lsize = self.local.for_range(width, height)
        self.kernel.set_args(color, out, np.int32(width), np.int32(height), np.int32(spp))
        return cl.enqueue_nd_range_kernel(queue, self.kernel, gsize, lsize, wait_for=wait_for)


@register
class BoxPipeline(Pipeline):
    """The box filter as a one-pass plan."""

    name = "box"
    fields = ("color",)

    def __init__(self, context, info, local: LocalSize | None = None):
        super().__init__(context, info)
        self.tuning = {}
        if local is None:
            from .tune.runtime import tuned
            from .tune.specs import local_size_of

            found = tuned(context, "box", info)
            local = local_size_of(found.config)
            self.tuning["box"] = found.source
        else:
            self.tuning["box"] = "api"
        self.box = Box(context, local)

    def describe(self) -> dict:
        return {"method": "box", "local_size": [self.box.local.x, self.box.local.y],
                "tuning": self.tuning}

    def enqueue(self, queue, samples: DeviceSamples, out, wait_for=None):
        ev = self.box(queue, samples["color"], out, samples.width, samples.height, samples.spp,
                      wait_for)
        self.events.append(("box", ev))
        return ev
