"""The guided refinement (kernels/guided.cl, clrecon/methods/guided.py): the kernels against
the NumPy reference, its range and degenerate windows, the pipeline's wiring, the knob's
contract, and one quality check against a converged reference."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close, trusted_reference
from layered_frames import frame

from clrecon.api import make_pipeline, run
from clrecon.core.pipeline import DeviceSamples
from clrecon.metrics import psnr
from clrecon.methods import guided as gd
from clrecon.scenes.builtin import get_scene
from clrecon.scenes.render import render_samples


def _device_refine(device, color, ga, gb, r):
    ctx, q = device.context, device.queue
    h, w, s, _ = color.shape
    mf = cl.mem_flags

    def up(a):
        return cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                         hostbuf=np.ascontiguousarray(a, np.float32))

    passes = gd.GuidedPasses(ctx, r)
    bufs = {k: cl.Buffer(ctx, mf.READ_WRITE, v) for k, v in passes.temporaries(w, h).items()}
    passes(q, up(color), up(ga), up(gb), bufs["guided_y"], bufs["guided_d"],
           bufs["guided_coef"], bufs["qa"], bufs["qb"], w, h, s)
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
@pytest.mark.parametrize("shape", [(13, 17, 5), (9, 6, 2), (1, 11, 8), (20, 3, 4)])
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


def _read(pipe, queue, name, shape):
    a = np.empty(shape, np.float32)
    cl.enqueue_copy(queue, a, pipe.buffer(name))
    return a


@pytest.mark.parametrize("method", ["layered", "sweep", "splat"])
@pytest.mark.parametrize("safeguard", [False, True])
def test_pipeline_refines_the_halves(device, rng, method, safeguard):
    """In the pipeline the refined halves are the reference's refinement of the method's own
    halves' images; without the safeguard the image is their mean."""
    buf = frame(rng, h=24, w=26, s=5)
    ctx, q = device.context, device.queue
    ds = DeviceSamples.wrap(ctx, buf, buf.arrays().keys())
    pipe = make_pipeline(method, ctx, ds.inspect(q), guided=2, safeguard=safeguard)
    out = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, buf.height * buf.width * 12)
    pipe(q, ds, out)
    q.finish()
    shape = (buf.height, buf.width, 3)
    ma, mb = _read(pipe, q, "ma", shape), _read(pipe, q, "mb", shape)
    qa, qb = _read(pipe, q, "qa", shape), _read(pipe, q, "qb", shape)
    ra, rb = gd.reference(buf.color, ma, mb, 2)
    tol = 1e-4 * max(1.0, float(np.abs(ra).max()))
    assert_close(qa, ra, rtol=1e-4, atol=tol, what="refined half A")
    assert_close(qb, rb, rtol=1e-4, atol=tol, what="refined half B")
    image = np.empty(shape, np.float32)
    cl.enqueue_copy(q, image, out)
    assert np.isfinite(image).all()
    if not safeguard:
        ha = buf.spp // 2
        mean = (ha * ra + (buf.spp - ha) * rb) / buf.spp
        assert_close(image, mean, rtol=1e-4, atol=tol, what="image = refined halves' mean")
    d = pipe.describe()
    assert d["guided"] == 2 and d["safeguard"] is safeguard


def test_knob_contract(device, rng):
    buf = frame(rng, h=12, w=12, s=4)
    with pytest.raises(ValueError, match="box has no image"):
        run(buf, method="box", device=device, guided=2)
    for bad in (-1, 9, 2.5, True, "2"):
        with pytest.raises(ValueError, match="guided: the window radius"):
            run(buf, method="layered", device=device, guided=bad)
    one = frame(rng, h=12, w=12, s=1)
    with pytest.raises(ValueError, match="guided: needs >= 2 samples"):
        run(one, method="layered", device=device, guided=2)
    # off is the method as it was, bit for bit
    a = run(buf, method="layered", device=device).image
    b = run(buf, method="layered", device=device, guided=0).image
    assert np.array_equal(a, b)
    # a frame without blur is planned as box: nothing to refine, the image is box's
    still = frame(rng, h=12, w=12, s=4, motion=False, aperture=0.0)
    img = run(still, method="layered", device=device, guided=2).image
    assert_close(img, still.color.mean(2), rtol=1e-5, atol=1e-6, what="box plan")


def test_refinement_beats_its_guide_on_a_builtin_scene(device):
    """Against the converged reference (never from the device under test): the guided
    image of layered's paper method is more accurate than that method's image, and than
    box, on `fence` at 8 spp (measured at 512x512: +7.6 dB over the guide)."""
    scene = get_scene("fence")
    w = h = 128
    ref = trusted_reference(scene, w, h, 1024)
    buf = render_samples(scene, w, h, 8, seed=108, device=device)
    box = psnr(buf.color.mean(2), ref)
    paper = psnr(run(buf, method="layered", device=device, safeguard=False).image, ref)
    guided = psnr(run(buf, method="layered", device=device, safeguard=False, guided=2).image,
                  ref)
    assert guided > paper + 1.0, (box, paper, guided)
    assert guided > box + 3.0, (box, paper, guided)
