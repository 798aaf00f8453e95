"""The guided refinement's kernels (kernels/guided.cl) against the NumPy reference
(clrecon/methods/guided.py): random frames and radii, an affine bias it must remove, the ends
of the float range, degenerate windows."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close

from clrecon.methods import guided as gd


def _device_refine(device, color, ga, gb, r, vw=None):
    ctx, q = device.context, device.queue
    h, w, s, _ = color.shape
    mf = cl.mem_flags

    def up(a):
        return cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                         hostbuf=np.ascontiguousarray(a, np.float32))

    passes = gd.GuidedPasses(ctx, r, vw)
    bufs = {k: cl.Buffer(ctx, mf.READ_WRITE, v) for k, v in passes.temporaries(w, h).items()}
    passes(q, up(color), up(ga), up(gb), bufs["guided_planes"], bufs["guided_coef"],
           bufs["qa"], bufs["qb"], w, h, s)
    qa, qb = np.empty((h, w, 3), np.float32), np.empty((h, w, 3), np.float32)
    cl.enqueue_copy(q, qa, bufs["qa"])
    cl.enqueue_copy(q, qb, bufs["qb"])
    return qa, qb


def _guides(rng, color):
    """Two guides that are structurally like the halves' box images but biased and smooth
    in places: an affine map of each half's mean plus a smooth offset field."""
    h, w, s, _ = color.shape
    ha = s // 2
    yy, xx = np.mgrid[0:h, 0:w]
    field = (0.3 * np.sin(xx / 3.0) * np.cos(yy / 4.0))[..., None]
    ga = 0.7 * color[:, :, :ha].mean(2) + 0.2 + field + rng.normal(0, 0.02, (h, w, 3))
    gb = 0.9 * color[:, :, ha:].mean(2) + 0.1 - field
    return ga.astype(np.float32), gb.astype(np.float32)


@pytest.mark.parametrize("r", [1, 2, 3])
@pytest.mark.parametrize("shape", [(13, 17, 5), (9, 6, 2), (1, 11, 8), (20, 3, 4), (12, 43, 4)])
def test_kernels_match_reference(device, rng, r, shape):
    h, w, s = shape
    color = rng.gamma(2.0, 1.0, (h, w, s, 3)).astype(np.float32)
    ga, gb = _guides(rng, color)
    qa, qb = _device_refine(device, color, ga, gb, r)
    ra, rb = gd.reference(color, ga, gb, r)
    assert_close(qa, ra, rtol=2e-5, atol=2e-5, what="half A")
    assert_close(qb, rb, rtol=2e-5, atol=2e-5, what="half B")
    # the refinement does something: it moves the biased guide toward the truth's box mean
    assert np.abs(ra - ga).max() > 0.05


def test_refinement_removes_an_affine_bias(device, rng):
    """A guide that is the truth under an affine colour map (a wrong gain and offset, a
    channel mixed in) is corrected: the regression recovers the map from the noisy box image,
    so the refined image is much closer to the truth than the guide or the box image."""
    h, w, s = 40, 40, 8
    yy, xx = np.mgrid[0:h, 0:w]
    truth = np.stack([0.5 + 0.4 * np.sin(xx / 5.0), 0.5 + 0.3 * np.cos(yy / 6.0),
                      0.4 + 0.2 * np.sin((xx + yy) / 7.0)], -1)
    color = (truth[:, :, None, :] + rng.normal(0, 0.2, (h, w, s, 3))).astype(np.float32)
    mix = np.array([[0.8, 0.1, 0.0], [0.0, 1.2, 0.0], [0.1, 0.0, 0.9]])
    g = (truth @ mix + 0.05).astype(np.float32)
    qa, qb = _device_refine(device, color, g, g, 2)
    q = 0.5 * (qa.astype(np.float64) + qb)
    box = color.astype(np.float64).mean(2)
    err = {k: float(np.mean((v - truth) ** 2)) for k, v in
           (("guide", g), ("box", box), ("refined", q))}
    assert err["refined"] < 0.2 * err["guide"], err
    assert err["refined"] < 0.2 * err["box"], err


@pytest.mark.parametrize("scale", [1e-20, 1e25])
def test_scale_covariant_at_the_ends_of_the_range(device, rng, scale):
    """Each window is computed in units of its largest value: colours near float32's ends
    give the same image, scaled (no square overflows, none underflows)."""
    h, w, s = 12, 14, 4
    color = rng.gamma(2.0, 1.0, (h, w, s, 3)).astype(np.float32)
    ga, gb = _guides(rng, color)
    qa, qb = _device_refine(device, color, ga, gb, 2)
    sa, sb = _device_refine(device, color * np.float32(scale), ga * np.float32(scale),
                            gb * np.float32(scale), 2)
    assert np.isfinite(sa).all() and np.isfinite(sb).all()
    assert_close(sa / scale, qa, rtol=1e-4, atol=1e-5, what="half A scaled back")
    assert_close(sb / scale, qb, rtol=1e-4, atol=1e-5, what="half B scaled back")


def test_degenerate_windows(device, rng):
    """A black frame stays black; a flat guide (its covariance 0) gives the guide plus the
    windows' mean residual, finite; a frame whose halves agree exactly (variance 0) too."""
    h, w, s = 10, 9, 4
    zero = np.zeros((h, w, s, 3), np.float32)
    qa, qb = _device_refine(device, zero, zero[:, :, 0], zero[:, :, 0], 2)
    assert not qa.any() and not qb.any()
    color = rng.gamma(2.0, 1.0, (h, w, s, 3)).astype(np.float32)
    flat = np.full((h, w, 3), 0.5, np.float32)
    qa, qb = _device_refine(device, color, flat, flat, 2)
    ra, rb = gd.reference(color, flat, flat, 2)
    assert np.isfinite(qa).all() and np.isfinite(qb).all()
    assert_close(qa, ra, rtol=2e-5, atol=2e-5, what="flat guide, half A")
    same = np.repeat(color[:, :, :1], s, axis=2)
    ga, gb = _guides(rng, same)
    qa, qb = _device_refine(device, same, ga, gb, 2)
    ra, _ = gd.reference(same, ga, gb, 2)
    assert np.isfinite(qa).all()
    assert_close(qa, ra, rtol=2e-5, atol=2e-5, what="no variance, half A")


@pytest.mark.parametrize("vw", [1, 8, 16])
def test_every_vector_width_matches_reference(device, rng, vw):
    """Windows a work-item: 1 (GPUs), 8 (CPUs), 16; a frame whose width leaves partial lane
    groups, interior groups (the lanes' path) and groups the image clips (pixel by pixel)."""
    h, w, s = 14, 45, 6
    color = rng.gamma(2.0, 1.0, (h, w, s, 3)).astype(np.float32)
    ga, gb = _guides(rng, color)
    qa, qb = _device_refine(device, color, ga, gb, 2, vw)
    ra, rb = gd.reference(color, ga, gb, 2)
    assert_close(qa, ra, rtol=2e-5, atol=2e-5, what=f"half A, {vw} lanes")
    assert_close(qb, rb, rtol=2e-5, atol=2e-5, what=f"half B, {vw} lanes")


def test_refused_vector_width(device):
    with pytest.raises(ValueError, match="vector width 4"):
        gd.GuidedPasses(device.context, 2, 4)
