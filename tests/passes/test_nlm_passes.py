"""The dual-buffer non-local means kernels (kernels/nlm.cl) against the NumPy reference
(clrecon/methods/nlm.py): random frames, radii and sizes (the 8-pixel lane groups' tails,
single rows and columns), unequal halves, noise-free halves, and what the filter must do."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close

from clrecon.methods import nlm


def _device_nlm(device, a, b, spp, r):
    ctx, q = device.context, device.queue
    h, w, _ = a.shape
    mf = cl.mem_flags

    def up(x):
        return cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                         hostbuf=np.ascontiguousarray(x, np.float32))

    passes = nlm.NlmPasses(ctx, r)
    bufs = {k: cl.Buffer(ctx, mf.READ_WRITE, v) for k, v in passes.temporaries(w, h).items()}
    passes(q, up(a), up(b), bufs["nlm_planes"], bufs["na"], bufs["nb"], w, h, spp)
    na, nb = np.empty((h, w, 3), np.float32), np.empty((h, w, 3), np.float32)
    cl.enqueue_copy(q, na, bufs["na"])
    cl.enqueue_copy(q, nb, bufs["nb"])
    return na, nb


def _halves(rng, h, w, noise=0.3):
    """Two noisy copies of one image with edges (a step and a ramp) and texture."""
    yy, xx = np.mgrid[0:h, 0:w]
    base = np.stack([(xx > w / 2) * 2.0 + 0.5, yy / max(h, 1) + 0.2,
                     0.5 + 0.3 * np.sin(xx / 2.0)], -1)
    a = base + rng.normal(0, noise, (h, w, 3))
    b = base + rng.normal(0, noise, (h, w, 3))
    return a.astype(np.float32), b.astype(np.float32), base


@pytest.mark.parametrize("r", [1, 2, 5])
@pytest.mark.parametrize("shape", [(13, 17, 8), (9, 6, 5), (1, 11, 4), (20, 3, 9), (12, 43, 16),
                                   (1, 1, 2)])
def test_kernels_match_reference(device, rng, r, shape):
    h, w, spp = shape
    a, b, _ = _halves(rng, h, w)
    na, nb = _device_nlm(device, a, b, spp, r)
    ra, rb = nlm.reference(a, b, spp, r)
    assert_close(na, ra, rtol=2e-5, atol=2e-5, what="half A")
    assert_close(nb, rb, rtol=2e-5, atol=2e-5, what="half B")
    if h * w > 1:  # it averages: each half moves
        assert np.abs(ra - a).max() > 0.05 and np.abs(rb - b).max() > 0.05


def test_unequal_halves_use_each_guides_variance(device, rng):
    """With an odd spp the halves' variances differ (var(A) = hb/S v, var(B) = ha/S v); a
    kernel that swapped them would give other weights."""
    a, b, _ = _halves(rng, 14, 19)
    na, nb = _device_nlm(device, a, b, 3, 3)  # halves of 1 and 2 samples
    ra, rb = nlm.reference(a, b, 3, 3)
    assert_close(na, ra, rtol=2e-5, atol=2e-5, what="half A")
    assert_close(nb, rb, rtol=2e-5, atol=2e-5, what="half B")
    sa, sb = nlm.reference(a, b, 4, 3)  # equal halves: other weights
    assert np.abs(sa - ra).max() > 1e-3 and np.abs(sb - rb).max() > 1e-3


def test_filter_reduces_noise_and_keeps_edges(rng, device):
    """On two noisy halves of a flat field with a step, the filtered halves are closer to
    the truth than the halves (noise averaged), and the step stays a step."""
    h, w = 24, 32
    truth = np.full((h, w, 3), 0.5)
    truth[:, w // 2:] = 2.0
    a = (truth + rng.normal(0, 0.1, truth.shape)).astype(np.float32)
    b = (truth + rng.normal(0, 0.1, truth.shape)).astype(np.float32)
    na, nb = _device_nlm(device, a, b, 8, 5)
    for x, n in ((a, na), (b, nb)):
        assert np.mean((n - truth) ** 2) < 0.3 * np.mean((x - truth) ** 2)
    # no bleeding across the step: both sides within 5 noise sigmas of their level
    assert np.abs(na[:, : w // 2 - 1] - 0.5).max() < 0.5
    assert np.abs(na[:, w // 2 + 1:] - 2.0).max() < 0.5


def test_noise_free_halves_average_only_equal_pixels(device):
    """Halves that agree carry no noise estimate: a pixel is averaged only with pixels of
    the same colour, so a noise-free image is returned as it is."""
    yy, xx = np.mgrid[0:10, 0:12]
    img = np.stack([xx * 0.1, yy * 0.2, (xx + yy) % 3 * 1.0], -1).astype(np.float32)
    na, nb = _device_nlm(device, img, img, 8, 4)
    assert_close(na, img, rtol=1e-6, atol=1e-6, what="half A")
    assert_close(nb, img, rtol=1e-6, atol=1e-6, what="half B")


def test_weights_come_from_the_other_half(device, rng):
    """Dual buffers: A's output depends on B only through the weights. With B a copy of the
    truth's edges at another noise, swapping the roles of A's noise changes A's output by
    less than averaging A with its own weights would."""
    a, b, _ = _halves(rng, 16, 16)
    na, _ = _device_nlm(device, a, b, 8, 2)
    b2 = b.copy()
    b2[8, 8] += 50.0  # a bright outlier in B: its neighbours in A lose weight at it
    na2, nb2 = _device_nlm(device, a, b2, 8, 2)
    ra2, rb2 = nlm.reference(a, b2, 8, 2)
    assert_close(na2, ra2, rtol=2e-5, atol=2e-5, what="half A")
    assert_close(nb2, rb2, rtol=2e-5, atol=2e-5, what="half B")
    # A's value at the outlier's pixel: its weights changed, not its own values
    assert np.abs(na2 - na).max() > 1e-3


@pytest.mark.parametrize("scale", [1e-15, 1e15])
def test_float_range(device, rng, scale):
    """Small and large colours: the same relative result (the weights are scale-free within
    float32's range of squares: clrecon/methods/nlm.py)."""
    a, b, _ = _halves(rng, 9, 13)
    na, nb = _device_nlm(device, a * np.float32(scale), b * np.float32(scale), 8, 2)
    ra, rb = nlm.reference(a, b, 8, 2)
    assert np.isfinite(na).all() and np.isfinite(nb).all()
    assert_close(na / scale, ra, rtol=1e-4, atol=1e-4, what="half A")
    assert_close(nb / scale, rb, rtol=1e-4, atol=1e-4, what="half B")


def test_radius_contract():
    for bad in (-1, 11, 2.5, True, "2"):
        with pytest.raises(ValueError, match="nlm: the search radius"):
            nlm.check_radius(bad)
    assert nlm.check_radius(0) == 0 and nlm.check_radius(10) == 10


def test_down_and_up_against_loops(rng):
    """The reference's 2x2 means and tent upsampling (clrecon.methods.nlm.down2, up2), odd
    sizes included, against plain loops."""
    x = rng.random((7, 9, 3))
    d = nlm.down2(x)
    assert d.shape == (3, 4, 3)
    assert np.allclose(d[1, 2], x[2:4, 4:6].mean((0, 1)))
    u = nlm.up2(d, x.shape)
    assert u.shape == x.shape
    near = np.empty_like(x)  # nearest, edge-replicated past the last full 2x2 block
    for i in range(7):
        for j in range(9):
            near[i, j] = d[min(i, 5) // 2, min(j, 7) // 2]
    t = (0.25, 0.5, 0.25)
    for i, j in ((0, 0), (3, 4), (6, 8), (5, 7)):
        want = sum(t[a + 1] * t[b + 1] * near[min(max(i + a, 0), 6), min(max(j + b, 0), 8)]
                   for a in (-1, 0, 1) for b in (-1, 0, 1))
        assert np.allclose(u[i, j], want)
    assert np.allclose(nlm.up2(np.full((3, 4, 3), 2.0), (7, 9, 3)), 2.0)


def _coarse_noise_halves(rng, h, w):
    """A smooth image with noise of a 4-pixel grain, opposite in the two halves, and fine
    noise: what the coarser scales are for."""
    yy, xx = np.mgrid[0:h, 0:w]
    base = np.stack([1 + 0.5 * np.sin(xx / 5.0), 1 + yy / 20.0, 0.7 + 0 * xx], -1)
    cn = rng.normal(0, 0.2, (h // 4 + 1, w // 4 + 1, 3)).repeat(4, 0).repeat(4, 1)[:h, :w]
    a = base + cn + rng.normal(0, 0.1, base.shape)
    b = base - cn + rng.normal(0, 0.1, base.shape)
    return a.astype(np.float32), b.astype(np.float32), base


@pytest.mark.parametrize("shape, r, scales", [((13, 17, 8), 2, 2), ((33, 40, 5), 3, 4),
                                              ((9, 6, 4), 1, 3), ((1, 11, 4), 2, 3),
                                              ((3, 3, 4), 1, 6), ((64, 48, 16), 3, 4)])
def test_scales_match_reference(device, rng, shape, r, scales):
    h, w, spp = shape
    a, b, _ = _coarse_noise_halves(rng, h, w)
    ctx, q = device.context, device.queue
    mf = cl.mem_flags
    passes = nlm.NlmPasses(ctx, r, scales)
    bufs = {k: cl.Buffer(ctx, mf.READ_WRITE, v) for k, v in passes.temporaries(w, h).items()}

    def up(x):
        return cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)

    evs = passes(q, up(a), up(b), bufs["nlm_planes"], bufs["na"], bufs["nb"], w, h, spp)
    passes.run_scales(q, bufs["nlm_planes"], bufs["na"], bufs["nb"], bufs, w, h, spp,
                      [evs[-1][1]])
    na, nb = np.empty((h, w, 3), np.float32), np.empty((h, w, 3), np.float32)
    cl.enqueue_copy(q, na, bufs["na"])
    cl.enqueue_copy(q, nb, bufs["nb"])
    one = nlm.reference(a, b, spp, r)
    ra, rb = nlm.multiscale(*one, spp, r, scales)
    assert_close(na, ra, rtol=2e-5, atol=2e-5, what="half A")
    assert_close(nb, rb, rtol=2e-5, atol=2e-5, what="half B")
    if nlm.levels(w, h, scales) and min(h, w) >= 8:  # the coarser scales do something
        assert np.abs(ra - one[0]).max() > 0.05


def test_more_scales_remove_coarse_noise(rng):
    """On halves whose noise has a grain coarser than a radius-3 window, four scales leave
    less error than one (the reference)."""
    a, b, base = _coarse_noise_halves(rng, 48, 64)
    err = [np.mean((nlm.multiscale(*nlm.reference(a, b, 8, 3), 8, 3, s)[0] - base) ** 2)
           for s in (1, 4)]
    assert err[1] < 0.8 * err[0], err


def test_scales_contract():
    for bad in (0, 7, 2.0, True):
        with pytest.raises((ValueError, TypeError), match="nlm_scales"):
            nlm.check_scales(bad)
    assert nlm.levels(17, 13, 3) == [(8, 6), (4, 3)]
    assert nlm.levels(17, 13, 1) == [] and nlm.levels(1, 50, 4) == []
