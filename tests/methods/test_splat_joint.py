"""The safeguard's joint halves for splat's mip plan: the bin, draw and upsample passes of both
halves in one pass over the frame (one PSF per bin from the frame's samples, each half's
colour into its own image), against the NumPy reference; the plan around them; the joint bins'
clearing; the fall-back where they do not fit."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close
from splat_frames import frame

from clrecon.core import pipeline as pipeline_module
from clrecon.core.errors import DeviceMemoryError
from clrecon.core.pipeline import DeviceSamples
from clrecon.methods import safeguard as sg
from clrecon.methods.splat import mip
from clrecon.methods.splat import mip_reference as mref
from clrecon.methods.splat import reference as ref
from clrecon.methods.splat.layers import layer_params
from clrecon.methods.splat.mip import MipSplat


def _run(device, pipe, buf, temporaries=None):
    """Run ``pipe`` on ``buf``: its image and the halves' images (ma, mb)."""
    s = DeviceSamples.upload(device.queue, buf, info=buf.inspect())
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, buf.height * buf.width * 12)
    pipe(device.queue, s, out, temporaries=temporaries).wait()
    imgs = [np.empty((buf.height, buf.width, 3), np.float32) for _ in range(3)]
    for img, b in zip(imgs, (out, pipe.buffer("ma"), pipe.buffer("mb"))):
        cl.enqueue_copy(device.queue, img, b)
    device.queue.finish()
    return imgs


def _level0(device, pipe, buffer) -> np.ndarray:
    g = pipe.full.geometry
    _, nw, nh, _ = g.levels[0]
    lev = np.empty(g.layers * nh * nw * 4, np.float32)
    cl.enqueue_copy(device.queue, lev, buffer)
    device.queue.finish()
    return lev.reshape(g.layers, nh, nw, 4)


@pytest.mark.parametrize("knobs,lanes", [
    (dict(mip_radius=2.0), 8),
    (dict(mip_radius=3.0, layers=2), 1),
    (dict(mip_radius=3.0, layers=3, scatter="atomic"), 1),
], ids=["tiles-lanes8", "tiles-scalar", "atomic"])
@pytest.mark.parametrize("spp", [3, 4, 5])
def test_joint_levels_match_the_reference(device, rng, knobs, lanes, spp, monkeypatch):
    """Both halves' level 0 (after the upsampling) against the reference's joint bins and
    draw, and each half's image against the reference composite of its level 0 and its own
    samples; 3 and 5 spp: halves of unequal counts (1 + 2, 2 + 3)."""
    monkeypatch.setattr(mip, "bin_lanes", lambda context: lanes)
    buf = frame(rng, h=14, w=17, s=spp, motion=True, aperture=14.0)
    info = buf.inspect()
    pipe = sg.Safeguarded(device.context, info, "splat", knobs)
    full = pipe.full
    assert full.describe()["plan"] == "mip" and full.geometry.nlev >= 2
    assert pipe.joint == full.joint_steps and "upsample" in pipe.joint
    _, ma, mb = _run(device, pipe, buf)
    ha, _ = sg.halves(spp)
    inv_far, scale = layer_params(info, full.layers)
    has_motion = full.has_motion and full.psf == "combined"
    want = mref.level0(buf, full.geometry, inv_far, scale, has_motion, joint_ha=ha)
    got = (_level0(device, pipe, full.buffer("mip_image")),
           _level0(device, pipe, pipe.buffer("mip_image_b")))
    p = full.geometry.pad
    region = np.s_[:, p:p + buf.height, p:p + buf.width]
    for name, g, w, m, cols in (("A", got[0], want[0], ma, buf.color[:, :, :ha]),
                                ("B", got[1], want[1], mb, buf.color[:, :, ha:])):
        peak = float(np.abs(w).max())
        assert peak > 0
        assert_close(g[region], w[region], rtol=1e-3, atol=1e-4 * peak,
                     what=f"half {name}'s level 0 {knobs} {spp} spp")
        img = ref.composite(np.zeros_like(w), w, p, buf.height, buf.width, color=cols)
        assert_close(m, img, rtol=2e-3, atol=2e-3 * float(img.max()),
                     what=f"half {name}'s image {knobs} {spp} spp")


def test_joint_weights_each_half_by_its_own_count(device, rng):
    """Half A's and half B's coverage at level 0 each sum to one per pixel (the frame's
    weight 1 / S rescaled to each half's count), to the analytic PSF sums' ~2%."""
    buf = frame(rng, h=24, w=26, s=5, motion=True, aperture=24.0, misses=False)
    pipe = sg.Safeguarded(device.context, buf.inspect(), "splat", {"mip_radius": 4.0})
    _run(device, pipe, buf)
    # the joint passes again without the upsampling (which fills only the frame region)
    full, q = pipe.full, device.queue
    s = DeviceSamples.upload(q, buf, info=buf.inspect())
    j = full._joint[2]
    imgs = [full.buffer("mip_image"), pipe.buffer("mip_image_b")]
    for b in imgs:
        cl.enqueue_fill_buffer(q, b, np.float32(0), 0, full.geometry.image_bytes)
    bins, flags = pipe.buffer("joint.bins"), pipe.buffers.get("joint.flags")
    inv_far, scale = layer_params(buf.inspect(), full.layers)
    j.bin(q, s, inv_far, scale, bins, flags=flags)
    j.draw(q, bins, imgs[0], flags=flags, img_b=imgs[1])
    for b in imgs:
        img = np.empty(full.geometry.pixels * 4, np.float32)
        cl.enqueue_copy(q, img, b)
        q.finish()
        total = float(img.reshape(-1, 4)[:, 3].sum())
        assert abs(total / (buf.width * buf.height) - 1.0) < 0.02, total


def test_joint_plan_and_describe(device, rng):
    buf = frame(rng, h=12, w=15, s=4, motion=True, aperture=10.0)
    info = buf.inspect()
    joint = sg.Safeguarded(device.context, info, "splat", {"mip_radius": 4.0})
    apart = sg.Safeguarded(device.context, info, "splat", {"mip_radius": 4.0}, joint=False)
    assert apart.joint == () and "mip_image_b" not in apart.plan.temporaries
    assert joint.joint_out == ("mip_image",)
    assert set(joint.plan.temporaries) >= {"mip_image_b", "joint.bins"}
    assert joint.plan.temporaries["joint.bins"] == joint.full.geometry.joint_bin_bytes
    assert joint.describe()["safeguard_joint"] == list(joint.joint)
    names = [st.name for st in joint.plan.steps]
    assert f"splat ({', '.join(joint.joint)}, both halves)" in names
    # the halves' PSFs differ (the frame's against their own), their colours do not: close
    img, _, _ = _run(device, joint, buf)
    other, _, _ = _run(device, apart, buf)
    assert np.isfinite(img).all()
    assert float(np.abs(img - other).mean()) < 0.05 * float(np.abs(other).mean())


def test_paper_plan_has_no_joint_steps(device, rng):
    info = frame(rng, h=10, w=12, s=4, motion=True).inspect()
    pipe = sg.Safeguarded(device.context, info, "splat", {"mip_radius": 0})
    assert pipe.full.joint_steps == () and pipe.joint == ()
    assert pipe.full.joint_halves(device.queue, None, 2, None) is None


def test_joint_bins_are_cleared_unless_known_clean(device, rng):
    """The draw zeroes the joint bins it consumes, so the safeguard's own skip their clear on
    the next frame; bins an embedder passes (here: junk) are cleared, and the image repeats
    bit for bit either way."""
    buf = frame(rng, h=12, w=15, s=4, motion=True, aperture=12.0)
    pipe = sg.Safeguarded(device.context, buf.inspect(), "splat", {"mip_radius": 4.0})
    first = _run(device, pipe, buf)[0]
    assert np.array_equal(_run(device, pipe, buf)[0], first)  # own bins, known clean
    junk = {}
    for name in ("joint.bins", "joint.flags"):
        if name in pipe.plan.temporaries:
            n = pipe.plan.temporaries[name]
            fill = np.full(n // 4, 7.0, np.float32) if name == "joint.bins" else \
                np.ones(n, np.uint8)
            junk[name] = cl.Buffer(device.context,
                                   cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR,
                                   hostbuf=fill)
    assert np.array_equal(_run(device, pipe, buf, temporaries=junk)[0], first)
    assert np.array_equal(_run(device, pipe, buf, temporaries=junk)[0], first)
    assert np.array_equal(_run(device, pipe, buf)[0], first)


def test_joint_falls_back_where_its_buffers_do_not_fit(device, rng, monkeypatch):
    """A device whose memory holds the plan but not the joint bins and half B's image: each
    half then runs the whole mip plan itself (its own PSFs)."""
    real = pipeline_module.check_memory

    def tight(dev, plan, info):
        if "joint.bins" in plan.temporaries:
            raise DeviceMemoryError("the plan needs more than the device's memory (test)")
        real(dev, plan, info)

    buf = frame(rng, h=14, w=17, s=4, motion=True, aperture=10.0)
    want = _run(device, sg.Safeguarded(device.context, buf.inspect(), "splat",
                                       {"mip_radius": 4.0}, joint=False), buf)
    monkeypatch.setattr(pipeline_module, "check_memory", tight)
    pipe = sg.Safeguarded(device.context, buf.inspect(), "splat", {"mip_radius": 4.0})
    assert pipe.joint == () and "joint.bins" not in pipe.plan.temporaries
    for g, w in zip(_run(device, pipe, buf), want):
        assert np.array_equal(g, w)


def test_joint_passes_refuse_what_they_are_not_for(device, rng):
    buf = frame(rng, h=10, w=12, s=4, motion=True)
    full = sg.Safeguarded(device.context, buf.inspect(), "splat", {"mip_radius": 4.0}).full
    geo = full.geometry
    for bad in (4, 5, -1):
        with pytest.raises(ValueError, match="joint_ha"):
            MipSplat(device.context, 4, True, geo, "tiles", joint_ha=bad)
    j = MipSplat(device.context, 4, True, geo, "tiles", joint_ha=2)
    s = DeviceSamples.upload(device.queue, buf, info=buf.inspect())
    with pytest.raises(ValueError, match="whole frame"):
        j.bin(device.queue, s.view(2, 0, None), 0.0, 1.0, full.buffer("mip_bins"),
              flags=full.buffer("mip_flags"))
    with pytest.raises(ValueError, match="img_b"):
        j.draw(device.queue, full.buffer("mip_bins"), full.buffer("mip_image"),
               flags=full.buffer("mip_flags"))
    with pytest.raises(ValueError, match="img_b"):
        full.mip.draw(device.queue, full.buffer("mip_bins"), full.buffer("mip_image"),
                      flags=full.buffer("mip_flags"), img_b=full.buffer("mip_image"))
