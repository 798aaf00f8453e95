"""Method ``splat``'s mip plan (``mip_radius``): the kernels against the NumPy reference
(:mod:`clrecon.methods.splat.mip_reference`), both scatters, reproducibility, the analytic PSF sums,
and the knob's validation."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close
from splat_frames import frame

import clrecon
from clrecon.api import make_pipeline
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods.splat import mip
from clrecon.methods.splat import mip_reference as mref
from clrecon.methods.splat import reference as ref
from clrecon.methods.splat.mip import MAX_LEVELS, MipGeometry


def run_mip(device, buf, **knobs):
    """The pipeline, its output and its level-0 image (what the composite reads)."""
    pipe = make_pipeline("splat", device.context, buf.inspect(), safeguard=False, **knobs)
    assert pipe.describe()["plan"] == "mip"
    s = DeviceSamples.upload(device.queue, buf, pipe.fields)
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, buf.width * buf.height * 12)
    pipe(device.queue, s, out).wait()
    g = pipe.geometry
    _, nw, nh, _ = g.levels[0]
    lev0 = np.empty(g.layers * nh * nw * 4, np.float32)
    img = np.empty((buf.height, buf.width, 3), np.float32)
    cl.enqueue_copy(device.queue, lev0, pipe.buffers["mip_image"])
    cl.enqueue_copy(device.queue, img, out)
    device.queue.finish()
    return pipe, img, lev0.reshape(g.layers, nh, nw, 4)


def reference(pipe, buf):
    from clrecon.methods.splat.layers import layer_params

    inv_far, scale = layer_params(buf.inspect(), pipe.layers)
    has_motion = pipe.has_motion and pipe.psf == "combined"
    lev0 = mref.level0(buf, pipe.geometry, inv_far, scale, has_motion)
    img = ref.composite(np.zeros_like(lev0), lev0, pipe.geometry.pad, buf.height, buf.width,
                        color=buf.color)
    return lev0, img


@pytest.mark.parametrize("knobs,motion,aperture", [
    (dict(mip_radius=2.0), False, 8.0),
    (dict(mip_radius=4.0, layers=2), True, 12.0),
    (dict(mip_radius=3.0, layers=3, scatter="atomic"), True, 20.0),
    (dict(mip_radius=8.0, psf="simplelens"), True, 6.0),
], ids=["static-r2", "motion-r4", "atomic-r3", "simplelens-ignores-motion"])
@pytest.mark.parametrize("lanes", [1, 8])
def test_mip_matches_reference(device, rng, knobs, motion, aperture, lanes, monkeypatch):
    """The level-0 image and the output against the reference; the owner tiles' records 1
    or 8 samples a step (rows of 17 px x 3 spp: six 8-sample steps and a scalar tail)."""
    monkeypatch.setattr(mip, "bin_lanes", lambda context: lanes)
    buf = frame(rng, h=14, w=17, s=3, motion=motion, aperture=aperture)
    pipe, got, lev0 = run_mip(device, buf, **knobs)
    if knobs.get("scatter") != "atomic":
        assert pipe.mip.bin_lanes == lanes
    assert pipe.geometry.nlev >= 2 or knobs["mip_radius"] >= 8.0
    want_lev0, want = reference(pipe, buf)
    # the frame region of level 0 (what the composite reads; the upsampling fills no more)
    p = pipe.geometry.pad
    region = np.s_[:, p:p + buf.height, p:p + buf.width]
    scale = float(np.abs(want_lev0).max())
    assert_close(lev0[region], want_lev0[region], rtol=1e-3, atol=1e-4 * scale,
                 what=f"level 0 {knobs}")
    assert_close(got, want, rtol=2e-3, atol=2e-3 * float(want.max()), what=f"image {knobs}")


def test_tiles_and_atomics_agree_and_tiles_repeat(device, rng):
    buf = frame(rng, h=20, w=23, s=4, motion=True, aperture=16.0)
    a = clrecon.reconstruct(buf, "splat", device, mip_radius=4.0, scatter="tiles",
                            safeguard=False)
    b = clrecon.reconstruct(buf, "splat", device, mip_radius=4.0, scatter="tiles",
                            safeguard=False)
    c = clrecon.reconstruct(buf, "splat", device, mip_radius=4.0, scatter="atomic",
                            safeguard=False)
    assert np.array_equal(a, b), "owner tiles add in a fixed order: bit-identical"
    assert_close(c, a, rtol=1e-3, atol=1e-4 * float(a.max()), what="atomic vs tiles")


def test_deterministic_takes_the_owner_tiles(device, rng):
    buf = frame(rng, h=10, w=12, s=2, motion=True)
    res = clrecon.run(buf, "splat", device, mip_radius=4.0, scatter="atomic",
                      deterministic=True, safeguard=False)
    assert res.method["scatter"] == "tiles" and res.method["deterministic"] is True


def test_energy_is_kept(device, rng):
    """Every sample lands in one bin and every bin's PSF sums to one: level 0's coverage
    sums to the samples' weight (1 per pixel), to the analytic sums' ~1%."""
    buf = frame(rng, h=24, w=26, s=4, motion=True, aperture=24.0, misses=False)
    pipe, _, _ = run_mip(device, buf, mip_radius=4.0, layers=2)
    from clrecon.methods.splat.layers import layer_params

    # bin and draw again (the run left the bins consumed, i.e. zero) and sum every level's
    # coverage before the upsampling, which fills only the frame region
    img = np.empty(pipe.geometry.pixels * 4, np.float32)
    cl.enqueue_fill_buffer(device.queue, pipe.buffers["mip_image"], np.float32(0), 0,
                           pipe.geometry.image_bytes)
    inv_far, scale = layer_params(buf.inspect(), pipe.layers)
    s = DeviceSamples.upload(device.queue, buf, pipe.fields)
    flags = pipe.buffers.get("mip_flags")  # the owner tiles' (consumed by the draw as well)
    pipe.mip.bin(device.queue, s, inv_far, scale, pipe.buffers["mip_bins"], flags=flags)
    pipe.mip.draw(device.queue, pipe.buffers["mip_bins"], pipe.buffers["mip_image"],
                  flags=flags)
    cl.enqueue_copy(device.queue, img, pipe.buffers["mip_image"])
    device.queue.finish()
    total = float(img.reshape(-1, 4)[:, 3].sum())
    assert abs(total / (buf.width * buf.height) - 1.0) < 0.02, total


@pytest.mark.parametrize("rho", [3.0, 4.0, 5.5, 8.0])
@pytest.mark.parametrize("length", [0.0, 1.0, 6.0, 30.0])
def test_analytic_psf_sum_matches_the_pixel_sum(rho, length):
    """The kernel normalises a disc from rho = 3 and a swept disc from rho = 4 by the plane
    integral of its PSF; the pixel sum agrees to 1.5% at any centre and direction."""
    if length >= 0.5 and rho < 4.0:
        pytest.skip("summed over the pixels below rho = 4")
    rng = np.random.default_rng(7)
    for _ in range(8):
        c = rng.random(2)
        a = rng.uniform(0, 2 * np.pi)
        u = (np.cos(a), np.sin(a))
        n = int(rho + length / 2 + 3)
        g = np.arange(-n, n + 1) + 0.5
        gx, gy = np.meshgrid(g - c[0], g - c[1])
        s = mref.psf(gx, gy, rho, length, u).sum()
        tot = np.pi * (rho**2 + 1 / 12) if length < 0.5 else 2 * length * np.pi * (rho**2 + 1 / 16)
        assert abs(s / tot - 1.0) < 0.015, (rho, length, s / tot)


def test_levels_cover_the_blur():
    g = MipGeometry(640, 360, 4, 8.0, max_coc=60.0, max_motion=300.0)
    # radii 8, 11.3, 16, 22.6 level pixels: CoC 60 fits level 2 (16 * 4 = 64), motion 300
    # level 3 (4 * 22.6 * 8 = 724; level 2 holds 256)
    assert g.nlev == 4 and not g.clamped
    assert_close(g.rl, [8.0, 8.0 * 2**0.5, 16.0, 8.0 * 2**1.5], rtol=1e-6, what="radii")
    pads = g.levels[:, 3]
    assert pads[0] == 2 * (8 + 16 + 2) and np.all(np.diff(pads) > 0)
    assert g.levels[1, 1] == 320 + 2 * pads[1] and g.levels[3, 2] == 45 + 2 * pads[3]
    huge = MipGeometry(64, 64, 1, 1.0, max_coc=1e12, max_motion=0.0)
    assert huge.nlev == MAX_LEVELS and huge.clamped


@pytest.mark.parametrize("knobs,match", [
    (dict(mip_radius=0.5), "mip_radius"),
    (dict(mip_radius=float("nan")), "mip_radius"),
    (dict(mip_radius=4.0, psf="stylized"), "stylized"),
    (dict(mip_radius=4.0, dense=True), "dense"),
])
def test_bad_knobs_are_refused(device, rng, knobs, match):
    buf = frame(rng, h=6, w=7, s=2)
    with pytest.raises(ValueError, match=match):
        clrecon.reconstruct(buf, "splat", device, safeguard=False, **knobs)


def test_no_holes_at_one_sample(device, rng):
    buf = frame(rng, h=16, w=18, s=1, motion=True, aperture=10.0, misses=False)
    got = clrecon.reconstruct(buf, "splat", device, mip_radius=4.0, safeguard=False)
    box = clrecon.reconstruct(buf, "box", device)
    assert not np.any((box.max(-1) > 0) & (got.max(-1) <= 0))


def test_bins_are_cleared_unless_known_clean(device, rng):
    """The draw pass zeroes the bins it consumes, so the pipeline's own bins skip their
    clear on the next frame; bins an embedder passes are cleared (here: filled with junk)."""
    buf = frame(rng, h=12, w=15, s=2, motion=True, aperture=12.0)
    pipe, first, _ = run_mip(device, buf, mip_radius=4.0)
    s = DeviceSamples.upload(device.queue, buf, pipe.fields)
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, buf.width * buf.height * 12)
    img = np.empty_like(first)
    pipe(device.queue, s, out).wait()  # own bins, already clean: no clear
    cl.enqueue_copy(device.queue, img, out)
    assert np.array_equal(img, first)
    size = pipe.plan.temporaries["mip_bins"]
    junk = cl.Buffer(device.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR,
                     hostbuf=np.full(size // 4, 7.0, np.float32))
    pipe(device.queue, s, out, temporaries={"mip_bins": junk}).wait()
    cl.enqueue_copy(device.queue, img, out)
    device.queue.finish()
    assert np.array_equal(img, first)
    if "mip_flags" in pipe.plan.temporaries:  # the owner tiles' flags: junk is cleared too
        n = pipe.plan.temporaries["mip_flags"]
        flags = cl.Buffer(device.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR,
                          hostbuf=np.ones(n, np.uint8))
        pipe(device.queue, s, out, temporaries={"mip_flags": flags}).wait()
        cl.enqueue_copy(device.queue, img, out)
        back = np.empty(n, np.uint8)
        cl.enqueue_copy(device.queue, back, flags)
        device.queue.finish()
        assert np.array_equal(img, first) and not back.any(), "the draw consumes every flag"
        pipe(device.queue, s, out).wait()  # own buffers again
        cl.enqueue_copy(device.queue, img, out)
        device.queue.finish()
        assert np.array_equal(img, first)


def test_composite_runs_as_a_step_of_its_own(device, rng):
    """A selection of steps binds only the temporaries its steps name: the composite alone,
    after a whole run, gets the ring it takes as an argument and gives the same image."""
    buf = frame(rng, h=12, w=15, s=4, motion=True, aperture=10.0)
    pipe, first, _ = run_mip(device, buf, mip_radius=4.0)
    s = DeviceSamples.upload(device.queue, buf, pipe.fields)
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, buf.width * buf.height * 12)
    pipe(device.queue, s, out, steps=("splat_composite",)).wait()
    img = np.empty_like(first)
    cl.enqueue_copy(device.queue, img, out)
    device.queue.finish()
    assert np.array_equal(img, first)
