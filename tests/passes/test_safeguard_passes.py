"""The safeguard's kernels (``kernels/safeguard.cl`` through
:class:`clrecon.methods.safeguard_passes.SafeguardPasses`) against the NumPy reference
(:func:`clrecon.methods.safeguard.reference`), at every vector width the window passes are
built for and at widths that leave a partial vector, for the three blend modes."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close

from clrecon.methods import safeguard as sg
from clrecon.methods.safeguard_passes import (
    SafeguardPasses,
    measures_convergence,
    models_covariance,
)
from clrecon.methods.safeguard_reference import variance_scale


def _run(device, color, m, ma, mb, mode, vw, z7=0.0, test3=True, cov=None):
    """The passes as the pipeline runs them (``cov=None``: the covariance term where the
    pipeline models it, from 16 spp)."""
    ctx, q = device.context, device.queue
    h, w, s, _ = color.shape
    cov = models_covariance(s) if cov is None else cov
    passes = SafeguardPasses(ctx, vw)
    mf = cl.mem_flags

    def up(a):
        return cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR,
                         hostbuf=np.ascontiguousarray(a, np.float32))

    bufs = {k: up(v) for k, v in dict(color=color, m=m, ma=ma, mb=mb).items()}
    box = cl.Buffer(ctx, mf.READ_WRITE, h * w * 12)
    # NaN where a pass leaves its buffer unwritten: the padding must be written, not assumed
    stats = up(np.full(passes.stats_bytes(w, h) // 4, np.nan))
    rows = up(np.full(passes.rows_bytes(w, h) // 4, np.nan))
    out = cl.Buffer(ctx, mf.READ_WRITE, h * w * 12)
    err = cl.Buffer(ctx, mf.READ_WRITE, h * w * 4)
    has = 0 if mode == sg.MODE_BOX else 1
    m_in = bufs["m"] if has else box
    quarters = measures_convergence(s)
    ev = passes.run_stats(q, bufs["color"], m_in, bufs["ma"], bufs["mb"], box, stats, w, h, s,
                          has, quarters=quarters)
    vscale = None
    if quarters:  # the sampler's convergence, measured (from 16 spp)
        vscale = up(np.full(1, np.nan))
        partial = up(np.full(passes.ratio_bytes(h) // 4, np.nan))
        ev = passes.run_ratio(q, stats, partial, vscale, w, h, s, [ev])[-1]
    passes.run_blend(q, stats, rows, box, m_in, out, err, w, h, mode, 1, [ev],
                     z7, vscale, test3, cov)[-1][1].wait()
    img, e = np.empty((h, w, 3), np.float32), np.empty((h, w), np.float32)
    cl.enqueue_copy(q, img, out)
    cl.enqueue_copy(q, e, err)
    if quarters:
        got = np.empty(1, np.float32)
        cl.enqueue_copy(q, got, vscale)
        return img, e, float(got[0])
    return img, e


CASES = [(vw, w, mode, 1.0) for vw in (1, 4, 8, 16) for w in (5, 16, 17, 37)
         for mode in (sg.MODE_BOX, sg.MODE_METHOD, sg.MODE_BLEND)]
# dim and bright frames: each pixel's statistics in units of its own exponent, the padding's
# below every pixel's (a padding exponent of 0 would flush a 1e-30 frame's border windows)
CASES += [(vw, 17, sg.MODE_BLEND, scale) for vw in (1, 16) for scale in (1e-30, 1e15)]
CASES = [(*c, 0.0, True) for c in CASES]
# the 7x7 bias mean tested at 2 standard errors (the guided refinement's chain), with and
# without the 3x3 test (bias_tests: the chain below 8 spp)
CASES += [(vw, w, mode, scale, 2.0, t3) for vw in (1, 8, 16) for w in (5, 37)
          for scale in (1.0, 1e15) for mode, t3 in ((sg.MODE_BLEND, True),
                                                    (sg.MODE_BLEND, False),
                                                    (sg.MODE_METHOD, False))]
# the 7x7 bias mean shrunk by its significance (independent_samples: z7 < 0)
CASES += [(vw, w, mode, scale, sg.SHRINK_Z7, True) for vw in (1, 16) for w in (5, 37)
          for scale in (1.0, 1e-30, 1e15) for mode in (sg.MODE_BLEND, sg.MODE_METHOD)]


@pytest.mark.parametrize("vw,w,mode,scale,z7,test3", CASES)
def test_kernels_match_reference(device, vw, w, mode, scale, z7, test3):
    rng = np.random.default_rng(w + 100 * vw + 7 * mode + int(1000 * abs(z7)) + 13 * test3)
    h, s = 9, 5
    color = rng.random((h, w, s, 3)) * rng.choice([0.5, 4.0], (h, w, 1, 1)) * scale
    ma, mb = (color.mean(2) + 0.2 * scale * rng.random((h, w, 3)) for _ in range(2))
    m = 0.5 * (ma + mb)
    m[h // 2, :] += 0.8 * scale  # a biased row: the bias estimate and the weight vary across it
    if w > 16:
        m[1, w // 2] += 3.0 * scale  # and one pixel's (the 3x3 test's)
    img, err = _run(device, color, m, ma, mb, mode, vw, z7, test3)
    f32 = [x.astype(np.float32) for x in (color, m, ma, mb)]
    want_img, want_err = sg.reference(*f32, mode=mode, z7=z7, test3=test3)
    if mode == sg.MODE_BLEND and z7:
        # each test changes the image: the case can tell a kernel that ignores it
        other, _ = sg.reference(*f32, mode=mode, test3=test3)
        assert np.abs(other - want_img).max() > 1e-3 * float(np.abs(want_img).max())
    if w > 16 and z7:  # the error estimate (and the blend's image) move with the 3x3 test
        other_img, other_err = sg.reference(*f32, mode=mode, z7=z7, test3=not test3)
        assert np.abs(other_err - want_err).max() > 1e-3 * float(np.abs(want_err).max())
        if mode == sg.MODE_BLEND:
            assert np.abs(other_img - want_img).max() > 1e-3 * float(np.abs(want_img).max())
    scale = float(np.abs(want_img).max())
    assert_close(img, want_img, rtol=1e-4, atol=1e-5 * scale, what=f"image vw={vw} w={w}")
    # the error image is float32: below its subnormals (a 1e-30 frame's ~1e-61) it is 0
    assert_close(err, want_err, rtol=1e-3, atol=max(1e-6 * float(want_img.max()) ** 2, 6e-45),
                 what=f"error vw={vw} w={w}")


def test_vector_width_is_checked(device):
    with pytest.raises(ValueError, match="vector width 3"):
        SafeguardPasses(device.context, 3)


def _stratified_colours(rng, h, w, s, iid):
    """(h, w, s, 3) colours of a step edge at a random place in each pixel, sampled at a
    Kronecker sequence with a random shift per pixel (stratified: any prefix is spread over
    the pixel) or at independent uniform points."""
    i = np.arange(s)
    shift = rng.random((h, w, 1))
    x = rng.random((h, w, s)) if iid else (i * 0.6180339887 + shift) % 1.0
    edge = rng.random((h, w, 1))
    lo, hi = rng.random((h, w, 1, 3)), 1.0 + 3.0 * rng.random((h, w, 1, 3))
    return np.where((x < edge)[..., None], lo, hi)


SCALED = [(vw, w, mode, s, bright) for vw in (1, 16) for w in (17, 37)
          for mode in (sg.MODE_BOX, sg.MODE_METHOD, sg.MODE_BLEND) for s in (16, 17)
          for bright in (1.0,)]
# a frame 1e-30 or 1e15 bright, and one whose pixels differ by 1e12: the ratio's row and
# frame sums rescale each pixel's statistics to the largest exponent
SCALED += [(vw, 37, sg.MODE_BLEND, 16, bright) for vw in (1, 16)
           for bright in (1e-30, 1e15, "mixed")]


@pytest.mark.parametrize("vw,w,mode,s,bright", SCALED)
def test_scaled_variances_match_reference(device, vw, w, mode, s, bright):
    """From 16 spp the halves' variances are scaled by the quarters' measured convergence:
    the kernels' factor, image and error against the reference's."""
    rng = np.random.default_rng(w + 100 * vw + 7 * mode + s)
    h = 9
    color = _stratified_colours(rng, h, w, s, iid=False)
    color = color * (rng.choice([1.0, 1e12], (h, w, 1, 1)) if bright == "mixed" else bright)
    sc = float(np.abs(color).max())
    ma, mb = (color.mean(2) + 0.2 * sc * rng.random((h, w, 3)) for _ in range(2))
    m = 0.5 * (ma + mb)
    m[h // 2, :] += 0.8 * sc
    c32, m32, ma32, mb32 = (a.astype(np.float32) for a in (color, m, ma, mb))
    img, err, got = _run(device, c32, m32, ma32, mb32, mode, vw)
    want_scale = variance_scale(c32)
    assert 0.0 < want_scale < 0.9  # the stratified samples converge faster than 1/n
    assert got == pytest.approx(want_scale, rel=1e-4)
    want_img, want_err = sg.reference(c32, m32, ma32, mb32, mode=mode)
    # the factor changes the estimate: the case can tell a kernel that ignores it
    half = sg.reference_of_halves(c32[:, :, :s // 2].mean(2), c32[:, :, s // 2:].mean(2),
                                  s // 2, s - s // 2, m32, ma32, mb32, mode)[1]
    assert np.abs(half - want_err).max() > 1e-3 * float(np.abs(want_err).max())
    scale = float(np.abs(want_img).max())
    assert_close(img, want_img, rtol=1e-4, atol=1e-5 * scale, what=f"image vw={vw} w={w}")
    assert_close(err, want_err, rtol=1e-3, atol=max(1e-6 * scale ** 2, 6e-45),
                 what=f"error vw={vw} w={w}")


def test_scale_is_one_for_independent_samples(device, rng):
    """Independent samples: the halves and the quarters estimate the same variance (the
    factor near 1, noise alone); a frame without spread: exactly 1."""
    h, w, s = 16, 48, 16
    color = _stratified_colours(rng, h, w, s, iid=True).astype(np.float32)
    m = color.mean(2)
    _, _, got = _run(device, color, m, m, m, sg.MODE_BOX, 16)
    assert got == pytest.approx(variance_scale(color), rel=1e-4)
    assert got > 0.85
    flat = np.full((h, w, s, 3), 0.5, np.float32)
    _, err, got = _run(device, flat, m, m, m, sg.MODE_BOX, 16)
    assert got == 1.0 and variance_scale(flat) == 1.0
    assert not err.any()


def test_below_16_spp_nothing_is_measured():
    assert not measures_convergence(15) and measures_convergence(16)
    rng = np.random.default_rng(3)
    assert variance_scale(_stratified_colours(rng, 4, 4, 15, iid=False)) == 1.0


def test_bias_tests_rule():
    """From halves of MIN_TEST_HALF samples (8 spp: 4 and 4; 7 spp's are 3 and 4) a method's
    own halves test neither window beyond the 3x3's 2 standard errors; below, they test the
    7x7 mean too. The guided chain always tests the 7x7 mean and keeps the 3x3 test from
    halves of CHAIN_TEST3_HALF samples (32 spp; 31 spp's are 15 and 16)."""
    from clrecon.methods.safeguard_passes import CHAIN_TEST3_HALF, MIN_TEST_HALF, bias_tests
    assert (MIN_TEST_HALF, CHAIN_TEST3_HALF) == (4, 16)
    for s in range(2, 70):
        assert bias_tests(False, s) == (s < 8, True), s
        assert bias_tests(True, s) == (True, s >= 32), s
        # declared independent samples test the 7x7 mean below 16 spp
        assert bias_tests(False, s, independent=True) == (s < 16, True), s


def test_shrinks_by_frame_rule():
    """The frame's q-value scales a method's own 7x7 mean from halves of 4 samples (8 spp;
    9 spp's are 4 and 5), never the guided chain's nor declared independent samples' (which
    test it below 16 spp and shrink it by its significance from there: bias_tests)."""
    from clrecon.methods.safeguard_passes import INDEPENDENT_TEST_HALF, shrinks_by_frame
    assert INDEPENDENT_TEST_HALF == 8
    for s in range(2, 70):
        assert shrinks_by_frame(False, s) == (s >= 8), s
        assert not shrinks_by_frame(True, s) and not shrinks_by_frame(False, s, True)


@pytest.mark.parametrize("s", [5, 16])
@pytest.mark.parametrize("mode", [sg.MODE_METHOD, sg.MODE_BLEND])
@pytest.mark.parametrize("vw", [1, 16])
def test_covariance_term_matches_reference(device, vw, mode, s):
    """The bias term with the covariance of m and box modelled as vm (e = d2 + vm - vb) and
    without it, at 5 and 16 spp, against the reference; the two differ (a kernel that ignores
    the flag fails one of them), and the pipeline's choice is the term from 16 spp."""
    assert models_covariance(16) and not models_covariance(8)
    rng = np.random.default_rng(vw + 10 * mode + s)
    h, w = 9, 21
    color = _stratified_colours(rng, h, w, s, iid=False).astype(np.float32)
    ma, mb = (color.mean(2) + 0.3 * rng.random((h, w, 3)).astype(np.float32) for _ in range(2))
    m = (0.5 * (ma + mb)).astype(np.float32)
    m[h // 2, :] += 0.4  # a bias row: the windows' bias means are not all clamped to 0
    got = {}
    for cov in (False, True):
        res = _run(device, color, m, ma, mb, mode, vw, cov=cov)
        img, err = res[0], res[1]
        want_img, want_err = sg.reference(color, m, ma, mb, mode=mode, cov=cov)
        scale = float(np.abs(want_img).max())
        assert_close(img, want_img, rtol=1e-4, atol=1e-5 * scale, what=f"image cov={cov}")
        assert_close(err, want_err, rtol=1e-3, atol=1e-6 * scale ** 2, what=f"error cov={cov}")
        got[cov] = err
    assert np.abs(got[True] - got[False]).max() > 1e-3 * float(np.abs(got[False]).max())
    assert (got[True] >= got[False] - 1e-6).all()  # +2 vm in e: never a smaller bias term
