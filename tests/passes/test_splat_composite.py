"""Pass ``splat_composite``: back-to-front composition with coverage re-weighting against its NumPy
reference, and the flat-field property it exists for."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close

from clrecon.methods.splat import reference as ref
from clrecon.methods.splat.composite import SplatComposite


def run(device, prim, direct, ring, pad, h, w, use_lap=True, color=None):
    ctx, q = device.context, device.queue
    ro = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
    nl = prim.shape[0]
    db = cl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(prim, np.float32))
    dd = cl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(direct, np.float32))
    dr = cl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(ring, np.float32))
    out = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, h * w * 12)
    dc, spp = None, 0
    if color is not None:
        dc = cl.Buffer(ctx, ro, hostbuf=np.ascontiguousarray(color, np.float32))
        spp = color.shape[2]
    SplatComposite(ctx, nl, use_lap)(q, db, dd, dr, w, h, pad, out, color=dc, spp=spp)
    img = np.empty((h, w, 3), np.float32)
    cl.enqueue_copy(q, img, out)
    q.finish()
    return img


@pytest.mark.parametrize("nl", [1, 3])
@pytest.mark.parametrize("use_lap", [True, False])
def test_composite_matches_reference(device, rng, nl, use_lap):
    h, w, pad = 9, 14, 3
    b0 = rng.normal(0, 1, (nl, h + 2 * pad, w + 2 * pad, 4)).astype(np.float32)
    ring = rng.normal(0, 0.1, (nl, 4)).astype(np.float32)
    direct = rng.uniform(-0.1, 1.5, b0.shape).astype(np.float32)
    direct[0, :3, :4] = 0.0  # some pixels with no coverage at all
    if not use_lap:
        b0[:] = 0.0
        ring[:] = 0.0
    got = run(device, b0, direct, ring, pad, h, w, use_lap)
    prim = ring[:, None, None, :] - b0
    want = ref.composite(prim, direct, pad, h, w)
    assert_close(got, want, rtol=1e-5, atol=1e-5, what="composite")
    assert got.min() >= 0


def test_flat_field_stays_flat_with_partial_coverage(device, rng):
    """Every layer's colour is c times its coverage (what splatting a flat field gives):
    the result is c wherever any coverage arrived, whatever the coverages are."""
    h, w, pad, nl = 6, 7, 2, 3
    cov = rng.uniform(0.05, 2.0, (nl, h + 2 * pad, w + 2 * pad))
    c = np.array([0.3, 2.0, 1e4])
    direct = np.concatenate([cov[..., None] * c, cov[..., None]], -1)
    got = run(device, np.zeros_like(direct), direct, np.zeros((nl, 4)), pad, h, w, False)
    assert_close(got, np.broadcast_to(c, got.shape), rtol=1e-5, what="flat field")


def test_uncovered_pixels_take_their_samples_mean(device, rng):
    """A pixel no layer covers (no sample's PSF reached it: 1-4 spp) is the mean of its own
    samples, not black; covered pixels are untouched by the samples."""
    h, w, pad, nl, spp = 8, 9, 2, 2, 3
    direct = rng.uniform(0.2, 1.5, (nl, h + 2 * pad, w + 2 * pad, 4)).astype(np.float32)
    direct[:, pad + 1:pad + 4, pad + 2:pad + 5] = 0.0  # a 3x3 hole in every layer
    color = rng.uniform(0.0, 2.0, (h, w, spp, 3)).astype(np.float32)
    zeros = np.zeros_like(direct)
    got = run(device, zeros, direct, np.zeros((nl, 4)), pad, h, w, False, color=color)
    want = ref.composite(-zeros, direct, pad, h, w, color=color)
    assert_close(got, want, rtol=1e-5, atol=1e-6, what="composite with samples")
    hole = np.zeros((h, w), bool)
    hole[1:4, 2:5] = True
    assert_close(got[hole], color.mean(2)[hole], rtol=1e-5, what="holes")
    assert_close(got[~hole], run(device, zeros, direct, np.zeros((nl, 4)), pad, h, w,
                                 False)[~hole], rtol=0, atol=0, what="covered pixels")


def test_uncovered_pixels_of_a_view_take_their_own_samples(device, rng):
    """The fallback reads samples offset .. offset + spp - 1 of a wider buffer (a half of a
    frame read in place): the same image as from a copy of those samples."""
    h, w, pad, nl, stride = 5, 6, 1, 1, 5
    direct = rng.uniform(0.2, 1.5, (nl, h + 2 * pad, w + 2 * pad, 4)).astype(np.float32)
    direct[:, pad:pad + 2, pad:pad + 3] = 0.0  # uncovered pixels
    color = rng.uniform(0.0, 2.0, (h, w, stride, 3)).astype(np.float32)
    ctx, q = device.context, device.queue
    ro = cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR
    planes = [cl.Buffer(ctx, ro, hostbuf=a) for a in (np.zeros_like(direct), direct,
                                                      np.zeros((nl, 4), np.float32))]
    wide = cl.Buffer(ctx, ro, hostbuf=color)
    comp = SplatComposite(ctx, nl, False)
    for offset, n in ((0, 2), (2, 3)):
        out = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, h * w * 12)
        comp(q, *planes, w, h, pad, out, color=wide, spp=n, stride=stride, offset=offset)
        got = np.empty((h, w, 3), np.float32)
        cl.enqueue_copy(q, got, out)
        q.finish()
        want = run(device, np.zeros_like(direct), direct, np.zeros((nl, 4)), pad, h, w, False,
                   color=np.ascontiguousarray(color[:, :, offset:offset + n]))
        assert np.array_equal(got, want), (offset, n)
        assert_close(got[:2, :3], color[:2, :3, offset:offset + n].mean(2), rtol=1e-5,
                     what="uncovered pixels")
