"""Dual-buffer non-local means in the pipeline (clrecon/methods/nlm.py; its kernels against
the NumPy reference: tests/passes/test_nlm_passes.py): the wiring after the method's halves
(or the guided refinement), the knob's contract, and one quality check against a converged
reference."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close, trusted_reference
from extremes import CASES, check_output, make_frame
from layered_frames import frame
from pipeline_run import check_off_and_still, check_refusals, read_buffer, run_plan

from clrecon.api import run
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods import nlm
from clrecon.methods import safeguard as sg
from clrecon.methods.safeguard import reference_of_halves
from clrecon.methods.safeguard_passes import bias_tests, models_covariance, shrinks_by_frame
from clrecon.methods.safeguard_reference import variance_scale
from clrecon.metrics import psnr
from clrecon.scenes.builtin import get_scene
from clrecon.scenes.render import render_samples


@pytest.mark.parametrize("method", ["layered", "sweep", "splat"])
@pytest.mark.parametrize("safeguard", [False, True])
@pytest.mark.parametrize("guided", [0, 2])
@pytest.mark.parametrize("spp, scales", [(5, 1), (16, 1), (5, 3)])
def test_pipeline_filters_the_halves(device, rng, method, safeguard, guided, spp, scales):
    """The filtered halves are the reference's filter of the halves' images the pipeline
    had before it (the method's, or the guided chain's); the image is their mean without
    the safeguard and the safeguard's blend with it."""
    buf = frame(rng, h=22, w=27, s=spp)
    q = device.queue
    pipe, image = run_plan(device, buf, method, guided=guided, nlm=3, nlm_scales=scales,
                           safeguard=safeguard)
    shape = (buf.height, buf.width, 3)
    ia, ib = ("ba", "bb") if guided else ("ma", "mb")
    ua, ub = read_buffer(pipe, q, ia, shape), read_buffer(pipe, q, ib, shape)
    ra, rb = nlm.multiscale(*nlm.reference(ua, ub, buf.spp, 3), buf.spp, 3, scales)
    tol = 1e-4 * max(1.0, float(np.abs(ra).max()))
    assert_close(read_buffer(pipe, q, "na", shape), ra, rtol=1e-4, atol=tol, what="filtered A")
    assert_close(read_buffer(pipe, q, "nb", shape), rb, rtol=1e-4, atol=tol, what="filtered B")
    assert np.abs(ra - ua).max() > 1e-3  # it does something on this frame
    assert np.isfinite(image).all()
    ha = buf.spp // 2
    if not safeguard:
        mean = (ha * ra + (buf.spp - ha) * rb) / buf.spp
        assert_close(image, mean, rtol=1e-4, atol=tol, what="image = filtered halves' mean")
    else:
        c = buf.color.astype(np.float64)
        tests = bias_tests(bool(guided), buf.spp)
        want, _, _ = reference_of_halves(c[:, :, :ha].mean(2), c[:, :, ha:].mean(2), ha,
                                         buf.spp - ha, None, ra, rb, sg.MODE_BLEND,
                                         sg.GUIDED_Z7 if tests[0] else 0.0, variance_scale(c),
                                         tests[1], models_covariance(buf.spp),
                                         sg.FDR_Q if guided else None,
                                         shrinks_by_frame(bool(guided), buf.spp))
        assert_close(image, want, rtol=1e-4, atol=tol, what="image = the safeguard's blend")
    d = pipe.describe()
    assert d["nlm"] == 3 and d["nlm_scales"] == scales and "nlm" in d["plan"]
    assert d["safeguard"] is safeguard


@pytest.mark.parametrize("safeguard", [False, True])
@pytest.mark.parametrize("spp, scales", [(5, 1), (16, 1), (5, 3)])
def test_box_filters_its_own_halves(device, rng, safeguard, spp, scales):
    """With box the filter takes box's own halves, the samples' means of each half (the
    NumPy means of the frame's samples, never the device's): the image is the reference's
    filtered halves' mean, or the safeguard's blend of it toward box (on by default)."""
    buf = frame(rng, h=22, w=27, s=spp)
    q = device.queue
    pipe, image = run_plan(device, buf, "box", nlm=3, nlm_scales=scales,
                           **({} if safeguard else {"safeguard": False}))
    shape = (buf.height, buf.width, 3)
    c = buf.color.astype(np.float64)
    ha = buf.spp // 2
    ua, ub = c[:, :, :ha].mean(2), c[:, :, ha:].mean(2)
    assert_close(read_buffer(pipe, q, "ma", shape), ua, rtol=1e-5, atol=1e-6, what="half A")
    assert_close(read_buffer(pipe, q, "mb", shape), ub, rtol=1e-5, atol=1e-6, what="half B")
    ra, rb = nlm.multiscale(*nlm.reference(ua, ub, buf.spp, 3), buf.spp, 3, scales)
    tol = 1e-4 * max(1.0, float(np.abs(ra).max()))
    assert_close(read_buffer(pipe, q, "na", shape), ra, rtol=1e-4, atol=tol, what="filtered A")
    assert np.abs(ra - ua).max() > 1e-3  # it does something on this frame
    if not safeguard:
        mean = (ha * ra + (buf.spp - ha) * rb) / buf.spp
        assert_close(image, mean, rtol=1e-4, atol=tol, what="image = filtered halves' mean")
    else:
        t7, t3 = bias_tests(False, buf.spp)
        want, _, w = reference_of_halves(ua, ub, ha, buf.spp - ha, None, ra, rb, sg.MODE_BLEND,
                                         sg.GUIDED_Z7 if t7 else 0.0, variance_scale(c), t3,
                                         models_covariance(buf.spp), None,
                                         shrinks_by_frame(False, buf.spp))
        assert_close(image, want, rtol=1e-4, atol=tol, what="image = the safeguard's blend")
        assert 0.0 < w.mean() < 1.0  # a blend, not one of its ends
    d = pipe.describe()
    assert d["method"] == "box" and d["nlm"] == 3 and d["safeguard"] is safeguard
    assert d["plan"] == "box+nlm+" + ("safeguard" if safeguard else "error")


def test_box_filter_gains_on_motion_at_64_spp(device):
    """Against the converged reference: on `fast_motion` at 64 spp, where every method's
    default stays within a few tenths of a dB of box, box's own halves filtered gain over
    box: 42.51 -> 44.42 dB at 256x256 (at 512x512 43.55 -> 47.01; at 128x128, whose
    minified textures leave the 3x3 patches few matches, +0.05: the blend keeps box)."""
    scene = get_scene("fast_motion")
    w = h = 256
    ref = trusted_reference(scene, w, h, 1024)
    buf = render_samples(scene, w, h, 64, seed=164, device=device)
    box = psnr(buf.color.mean(2).astype(np.float32), ref)
    filtered = psnr(run(buf, method="box", device=device, nlm=3).image, ref)
    assert filtered > box + 1.0, (box, filtered)


def test_knob_contract(device, rng):
    buf, one = frame(rng, h=12, w=12, s=4), frame(rng, h=12, w=12, s=1)
    check_refusals(device, buf, one, "splat", "nlm", 2, (-1, 11, 2.5, True, "2"),
                   "nlm: the search radius", box_refused=False, safeguard=False)
    with pytest.raises(ValueError, match="nlm: needs >= 2 samples"):
        run(one, method="box", device=device, nlm=2)
    with pytest.raises(ValueError, match="safeguard: box is the unbiased"):
        run(buf, method="box", device=device, safeguard=True)
    with pytest.raises(ValueError, match="nlm_scales: 3 scales of the non-local means need"):
        run(buf, method="splat", device=device, nlm_scales=3)
    for bad in (0, 7):
        with pytest.raises(ValueError, match="nlm_scales"):
            run(buf, method="splat", device=device, nlm=2, nlm_scales=bad)
    # off is the method as it was; a frame without blur is planned as box, whose halves
    # the filter then takes: box's nlm image
    check_off_and_still(device, rng, buf, "splat", "nlm", 2, box_takes=True, guided=2)


def test_filter_gains_on_a_builtin_scene(device):
    """Against the converged reference (never from the device under test): on `huge_coc` at
    4 spp, whose far wall keeps a fine grain in every method's image (a checker finer than
    its blur), the guided chain with the filter is more accurate than without (at 256x256:
    36.8 -> 38.3 dB; here at 128x128)."""
    scene = get_scene("huge_coc")
    w = h = 128
    ref = trusted_reference(scene, w, h, 1024)
    buf = render_samples(scene, w, h, 4, seed=104, device=device)
    without = psnr(run(buf, method="splat", device=device, guided=2).image, ref)
    with_nlm = psnr(run(buf, method="splat", device=device, guided=2, nlm=5).image, ref)
    assert with_nlm > without + 0.5, (without, with_nlm)


def test_frames_it_was_not_built_for(device, rng):
    """Reused frame after frame: a frame of another shape is refused with the bound named;
    with grow=True the pipeline re-plans, filter included, and gives the image a pipeline
    made for that frame gives."""
    a = frame(rng, h=16, w=18, s=4)
    b = frame(rng, h=21, w=23, s=6)
    pipe, _ = run_plan(device, a, "splat", nlm=2)
    with pytest.raises(ValueError, match="width"):
        pipe(device.queue, DeviceSamples.wrap(device.context, b, b.arrays().keys()),
             cl.Buffer(device.context, cl.mem_flags.READ_WRITE, b.height * b.width * 12))
    grown, _ = run_plan(device, a, "splat", nlm=2, grow=True)
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, b.height * b.width * 12)
    grown(device.queue, DeviceSamples.wrap(device.context, b, b.arrays().keys()), out)
    img = np.empty((b.height, b.width, 3), np.float32)
    cl.enqueue_copy(device.queue, img, out)
    assert grown.describe()["nlm"] == 2
    assert_close(img, run(b, method="splat", device=device, nlm=2).image, rtol=1e-5,
                 atol=1e-6, what="grown image")


@pytest.mark.parametrize("flat", [False, True], ids=["textured", "flat"])
@pytest.mark.parametrize("case", [c for c in CASES if c.shape[2] >= 2],
                         ids=[c.name for c in CASES if c.shape[2] >= 2])
def test_extremes(device, case, flat):
    """The numerical extremes of the methods' suite (tests/support/extremes.py) through the
    filter, alone and after the guided refinement, with and without the safeguard: finite,
    non-negative (the filter's weights make a convex combination), a flat field's mean
    kept."""
    buf = make_frame(case, flat)
    for knobs in ({"nlm": 3, "safeguard": False}, {"nlm": 3}, {"guided": 2, "nlm": 3},
                  {"guided": 2, "nlm": 3, "nlm_scales": 4, "safeguard": False}):
        img = run(buf, method="splat", device=device, **knobs).image
        check_output(img, buf, flat, f"splat {knobs}/{case.name}")
