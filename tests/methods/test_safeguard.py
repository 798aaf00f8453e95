"""The per-pixel safeguard and error estimate (kernels/safeguard.cl, clrecon/methods/safeguard.py):
the device against the NumPy reference, the estimator's statistics, the knobs' contract."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close
from layered_frames import frame

from clrecon.api import METHODS, make_pipeline, run
from clrecon.core.camera import CocModel
from clrecon.core.pipeline import DeviceSamples
from clrecon.core.samples import SampleBuffer
from clrecon.methods import safeguard as sg
from clrecon.methods.safeguard_passes import bias_tests, shrinks_by_frame


def _half(buf: SampleBuffer, sl: slice) -> SampleBuffer:
    return SampleBuffer(**{k: np.ascontiguousarray(v[:, :, sl]) for k, v in
                           buf.arrays().items()}, coc_model=buf.coc_model)


def _expected(buf, method, device, mode):
    """The reference from the method's own images (safeguard off) on the frame and on the
    two halves, each made by run() on a host-split buffer; a method that declares
    ``halves_mean`` blends the halves' mean instead of its image of the frame."""
    if mode == sg.MODE_BOX:
        return sg.reference(buf.color, mode=mode)
    ha, _ = sg.halves(buf.spp)
    knobs = {} if method == "box" else {"safeguard": False}
    m = run(buf, method=method, device=device, **knobs).image
    halves = [_half(buf, slice(0, ha)), _half(buf, slice(ha, None))]
    if mode == sg.MODE_BLEND and METHODS[method].shared_steps:
        ma, mb = _shared_halves(buf, halves, method, device)
    else:
        ma, mb = (run(h, method=method, device=device, **knobs).image for h in halves)
    if mode == sg.MODE_BLEND and METHODS[method].halves_mean:
        m = None
    test7, test3 = bias_tests(False, buf.spp)  # below 8 spp the 7x7 mean is tested
    shrink = shrinks_by_frame(False, buf.spp)  # from 8 spp scaled by the frame's q-value
    return sg.reference(buf.color, m, ma, mb, mode=mode, z7=sg.GUIDED_Z7 if test7 else 0.0,
                        test3=test3, frame_shrink=shrink)


def _shared_halves(buf, halves, method, device):
    """The halves' images made with the frame's outputs of the method's shared steps
    (layered: the frame's statistics and partitions), through the executor's ``steps``."""
    from clrecon.core.device import get_device

    dev = get_device(device)
    ctx, q = dev.context, dev.queue
    full = make_pipeline(method, ctx, buf.inspect(), safeguard=False)
    out = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, buf.height * buf.width * 12)
    shared = METHODS[method].shared_steps
    full(q, DeviceSamples.upload(q, buf), out, steps=shared)
    outs = {o for st in full.plan.steps if st.name in shared for o in st.outputs}
    images = []
    for h in halves:
        pipe = make_pipeline(method, ctx, replace(buf.inspect(), spp=h.spp), safeguard=False)
        rest = tuple(st.name for st in pipe.plan.steps if st.name not in shared)
        pipe(q, DeviceSamples.upload(q, h), out, steps=rest,
             temporaries={k: full.buffers[k] for k in outs})
        img = np.empty((buf.height, buf.width, 3), np.float32)
        cl.enqueue_copy(q, img, out)
        images.append(img)
    return images


@pytest.mark.parametrize("method", ["sweep", "layered", "splat"])
@pytest.mark.parametrize("spp", [4, 5, 8, 12, 16, 17])
def test_blend_and_error_match_reference(device, method, spp):
    buf = frame(np.random.default_rng(spp), h=13, w=17, s=spp)
    got = run(buf, method=method, device=device, estimate_error=True)
    assert got.method["safeguard"] is True
    img, err = _expected(buf, method, device, sg.MODE_BLEND)
    scale = float(np.abs(img).max())
    assert_close(got.image, img, rtol=1e-4, atol=1e-5 * scale, what=f"{method} image")
    assert_close(got.error, err, rtol=1e-3, atol=1e-6 * scale ** 2, what=f"{method} error")


@pytest.mark.parametrize("spp", [5, 8, 16])
def test_independent_samples_declared(device, spp):
    """``independent_samples=True``: below 16 spp the 7x7 bias mean tested at 2 standard
    errors (not scaled by the frame's q-value, as undeclared samples' from 8 spp), from 16
    spp shrunk by its significance (the reference's ``z7 < 0``) with no measured convergence
    (the halves' variances as they are: no ``safeguard_ratio``); below 8 spp the tested mean
    as for any frame, bit for bit; described; a pipeline without halves takes it and changes
    nothing."""
    buf = frame(np.random.default_rng(30 + spp), h=13, w=17, s=spp)
    got = run(buf, method="sweep", device=device, estimate_error=True,
              independent_samples=True)
    plain = run(buf, method="sweep", device=device, estimate_error=True)
    assert got.method["safeguard_samples"].startswith("independent")
    assert "safeguard_samples" not in plain.method
    assert ("safeguard_convergence" in plain.method) == (spp >= 16)
    assert "safeguard_convergence" not in got.method
    assert not any("safeguard_ratio" in k for k in got.pass_ms)
    if spp < 8:
        assert np.array_equal(got.image, plain.image) and np.array_equal(got.error, plain.error)
        return
    ha, _ = sg.halves(spp)
    halves = [_half(buf, slice(0, ha)), _half(buf, slice(ha, None))]
    ma, mb = (run(h, method="sweep", device=device, safeguard=False).image for h in halves)
    tested = spp < 16  # safeguard_passes.bias_tests
    assert got.method["safeguard_bias_tests"]["7x7 at 2 se"] == tested
    assert not got.method["safeguard_bias_tests"]["7x7 by the frame's q-value"]
    assert plain.method["safeguard_bias_tests"]["7x7 by the frame's q-value"]
    img, err = sg.reference(buf.color, None, ma, mb, mode=sg.MODE_BLEND,
                            z7=sg.GUIDED_Z7 if tested else sg.SHRINK_Z7, vscale=1.0)
    scale = float(np.abs(img).max())
    assert_close(got.image, img, rtol=1e-4, atol=1e-5 * scale, what="image")
    assert_close(got.error, err, rtol=1e-3, atol=1e-6 * scale ** 2, what="error")
    box = run(buf, method="box", device=device, independent_samples=True)  # no halves
    assert np.array_equal(box.image, run(buf, method="box", device=device).image)


@pytest.mark.parametrize("method", ["sweep", "splat"])
def test_error_alone_keeps_the_method_image(device, method):
    buf = frame(np.random.default_rng(7), h=11, w=14, s=4)
    got = run(buf, method=method, device=device, safeguard=False, estimate_error=True)
    assert got.method["safeguard"] is False
    paper = run(buf, method=method, device=device, safeguard=False).image
    assert np.array_equal(got.image, paper)
    _, err = _expected(buf, method, device, sg.MODE_METHOD)
    assert_close(got.error, err, rtol=1e-3, atol=1e-6 * float(err.max()), what="error")


@pytest.mark.parametrize("s", [8, 16])
def test_box_error_is_its_variance(device, s):
    """Box's error estimate is unbiased for its variance: i.i.d. samples of known variance
    (from 16 spp the quarters measure the samples' convergence: 1/n for these)."""
    rng = np.random.default_rng(11)
    h, w, sigma = 48, 64, 0.5
    buf = SampleBuffer.zeros(h, w, s, CocModel(0.0, 0.0))
    buf.color[:] = 2.0 + sigma * rng.standard_normal(buf.color.shape).astype(np.float32)
    buf.color[:] = np.abs(buf.color)
    got = run(buf, method="box", device=device, estimate_error=True)
    assert np.array_equal(got.image, buf.color.mean(2, dtype=np.float64).astype(np.float32)) \
        or np.allclose(got.image, buf.color.mean(2), rtol=1e-6)
    _, err = sg.reference(buf.color, mode=sg.MODE_BOX)
    assert_close(got.error, err, rtol=1e-4, atol=1e-9, what="box error")
    # the variance of a mean of s samples, per channel, averaged over RGB: sigma^2 / s
    assert abs(float(got.error.mean()) / (sigma ** 2 / s) - 1) < 0.05


def test_weight_goes_to_box_where_box_is_exact(device):
    """Every sample of a pixel with one colour: box has no variance, so the image is box's
    wherever the method differs (a method's bias never survives an exact box)."""
    buf = frame(np.random.default_rng(5), h=12, w=12, s=4)
    rng = np.random.default_rng(6)
    buf.color[:] = rng.uniform(0.1, 3.0, (12, 12, 1, 3)).astype(np.float32)
    got = run(buf, method="sweep", device=device)
    assert_close(got.image, buf.color[:, :, 0], rtol=1e-5, atol=1e-6, what="image")


def test_blend_lies_between_box_and_method(device):
    """Between box and the method's image it blends: layered's halves' mean."""
    buf = frame(np.random.default_rng(8), h=15, w=15, s=6)
    blend = run(buf, method="layered", device=device).image.astype(np.float64)
    ha, hb = sg.halves(buf.spp)
    ma, mb = _shared_halves(buf, [_half(buf, slice(0, ha)), _half(buf, slice(ha, None))],
                            "layered", device)
    paper = (ha * ma.astype(np.float64) + hb * mb) / buf.spp
    box = buf.color.mean(2, dtype=np.float64)
    lo, hi = np.minimum(paper, box), np.maximum(paper, box)
    tol = 1e-5 * float(np.abs(box).max())
    assert ((blend >= lo - tol) & (blend <= hi + tol)).all()


def test_one_sample_per_pixel(device):
    buf = frame(np.random.default_rng(9), h=8, w=9, s=1)
    got = run(buf, method="sweep", device=device)  # default: no halves, no safeguard
    assert got.method.get("safeguard") is not True
    with pytest.raises(ValueError, match="estimate_error: needs >= 2 samples"):
        run(buf, method="sweep", device=device, estimate_error=True)
    with pytest.raises(ValueError, match="safeguard: needs >= 2 samples"):
        run(buf, method="sweep", device=device, safeguard=True)


def test_knob_checks(device):
    info = frame(np.random.default_rng(1), h=8, w=8, s=2).inspect()
    with pytest.raises(TypeError, match="safeguard: must be"):
        make_pipeline("sweep", device.context, info, safeguard="yes")
    with pytest.raises(TypeError, match="estimate_error: must be"):
        make_pipeline("sweep", device.context, info, estimate_error=1)
    with pytest.raises(ValueError, match="box is the unbiased estimate"):
        make_pipeline("box", device.context, info, safeguard=True)


def test_embedding_with_caller_error_buffer(device):
    """A pipeline on the caller's queue writes the error into the caller's temporary."""
    buf = frame(np.random.default_rng(12), h=10, w=12, s=4)
    q = device.queue
    info = buf.inspect()
    pipe = make_pipeline("splat", device.context, info, estimate_error=True)
    ds = DeviceSamples.upload(q, buf, pipe.fields, info=info)
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, 10 * 12 * 12)
    err_buf = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, 10 * 12 * 4)
    ev = pipe(q, ds, out, temporaries={"error": err_buf})
    err = np.empty((10, 12), np.float32)
    cl.enqueue_copy(q, err, err_buf, wait_for=[ev])
    want = run(buf, method="splat", device=device, estimate_error=True).error
    assert_close(err, want, rtol=1e-6, atol=0, what="error")


def test_grow_from_a_sharp_frame(device):
    """A pipeline planned on a frame without blur (the box plan) that grows into a blurred
    frame re-plans with the safeguard."""
    sharp = SampleBuffer.zeros(10, 10, 4, CocModel(0.0, 0.0))
    sharp.color[:] = np.random.default_rng(2).uniform(0, 1, sharp.color.shape)
    blurred = frame(np.random.default_rng(3), h=10, w=10, s=4)
    pipe = make_pipeline("sweep", device.context, sharp.inspect(), grow=True)
    q = device.queue
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, 10 * 10 * 12)
    info = blurred.inspect()
    ds = DeviceSamples.upload(q, blurred, info=info)
    ev = pipe(q, ds, out)
    img = np.empty((10, 10, 3), np.float32)
    cl.enqueue_copy(q, img, out, wait_for=[ev])
    assert pipe.describe()["safeguard"] is True
    want = run(blurred, method="sweep", device=device).image
    assert_close(img, want, rtol=1e-5, atol=1e-6, what="grown image")


@pytest.mark.parametrize("spp", [4, 8])  # 8: the frame's q-value scales the 7x7 mean
@pytest.mark.parametrize("scale", [1e-30, 1e15, 1e30])
def test_extreme_colours(device, scale, spp):
    """Squares of valid colours overflow float32: the image stays the reference's at any
    scale, and the error image saturates at float32's largest value, never NaN or inf."""
    buf = frame(np.random.default_rng(21), h=12, w=13, s=spp)
    c = buf.color / buf.color.max()
    buf.color[:] = (c * scale).astype(np.float32)
    buf.color[:6] = (c[:6] * 1e-3 * scale).astype(np.float32)  # a dim half beside a bright one
    got = run(buf, method="sweep", device=device, estimate_error=True)
    img, err = _expected(buf, "sweep", device, sg.MODE_BLEND)
    assert np.isfinite(got.image).all() and np.isfinite(got.error).all()
    assert_close(got.image, img, rtol=1e-3, atol=1e-5 * scale, what="image")
    fmax = np.finfo(np.float32).max
    sat = err >= fmax
    # below float32's smallest subnormal an error is 0
    atol = max(min(1e-6 * scale ** 2, fmax), 6e-45)
    assert_close(got.error[~sat], err[~sat], rtol=2e-3, atol=atol, what="error")
    assert (got.error[sat] == fmax).all()


@pytest.mark.parametrize("method", ["sweep", "layered", "splat"])
def test_halves_mean_skips_the_run_on_the_frame(device, method):
    """Every method blends the mean of its halves' images (weights independent of the
    sample count): its passes run on the halves only, but for layered's statistics and
    partitions, which run once on the frame for both halves."""
    buf = frame(np.random.default_rng(3), h=12, w=15, s=4)
    got = run(buf, method=method, device=device)
    shared = set(METHODS[method].shared_steps)
    own = [k for k in got.pass_ms if not k.startswith("safeguard") and k not in shared]
    assert own and all(k.endswith("(halves)") for k in own) == METHODS[method].halves_mean
    assert shared <= set(got.pass_ms)
    assert not {f"{k} (halves)" for k in shared} & set(got.pass_ms)
    assert (got.method.get("safeguard_image") is not None) == METHODS[method].halves_mean
    # the error alone keeps the method's image of the frame
    alone = run(buf, method=method, device=device, safeguard=False, estimate_error=True)
    assert any(not k.endswith("(halves)") and not k.startswith("safeguard")
               for k in alone.pass_ms)


@pytest.mark.parametrize("spp, guided, t7, t3", [(4, 0, True, True), (8, 0, False, True),
                                                 (16, 0, False, True),
                                                 (5, 2, True, False), (8, 2, True, False),
                                                 (32, 2, True, True)])
def test_describe_names_the_bias_tests(device, spp, guided, t7, t3):
    """Which windows the blend tests (safeguard_passes.bias_tests) is in the plan's
    description: below 8 spp the 7x7 mean is tested (the guided chain's always, at a false
    discovery rate), and the guided chain keeps the 3x3 test only from 32 spp."""
    buf = frame(np.random.default_rng(spp), h=12, w=13, s=spp)
    got = run(buf, method="splat", device=device, guided=guided)
    at = f"FDR {sg.FDR_Q}" if guided else "2 se"  # the chain: its frame's z (safeguard_fdr)
    want = {f"7x7 at {at}": t7, "3x3 at 2 se": t3}
    # a method's own blend: whether the frame's q-value scales its 7x7 mean (from 8 spp:
    # safeguard_passes.shrinks_by_frame)
    want |= {} if guided else {"7x7 by the frame's q-value": spp >= 8}
    assert got.method["safeguard_bias_tests"] == want
