"""The hybrid (clrecon/methods/hybrid.py; its kernel against the NumPy reference:
tests/passes/test_hybrid_passes.py): the wiring of its two members and the blend, the knob's
contract, frames it was not built for, the numerical extremes, and one quality check against
a converged reference."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close, trusted_reference
from extremes import CASES, check_output, make_frame
from layered_frames import frame
from pipeline_run import read_buffer, run_plan

from clrecon.api import run
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods import hybrid
from clrecon.metrics import psnr
from clrecon.scenes.builtin import get_scene
from clrecon.scenes.render import render_samples

CHAIN = {"guided": 2, "nlm": 3}


@pytest.mark.parametrize("method", ["sweep", "layered", "splat"])
@pytest.mark.parametrize("spp", [8, 17])
def test_pipeline_blends_its_members(device, rng, method, spp):
    """The members' images are the chain's and box nlm's own (run alone on the frame), and
    the image and error are the reference blend of the members' images and estimates."""
    buf = frame(rng, h=22, w=27, s=spp)
    q = device.queue
    pipe, image = run_plan(device, buf, method, hybrid=True, **CHAIN)
    shape = (buf.height, buf.width)
    ia, ib = read_buffer(pipe, q, "ia", shape + (3,)), read_buffer(pipe, q, "ib", shape + (3,))
    ea = read_buffer(pipe.chain, q, "error", shape)
    eb = read_buffer(pipe.box, q, "error", shape)
    alone_a = run(buf, method=method, device=device, estimate_error=True, **CHAIN)
    alone_b = run(buf, method="box", device=device, nlm=3, estimate_error=True)
    assert_close(ia, alone_a.image, rtol=1e-5, atol=1e-6, what="chain member")
    assert_close(ea, alone_a.error, rtol=1e-5, atol=1e-9, what="chain member's error")
    assert_close(ib, alone_b.image, rtol=1e-5, atol=1e-6, what="box nlm member")
    assert_close(eb, alone_b.error, rtol=1e-5, atol=1e-9, what="box nlm member's error")
    want, werr, wa = hybrid.reference(ia, ea, ib, eb)
    assert_close(image, want, rtol=1e-5, atol=1e-6, what="image")
    assert_close(read_buffer(pipe, q, "error", shape), werr, rtol=1e-4, atol=1e-12,
                 what="error")
    assert np.abs(ia - ib).max() > 1e-3 and 0.0 < wa.mean() < 1.0  # two images, blended
    d = pipe.describe()
    assert d["method"] == method and d["hybrid"]["with"] == "box+nlm+safeguard"
    assert d["plan"].endswith("+hybrid") and d["estimate_error"] is True


@pytest.mark.parametrize("spp", [2, 5, 7])
def test_below_8_spp_the_chain_alone(device, rng, spp):
    """Halves of fewer than 4 samples: the chain's image and error estimate, bit for bit,
    and no box member."""
    buf = frame(rng, h=13, w=11, s=spp)
    got = run(buf, method="splat", device=device, hybrid=True, estimate_error=True, **CHAIN)
    alone = run(buf, method="splat", device=device, estimate_error=True, **CHAIN)
    assert np.array_equal(got.image, alone.image) and np.array_equal(got.error, alone.error)
    assert not any(k.startswith("box nlm") for k in got.pass_ms)
    assert got.method["hybrid"]["with"] is None and not hybrid.blends(spp)
    assert hybrid.blends(8) and hybrid.blends(9)


def test_a_frame_without_blur_runs_box_nlm_once(device, rng):
    """A chain planned as box is box's nlm already: no second member, the image is
    ``run(method="box", nlm=...)``'s."""
    still = frame(rng, h=12, w=12, s=8, motion=False, aperture=0.0)
    got = run(still, method="splat", device=device, hybrid=True, estimate_error=True, **CHAIN)
    want = run(still, method="box", device=device, nlm=3, estimate_error=True)
    assert np.array_equal(got.image, want.image) and np.array_equal(got.error, want.error)
    assert got.method["hybrid"]["with"] is None
    assert not any(k.startswith("box nlm") for k in got.pass_ms)


def test_run_returns_the_blend_and_its_error(device, rng):
    buf = frame(rng, h=14, w=15, s=8)
    a = run(buf, method="splat", device=device, hybrid=True, **CHAIN)
    b = run(buf, method="splat", device=device, hybrid=True, estimate_error=True, **CHAIN)
    assert np.array_equal(a.image, b.image)
    assert b.error.shape == (14, 15) and np.isfinite(b.error).all() and (b.error >= 0).all()
    assert any(k.startswith("box nlm: ") for k in b.pass_ms) and "hybrid_blend" in b.pass_ms


def test_knob_contract(device, rng):
    buf, one = frame(rng, h=12, w=12, s=4), frame(rng, h=12, w=12, s=1)
    for knobs, msg in (({"nlm": 3, "hybrid": True}, "hybrid: box's own chain"),
                       ({"hybrid": True}, "hybrid: needs nlm=R"),
                       ({"nlm": 3, "hybrid": True, "safeguard": False}, "safeguard=False"),
                       ({"nlm": 3, "hybrid": "yes"}, "hybrid")):
        with pytest.raises((ValueError, TypeError), match=msg):
            run(buf, method="box" if "box's" in msg else "splat", device=device, **knobs)
    with pytest.raises(ValueError, match="hybrid: needs >= 2 samples"):
        run(one, method="splat", device=device, nlm=3, hybrid=True)
    # off is the chain as it was, bit for bit
    assert np.array_equal(run(buf, method="splat", device=device, **CHAIN).image,
                          run(buf, method="splat", device=device, hybrid=False, **CHAIN).image)


def test_frames_it_was_not_built_for(device, rng):
    """Reused frame after frame: a frame of another shape is refused with the bound named;
    with grow=True both members re-plan (from 4 spp, the chain alone, to 8, blended) and
    the image is a fresh pipeline's."""
    a = frame(rng, h=16, w=18, s=4)
    b = frame(rng, h=21, w=23, s=8)
    pipe, _ = run_plan(device, a, "splat", hybrid=True, **CHAIN)
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, b.height * b.width * 12)
    with pytest.raises(ValueError, match="width"):
        pipe(device.queue, DeviceSamples.wrap(device.context, b, b.arrays().keys()), out)
    grown, _ = run_plan(device, a, "splat", hybrid=True, grow=True, **CHAIN)
    grown(device.queue, DeviceSamples.wrap(device.context, b, b.arrays().keys()), out)
    img = np.empty((b.height, b.width, 3), np.float32)
    cl.enqueue_copy(device.queue, img, out)
    assert grown.describe()["hybrid"]["with"] and grown.info.width == b.width
    assert_close(img, run(b, method="splat", device=device, hybrid=True, **CHAIN).image,
                 rtol=1e-5, atol=1e-6, what="grown image")


def test_negative_radiance_is_its_parts_difference(device):
    """The weights depend on the colours: a frame with negative colours runs once per part
    (run()'s rule for such pipelines) and gives f(c+) - f(c-)."""
    def make():  # the same frame each call (one seed)
        return frame(np.random.default_rng(7), h=12, w=13, s=8)

    signed, pos_part, neg_part = make(), make(), make()
    signed.color[::3] *= -0.5
    pos_part.color[...] = np.maximum(signed.color, 0)
    neg_part.color[...] = np.maximum(-signed.color, 0)
    got = run(signed, method="splat", device=device, allow_negative=True, hybrid=True,
              **CHAIN).image
    want = (run(pos_part, method="splat", device=device, hybrid=True, **CHAIN).image
            - run(neg_part, method="splat", device=device, hybrid=True, **CHAIN).image)
    assert_close(got, want, rtol=1e-5, atol=1e-5, what="f(c+) - f(c-)")


def test_gains_where_every_method_stays_near_box(device):
    """Against the converged reference (never from the device under test): on
    `fast_motion` at 64 spp, where the splat chain is held near box by its bias, the hybrid
    takes box nlm's image there (at 256x256 and seed 164: 41.63 -> 44.17 dB)."""
    scene = get_scene("fast_motion")
    w = h = 256
    ref = trusted_reference(scene, w, h, 1024)
    buf = render_samples(scene, w, h, 64, seed=164, device=device)
    chain = psnr(run(buf, method="splat", device=device, nlm_scales=4, **CHAIN).image, ref)
    both = psnr(run(buf, method="splat", device=device, nlm_scales=4, hybrid=True,
                    **CHAIN).image, ref)
    assert both > chain + 1.0, (chain, both)


@pytest.mark.parametrize("flat", [False, True], ids=["textured", "flat"])
@pytest.mark.parametrize("case", [c for c in CASES if c.shape[2] >= 2],
                         ids=[c.name for c in CASES if c.shape[2] >= 2])
def test_extremes(device, case, flat):
    """The methods' numerical extremes (tests/support/extremes.py) through the hybrid:
    finite, non-negative (a convex combination of two such images), a flat field's mean
    kept; its error estimate finite and non-negative."""
    buf = make_frame(case, flat)
    res = run(buf, method="splat", device=device, hybrid=True, estimate_error=True, **CHAIN)
    check_output(res.image, buf, flat, f"splat hybrid/{case.name}")
    assert np.isfinite(res.error).all() and (res.error >= 0).all(), case.name
