"""The per-pixel safeguard: every method's squared error estimated from the samples, and a
blend toward the box filter wherever the method's bias dominates (``kernels/safeguard.cl``).

Why. The three papers' methods trade bias for variance once and for all: at 16-64 spp
their images stop improving and fall below the per-pixel average (box), whose error is pure
variance and keeps falling. A renderer that adds samples expects a better image; it also
wants to know where the image is wrong (to place its next samples).

How. The frame's samples are split per pixel into two halves, A (samples ``0..ha-1``) and
B (``ha..S-1``): two independent estimates of everything. The method runs on the frame
(image ``m``; see below for the methods that take the halves' mean) and on each half
(``mA``, ``mB``); box is the samples' mean, ``boxA``/``boxB``
the halves'. With ``k = ha hb / S^2`` (``1/4`` for equal halves), per pixel, in linear
radiance averaged over RGB:

* ``vb = k |boxA - boxB|^2`` estimates box's variance (its whole error: box is unbiased).
  Independent halves, not the samples' spread: a renderer's samples are usually stratified,
  and the spread of stratified samples overstates the variance of their mean many times
  over (100x at 64 spp on the built-in scenes);
* ``vm = k |mA - mB|^2`` estimates the method's variance (the halves' images differ by noise
  alone);
* ``d2 = |m - box|^2`` has expectation ``bias^2 + var(m - box)``, so ``e = d2 - vm - vb``
  estimates the method's squared bias (from 16 spp ``d2 + vm - vb``: the covariance of
  ``m`` and box modelled, ``safeguard_passes.models_covariance``); it is averaged over a
  7x7 window (a bias is coherent in space, noise is not), and over 3x3 where that mean
  stands two standard errors above zero (a bias along a thin edge, which the wider window
  dilutes; the noise of the 3x3 mean alone would otherwise pull the image toward box at
  low spp): ``b2 = max(0, mean7(e), mean3(e) - 2 se3(e))`` (below 16 spp and with the
  guided refinement ``mean7`` is tested or scaled: ``bias_tests``, ``shrinks_by_frame``);
* the method's error is ``err_m = b2 + mean3(vm)``; the weight that minimises the expected
  squared error of ``box + w (m - box)`` when the two errors are independent is ``w = vb /
  (vb + err_m)``, and the blend's error ``w^2 err_m + (1 - w)^2 vb``. Here ``vb`` is
  ``max(mean3(vb), mean7(vb))`` (box's own error estimate stays the unbiased
  ``mean3(vb)``): a pixel whose own samples all missed a rare contributor (a blurred
  highlight) has halves that agree and a variance near 0, while its neighbours' samples
  show the spread (without the 7x7 term the blend lost 2 dB on ``bokeh`` at 8 spp).

The sampler's convergence. Halves measure the variance of a half's mean; ``k`` turns it
into the frame's as if the samples were independent (variance ``1/n``). Stratified samples
converge faster, so ``vb`` and ``vm`` overstate the frame's variances, and the blend keeps
a biased method where box is already the better. From 16 spp (quarters of >= 4 samples)
the frame measures it (declared ``independent_samples``: ``s = 1``): ``s = sum S vb / sum
dq``, ``dq`` the quarters' squared difference per unit of their ``1/n0 + 1/n1`` (``s = 1``
for independent samples), clamped to [0, 1], scales ``vb`` and ``vm`` (``safeguard_ratio``),
assuming the quarter-to-half convergence holds from half to frame.

As samples grow, ``vb`` falls like box's error while a method's bias does not: ``w`` goes
to 0 and the image to box's (consistent); where the method is unbiased ``w`` stays near 1.
Range: colours reach 1e30: each pixel's statistics are in units of its own binary
exponent, rescaled to a window's largest (the error saturates at FLT_MAX above ~1e19).

The method's image is the mean of its halves' images (``Pipeline.halves_mean``); what runs
once for both halves and the cost: docs/ARCHITECTURE.md. ``safeguard=False``: the paper.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from clrecon.core.errors import DeviceMemoryError
from clrecon.core.pipeline import DeviceSamples, Pipeline, make_method
from clrecon.core.plan import BOX_PLAN, Plan, Step, shape_bounds, unique_bounds
from clrecon.core.samples import FIELDS
from clrecon.methods import nlm as nl
from clrecon.methods.guided import GuidedPasses, check_radius
from clrecon.methods.safeguard_passes import (
    FDR_Q,
    SafeguardPasses,
    bias_tests,
    halves,
    measures_convergence,
    models_covariance,
    shrinks_by_frame,
)

# the NumPy reference and the blend's modes, re-exported from their module (``X as X``)
from clrecon.methods.safeguard_reference import MODE_BLEND as MODE_BLEND  # noqa: E402
from clrecon.methods.safeguard_reference import MODE_BOX as MODE_BOX  # noqa: E402
from clrecon.methods.safeguard_reference import MODE_METHOD as MODE_METHOD
from clrecon.methods.safeguard_reference import reference as reference
from clrecon.methods.safeguard_reference import reference_of_halves as reference_of_halves

#: below 8 spp every blend tests its 7x7 bias mean at 2 standard errors, declared
#: independent samples below 16 (bias_tests); from 16 spp those shrink it by its
#: significance (z7 < 0 in kernels/safeguard.cl; docs/measurements/sampler-random-pocl.md)
GUIDED_Z7, SHRINK_Z7 = 2.0, -1.0


class Safeguarded(Pipeline):
    #: the weights depend on the colours: a frame with negative radiance is reconstructed
    #: as its positive and negative parts apart (see :func:`clrecon.core.pipeline.run`)
    color_linear = False

    """A method's pipeline with the safeguard: ``inner`` (a method name) planned for the
    frame and for its halves, then ``safeguard_stats`` and ``safeguard_blend``.

    ``blend=False`` keeps the method's image (the error estimate alone); with ``inner ==
    "box"`` the image is box's and the error its variance (the halves are not re-run).
    The error image is the temporary ``"error"`` ((H, W) float32: the estimated squared
    error of the image, linear radiance, mean over RGB). ``views=False`` copies the halves
    (``safeguard_split``) even where the method could read them in place. ``joint=False``
    runs a method's ``joint_steps`` (both halves at once) on each half: the same bits."""

    def __init__(self, context, info, method: str, knobs: dict, blend: bool = True,
                 full: Pipeline | None = None, views: bool = True, joint: bool = True,
                 guided: int = 0, guide_blend: bool = True, nlm: int = 0, nlm_scales: int = 1,
                 independent_samples: bool = False):
        self._flags = dict(views=views, joint=joint, guided=guided, guide_blend=guide_blend,
                           nlm=nlm, nlm_scales=nlm_scales,
                           independent_samples=bool(independent_samples))
        self.independent = bool(independent_samples)
        if info.spp < 2:
            raise ValueError(f"safeguard: needs >= 2 samples per pixel (two independent "
                             f"halves), the frame has {info.spp}")
        super().__init__(context, info)
        self.name = method
        self.inner_method, self.inner_knobs, self.blend = method, dict(knobs), bool(blend)
        self.passes = SafeguardPasses(context)
        self.full = full if full is not None else make_method(method, context, info, **knobs)
        # a plan that is the per-pixel average (a frame without blur) is box: its error is
        # box's variance, and there is nothing to blend
        is_box = method == "box" or self.full.plan.name == BOX_PLAN
        # nlm on box's own halves (box, or a method planned as box): blended like a method's
        nlm = nl.check_radius(nlm)
        self.box_halves = is_box and nlm > 0
        self.mode = MODE_BOX if is_box and not self.box_halves else (
            MODE_BLEND if blend else MODE_METHOD)
        # a method whose weights do not depend on the sample count (its class says so) gets
        # the blend's method image from its halves, (ha mA + hb mB) / S, instead of a third
        # run on the frame: the same bias and variance, a third less work. The error alone
        # (MODE_METHOD) keeps the method's own image.
        # guided: the halves' images refined by their box images (clrecon.methods.guided);
        # the image is the refined halves' mean, with or without the blend
        self.guided = 0 if is_box else check_radius(guided)
        # nlm: the halves' images (the method's or the refined ones) averaged further with
        # dual-buffer non-local means (clrecon.methods.nlm)
        self.nlm = nlm if self.box_halves or not is_box else 0
        mean_of_halves = self.full.halves_mean or self.box_halves  # box's: by definition
        for knob, on in (("guided", self.guided), ("nlm", self.nlm)):
            if on and not mean_of_halves:
                raise ValueError(f"{knob}: {method}'s image is not the mean of its halves' "
                                 f"images, so the filtered halves cannot stand for it")
        self.halves_mean = (self.mode == MODE_BLEND or bool(self.guided or self.nlm)) and \
            mean_of_halves
        ha, hb = halves(info.spp)
        self.half_a = self.half_b = None
        if not is_box:
            self.half_a = make_method(method, context, replace(info, spp=ha), **knobs)
            self.half_b = self.half_a if hb == ha else make_method(
                method, context, replace(info, spp=hb), **knobs)
        # the steps the frame runs for the halves (their outputs are the halves' inputs)
        have = {st.name: st for st in self.full.plan.steps}
        self.shared = tuple(n for n in self.full.shared_steps if n in have) \
            if self.halves_mean else ()
        self.shared_out = tuple(o for n in self.shared for o in have[n].outputs)
        npx = info.width * info.height
        inner_fields = tuple(f for f in FIELDS if f in set(self.full.plan.fields) | {"color"})
        temps = {"m": npx * 12, "box": npx * 12, "error": npx * 4,
                 "stats": self.passes.stats_bytes(info.width, info.height),
                 "rows": self.passes.rows_bytes(info.width, info.height)}
        # halves whose passes read a view of the frame (DeviceSamples.view) are read in place;
        # the others from copies (safeguard_split): a full read and write of their fields
        self.views = bool(views) and not is_box and self.half_a.sample_views and \
            self.half_b.sample_views
        half_fields = inner_fields if self.views else tuple(
            f"{h}.{f}" for h in "ab" for f in inner_fields)
        # steps the frame runs once for both halves, and their outputs the halves' rest reads
        js = tuple(getattr(self.full, "joint_steps", ())) if joint and self.views else ()
        self.joint = js if self.halves_mean and all(n in have for n in js) else ()
        rest_in = {i for st in self.half_a.plan.steps if st.name not in self.shared + self.joint
                   for i in st.inputs} if self.joint else set()
        self.joint_out = tuple(dict.fromkeys(o for n in self.joint for o in have[n].outputs
                                             if o in self.full.plan.temporaries and o in rest_in))
        steps = []
        if self.box_halves:
            temps |= {"ma": npx * 12, "mb": npx * 12}
            steps.append(self.passes.box_halves_step())
        if not is_box:
            temps |= {"ma": npx * 12, "mb": npx * 12}
            if not self.views:
                for half, n in (("a", ha), ("b", hb)):
                    for f in inner_fields:
                        temps[f"{half}.{f}"] = npx * n * int(np.prod(FIELDS[f])) * 4
                steps.append(Step("safeguard_split", inner_fields, half_fields,
                                  self._split_step(inner_fields)))
            if not self.halves_mean:
                steps.append(Step(method, inner_fields, ("m",), self._inner_step()))
            elif self.shared:
                steps.append(Step(f"{method} ({', '.join(self.shared)})", inner_fields, (),
                                  self._inner_step(self.shared)))
            for o in self.joint_out:  # half B's copy of each (half A's: the frame's own)
                temps[f"{o}_b"] = self.full.plan.temporaries[o]
            if self.joint:
                steps.append(Step(f"{method} ({', '.join(self.joint)}, both halves)",
                                  inner_fields, tuple(f"{o}_b" for o in self.joint_out),
                                  self._joint_step()))
            steps.append(Step(f"{method} (halves)", half_fields, ("ma", "mb"),
                              self._halves_step(inner_fields)))
        # the halves' images the statistics read: the method's, or their refinements (each
        # blended toward the method's own where that is estimated the better: guide_blend)
        self.guide_blend = bool(self.guided) and bool(guide_blend)
        self.half_images = ("ba", "bb") if self.guide_blend else \
            ("qa", "qb") if self.guided else ("ma", "mb")
        if self.guided:
            passes = GuidedPasses(context, self.guided)
            temps |= passes.temporaries(info.width, info.height)
            steps.append(passes.step())
        if self.guide_blend:
            temps |= {"ba": npx * 12, "bb": npx * 12}
            steps.append(Step("guided_blend", ("qa", "qb", "ma", "mb"), ("ba", "bb"),
                              self._guide_blend_step()))
        if self.nlm:
            passes = nl.NlmPasses(context, self.nlm, nlm_scales)
            temps |= passes.temporaries(info.width, info.height)
            steps.append(passes.step(self.half_images))
            self.half_images = ("na", "nb")
        images = () if is_box else self.half_images if self.halves_mean else \
            ("m",) + self.half_images
        steps.append(Step("safeguard_stats", ("color",) + images,
                          ("box", "stats") + (("m",) if self.halves_mean else ()),
                          self._stats_step()))
        # from 16 spp the halves' variances are scaled by the sampler's measured convergence
        # (declared independent samples converge as the halves assume: nothing to measure)
        self.scaled = measures_convergence(info.spp) and not self.independent
        if self.scaled:
            temps |= {"sg_partial": self.passes.ratio_bytes(info.height), "sg_scale": 4}
            steps.append(Step("safeguard_ratio", ("stats",), ("sg_scale",),
                              self._ratio_step()))
        # the 7x7 test at a false discovery rate (the chain) or the mean scaled by the
        # frame's q-value (from 8 spp): the frame's histogram
        self.frame_shrink = shrinks_by_frame(bool(self.guided), info.spp, self.independent)
        if self.guided or self.frame_shrink:
            q = FDR_Q if self.guided else None
            temps |= {"sg_fdr_hist": self.passes.fdr_bytes(info.height),
                      "sg_fdr_z": self.passes.fdr_table_bytes(q)}
        steps.append(Step("safeguard_blend", ("stats", "box") + (() if is_box else ("m",))
                          + (("sg_scale",) if self.scaled else ()), ("out", "error"),
                          self._blend_step()))
        bounds = tuple(self.full.plan.bounds) + shape_bounds(
            info, "the halves' pipelines are planned for spp // 2 and spp - spp // 2")
        suffix = ("guided+" if self.guided else "") + ("nlm+" if self.nlm else "") + (
            "safeguard" if self.mode == MODE_BLEND else "error")
        plan = Plan(method, f"{self.full.plan.name}+{suffix}", inner_fields, tuple(steps),
                    temps, unique_bounds(bounds))
        try:
            self.set_plan(plan)
        except DeviceMemoryError:
            if not self.joint:
                raise
            # half B's buffers of the joint steps do not fit: each half runs them itself
            self.__init__(context, info, method, knobs, blend, full=self.full,
                          **{**self._flags, "joint": False})
            self._flags["joint"] = joint

    # -- steps -------------------------------------------------------------------------------
    def _split_step(self, fields):
        def run(queue, f, wait_for):
            evs = []
            for name in fields:
                width = int(np.prod(FIELDS[name]))
                evs.append(("safeguard_split", self.passes.split_field(
                    queue, f.buffers[name], f.buffers[f"a.{name}"], f.buffers[f"b.{name}"],
                    f.width * f.height, f.spp, width, wait_for)))
            return evs
        return run

    def _inner_step(self, steps=None):
        def run(queue, f, wait_for):
            self.full(queue, f.samples, f.buffers["m"], wait_for=wait_for, steps=steps)
            return list(self.full.events)
        return run

    def _joint_step(self):
        def run(queue, f, wait_for):
            ha, _ = halves(f.spp)
            evs = self.full.joint_halves(queue, f.samples, ha,
                                         *(f.buffers[f"{o}_b"] for o in self.joint_out),
                                         wait_for=wait_for)
            if evs is None:
                raise RuntimeError(f"safeguard: {self.name}'s plan cannot run "
                                   f"{', '.join(self.joint)} for both halves")
            return [(f"{name} (halves)", ev) for name, ev in evs]
        return run

    def _halves_step(self, fields):
        def run(queue, f, wait_for):
            ha, hb = halves(f.spp)
            evs = []
            for half, n, pipe, out in (("a", ha, self.half_a, "ma"), ("b", hb, self.half_b, "mb")):
                info = replace(f.info, spp=n)
                if self.views:
                    ds = f.samples.view(n, 0 if half == "a" else ha, info)
                else:
                    ds = DeviceSamples(f.height, f.width, n,
                                       {k: f.buffers[f"{half}.{k}"] for k in fields},
                                       f.samples.coc, info)
                if self.shared or self.joint:  # the frame's outputs of those, the rest here
                    done = self.shared + self.joint
                    rest = tuple(st.name for st in pipe.plan.steps if st.name not in done)
                    given = {k: self.full.buffer(k) for k in self.shared_out
                             if k in pipe.plan.temporaries}
                    # the joint steps' outputs: half A's in the frame's buffers, B's apart
                    given |= {o: self.full.buffer(o) if half == "a" else f.buffers[f"{o}_b"]
                              for o in self.joint_out}
                    pipe(queue, ds, f.buffers[out], wait_for=wait_for, steps=rest,
                         temporaries=given)
                else:
                    pipe(queue, ds, f.buffers[out], wait_for=wait_for)
                evs.extend((f"{name} (halves)", ev) for name, ev in pipe.events)
            if self.joint and hasattr(self.full, "joint_drawn"):  # splat: bins zero again
                self.full.joint_drawn(*(f.buffers[f"{o}_b"] for o in self.joint_out))
            return evs
        return run

    def _guide_blend_step(self):
        """The safeguard's estimator with the refined halves in place of box's: per pixel
        the weight of the method's image against the refinement, then each half blended
        with it (the halves stay independent but for the shared weight)."""
        def run(queue, f, wait_for):
            b, p = f.buffers, self.passes
            ev0 = p.run_stats(queue, b["color"], b["m"], b["ma"], b["mb"], b["box"],
                              b["stats"], f.width, f.height, f.spp, 2, wait_for,
                              ua=b["qa"], ub=b["qb"])
            ev1 = p.run_rows(queue, b["stats"], b["rows"], f.width, f.height, [ev0])
            evs = [("guided_blend", ev0), ("guided_blend", ev1)]
            for q, m, out in (("qa", "ma", "ba"), ("qb", "mb", "bb")):
                evs.append(("guided_blend", p.run_blend_only(
                    queue, b["rows"], b[q], b[m], b[out], b["error"], f.width, f.height,
                    MODE_BLEND, 0, [ev1])))
            return evs
        return run

    def _stats_step(self):
        def run(queue, f, wait_for):
            b = f.buffers
            has = self.mode != MODE_BOX
            ia, ib = self.half_images
            m, ma, mb = (b["m"], b[ia], b[ib]) if has else (b["box"],) * 3
            ev = self.passes.run_stats(queue, b["color"], m, ma, mb, b["box"], b["stats"],
                                       f.width, f.height, f.spp,
                                       2 if self.halves_mean else int(has), wait_for,
                                       quarters=self.scaled)
            return [("safeguard_stats", ev)]
        return run

    def _ratio_step(self):
        def run(queue, f, wait_for):
            b = f.buffers
            return [("safeguard_ratio", ev) for ev in self.passes.run_ratio(
                queue, b["stats"], b["sg_partial"], b["sg_scale"], f.width, f.height, f.spp,
                wait_for)]
        return run

    def _blend_step(self):
        def run(queue, f, wait_for):
            b = f.buffers
            m = b["m"] if self.mode != MODE_BOX else b["box"]
            t7, t3 = bias_tests(bool(self.guided), f.spp, self.independent)
            return self.passes.run_blend(queue, b["stats"], b["rows"], b["box"], m,
                                         b["out"], b["error"], f.width, f.height, self.mode, 1,
                                         wait_for, GUIDED_Z7 if t7 else
                                         SHRINK_Z7 if self.independent else 0.0,
                                         b["sg_scale"] if self.scaled else None, t3,
                                         models_covariance(f.spp), (b["sg_fdr_hist"],
                                         b["sg_fdr_z"], FDR_Q if self.guided else None)
                                         if self.guided or self.frame_shrink else None)
        return run

    # -- protocol ----------------------------------------------------------------------------
    def regrow(self, info) -> None:
        self.__init__(self.context, info, self.inner_method, self.inner_knobs, self.blend,
                      **self._flags)

    def describe(self) -> dict:
        d = dict(self.full.describe())
        d["safeguard"] = self.mode == MODE_BLEND
        d |= {"guided": self.guided, "guide_blend": self.guide_blend} if self.guided else {}
        d |= {"nlm": self.nlm, "nlm_scales": self._flags["nlm_scales"]} if self.nlm else {}
        if self.mode == MODE_BOX and self.inner_method != "box":
            d["safeguard_note"] = "the plan is box (no blur beyond the pixel): nothing to blend"
        d["estimate_error"] = True
        t7, t3 = bias_tests(bool(self.guided), self.info.spp, self.independent)  # the plan's
        at = f"FDR {FDR_Q}" if self.guided else "2 se"
        d["safeguard_bias_tests"] = {f"7x7 at {at}": t7, "3x3 at 2 se": t3} | (
            {} if self.guided else {"7x7 by the frame's q-value": self.frame_shrink})
        said = {"safeguard_convergence": (self.scaled, "measured (the halves' variances "
                                          "scaled by it)"),
                "safeguard_samples": (self.independent, "independent (declared): the halves' "
                                      "variances as they are; the 7x7 bias mean tested "
                                      "below 16 spp, from 16 shrunk by its significance"),
                "safeguard_covariance": (models_covariance(self.info.spp), "modelled as the "
                                         "method's variance (e = d2 + vm - vb)"),
                "nlm_of": (self.box_halves, "box's own halves (the samples' means)"),
                "safeguard_image": (self.halves_mean, "the mean of the halves' images"),
                "safeguard_joint": (bool(self.joint), list(self.joint))}
        d |= {k: v for k, (on, v) in said.items() if on}
        d["plan"] = self.plan.name
        return d
