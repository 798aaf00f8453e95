"""The safeguard's joint steps: layered's reproject run once on the frame for both halves
(half A into the frame pipeline's grids, B into the wrapper's ``grids_b``) gives the images
of each half reprojecting its own view, bit for bit; it stays off where the plan cannot
(fixed point) and falls back where half B's grids do not fit the device."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_close
from layered_frames import frame
from pipeline_run import image_and_error as _images

from clrecon.core import pipeline as pipeline_module
from clrecon.core.errors import DeviceMemoryError
from clrecon.methods import safeguard as sg


@pytest.mark.parametrize("knobs", [{}, {"splat": "bilinear"}], ids=["nearest", "bilinear"])
@pytest.mark.parametrize("spp", [4, 5, 8, 16])
def test_joint_reproject_is_each_half_reprojecting_itself(device, spp, knobs):
    """4 and 16 spp: the halves' vector lanes (4 and 8 samples) are whole in the joint pass;
    8: lanes of eight split four and four; 5: halves of 2 and 3 (one sample at a time)."""
    buf = frame(np.random.default_rng(20 + spp), h=21, w=26, s=spp)
    info = buf.inspect()
    joint = sg.Safeguarded(device.context, info, "layered", knobs)
    apart = sg.Safeguarded(device.context, info, "layered", knobs, joint=False)
    if not joint.views:
        pytest.skip("layered reads whole frames on this device (fixed point)")
    assert joint.joint == ("reproject",) and apart.joint == ()
    assert "grids_b" in joint.plan.temporaries and "grids_b" not in apart.plan.temporaries
    assert "layered (reproject, both halves)" in [st.name for st in joint.plan.steps]
    assert joint.describe()["safeguard_joint"] == ["reproject"]
    assert "safeguard_joint" not in apart.describe()
    got, want = _images(device, joint, buf), _images(device, apart, buf)
    if joint.full.reproject.local.x > 1:  # float atomics: the adds in the device's order
        for g, w in zip(got, want):
            assert_close(g, w, rtol=1e-4, atol=1e-5 * float(np.abs(w).max()))
    else:
        for name, g, w in zip(("image", "error"), got, want):
            assert np.array_equal(g, w), f"{name}: {spp} spp {knobs}"


def test_joint_with_atomic_groups(device, monkeypatch):
    """A tuned group of 16 items per slot (a GPU's way: float atomics) in the joint pass."""
    monkeypatch.setenv("CLRECON_TUNE_REPROJECT", '{"wg_x": 16, "wg_y": 1}')
    buf = frame(np.random.default_rng(3), h=18, w=20, s=8)
    info = buf.inspect()
    joint = sg.Safeguarded(device.context, info, "layered", {})
    apart = sg.Safeguarded(device.context, info, "layered", {}, joint=False)
    assert joint.full.reproject.local.x == 16 and joint.joint
    for g, w in zip(_images(device, joint, buf), _images(device, apart, buf)):
        assert_close(g, w, rtol=1e-4, atol=1e-5 * float(np.abs(w).max()))


def test_fixed_point_plan_has_no_joint_step(device, monkeypatch):
    monkeypatch.setenv("CLRECON_TUNE_REPROJECT", '{"wg_x": 16, "wg_y": 1}')
    info = frame(np.random.default_rng(5), h=12, w=15, s=4).inspect()
    pipe = sg.Safeguarded(device.context, info, "layered", {"deterministic": True})
    if not pipe.full.fixed:
        pytest.skip("no int64 atomics: the plan runs wg_x = 1")
    assert pipe.full.joint_steps == () and pipe.joint == ()
    with pytest.raises(ValueError, match="fixed-point"):
        pipe.full.reproject.joint_halves(device.queue, None, 2, None, None, None, None, None)


@pytest.mark.parametrize("chain", [{}, {"guided": 2, "nlm": 3, "nlm_scales": 2,
                                    "independent_samples": True}], ids=["plain", "chain"])
def test_joint_falls_back_where_half_b_grids_do_not_fit(device, monkeypatch, chain):
    """A device whose memory holds the plan but not half B's second grids: each half then
    reprojects itself, and the image is the same (the chain's knobs kept: the fallback
    re-plans with every one of them)."""
    real = pipeline_module.check_memory

    def tight(dev, plan, info):
        if "grids_b" in plan.temporaries:
            raise DeviceMemoryError("the plan needs more than the device's memory (test)")
        real(dev, plan, info)

    buf = frame(np.random.default_rng(8), h=14, w=17, s=8 if chain else 4)
    want = _images(device, sg.Safeguarded(device.context, buf.inspect(), "layered", {},
                                          **chain), buf)
    monkeypatch.setattr(pipeline_module, "check_memory", tight)
    pipe = sg.Safeguarded(device.context, buf.inspect(), "layered", {}, **chain)
    assert pipe.joint == () and "grids_b" not in pipe.plan.temporaries
    assert all(pipe._flags[k] == v for k, v in chain.items())
    assert pipe._flags["joint"] is True  # a larger frame after regrow tries again
    for g, w in zip(_images(device, pipe, buf), want):
        assert np.array_equal(g, w)
