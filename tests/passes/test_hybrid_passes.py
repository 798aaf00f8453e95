"""The hybrid's blend (kernels/hybrid.cl) against the NumPy reference
(clrecon/methods/hybrid.py): random images and error estimates of several sizes (windows
clipped at every edge), estimates that are 0, equal, or saturated at FLT_MAX."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close

from clrecon.methods import hybrid

FMAX = float(np.finfo(np.float32).max)


def _device_blend(device, a, ea, b, eb):
    ctx, q = device.context, device.queue
    h, w = ea.shape
    mf = cl.mem_flags

    def up(x):
        return cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                         hostbuf=np.ascontiguousarray(x, np.float32))

    out = cl.Buffer(ctx, mf.READ_WRITE, h * w * 12)
    err = cl.Buffer(ctx, mf.READ_WRITE, h * w * 4)
    hybrid.HybridBlend(ctx)(q, up(a), up(ea), up(b), up(eb), out, err, w, h)
    img, e = np.empty((h, w, 3), np.float32), np.empty((h, w), np.float32)
    cl.enqueue_copy(q, img, out)
    cl.enqueue_copy(q, e, err)
    q.finish()
    return img, e


@pytest.mark.parametrize("shape", [(13, 17), (1, 1), (1, 9), (8, 1), (20, 33)])
def test_blend_matches_reference(device, rng, shape):
    h, w = shape
    a, b = rng.uniform(0, 2, (h, w, 3)), rng.uniform(0, 2, (h, w, 3))
    ea, eb = rng.uniform(0, 1e-2, (h, w)) ** 2, rng.uniform(0, 1e-2, (h, w)) ** 2
    got, gerr = _device_blend(device, a, ea, b, eb)
    want, werr, wa = hybrid.reference(a.astype(np.float32), ea.astype(np.float32),
                                      b.astype(np.float32), eb.astype(np.float32))
    assert_close(got, want, rtol=1e-5, atol=1e-6, what="image")
    assert_close(gerr, werr, rtol=1e-4, atol=1e-12, what="error")
    if h * w > 1:  # a blend, not one of its ends
        assert 0.05 < wa.mean() < 0.95


def test_blend_edge_cases(device, rng):
    """Zero estimates on both (equal weights), on one (that image alone), one window
    saturated at FLT_MAX (the other image), both saturated (equal weights, finite)."""
    h, w = 16, 16
    a, b = rng.uniform(0, 1, (h, w, 3)), rng.uniform(0, 1, (h, w, 3))
    ea, eb = np.zeros((h, w)), np.zeros((h, w))
    eb[:, 8:] = 1e-3            # right half: a is exact, b is not
    ea[12:, :] = FMAX           # bottom rows: a saturated
    eb[12:, :4] = FMAX          # bottom-left corner: both saturated
    got, gerr = _device_blend(device, a, ea, b, eb)
    want, werr, wa = hybrid.reference(a.astype(np.float32), ea, b.astype(np.float32), eb)
    assert_close(got, want, rtol=1e-5, atol=1e-6, what="image")
    assert np.isfinite(got).all() and np.isfinite(gerr).all()
    assert np.all(wa[:4, :4] == 0.5)          # both 0 over the window
    assert np.all(wa[:4, 12:] == 1.0)         # only b errs there
    assert np.all(wa[15, 7:] == 0.0)          # a saturated, b finite over the window
    assert np.all(wa[15, :1] == 0.5)          # both saturated: equal sums
    assert_close(gerr, werr, rtol=1e-4, atol=1e-12, what="error")
