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
