"""A re-planned frame reuses the previous plan's device buffers (``clrecon.core.pipeline.
reusing``, through ``clrecon.run``): whatever they hold, the image is a fresh pipeline's."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close

import clrecon
from clrecon import api
from clrecon.api import make_pipeline
from clrecon.core.pipeline import DeviceSamples, Pipeline
from clrecon.scenes import get_scene, render_samples


def _frame(scene, spp, seed, device):
    return render_samples(get_scene(scene), 40, 32, spp=spp, seed=seed, device=device)


def _fresh_image(device, method, knobs, buf):
    fresh = make_pipeline(method, device.context, buf.inspect(), **knobs)
    s = DeviceSamples.upload(device.queue, buf, info=buf.inspect())
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, buf.height * buf.width * 12)
    ev = fresh(device.queue, s, out)
    img = np.empty((buf.height, buf.width, 3), np.float32)
    cl.enqueue_copy(device.queue, img, out, wait_for=[ev])
    return img


@pytest.mark.parametrize("method,knobs", [("sweep", {}), ("layered", {}), ("splat", {}),
                                          ("splat", {"guided": 2}),
                                          ("splat", {"guided": 2, "nlm": 3, "nlm_scales": 3}),
                                          ("box", {"estimate_error": True})])
@pytest.mark.parametrize("spp", [8, 16])
def test_a_replanned_frame_reuses_the_last_plans_buffers_whatever_they_hold(
        device, monkeypatch, method, knobs, spp):
    """run() hands a re-planned frame the previous plan's buffers (``reusing``): the image is
    a fresh pipeline's bit for bit even when those buffers hold NaN, and some are reused."""
    released, real = [], Pipeline.release_buffers

    def poisoned(self):
        bufs = real(self)
        for b in bufs:  # 0xFF bytes: NaN floats, -1 ints
            cl.enqueue_fill_buffer(device.queue, b, np.uint8(255), 0, b.size).wait()
        released.extend(bufs)
        return bufs

    monkeypatch.setattr(Pipeline, "release_buffers", poisoned)
    a = _frame("fence", spp, 1, device)
    b = _frame("deep", spp, 2, device)
    clrecon.run(a, method, device, **knobs)
    got = clrecon.run(b, method, device, **knobs)
    assert got.plan_ms > 0.0 and released  # re-planned, with the last plan's buffers
    newest = list(api._sessions.values())[-1].pipe
    held = {id(x) for p in newest.pipelines() for x in p._own.values()}
    assert any(id(x) in held for x in released), "no released buffer was reused"
    assert_close(got.image, _fresh_image(device, method, knobs, b), rtol=0, atol=0,
                 what="re-planned frame on reused buffers")

