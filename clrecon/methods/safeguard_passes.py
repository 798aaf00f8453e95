"""The safeguard's kernels (``kernels/safeguard.cl``) and their buffers' layout: the pixel
statistics as five planes with three padding columns on each side, the windowed sums' row
segments as eight planes, and ``SG_VW`` pixels of a row a work-item in the window passes.

Why planes and vectors: PoCL 3.1 vectorises a kernel across work-items only where its body
holds no vector-typed value, and LLVM's SLP pass makes such values from a window's adjacent
loads, so the one-pixel-a-work-item window passes ran scalar (PoCL's remarks,
``POCL_VECTORIZER_REMARKS=1``: "instruction return type cannot be vectorized"). Sixteen
pixels a work-item as ``float16`` read each plane with contiguous vector loads:
``safeguard_rows`` at 1280x720 on a 2-core Xeon went from 10.3 to 0.9 ms, the same values
bit for bit. A GPU runs one pixel a work-item (``SG_VW = 1``), as before.
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.core.device import cpu_context, get_kernel
from clrecon.core.plan import Step

#: the statistics' planes: d2, vb, vm, the exponent and the quarters' dq
STAT_PLANES = 5
#: the fewest samples a quarter (half a half) holds for the sampler's convergence to be
#: measured (:func:`measures_convergence`): from 16 spp
MIN_QUARTER = 4
#: the fewest samples a half holds for a method's own blend to leave its 7x7 bias mean
#: untested, scaled by the frame's q-value instead (:func:`bias_tests`,
#: :func:`shrinks_by_frame`): from 8 spp, the count :data:`MIN_QUARTER` asks of a quarter
MIN_TEST_HALF = 4
#: the fewest samples a half holds for the guided chain's blend to keep its 3x3 test
#: (:func:`bias_tests`): from 32 spp
CHAIN_TEST3_HALF = 16
#: the 7x7 test's histogram at a false discovery rate (kernels/safeguard_fdr.cl): bins of
#: z = mu7 / se7 a pixel, 1 / FDR_SCALE wide, the last holding z >= FDR_BINS / FDR_SCALE (8)
FDR_BINS, FDR_SCALE = 256, 32
#: the frame's null of z (:func:`shrinks_by_frame`): its histogram's peak, smoothed by a
#: triangle of +-FDR_MODE_RADIUS bins (+-0.25)
FDR_MODE_RADIUS = 8
#: declared independent samples test the 7x7 bias mean at 2 standard errors below halves of
#: this many samples (16 spp) and shrink it by its significance from there (:func:`bias_tests`)
INDEPENDENT_TEST_HALF = 8
#: the guided chain tests its 7x7 bias mean at every spp (its regression removes the bias
#: coherent over its windows), at the z where the frame's pixels pass at this false discovery
#: rate (Benjamini-Hochberg: few true biases in a frame set a high bar, many a low one; the
#: usual level; ``docs/measurements/chain-safeguard-pocl.md`` section 7)
FDR_Q = 0.05
#: the row segments' planes: vb3, vm3, e3, ee3 (3 wide), e7, vb7, e3max, e7max, ee7 (7 wide)
ROW_PLANES = 9
#: padding columns on each side of the statistics' planes (the 7-wide window's reach)
PAD = 3


def halves(spp: int) -> tuple[int, int]:
    """The two halves' sample counts: ``spp // 2`` and the rest."""
    return spp // 2, spp - spp // 2


def measures_convergence(spp: int) -> bool:
    """Whether a frame of ``spp`` samples a pixel has its halves' variances scaled by the
    sampler's measured convergence (``safeguard_ratio``): each half's quarters hold at least
    :data:`MIN_QUARTER` samples."""
    return halves(int(spp))[0] // 2 >= MIN_QUARTER


def models_covariance(spp: int) -> bool:
    """Whether the blend's bias term adds back the covariance of the method's image and
    box, modelled as the method's variance: ``e = d2 + vm - vb`` instead of ``d2 - vm - vb``.

    ``m`` averages each pixel's own samples too, so ``var(m - box) = vm + vb - 2 cov(m, box)``
    and ``d2 - vm - vb`` is biased low by ``2 cov``: a biased method keeps weight where box is
    the better (the 64-spp cells below box). The halves estimate ``cov`` as ``k <mA - mB,
    boxA - boxB>``, unbiased but noisy: its positive part cost 0.2-0.85 dB where the method is
    unbiased and every point of weight counts (huge_coc,
    ``docs/measurements/convergence-pocl-128-spatial.md``). A model instead: a smoothing with
    non-negative weights ``h`` (sum 1) has ``cov(m, box) = h0 vb`` and ``var(m) = sum(h^2)
    vb``, ``h0`` the weight of the pixel's own samples; for a box kernel (and a disc PSF)
    ``h0 = sum(h^2)``, so ``cov = vm``, and for a kernel peaked at its own pixel ``h0 >
    sum(h^2)``: ``vm`` is a lower bound. It adds no noise beyond ``vm``'s own. Applied where
    the halves' variances are measured (:func:`measures_convergence`, from 16 spp): with
    the halves' unscaled variances at 8 spp it cost 0.14-0.49 dB on huge_coc (128x128, 4
    seeds), so below 16 spp ``e`` stays as it was. From 16 spp
    (``docs/measurements/convergence-pocl-128-covariance.md``): the 64-spp cells more than
    0.5 dB below box went from 7 to 4 (sweep on fence, spheres, bokeh; layered on spheres),
    huge_coc -0.07 to -0.37 dB. The guided chain's blend toward its guide keeps ``d2 - vm -
    vb`` (its reference is the refinement, not box)."""
    return measures_convergence(spp)


def bias_tests(guided: bool, spp: int, independent: bool = False) -> tuple[bool, bool]:
    """``(test7, test3)`` of the blend's bias term: whether its 7x7 mean must stand 2
    standard errors above zero (``safeguard.GUIDED_Z7``), and whether it keeps the 3x3 mean
    where that stands 2 standard errors above zero (a bias along a thin edge).

    From halves of :data:`MIN_TEST_HALF` samples (8 spp) a method's own halves leave the
    7x7 mean untested: the frame's q-value scales it instead (:func:`shrinks_by_frame`).
    Declared ``independent`` samples test it below 16 spp: at 8 spp +0.25 dB on average
    over the significance shrinkage they take from 16 (-0.18 to +2.15; at 16 spp +0.11,
    at 64 -0.19, ``docs/measurements/frame-shrink/random-512.md``). Below 8 spp the
    windows' means of 2-3-sample halves are mostly noise,
    whose positive part pulls the image toward a box 10-20 dB worse, so every method tests
    its 7x7 mean (``docs/measurements/safeguard-lowspp-pocl.md``: the defaults +0.01 to
    +2.6 dB in 33 of 36 cells at 4 spp, 256x256 and 512x512). Every method's own blend
    keeps the 3x3 test.

    The guided chain always tests its 7x7 mean, and keeps the 3x3 test only from halves of
    :data:`CHAIN_TEST3_HALF` samples (32 spp). Its image is 10-20 dB better than box's
    below that, so a 3x3 window (27 noisy terms, its standard error from the same 9
    pixels) that passes by chance pulls a pixel toward a box far worse than the bias it
    removes; the 7x7 test alone (``docs/measurements/chain-safeguard-pocl.md`` section 6,
    512x512, six scenes, both samplers) gained at 8 and 16 spp in 22 of 24 cells (-0.01 to
    +0.92 dB, the rest +0.00 to -0.01) and was mixed at 32 spp (-0.16 to +0.20); at 64 spp
    with the lattice the 3x3 test earns its keep (fence +0.25, spheres +0.37, fast_motion
    +0.48 with it). Below 8 spp it was already left out."""
    h = min(halves(int(spp)))
    test7 = bool(guided) or h < (INDEPENDENT_TEST_HALF if independent else MIN_TEST_HALF)
    return test7, not guided or h >= CHAIN_TEST3_HALF


def shrinks_by_frame(guided: bool, spp: int, independent: bool = False) -> bool:
    """Whether the blend scales its 7x7 bias mean by ``1 - q``, ``q`` the frame's false
    discovery rate at the mean's significance with a null read off the frame
    (``kernels/safeguard_fdr.cl``: ``safeguard_fdr_shrink``): a method's own blend from
    halves of :data:`MIN_TEST_HALF` samples (8 spp), where it took the mean untested, unless
    the samples are declared independent.

    A mean of ``e`` is positive or negative by noise and positive by a bias as well, so the
    frame's z histogram holds the noise's distribution as its central peak: a normal
    matched to that peak (Efron's empirical null: its mode, and its width from the peak's
    half width at half maximum; a peak above 0 is the biased pixels', and the null then
    ``N(0, 1)``) says how many of the ``R(t)`` positive means at ``|z| >= t`` are noise.
    The blend's weight with ``(1 - q) mu7`` minimises the expected error when ``q`` is the
    chance the mean is noise. A stratified sampler's halves misstate the variance, by
    different amounts across the frame (its measured factor is one number a frame): the
    noise's means centre below 0 (the mode of z -0.1 to -1.1 at 8 spp) and, where the
    halves overstate the variance most, form a heavy negative tail that is no mirror of the
    noise among the positive means (bokeh at 16 spp: 33 820 means at z <= -3 against
    10 923 at z >= 3); the peak is what the two share. Its one constant is the peak's
    smoothing (:data:`FDR_MODE_RADIUS`). Measured (``docs/measurements/frame-shrink-pocl.md``,
    ``tools/frame_shrink_study.py``: the methods' device halves, six scenes, 512x512)
    against the untested mean: on the lattice +0.09 / +0.11 / +0.01 / +0.02 dB on average
    at 8 / 16 / 32 / 64 spp (least -0.43), on undeclared independent samples +0.60 / +0.40
    / +0.22 / +0.12 (least -0.01); the negative means mirrored about the frame's mode (at
    8-15 spp until 2026-12-08) lost up to 0.93 dB at 16 spp and 0.51 at 64. Declared
    independent samples test the mean at 2 standard errors below 16 spp and shrink it by
    its significance from 16 (:func:`bias_tests`); the guided chain keeps its own test
    (:data:`FDR_Q`)."""
    h = min(halves(int(spp)))
    return not guided and not independent and h >= MIN_TEST_HALF


def vector_width(context: cl.Context) -> int:
    """Pixels a work-item of the window passes: 16 on a CPU (PoCL and Intel's runtime vectorise
    the explicit ``float16``), 1 elsewhere."""
    return 16 if cpu_context(context) else 1


class SafeguardPasses:
    """The kernels of ``kernels/safeguard.cl``, built for this context's vector width, and
    ``kernels/safeguard_ratio.cl``'s two and ``kernels/safeguard_fdr.cl``'s four."""

    def __init__(self, context: cl.Context, vw: int | None = None):
        """``vw``: the vector width (1, 4, 8 or 16; default :func:`vector_width`)."""
        self.vw = vector_width(context) if vw is None else int(vw)
        if self.vw not in (1, 4, 8, 16):
            raise ValueError(f"safeguard: vector width {vw} is not 1, 4, 8 or 16")
        defines = {"SG_VW": self.vw, "FDR_BINS": FDR_BINS, "FDR_SCALE": FDR_SCALE,
                   "FDR_MODE_RADIUS": FDR_MODE_RADIUS}
        self.split = get_kernel(context, "safeguard", "safeguard_split", defines)
        self.box_halves = get_kernel(context, "safeguard", "safeguard_box_halves", defines)
        self.stats = get_kernel(context, "safeguard", "safeguard_stats", defines)
        self.rows = get_kernel(context, "safeguard", "safeguard_rows", defines)
        self.blend = get_kernel(context, "safeguard", "safeguard_blend", defines)
        self.ratio_rows = get_kernel(context, "safeguard_ratio", "safeguard_ratio_rows")
        self.ratio = get_kernel(context, "safeguard_ratio", "safeguard_ratio")
        self.fdr_rows = get_kernel(context, "safeguard_fdr", "safeguard_fdr_rows", defines)
        self.fdr = get_kernel(context, "safeguard_fdr", "safeguard_fdr", defines)
        self.fdr_shrink = get_kernel(context, "safeguard_fdr", "safeguard_fdr_shrink", defines)
        self.fdr_sum = get_kernel(context, "safeguard_fdr", "safeguard_fdr_sum", defines)
        #: the variances' factor where it is not measured: 1 (independent samples)
        self.one = cl.Buffer(context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR,
                             hostbuf=np.ones(1, np.float32))

    # -- layout ------------------------------------------------------------------------------
    def rows_pitch(self, width: int) -> int:
        """Floats a row of each row-segment plane: the width rounded up to the vector width."""
        return -(-int(width) // self.vw) * self.vw

    def stats_pitch(self, width: int) -> int:
        """Floats a row of each statistics plane: the rows' pitch and both paddings (a
        work-item's window reads columns x0 .. x0 + SG_VW + 5)."""
        return self.rows_pitch(width) + 2 * PAD

    def stats_bytes(self, width: int, height: int) -> int:
        return STAT_PLANES * self.stats_pitch(width) * int(height) * 4

    def rows_bytes(self, width: int, height: int) -> int:
        return ROW_PLANES * self.rows_pitch(width) * int(height) * 4

    @staticmethod
    def ratio_bytes(height: int) -> int:
        """The ratio's row sums: three floats a row."""
        return 3 * int(height) * 4

    # -- launches ----------------------------------------------------------------------------
    def split_field(self, queue, src, dst_a, dst_b, pixels, spp, width, wait_for=None):
        ha, _ = halves(spp)
        self.split.set_args(src, dst_a, dst_b, np.int32(pixels), np.int32(spp), np.int32(ha),
                            np.int32(width))
        return cl.enqueue_nd_range_kernel(queue, self.split, (pixels,), None,
                                          wait_for=wait_for)

    def run_box_halves(self, queue, color, ma, mb, pixels, spp, wait_for=None):
        """ma, mb: the means of each pixel's two halves of its samples (box's halves)."""
        ha, _ = halves(spp)
        self.box_halves.set_args(color, ma, mb, np.int32(pixels), np.int32(spp), np.int32(ha))
        return cl.enqueue_nd_range_kernel(queue, self.box_halves, (pixels,), None,
                                          wait_for=wait_for)

    def box_halves_step(self) -> Step:
        """The plan step of :meth:`run_box_halves`: color -> ma, mb."""
        def run(queue, f, wait_for):
            b = f.buffers
            return [("safeguard_box_halves", self.run_box_halves(
                queue, b["color"], b["ma"], b["mb"], f.width * f.height, f.spp, wait_for))]
        return Step("box (halves)", ("color",), ("ma", "mb"), run)

    def run_stats(self, queue, color, m, ma, mb, box, stats, w, h, spp, has_method,
                  wait_for=None, ua=None, ub=None, quarters: bool = False):
        """has_method: 0 box alone, 1 with the method's image m, 2 m written as the halves'
        mean. ``ua``, ``ub``: the reference's halves as images (box is then their mean)
        instead of the samples' means. ``quarters``: also the quarters' plane (dq) that
        :meth:`run_ratio` reads (the samples' halves only, ``spp`` measuring convergence).
        One work-item per column of the planes (the padding's too)."""
        ha, _ = halves(spp)
        sp = self.stats_pitch(w)
        ref = ua is not None
        if quarters and (ref or not measures_convergence(spp)):
            raise ValueError(f"safeguard: the quarters need the samples and >= "
                             f"{4 * MIN_QUARTER} spp (the frame has {spp})")
        self.stats.set_args(color, m, ma, mb, box, stats, np.int32(w), np.int32(h),
                            np.int32(spp), np.int32(ha), np.int32(has_method), np.int32(sp),
                            ua if ref else color, ub if ref else color, np.int32(ref),
                            np.int32(bool(quarters)))
        return cl.enqueue_nd_range_kernel(queue, self.stats, (sp, h), None, wait_for=wait_for)

    def run_ratio(self, queue, stats, partial, scale, w, h, spp, wait_for=None):
        """The sampler's convergence from statistics written with ``quarters``: ``scale``
        (one float) = the frame's halves' squared difference over its quarters', per unit
        of their independent-sample variances, clamped to [0, 1]. Two launches, their
        events in order."""
        self.ratio_rows.set_args(stats, partial, np.int32(w), np.int32(h),
                                 np.int32(self.stats_pitch(w)), np.int32(spp))
        ev = cl.enqueue_nd_range_kernel(queue, self.ratio_rows, (int(h),), None,
                                        wait_for=wait_for)
        self.ratio.set_args(partial, np.int32(h), scale)
        return [ev, cl.enqueue_nd_range_kernel(queue, self.ratio, (1,), None, wait_for=[ev])]

    def run_blend(self, queue, stats, rows, box, m, out, error, w, h, mode, write_error,
                  wait_for=None, z7: float = 0.0, vscale=None, test3: bool = True,
                  cov: bool = False, fdr=None):
        """The windowed sums' row segments, then the blend: [("safeguard_rows", ev),
        ("safeguard_blend", ev)]. ``z7 > 0``: the 7x7 bias mean is tested at ``z7``
        standard errors, as the 3x3 one at 2; ``test3=False``: the bias term leaves the
        3x3 test out (:func:`bias_tests`). ``vscale``: the halves' variances' factor
        (:meth:`run_ratio`'s buffer; None: 1). ``cov``: the bias term adds back the
        covariance of the method's image and box, modelled as ``vm`` (``e = d2 + vm - vb``;
        :func:`models_covariance`). ``fdr = (hist, z, q)``: the 7x7 test's z is the frame's
        at false discovery rate ``q`` (:meth:`run_fdr`, its two launches between), not
        ``z7``; ``q = None``: ``z`` is the frame's table of factors (:data:`FDR_BINS`
        floats) that scale a positive 7x7 mean by its significance (:meth:`run_fdr`)."""
        ev = self.run_rows(queue, stats, rows, w, h, wait_for, vscale, cov)
        evs = [("safeguard_rows", ev)]
        if fdr is not None:
            hist, z, q = fdr
            evs += [("safeguard_fdr", e) for e in self.run_fdr(queue, rows, hist, z, q, w, h,
                                                              [ev])]
        return evs + [("safeguard_blend", self.run_blend_only(
            queue, rows, box, m, out, error, w, h, mode, write_error, [evs[-1][1]], z7, test3,
            None if fdr is None else fdr[1], 0 if fdr is None else 1 if fdr[2] else 2))]

    def run_fdr(self, queue, rows, hist, z, q: float | None, w, h, wait_for=None):
        """From the row segments, the frame's histogram of its pixels' 7x7 bias means' ``|z|
        = |mu7| / se7`` by sign (``hist``: :meth:`fdr_bytes`), then ``z``: with ``q`` (the
        guided chain's test), one float, the lowest z at which the frame's means pass at
        false discovery rate ``q`` (Benjamini-Hochberg, to 1 / FDR_SCALE); with ``q =
        None`` (a method's own blend from 8 spp: :func:`shrinks_by_frame`), the table of
        :data:`FDR_BINS` factors ``1 - q-value``, the frame's null a normal matched to its
        histogram's peak (:func:`~clrecon.methods.safeguard_reference.fdr_shrink_table`).
        Three launches (the rows, their sum, the
        threshold or table), their events in order."""
        self.fdr_rows.set_args(rows, hist, np.int32(w), np.int32(h),
                               np.int32(self.rows_pitch(w)), np.int32(q is None))
        ev = cl.enqueue_nd_range_kernel(queue, self.fdr_rows, (int(h),), None,
                                        wait_for=wait_for)
        self.fdr_sum.set_args(hist, np.int32(h))
        ev_sum = cl.enqueue_nd_range_kernel(queue, self.fdr_sum, (2 * FDR_BINS,), None,
                                            wait_for=[ev])
        if q is None:
            self.fdr_shrink.set_args(hist, z)
            k = self.fdr_shrink
        else:
            self.fdr.set_args(hist, np.int32(w * h), np.float32(q), z)
            k = self.fdr
        return [ev, ev_sum, cl.enqueue_nd_range_kernel(queue, k, (1,), None, wait_for=[ev_sum])]

    @staticmethod
    def fdr_bytes(height: int) -> int:
        """Bytes of :meth:`run_fdr`'s histogram (two halves of :data:`FDR_BINS` a row)."""
        return int(height) * 2 * FDR_BINS * 4

    @staticmethod
    def fdr_table_bytes(q: float | None) -> int:
        """Bytes of :meth:`run_fdr`'s ``z``: one float with ``q``, the table without."""
        return 4 if q is not None else FDR_BINS * 4

    def run_rows(self, queue, stats, rows, w, h, wait_for=None, vscale=None, cov=False):
        """The windowed sums' row segments alone (``vscale``, ``cov`` as for
        :meth:`run_blend`)."""
        sp, rp = self.stats_pitch(w), self.rows_pitch(w)
        self.rows.set_args(stats, rows, np.int32(w), np.int32(h), np.int32(sp), np.int32(rp),
                           self.one if vscale is None else vscale,
                           np.float32(1.0 if cov else -1.0))
        return cl.enqueue_nd_range_kernel(queue, self.rows, (rp // self.vw, h), None,
                                          wait_for=wait_for)

    def run_blend_only(self, queue, rows, box, m, out, error, w, h, mode, write_error,
                       wait_for=None, z7: float = 0.0, test3: bool = True, zfdr=None,
                       fdr_mode: int = 1):
        """The blend from row segments already computed (the same weights for any box and
        m: the guided refinement blends each half with them). ``out`` may be ``box`` or
        ``m`` (a work-item reads them at its own pixels only). ``zfdr``: :meth:`run_fdr`'s
        ``z``: with ``fdr_mode`` 1 the z read in place of ``z7``, with 2 the table of
        factors (``z7`` unused)."""
        rp = self.rows_pitch(w)
        self.blend.set_args(rows, box, m, out, error, np.int32(w), np.int32(h), np.int32(rp),
                            np.int32(mode), np.int32(write_error), np.float32(z7),
                            np.int32(bool(test3)),
                            np.int32(0 if zfdr is None else fdr_mode),
                            self.one if zfdr is None else zfdr)
        return cl.enqueue_nd_range_kernel(queue, self.blend, (rp // self.vw, h), None,
                                          wait_for=wait_for)
