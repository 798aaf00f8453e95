"""Views of a frame's samples (``DeviceSamples.view``): the checks, the refusal by passes that
read whole frames, and the safeguard reading its halves in place where the method's passes
take views (sweep's block sort, layered but its fixed-point plan, splat's mip plan):
bit-identical to reading copies of the halves."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close
from layered_frames import frame

from clrecon.api import make_pipeline
from clrecon.core.pipeline import DeviceSamples
from clrecon.core.samples import SampleBuffer
from clrecon.methods import safeguard as sg


def _half(buf: SampleBuffer, sl: slice) -> SampleBuffer:
    return SampleBuffer(**{k: np.ascontiguousarray(v[:, :, sl]) for k, v in
                           buf.arrays().items()}, coc_model=buf.coc_model)


def _image(device, pipe, samples, buf, name="out"):
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, buf.height * buf.width * 12)
    pipe(device.queue, samples, out).wait()
    img = np.empty((buf.height, buf.width) + ((3,) if name == "out" else ()), np.float32)
    cl.enqueue_copy(device.queue, img, out if name == "out" else pipe.buffer(name))
    return img


def test_view_checks(device):
    buf = frame(np.random.default_rng(1), h=6, w=7, s=4)
    s = DeviceSamples.upload(device.queue, buf, info=buf.inspect())
    assert not s.is_view and s.strided("color") == (s.buffers["color"], 4, 0)
    v = s.view(2, 2)
    assert v.is_view and v.shape == (6, 7, 2) and v.strided("depth") == (s["depth"], 4, 2)
    with pytest.raises(ValueError, match="strided"):
        v["color"]
    with pytest.raises(ValueError, match="view of a view"):
        v.view(1, 0)
    with pytest.raises(ValueError, match="not inspected"):
        v.inspect(device.queue)
    for spp, offset in ((3, 2), (2, -1), (5, 0)):
        with pytest.raises(ValueError, match="offset must be"):
            s.view(spp, offset)
    with pytest.raises(ValueError, match="needs a buffer of at least"):  # sized by stride
        DeviceSamples(6, 7, 4, s.buffers, s.coc, None, 8, 0)


def test_whole_frame_pipelines_refuse_a_view(device):
    buf = frame(np.random.default_rng(2), h=6, w=7, s=4)
    s = DeviceSamples.upload(device.queue, buf, info=buf.inspect())
    info = buf.inspect()
    half = s.view(2, 0, info.__class__(**{**info.__dict__, "spp": 2}))
    for method, knobs in (("splat", {"mip_radius": 0}), ("box", {})):  # splat: the paper's
        pipe = make_pipeline(method, device.context, half.info, safeguard=False, **knobs)
        assert not pipe.sample_views
        with pytest.raises(ValueError, match="reads whole frames, not a view"):
            _image(device, pipe, half, buf)


@pytest.mark.parametrize("method, knobs", [("sweep", {"sort": "block"}),
                                           ("splat", {"mip_radius": 3.0}),
                                           ("splat", {"mip_radius": 3.0, "scatter": "atomic"})])
@pytest.mark.parametrize("spp", [4, 5, 8, 16, 24])
def test_a_pass_reads_a_view_as_its_half(device, spp, method, knobs):
    """(8, 16, 24 spp: halves of 4k samples a pixel, which splat's bin records on a CPU read
    as runs of 4 a step, of one pixel or two; 4 and 5: gathers)"""
    buf = frame(np.random.default_rng(spp), h=13, w=11, s=spp)
    s = DeviceSamples.upload(device.queue, buf, info=buf.inspect())
    ha, _ = sg.halves(spp)
    for sl, offset in ((slice(0, ha), 0), (slice(ha, None), ha)):
        h = _half(buf, sl)
        try:
            pipe = make_pipeline(method, device.context, h.inspect(), safeguard=False,
                                 **knobs)
        except ValueError as e:  # a device whose local memory holds no block
            pytest.skip(str(e))
        assert pipe.sample_views
        got = _image(device, pipe, s.view(h.spp, offset, h.inspect()), buf)
        want = _image(device, pipe, DeviceSamples.upload(device.queue, h, info=h.inspect()),
                      buf)
        if knobs.get("scatter") == "atomic":  # float atomics add in the device's order
            assert_close(got, want, rtol=1e-5, atol=1e-6, what=f"{method} {knobs}")
        else:
            assert np.array_equal(got, want)


@pytest.mark.parametrize("method, knobs", [("sweep", {"sort": "block"}), ("layered", {}),
                                           ("layered", {"splat": "bilinear"}), ("splat", {})])
@pytest.mark.parametrize("spp", [4, 5])
def test_safeguard_reads_the_halves_in_place_as_it_would_copies(device, spp, method, knobs):
    buf = frame(np.random.default_rng(10 + spp), h=12, w=15, s=spp)
    info = buf.inspect()
    try:
        inplace = sg.Safeguarded(device.context, info, method, knobs)
    except ValueError as e:  # a device whose local memory holds no sweep block
        pytest.skip(str(e))
    copied = sg.Safeguarded(device.context, info, method, knobs, views=False)
    assert inplace.views == inplace.half_a.sample_views and not copied.views
    if not inplace.views:
        pytest.skip(f"{method} {knobs} reads whole frames on this device")
    names = [st.name for st in inplace.plan.steps]
    assert "safeguard_split" not in names and not any(
        k.startswith(("a.", "b.")) for k in inplace.plan.temporaries)
    assert "safeguard_split" in [st.name for st in copied.plan.steps]
    s = DeviceSamples.upload(device.queue, buf, info=info)
    for name in ("out", "error"):
        assert np.array_equal(_image(device, inplace, s, buf, name),
                              _image(device, copied, s, buf, name)), name
    # the error estimate alone runs the whole plan (layered's statistics too) on each half
    alone = sg.Safeguarded(device.context, info, method, knobs, blend=False)
    alone_copied = sg.Safeguarded(device.context, info, method, knobs, blend=False,
                                  views=False)
    assert alone.views
    assert np.array_equal(_image(device, alone, s, buf, "error"),
                          _image(device, alone_copied, s, buf, "error"))


def test_fixed_point_layered_reads_whole_frames(device, monkeypatch):
    """deterministic=True with a tuned wg_x > 1 accumulates in fixed point, scaled by a colour
    bound over the frame's samples: that plan does not take views, the safeguard copies."""
    monkeypatch.setenv("CLRECON_TUNE_REPROJECT", '{"wg_x": 16, "wg_y": 1}')
    info = frame(np.random.default_rng(5), h=12, w=15, s=4).inspect()
    pipe = sg.Safeguarded(device.context, info, "layered", {"deterministic": True})
    if not pipe.half_a.fixed:
        pytest.skip("no int64 atomics: the plan runs wg_x = 1")
    assert not pipe.half_a.sample_views and not pipe.views
    assert "safeguard_split" in [st.name for st in pipe.plan.steps]


def test_a_replan_says_anew_whether_it_takes_views(device):
    """regrow re-runs __init__: a plan that reads whole frames (sweep on a frame without blur
    is box) does not keep the block plan's word."""
    blurred = frame(np.random.default_rng(4), h=6, w=7, s=4).inspect()
    sharp = SampleBuffer.zeros(6, 7, 4).inspect()
    pipe = make_pipeline("sweep", device.context, blurred, safeguard=False, sort="block")
    assert pipe.sample_views
    pipe.__init__(device.context, sharp)
    assert pipe.plan.name != "block" and not pipe.sample_views
