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
pixel's own estimates: the blend's squared error were the two estimates exact and the two
errors fully correlated (both images come from the same samples), the largest any
correlation gives. It inherits the members' calibration, which understates: measured
(512x512, seed 100 + spp, fence, deep, fast_motion at 8 and 64 spp) its frame mean is
0.30-0.75 of the true MSE (the chain's own 0.24-0.62), and its Spearman rank correlation
with the true error over 8x8 tiles 0.77-0.95 (the chain's 0.73-0.94). Below 8 spp the
chain runs alone (:func:`blends`).

Measured (``docs/measurements/trade-512-hybrid.md``: ``splat guided nlm3x4 +hybrid``
against the chain alone, 512x512, six blurred scenes): at 8-64 spp +0.21 to +1.25 dB on fence
(16-64), spheres, deep and fast_motion (+3.35 at 64 spp, still 1.7 dB below box nlm alone:
the estimates are not sharp enough to give it all the weight), -0.02 to -0.15 on fence (8),
bokeh (8, 16) and huge_coc; at 4 spp, before the gate, -0.4 to -1.2 on fence, deep and
fast_motion. A NumPy prototype on the device's images measured the alternatives: a per-pixel
choice of the smaller estimate, or the estimates' 1x1 or 3x3 means, did worse on most cells.

Cost: both members, then one pass (the box member at 512x512: 60-80 ms).
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.device import get_kernel
from clrecon.core.pipeline import Pipeline
from clrecon.core.plan import Plan, Step, unique_bounds
from clrecon.methods.safeguard_passes import MIN_TEST_HALF, halves

#: the error estimates' window half side (the safeguard's 7x7 bias window)
HR = 3


def blends(spp: int) -> bool:
    """Whether a frame of ``spp`` samples a pixel is blended: each half holds at least
    :data:`~clrecon.methods.safeguard_passes.MIN_TEST_HALF` samples (8 spp), the count from
    which the safeguard takes its windows' means as they come. Below, the estimates from
    halves of 2-3 samples are mostly noise: at 4 spp the blend lost 0.4-1.2 dB to the chain
    on fence, deep and fast_motion (512x512), so the chain runs alone."""
    return min(halves(int(spp))) >= MIN_TEST_HALF


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
    """The method's chain and box's (two :class:`~clrecon.methods.safeguard.Safeguarded`
    pipelines of the frame, both estimating their error) blended by ``hybrid_blend``; below
    8 spp the chain alone (:func:`blends`)."""

    #: the weights depend on the colours (see :func:`clrecon.core.pipeline.run`)
    color_linear = False

    def __init__(self, context, info, make_chain, make_box):
        """``make_chain(info)``, ``make_box(info)``: the members planned for a frame (again
        on :meth:`regrow`)."""
        super().__init__(context, info)
        self._make = (make_chain, make_box)
        self.chain = chain = make_chain(info)
        # a chain planned as box (a frame without blur) already is box's nlm: no second one
        self.alone = not blends(info.spp) or getattr(chain, "box_halves", False)
        self.box = box = None if self.alone else make_box(info)
        self.name = chain.name
        npx = info.width * info.height
        if box is None:  # the chain into the image, its estimate into the error
            steps = (Step(f"{chain.name} chain", chain.plan.fields, ("out",),
                          self._member(chain, "out", "")),
                     Step("hybrid_error", (), ("error",), self._copy_error))
            temps, bounds = {"error": npx * 4}, tuple(chain.plan.bounds)
            fields = chain.plan.fields
        else:
            self.blend = HybridBlend(context)
            fields = tuple(dict.fromkeys(chain.plan.fields + box.plan.fields))
            steps = (Step(f"{chain.name} chain", fields, ("ia",),
                          self._member(chain, "ia", "")),
                     Step("box nlm", ("color",), ("ib",), self._member(box, "ib", "box nlm: ")),
                     Step("hybrid_blend", ("ia", "ib"), ("out", "error"), self._blend))
            temps = {"ia": npx * 12, "ib": npx * 12, "error": npx * 4}
            bounds = tuple(chain.plan.bounds) + tuple(box.plan.bounds)
        self.set_plan(Plan(chain.name, f"{chain.plan.name}+hybrid", fields, steps, temps,
                           unique_bounds(bounds)))

    @staticmethod
    def _member(pipe, out: str, prefix: str):
        def run(queue, f, wait_for):
            pipe(queue, f.samples, f.buffers[out], wait_for=wait_for)
            return [(prefix + name, ev) for name, ev in pipe.events]
        return run

    def _copy_error(self, queue, f, wait_for):
        return [("hybrid_error", cl.enqueue_copy(queue, f.buffers["error"],
                                                 self.chain.buffer("error"),
                                                 wait_for=wait_for))]

    def _blend(self, queue, f, wait_for):
        b = f.buffers
        return [("hybrid_blend", self.blend(queue, b["ia"], self.chain.buffer("error"), b["ib"],
                                            self.box.buffer("error"), b["out"], b["error"],
                                            f.width, f.height, wait_for))]

    def regrow(self, info) -> None:
        self.__init__(self.context, info, *self._make)

    def describe(self) -> dict:
        d = dict(self.chain.describe())
        d["hybrid"] = {"with": None if self.box is None else self.box.plan.name,
                       "window": 2 * HR + 1,
                       "weights": "inverse of the 7x7 sums of the error estimates"
                       if self.box is not None else
                       f"the chain alone: halves of fewer than {MIN_TEST_HALF} samples"
                       if not blends(self.info.spp) else
                       "the chain alone: planned as box, it is box's nlm"}
        d["estimate_error"] = True
        d["plan"] = self.plan.name
        return d
