"""The safeguard's joint steps for splat: the mip plan's bins of both halves from one read of
the frame (``MipSplat.bin_joint``: half A into the frame pipeline's bins, B into the
wrapper's ``mip_bins_b``) give the images of each half binning its own view, bit for bit,
frame after frame (the draws leave both bins zero); off below ``JOINT_MIN_SPP``, for an odd
spp and for the atomic scatter."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from layered_frames import frame
from pipeline_run import image_and_error as _images

from clrecon.core.pipeline import DeviceSamples
from clrecon.methods import safeguard as sg
from clrecon.methods.splat.mip_plan import JOINT_MIN_SPP


def _pair(device, buf, knobs=None):
    info = buf.inspect()
    joint = sg.Safeguarded(device.context, info, "splat", dict(knobs or {}))
    apart = sg.Safeguarded(device.context, info, "splat", dict(knobs or {}), joint=False)
    if joint.full.plan_name != "mip":
        pytest.skip(f"the frame is planned {joint.full.plan_name!r}, not mip")
    return joint, apart


@pytest.mark.parametrize("spp", [16, 18, 32])
def test_joint_bins_are_each_half_binning_itself(device, spp):
    """16 and 32: halves of 8 and 16 samples (whole lanes of eight); 18: halves of 9 (each
    half's own pass ends its rows with single samples, the joint pass does not)."""
    buf = frame(np.random.default_rng(40 + spp), h=23, w=29, s=spp)
    joint, apart = _pair(device, buf)
    assert joint.joint == ("clear_bins", "bin") and apart.joint == ()
    assert {"mip_bins_b", "mip_flags_b"} <= set(joint.plan.temporaries)
    assert "mip_bins_b" not in apart.plan.temporaries
    assert joint.describe()["safeguard_joint"] == ["clear_bins", "bin"]
    assert "splat (clear_bins, bin, both halves)" in [st.name for st in joint.plan.steps]
    for name, g, w in zip(("image", "error"), _images(device, joint, buf),
                          _images(device, apart, buf)):
        assert np.array_equal(g, w), f"{name}: {spp} spp"
        assert np.isfinite(g).all() and np.abs(g).max() > 0


def test_frames_in_turn(device):
    """One pipeline, frames a, b, a: each is the separate halves' image (each half's draw
    zeroes the bins it consumes, so the next frame's bins start clean: a bin left over would
    add a previous frame's samples)."""
    bufs = [frame(np.random.default_rng(seed), h=17, w=21, s=16) for seed in (1, 2)]
    joint, apart = _pair(device, bufs[0])
    for buf in (bufs[0], bufs[1], bufs[0]):
        got, want = _images(device, joint, buf), _images(device, apart, buf)
        for g, w in zip(got, want):
            assert np.array_equal(g, w)


@pytest.mark.parametrize("spp, knobs", [(JOINT_MIN_SPP - 2, {}), (JOINT_MIN_SPP + 1, {}),
                                        (JOINT_MIN_SPP, {"scatter": "atomic"})],
                         ids=["below", "odd", "atomic"])
def test_no_joint_step(device, spp, knobs):
    buf = frame(np.random.default_rng(7), h=9, w=11, s=spp)
    pipe = sg.Safeguarded(device.context, buf.inspect(), "splat", knobs)
    assert pipe.full.joint_steps == () and pipe.joint == ()
    assert "mip_bins_b" not in pipe.plan.temporaries


def test_bin_joint_refuses_what_it_cannot_bin(device):
    buf = frame(np.random.default_rng(9), h=9, w=11, s=16)
    joint, _ = _pair(device, buf)
    s = DeviceSamples.upload(device.queue, buf, info=buf.inspect())
    mip, b = joint.full.mip, joint.full.buffer("mip_bins")
    with pytest.raises(ValueError, match="whole frame"):
        mip.bin_joint(device.queue, s.view(8, 0), 0.0, 1.0, b, b, b, b)
    assert joint.full.joint_halves(device.queue, s, 5, b, b) is None  # halves of 5 and 11


def test_a_frame_stopped_after_the_joint_bins(device):
    """Only the joint step of a frame runs (its bins are left full, never drawn): the next
    whole frame clears both halves' bins first, and its image is the separate halves'."""
    bufs = [frame(np.random.default_rng(seed), h=15, w=19, s=16) for seed in (3, 4)]
    joint, apart = _pair(device, bufs[0])
    _images(device, joint, bufs[0])  # the bins clean after a whole frame
    s = DeviceSamples.upload(device.queue, bufs[0], info=bufs[0].inspect())
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, bufs[0].height * bufs[0].width * 12)
    step = next(st.name for st in joint.plan.steps if "both halves" in st.name)
    joint(device.queue, s, out, steps=(step,)).wait()
    for g, w in zip(_images(device, joint, bufs[1]), _images(device, apart, bufs[1])):
        assert np.array_equal(g, w)
