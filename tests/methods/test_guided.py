"""The guided refinement in the pipeline (clrecon/methods/guided.py; its kernels against the
NumPy reference: tests/passes/test_guided_passes.py): the wiring into the safeguard's halves,
the knob's contract, and one quality check against a converged reference."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close, trusted_reference
from layered_frames import frame
from pipeline_run import check_off_and_still, check_refusals, read_buffer, run_plan

from clrecon.api import make_pipeline, run
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods import guided as gd
from clrecon.methods import safeguard as sg
from clrecon.methods.safeguard import reference_of_halves
from clrecon.methods.safeguard_passes import bias_tests, models_covariance
from clrecon.methods.safeguard_reference import variance_scale
from clrecon.metrics import psnr
from clrecon.scenes.builtin import get_scene
from clrecon.scenes.render import render_samples


@pytest.mark.parametrize("method", ["layered", "sweep", "splat"])
@pytest.mark.parametrize("safeguard", [False, True])
@pytest.mark.parametrize("guide_blend", [False, True])
@pytest.mark.parametrize("spp", [5, 16])
def test_pipeline_refines_the_halves(device, rng, method, safeguard, guide_blend, spp):
    """In the pipeline the refined halves are the reference's refinement of the method's own
    halves' images (then blended toward them: guide_blend); without the safeguard the image
    is the halves' mean (from 16 spp the safeguard's variances scaled by the quarters)."""
    buf = frame(rng, h=24, w=26, s=spp)
    q = device.queue
    pipe, image = run_plan(device, buf, method, guided=2, safeguard=safeguard,
                           guide_blend=guide_blend)
    shape = (buf.height, buf.width, 3)
    ma, mb = read_buffer(pipe, q, "ma", shape), read_buffer(pipe, q, "mb", shape)
    qa, qb = read_buffer(pipe, q, "qa", shape), read_buffer(pipe, q, "qb", shape)
    ra, rb = gd.reference(buf.color, ma, mb, 2)
    tol = 1e-4 * max(1.0, float(np.abs(ra).max()))
    assert_close(qa, ra, rtol=1e-4, atol=tol, what="refined half A")
    assert_close(qb, rb, rtol=1e-4, atol=tol, what="refined half B")
    if guide_blend:
        ra, rb = gd.chain_reference(buf.color, ma, mb, 2)
        ba, bb = read_buffer(pipe, q, "ba", shape), read_buffer(pipe, q, "bb", shape)
        assert_close(ba, ra, rtol=1e-4, atol=tol, what="blended half A")
        assert_close(bb, rb, rtol=1e-4, atol=tol, what="blended half B")
        # the blend does something on this frame: some pixels keep the method's image more
        assert np.abs(ba - qa).max() > 1e-3
    assert np.isfinite(image).all()
    ha = buf.spp // 2
    if not safeguard:
        mean = (ha * ra + (buf.spp - ha) * rb) / buf.spp
        assert_close(image, mean, rtol=1e-4, atol=tol, what="image = refined halves' mean")
    else:  # the safeguard's blend toward box, its 7x7 bias mean tested at the frame's z
        c = buf.color.astype(np.float64)
        want, _, _ = reference_of_halves(c[:, :, :ha].mean(2), c[:, :, ha:].mean(2), ha,
                                         buf.spp - ha, None, ra, rb, sg.MODE_BLEND,
                                         sg.GUIDED_Z7, variance_scale(c),
                                         bias_tests(True, buf.spp)[1],
                                         models_covariance(buf.spp), sg.FDR_Q)
        assert_close(image, want, rtol=1e-4, atol=tol, what="image = the safeguard's blend")
    d = pipe.describe()
    assert d["guided"] == 2 and d["safeguard"] is safeguard
    assert d["guide_blend"] is guide_blend


def test_knob_contract(device, rng):
    buf, one = frame(rng, h=12, w=12, s=4), frame(rng, h=12, w=12, s=1)
    check_refusals(device, buf, one, "layered", "guided", 2, (-1, 9, 2.5, True, "2"),
                   "guided: the window radius")
    with pytest.raises(ValueError, match="guide_blend"):
        run(buf, method="layered", device=device, guided=2, guide_blend="yes")
    # off is the method as it was; a frame without blur: nothing to refine, box's image
    check_off_and_still(device, rng, buf, "layered", "guided", 2)


@pytest.mark.parametrize("method, knobs", [("layered", {"guide_blend": False}),
                                           ("splat", {})])
def test_refinement_beats_its_guide_on_a_builtin_scene(device, method, knobs):
    """Against the converged reference (never from the device under test): the guided
    image of a paper's method is more accurate than that method's image, and than box, on
    `fence` at 8 spp (at 128x128: +1.6 dB for layered, +1.4 for splat; at 512x512 +7.6 and
    +7.8)."""
    scene = get_scene("fence")
    w = h = 128
    ref = trusted_reference(scene, w, h, 1024)
    buf = render_samples(scene, w, h, 8, seed=108, device=device)
    box = psnr(buf.color.mean(2), ref)
    paper = psnr(run(buf, method=method, device=device, safeguard=False).image, ref)
    guided = psnr(run(buf, method=method, device=device, safeguard=False, guided=2,
                      **knobs).image, ref)
    assert guided > paper + 1.0, (box, paper, guided)
    assert guided > box + 3.0, (box, paper, guided)


def test_frames_it_was_not_built_for(device, rng):
    """Reused frame after frame: a frame of another shape is refused with the bound named;
    a pipeline made with grow=True re-plans, refinement included, and gives the image a
    pipeline made for that frame gives."""
    a = frame(rng, h=16, w=18, s=4)
    b = frame(rng, h=20, w=23, s=6)
    ctx, q = device.context, device.queue
    pipe = make_pipeline("splat", ctx, DeviceSamples.wrap(ctx, a, a.arrays().keys())
                         .inspect(q), guided=2)
    dsb = DeviceSamples.wrap(ctx, b, b.arrays().keys())
    out = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, b.height * b.width * 12)
    with pytest.raises(ValueError, match="width"):
        pipe(q, dsb, out)
    grown = make_pipeline("splat", ctx, DeviceSamples.wrap(ctx, a, a.arrays().keys())
                          .inspect(q), guided=2, grow=True)
    grown(q, dsb, out)
    img = np.empty((b.height, b.width, 3), np.float32)
    cl.enqueue_copy(q, img, out)
    assert grown.describe()["guided"] == 2
    want = run(b, method="splat", device=device, guided=2).image
    assert_close(img, want, rtol=1e-5, atol=1e-6, what="grown image")
