"""A hybrid of two safeguarded images of one frame, blended per pixel by their own error
estimates (``hybrid=True``; ``kernels/hybrid.cl``).

Why. A method's chain (``guided``, ``nlm``) uses what the samples say of depth, lens and
time; where the blur is wide that is worth 1.5-5 dB over any filter of the image. Where every
method's bias holds its safeguard near box (a fast-moving panel at 64 spp), box's own halves
filtered by the same non-local means (``method="box", nlm=R``) are the better image by up to
5 dB (``docs/measurements/trade-512-box-nlm.md``). Both come with a per-pixel error estimate
from the halves (the safeguard's), so each pixel can weigh the two.

How. The members are the method's safeguarded chain and box's, each with the frame's
``nlm`` and ``nlm_scales``; each writes its image and its error estimate. Per pixel, with
``Sa``, ``Sb`` the members' estimates summed over the 7x7 window (the safeguard's own bias
window), the chain weighs ``wa = Sb / (Sa + Sb)`` (inverse-error weights); the image is
``b + wa (a - b)``. The error estimate is ``(wa sqrt(ea) + (1 - wa) sqrt(eb))^2`` from the
pixel's own estimates: the blend's squared error were the two errors fully correlated, an
upper bound for any correlation (both images come from the same samples). Measured before it
was built (a NumPy prototype on the device's images, 512x512, 8, 16, 64 spp, six blurred
scenes): the inverse weights over 7x7 gained over the chain alone on four scenes (up to
+3.4 dB, fast_motion at 64 spp) and lost 0.03-0.15 dB on bokeh and huge_coc; a per-pixel
choice of the smaller estimate, or a 1x1 or 3x3 window, did worse.

Cost: both members, then one pass (the box member at 512x512: 60-80 ms).
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.device import get_kernel
from clrecon.core.pipeline import Pipeline
from clrecon.core.plan import Plan, Step, unique_bounds

#: the error estimates' window half side (the safeguard's 7x7 bias window)
HR = 3
_FLT_MAX = float(np.finfo(np.float32).max)


def reference(a, ea, b, eb, r: int = HR):
    """(image, error, wa) of the blend: ``a``, ``b`` (H, W, 3), ``ea``, ``eb`` (H, W) the
    members' images and error estimates (see the module). The window sums are float32 in
    the kernel's order (saturated estimates sum to inf, as there); the rest float64."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    ea, eb = np.asarray(ea, np.float32), np.asarray(eb, np.float32)
    h, w = ea.shape
    pa, pb = np.pad(ea, r), np.pad(eb, r)
    sa, sb = np.zeros((h, w), np.float32), np.zeros((h, w), np.float32)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for dy in range(2 * r + 1):
            for dx in range(2 * r + 1):
                sa += pa[dy:dy + h, dx:dx + w]
                sb += pb[dy:dy + h, dx:dx + w]
        s = sa + sb
        sa, sb, s = (x.astype(np.float64) for x in (sa, sb, s))
        ea, eb = ea.astype(np.float64), eb.astype(np.float64)
        wa = np.where((s > 0) & np.isfinite(s), sb / np.where(s > 0, s, 1.0),
                      np.where(sa < sb, 1.0, np.where(sa > sb, 0.0, 0.5)))
        img = b + wa[..., None] * (a - b)
        err = np.minimum((wa * np.sqrt(ea) + (1 - wa) * np.sqrt(eb)) ** 2, _FLT_MAX)
    return img, err, wa


class HybridBlend:
    """Pass ``hybrid_blend`` (``kernels/hybrid.cl``)."""

    def __init__(self, context):
        self.kernel = get_kernel(context, "hybrid", "hybrid_blend", {"HR": HR})

    def __call__(self, queue, a, ea, b, eb, out, error, width: int, height: int,
                 wait_for=None) -> cl.Event:
        self.kernel.set_args(a, ea, b, eb, out, error, np.int32(width), np.int32(height))
        return cl.enqueue_nd_range_kernel(queue, self.kernel, (width, height), None,
                                          wait_for=wait_for)


class Hybrid(Pipeline):
    """``chain`` and ``box`` (two :class:`~clrecon.methods.safeguard.Safeguarded` pipelines
    of the frame, both estimating their error) blended by ``hybrid_blend``."""

    #: the weights depend on the colours (see :func:`clrecon.core.pipeline.run`)
    color_linear = False

    def __init__(self, context, info, chain: Pipeline, box: Pipeline, make):
        """``make(info) -> (chain, box)`` re-plans both members (:meth:`regrow`)."""
        super().__init__(context, info)
        self.chain, self.box, self._make = chain, box, make
        self.name = chain.name
        self.blend = HybridBlend(context)
        npx = info.width * info.height
        fields = tuple(dict.fromkeys(chain.plan.fields + box.plan.fields))
        steps = (Step(f"{chain.name} chain", fields, ("ia",), self._member(chain, "ia", "")),
                 Step("box nlm", ("color",), ("ib",), self._member(box, "ib", "box nlm: ")),
                 Step("hybrid_blend", ("ia", "ib"), ("out", "error"), self._blend))
        plan = Plan(chain.name, f"{chain.plan.name}+hybrid", fields, steps,
                    {"ia": npx * 12, "ib": npx * 12, "error": npx * 4},
                    unique_bounds(tuple(chain.plan.bounds) + tuple(box.plan.bounds)))
        self.set_plan(plan)

    @staticmethod
    def _member(pipe, out: str, prefix: str):
        def run(queue, f, wait_for):
            pipe(queue, f.samples, f.buffers[out], wait_for=wait_for)
            return [(prefix + name, ev) for name, ev in pipe.events]
        return run

    def _blend(self, queue, f, wait_for):
        b = f.buffers
        return [("hybrid_blend", self.blend(queue, b["ia"], self.chain.buffer("error"), b["ib"],
                                            self.box.buffer("error"), b["out"], b["error"],
                                            f.width, f.height, wait_for))]

    def regrow(self, info) -> None:
        chain, box = self._make(info)
        self.__init__(self.context, info, chain, box, self._make)

    def describe(self) -> dict:
        d = dict(self.chain.describe())
        d["hybrid"] = {"with": self.box.plan.name, "window": 2 * HR + 1,
                       "weights": "inverse of the 7x7 sums of the error estimates"}
        d["estimate_error"] = True
        d["plan"] = self.plan.name
        return d
