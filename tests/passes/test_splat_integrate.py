"""Pass ``splat_integrate``: the convolution pyramid kernel against its NumPy reference, and the
pyramid (F_5 and F_7) against an exact FFT Poisson solve of the same Laplacian.

Stated tolerance (measured on the test image below: F_5 RMS 0.0070, max 0.133; F_7 RMS
0.0075, max 0.146, for a unit-height disc): RMS error <= 0.012 and max error <= 0.2 of the
image's peak. The pyramid approximates the Green's function, so its error is a smooth
low-amplitude distortion, not noise.
"""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close

from clrecon.methods.splat import reference as ref
from clrecon.methods.splat.integrate import SplatIntegrate
from clrecon.methods.splat.precompute import laplacian5, poisson_fft


def discs(h=160, w=200, pad=40):
    yy, xx = np.mgrid[:h, :w]
    f = ((xx - 90) ** 2 + (yy - 70) ** 2 < 30 ** 2).astype(float)
    f += 0.5 * ((xx - 140) ** 2 + (yy - 100) ** 2 < 12 ** 2)
    return np.pad(f, pad)


@pytest.mark.parametrize("pyramid", ["f5", "f7"])
def test_pyramid_agrees_with_fft_poisson(pyramid):
    f = discs()
    lap = laplacian5(f)
    exact = poisson_fft(lap)
    np.testing.assert_allclose(exact, f, atol=1e-9)  # the FFT solve is exact
    got = ref.integrate(lap, pyramid)
    err = got - exact
    assert np.sqrt((err ** 2).mean()) <= 0.012
    assert np.abs(err).max() <= 0.2
    assert got.sum() / f.sum() == pytest.approx(1.0, abs=0.02)


@pytest.mark.parametrize("pyramid", ["f5", "f7"])
@pytest.mark.parametrize("shape", [(7, 5), (1, 1), (3, 40), (75, 64)], ids=str)
def test_integrate_kernel_matches_reference(device, rng, pyramid, shape):
    h, w = shape
    layers = 2
    lap = rng.normal(0, 1, (layers, h, w, 4)).astype(np.float32)
    ctx, q = device.context, device.queue
    rw = cl.mem_flags.READ_WRITE
    dlap = cl.Buffer(ctx, rw | cl.mem_flags.COPY_HOST_PTR, hostbuf=lap)
    dout = cl.Buffer(ctx, rw, lap.nbytes)
    dring = cl.Buffer(ctx, rw, layers * 16)
    integ = SplatIntegrate(ctx, h, w, pyramid)
    for layer in range(layers):
        integ(q, dlap, layer, dout, dring)
    b0 = np.empty_like(lap)
    ring = np.empty((layers, 4), np.float32)
    cl.enqueue_copy(q, b0, dout)
    cl.enqueue_copy(q, ring, dring)
    q.finish()
    got = ring[:, None, None, :] - b0  # the image, as composite forms it
    for layer in range(layers):
        for c in range(4):
            want = ref.integrate(lap[layer, :, :, c].astype(np.float64), pyramid)
            scale = np.abs(want).max() + 1.0
            assert_close(got[layer, :, :, c], want, rtol=1e-4, atol=2e-5 * scale,
                         what=f"layer {layer} channel {c}")
