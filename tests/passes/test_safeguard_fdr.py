"""The 7x7 bias mean judged against the frame (``kernels/safeguard_fdr.cl`` through
:class:`clrecon.methods.safeguard_passes.SafeguardPasses`): the guided chain's test at a
false discovery rate (the NumPy reference's threshold against known answers and the exact
Benjamini-Hochberg procedure, the kernels' threshold against the reference's, and the blend
reading it) and a method's own blend's mean scaled by the frame's q-value (the reference's
table against known answers, the kernels' table and image against the reference's)."""
from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close

from clrecon.methods import safeguard as sg
from clrecon.methods import safeguard_reference as sr
from clrecon.methods.safeguard_passes import FDR_BINS, FDR_SCALE, SafeguardPasses
from clrecon.methods.safeguard_reference import (
    _lum2,
    _window_count,
    _window_mean,
    fdr_shrink,
    fdr_shrink_table,
    fdr_threshold,
    halves,
    shrink_table_of,
)

TOP = FDR_BINS / FDR_SCALE


def _z_frame(zs):
    """(mu7, var7) whose pixels' mu7 / se7 are ``zs`` (se7 = 1)."""
    zs = np.asarray(zs, np.float64)
    return zs, np.ones_like(zs)


def test_known_answers():
    # 1000 pixels of noise (z 0.5) and 100 biased (z 5): R(t) = 100 from t = 0.5 to 5, so
    # the lowest edge with 1100 Q(t) <= 0.05 * 100 is the first above Q^-1(5 / 1100) = 2.6104
    mu, var = _z_frame([0.5] * 1000 + [5.0] * 100)
    assert fdr_threshold(mu, var, 0.05) == np.ceil(2.6104 * FDR_SCALE) / FDR_SCALE
    # noise alone, or no positive mean: no edge passes
    assert fdr_threshold(*_z_frame([0.5] * 1000), 0.05) == TOP
    assert fdr_threshold(-np.ones(50), np.ones(50), 0.05) == TOP
    # a mean with no spread (se 0) is z = inf, a discovery at every edge: R(t) = 1, the
    # edge the first above Q^-1(0.05 / 21)
    mu, var = _z_frame([0.5] * 20 + [1.0])
    var[-1] = 0.0
    edge = np.ceil(NormalDist().inv_cdf(1 - 0.05 / 21) * FDR_SCALE) / FDR_SCALE
    assert fdr_threshold(mu, var, 0.05) == edge


def _bh_count(z, q):
    """The exact Benjamini-Hochberg procedure: how many of the one-sided p-values pass."""
    p = np.sort([0.5 * math.erfc(v / math.sqrt(2)) for v in z])
    ok = np.nonzero(p <= q * np.arange(1, p.size + 1) / p.size)[0]
    return ok[-1] + 1 if ok.size else 0


@pytest.mark.parametrize("seed", range(4))
def test_binned_threshold_brackets_the_exact_procedure(seed):
    """The binned threshold discovers at most what the exact procedure does at rate q, and at
    least what it does at q / 1.2 (a bin 1/32 wide moves the normal's tail by under 1.2x below
    z = 5.8)."""
    rng = np.random.default_rng(seed)
    n_bias = int(rng.integers(50, 800))
    z = np.concatenate([rng.normal(size=20000), rng.normal(3.0, 0.8, n_bias)])
    t = fdr_threshold(*_z_frame(z), 0.05)
    found = int(np.sum(z >= t))
    assert _bh_count(z, 0.05 / 1.2) <= found <= _bh_count(z, 0.05)
    assert 1.6 < t < 5.0


def _frame(rng, h, w, s, strength, smooth=False):
    """Samples, and a method's image and halves with a biased patch of ``strength``; the
    halves the samples' means plus noise, or with ``smooth`` the samples' expectation plus
    a little (a method smoother than box: the noise's 7x7 means centre near 0)."""
    scale = rng.choice([0.5, 4.0], (h, w, 1, 1))
    color = rng.random((h, w, s, 3)) * scale
    base = 0.5 * scale[:, :, 0] if smooth else color.mean(2)
    ma, mb = (base + (0.01 if smooth else 0.2) * rng.random((h, w, 3)) for _ in range(2))
    m = 0.5 * (ma + mb)
    m[h // 3: h // 3 + 6, w // 4: w // 4 + 9] += strength  # a biased patch
    return color, m, ma, mb


def _mu_var(color, m, ma, mb):
    """The 7x7 bias mean and its squared standard error as the blend computes them (below 16 spp:
    no covariance term, the halves' variances unscaled)."""
    c = color.astype(np.float64)
    ha, hb = halves(c.shape[2])
    a, b = c[:, :, :ha].mean(2), c[:, :, ha:].mean(2)
    k, box = ha * hb / (ha + hb) ** 2, (ha * a + hb * b) / (ha + hb)
    e = _lum2(m.astype(np.float64) - box) - k * _lum2(ma.astype(np.float64) - mb) \
        - k * _lum2(a - b)
    mu7 = _window_mean(e, 3)
    return mu7, np.maximum(_window_mean(e * e, 3) - mu7 * mu7, 0.0) / _window_count(e.shape, 3)


def _device(device, vw, color, m, ma, mb, shrink=False):
    """(z, image) of the passes as the chain's blend runs them; ``shrink``: (table, image,
    the frame's histogram) as a method's own blend from 8 spp runs them (the 3x3 test
    kept)."""
    ctx, q = device.context, device.queue
    h, w, s, _ = color.shape
    passes, mf = SafeguardPasses(ctx, vw), cl.mem_flags

    def up(a):
        return cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR,
                         hostbuf=np.ascontiguousarray(a, np.float32))

    bufs = {k: up(v) for k, v in dict(color=color, m=m, ma=ma, mb=mb).items()}
    box, out = (cl.Buffer(ctx, mf.READ_WRITE, h * w * 12) for _ in range(2))
    err = cl.Buffer(ctx, mf.READ_WRITE, h * w * 4)
    stats = up(np.full(passes.stats_bytes(w, h) // 4, np.nan))
    rows = up(np.full(passes.rows_bytes(w, h) // 4, np.nan))
    # the histogram starts as garbage: each row's pass must clear its own
    hist = up(np.full(passes.fdr_bytes(h) // 4, 7, np.int32).view(np.float32))
    fq = None if shrink else sg.FDR_Q
    z = up(np.full(passes.fdr_table_bytes(fq) // 4, np.nan))
    ev = passes.run_stats(q, bufs["color"], bufs["m"], bufs["ma"], bufs["mb"], box, stats,
                          w, h, s, 1)
    passes.run_blend(q, stats, rows, box, bufs["m"], out, err, w, h, sg.MODE_BLEND, 1, [ev],
                     sg.GUIDED_Z7, None, shrink, False, (hist, z, fq))[-1][1].wait()
    img = np.empty((h, w, 3), np.float32)
    if shrink:
        table, total = np.empty(FDR_BINS, np.float32), np.empty(2 * FDR_BINS, np.int32)
        cl.enqueue_copy(q, table, z)
        cl.enqueue_copy(q, total, hist)  # the rows' sums, in the first row
        cl.enqueue_copy(q, img, out)
        return table, img, total
    zs = np.empty(1, np.float32)
    cl.enqueue_copy(q, zs, z)
    cl.enqueue_copy(q, img, out)
    return float(zs[0]), img


@pytest.mark.parametrize("vw", [1, 16])
@pytest.mark.parametrize("w, strength", [(37, 0.6), (64, 1.2), (33, 0.0)])
def test_kernels_match_reference(device, vw, w, strength):
    rng = np.random.default_rng(w + vw)
    color, m, ma, mb = _frame(rng, 40, w, 5, strength)
    z, img = _device(device, vw, color, m, ma, mb)
    f32 = [x.astype(np.float32) for x in (color, m, ma, mb)]
    want_z = fdr_threshold(*_mu_var(*f32), sg.FDR_Q)
    # float32 sums against float64 ones: a pixel at a bin's edge may fall either side
    assert abs(z - want_z) <= 1.0 / FDR_SCALE, (z, want_z)
    if strength:  # the biased patch sets a threshold between the extremes
        assert 1.6 < want_z < 4.0
    want, _ = sg.reference(*f32, z7=sg.GUIDED_Z7, test3=False, vscale=1.0, fdr_q=sg.FDR_Q)
    if z == want_z:
        assert_close(img, want, rtol=1e-4, atol=1e-5 * float(np.abs(want).max()),
                     what=f"image vw={vw} w={w}")
    if strength:  # the frame's z, not the fixed one: the case tells a blend that ignores it
        fixed, _ = sg.reference(*f32, z7=sg.GUIDED_Z7, test3=False, vscale=1.0)
        assert np.abs(fixed - want).max() > 1e-3 * float(np.abs(want).max())


def test_shrink_table_known_answers():
    """``1 - q``, ``q`` the least ``N(t) / R(t)`` at or below each bin, the null the frame's
    negative means mirrored about 0: 100 noise pixels on each side at |z| 0.5 and 50 biased
    at z 5 give q = 100 / 150 from 0 to 0.5, then 0 (R = 50, N = 0) up to 5 and beyond
    (R = 0 there: 1, but the least below is 0)."""
    mu = np.array([0.5] * 100 + [-0.5] * 100 + [5.0] * 50)
    table = fdr_shrink_table(mu, np.ones_like(mu), null="zero")
    edge = int(0.5 * FDR_SCALE)  # the bin that holds |z| = 0.5
    assert np.allclose(table[:edge + 1], 1 - 100 / 150)
    assert np.all(table[edge + 1:] == 1.0)
    # noise alone (as many negative as positive at every |z|): every positive mean is 0
    mu = np.random.default_rng(1).normal(size=4000)
    mu = np.concatenate([mu, -mu])
    assert np.all(fdr_shrink(mu, np.ones_like(mu), null="zero") == 0.0)
    # no negative mean: nothing is noise, every positive mean as it is
    mu = np.abs(mu) + 0.01
    assert np.array_equal(fdr_shrink(mu, np.ones_like(mu), null="zero"), mu)
    # the negative means of windows without noise do not count
    neg = np.concatenate([mu, -mu])
    quiet = np.arange(neg.size) >= mu.size
    assert np.array_equal(fdr_shrink(neg, np.ones_like(neg), ~quiet, "zero")[~quiet], mu)
    # a factor never rises as |z| falls, and lies in [0, 1], for every null
    mu = np.random.default_rng(2).normal(0.5, 1.0, 5000)
    for null in ("normal", "mode", "zero"):
        t = fdr_shrink_table(mu, np.ones_like(mu), null=null)
        assert np.all(np.diff(t) >= 0) and t.min() >= 0.0 and t.max() <= 1.0 and t.max() > 0.5
    with pytest.raises(ValueError, match="null"):
        fdr_shrink_table(mu, np.ones_like(mu), null="half")


def test_shrink_table_centred_known_answers():
    """Mirrored about the frame's mode (``null="mode"``) or about 0, on z at the signed bins'
    centres: 200 pixels at the mode (z -0.98), 100 at 2 below it (-2.98), 100 at 2 above
    (+1.02: their mirror image) and 50 at +5.02. About the mode, the 100 above are noise as
    likely as not against 150 positive: 1/3 up to their bin, 1 beyond; about 0 the 200 at
    the mode outnumber every positive below 1: 0 there. A mode above 0 is not the null's."""
    def at(k, n):  # n pixels at signed bin k's centre
        return [(k - FDR_BINS + 0.5) / FDR_SCALE] * n
    mode = FDR_BINS - 32
    mu = np.array(at(mode, 200) + at(mode - 64, 100) + at(mode + 64, 100) + at(FDR_BINS + 160,
                                                                               50))
    one = np.ones_like(mu)
    centred, zero = (fdr_shrink_table(mu, one, null=n) for n in ("mode", "zero"))
    assert np.allclose(centred[:33], 1 / 3) and np.all(centred[33:] == 1.0)
    assert np.all(zero[:32] == 0.0) and np.allclose(zero[32:96], 1 / 3)
    assert np.all(zero[96:] == 1.0)
    # a mode above 0 is the biased pixels': the null stays about 0
    mu = np.concatenate([mu, at(FDR_BINS + 64, 1000)])
    one = np.ones_like(mu)
    zero = fdr_shrink_table(mu, one, null="zero")
    assert np.array_equal(fdr_shrink_table(mu, one, null="mode"), zero) and zero[64] > 0.5


def _signed_hist(counts):
    """The kernels' histogram layout from counts by signed bin (2 FDR_BINS, z from
    -FDR_BINS / FDR_SCALE up)."""
    counts = np.asarray(counts, np.int64)
    return np.concatenate([counts[FDR_BINS:], counts[:FDR_BINS][::-1]])


def _normal_counts(n, mu, sigma):
    """n pixels spread over the signed bins as a normal N(mu, sigma^2) of z would be."""
    edges = (np.arange(2 * FDR_BINS + 1) - FDR_BINS) / FDR_SCALE
    cdf = np.array([NormalDist(mu, sigma).cdf(e) for e in edges])
    return np.round(n * np.diff(cdf)).astype(np.int64)


def test_normal_null_known_answers():
    """The normal null matched to the frame's peak: 200 000 noise pixels as N(-0.5, 1.3^2)
    give back its mode, width and count (to a bin, 3% and 3%), and 2000 biased ones at z 5
    keep their mean (their factor near 1) while a positive mean at z 1 is mostly noise (and
    by the local rate, measured not shipped, one at z 4 too, where the q-value keeps most of
    it). A
    heavy negative tail (windows whose halves overstate the variance) leaves the table as
    it is, where the mirrored null would count it as noise among the positive means. A peak
    above 0 is the biased pixels': the null is then N(0, 1). An empty frame gives factors
    0."""
    noise = _normal_counts(200_000, -0.5, 1.3)
    biased = np.zeros(2 * FDR_BINS, np.int64)
    biased[FDR_BINS + 160] = 2000  # z 5.0 to 5.03
    frame = noise + biased
    mu, sigma, n0 = sr.normal_null(sr.smoothed_counts(frame), int(frame.sum()))
    assert abs(mu + 0.5) <= 1.0 / FDR_SCALE, mu
    assert abs(sigma / 1.3 - 1) < 0.03 and abs(n0 / 200_000 - 1) < 0.03, (sigma, n0)
    table = shrink_table_of(_signed_hist(noise + biased))
    assert table[160] > 0.99 and table[32] < 0.5
    # the local rate: a mean at z 4 is as likely noise as the null expects there, however
    # many biased means lie above it; the tail area's q-value counts those in
    local = shrink_table_of(_signed_hist(noise + biased), rate="local")
    assert local[128] < 0.5 < table[128] and local[160] > 0.99
    tail = noise.copy()
    tail[FDR_BINS - 192:FDR_BINS - 128] += 500  # 32 000 means at z -6 to -4
    assert np.array_equal(shrink_table_of(_signed_hist(tail + biased)), table)
    assert shrink_table_of(_signed_hist(tail + biased), "mode")[128] < 0.5 < table[128]
    with pytest.raises(ValueError, match="rate"):
        shrink_table_of(_signed_hist(noise), "mode", rate="local")
    up = _normal_counts(200_000, 0.8, 1.0)
    assert sr.normal_null(sr.smoothed_counts(up), int(up.sum()))[:2] == (0.0, 1.0)
    assert np.array_equal(shrink_table_of(np.zeros(2 * FDR_BINS, np.int64)),
                          np.zeros(FDR_BINS))


@pytest.mark.parametrize("vw", [1, 16])
@pytest.mark.parametrize("w, strength", [(37, 0.6), (64, 1.2), (33, 0.0)])
def test_shrink_kernels_match_reference(device, vw, w, strength):
    rng = np.random.default_rng(3 * w + vw)
    color, m, ma, mb = _frame(rng, 40, w, 8, strength, smooth=True)
    # a block without noise (every sample alike) whose means are rounding: not counted
    color[-12:, :12] = 0.3
    ma[-12:, :12] = mb[-12:, :12] = m[-12:, :12] = 0.3 + 1e-7 * rng.random((12, 12, 3))
    table, img, total = _device(device, vw, color, m, ma, mb, shrink=True)
    # the table from the kernels' own histogram (the null's fit to the bin, its tail in
    # float32 against float64)
    assert np.allclose(table, shrink_table_of(total), rtol=0, atol=2e-6)
    f32 = [x.astype(np.float32) for x in (color, m, ma, mb)]
    mu7, var7 = _mu_var(*f32)
    c = f32[0].astype(np.float64)
    noisy = _window_mean(_lum2(c[:, :, :4].mean(2) - c[:, :, 4:].mean(2)), 3) > 0
    assert not noisy.all()
    want_t = fdr_shrink_table(mu7, var7, noisy)
    # float32 sums against float64 ones: a pixel at a bin's edge may fall either side
    j = np.minimum(np.floor(np.abs(mu7) / np.sqrt(var7) * FDR_SCALE), FDR_BINS - 1)
    want_h = [np.bincount(j[sel & noisy].astype(int), minlength=FDR_BINS)
              for sel in (mu7 > 0, mu7 < 0)]
    assert np.abs(total - np.concatenate(want_h)).sum() <= 4
    if not np.array_equal(total, np.concatenate(want_h)):
        return  # a moved count may move the mode: the table from the kernels' is checked
    assert np.abs(table - want_t).max() <= 2e-6
    want, _ = sg.reference(*f32, test3=True, vscale=1.0, frame_shrink=True)
    if strength:  # the biased patch keeps its mean: the factors at its z are near 1
        assert want_t[-1] > 0.9
    scale = float(np.abs(want).max())
    bad = np.abs(img - want).max(-1) > 1e-4 * scale  # pixels at a bin's edge, if any
    assert bad.mean() < 0.02, bad.mean()
    assert_close(img[~bad], want[~bad], rtol=1e-4, atol=1e-5 * scale, what=f"vw={vw} w={w}")
    if strength:  # the frame's factors, not the untested mean
        untested, _ = sg.reference(*f32, test3=True, vscale=1.0)
        assert np.abs(untested - want).max() > 1e-3 * scale
