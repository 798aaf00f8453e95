"""Method ``box``: the per-pixel average of a pixel's samples (the baseline of every report)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.device import get_kernel
from clrecon.core.knobs import KnobTypeError
from clrecon.core.local_size import LocalSize
from clrecon.core.pipeline import Pipeline, register
from clrecon.core.plan import BOX_PLAN, Plan, Step, shape_bounds
from clrecon.tune.local import local_size_of
from clrecon.tune.runtime import tuned
from clrecon.tune.tunable import DEFAULT_LOCAL, GPU_LOCAL, Tunable, local_candidates


class Box:
    """Pass ``box``: ``kernels/box.cl`` / ``box_average``."""

    name = "box"
    TUNABLE = Tunable(name, "box", DEFAULT_LOCAL, local_candidates, gpu=GPU_LOCAL)

    def __init__(self, context: cl.Context, local: LocalSize | None = None):
        self.local = check_local("local", local) or LocalSize(16, 4)
        dev = context.devices[0]
        self.local.check(dev, self.name)  # before building for a size that cannot launch
        # the local size is a launch parameter only: every candidate shares one program
        self.kernel = get_kernel(context, "box", "box_average")
        self.local.check(dev, self.name, self.kernel)

    def __call__(self, queue, color: cl.Buffer, out: cl.Buffer, width: int, height: int,
                 spp: int, wait_for=None) -> cl.Event:
        gsize, lsize = self.local.for_range(width, height)
        self.kernel.set_args(color, out, np.int32(width), np.int32(height), np.int32(spp))
        return cl.enqueue_nd_range_kernel(queue, self.kernel, gsize, lsize, wait_for=wait_for)


def check_local(name: str, local) -> LocalSize | None:
    """``local`` if it is a :class:`LocalSize` or ``None`` (its values are checked by
    :class:`LocalSize` itself, the device's limits by :meth:`LocalSize.check`)."""
    if local is not None and not isinstance(local, LocalSize):
        raise KnobTypeError(f"{name}: must be a LocalSize(x, y) or None, got {local!r} "
                            f"({type(local).__name__})")
    return local


def box_step(box: Box) -> Step:
    """The box pass as a plan step (every method's box plan uses it)."""

    def run(queue, f, wait_for):
        ev = box(queue, f.buffers["color"], f.buffers["out"], f.width, f.height, f.spp,
                 wait_for)
        return [("box", ev)]

    return Step("box", ("color",), ("out",), run)


def box_plan(method: str, box: Box, info, extra_bounds=()) -> Plan:
    """The plan that is the per-pixel average. Its own bounds are the frame's shape (the
    kernel takes spp as an argument); a method that chose it because the frame's blur stays
    inside the pixel adds the bounds that choice rests on."""
    return Plan(method, BOX_PLAN, ("color",), (box_step(box),), {},
                shape_bounds(info) + tuple(extra_bounds))


@register
class BoxPipeline(Pipeline):
    """The box filter as a one-pass plan."""

    name = "box"

    def __init__(self, context, info, local: LocalSize | None = None):
        check_local("local", local)
        super().__init__(context, info)
        self.tuning = {}
        if local is None:
            found = tuned(context, Box.TUNABLE, info)
            local = local_size_of(found.config)
            self.tuning["box"] = found.source
        else:
            self.tuning["box"] = "api"
        self.box = Box(context, local)
        self.set_plan(box_plan("box", self.box, info))

    def describe(self) -> dict:
        return {"method": "box", "plan": BOX_PLAN,
                "local_size": [self.box.local.x, self.box.local.y], "tuning": self.tuning}
