"""One run of a plan on a host frame, and its temporaries read back: what the tests of the
steps inside the safeguard (the guided refinement, the non-local means) compare with their
NumPy references; and the part of those steps' knob contracts they share."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import assert_close
from layered_frames import frame

from clrecon.api import make_pipeline, run
from clrecon.core.pipeline import DeviceSamples


def run_plan(device, buf, method: str, **knobs):
    """(pipeline, image): ``method`` planned for ``buf``'s own description with ``knobs``,
    run once on it (its arrays read in place), finished."""
    ctx, q = device.context, device.queue
    ds = DeviceSamples.wrap(ctx, buf, buf.arrays().keys())
    pipe = make_pipeline(method, ctx, ds.inspect(q), **knobs)
    out = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, buf.height * buf.width * 12)
    pipe(q, ds, out)
    image = np.empty((buf.height, buf.width, 3), np.float32)
    cl.enqueue_copy(q, image, out)
    q.finish()
    return pipe, image


def image_and_error(device, pipe, buf):
    """(image, error) of a safeguarded ``pipe`` run once on ``buf`` (uploaded with its own
    description)."""
    s = DeviceSamples.upload(device.queue, buf, info=buf.inspect())
    out = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, buf.height * buf.width * 12)
    pipe(device.queue, s, out).wait()
    img = np.empty((buf.height, buf.width, 3), np.float32)
    err = np.empty((buf.height, buf.width), np.float32)
    cl.enqueue_copy(device.queue, img, out)
    cl.enqueue_copy(device.queue, err, pipe.buffer("error"))
    device.queue.finish()
    return img, err


def read_buffer(pipe, queue, name: str, shape) -> np.ndarray:
    """The pipeline's temporary ``name`` as float32 of ``shape``."""
    a = np.empty(shape, np.float32)
    cl.enqueue_copy(queue, a, pipe.buffer(name))
    return a


def check_off_and_still(device, rng, buf, method: str, knob: str, on, box_takes=False,
                        **base):
    """A step's knob off (``knob=0``) is ``method`` with ``base`` as it was, bit for bit;
    on (``on``), a frame without blur (planned as box) gives box's image, or with
    ``box_takes`` (a step box has too) box's image with the step: ``run(method="box")``'s."""
    a = run(buf, method=method, device=device, **base).image
    b = run(buf, method=method, device=device, **base, **{knob: 0}).image
    assert np.array_equal(a, b)
    still = frame(rng, h=12, w=12, s=4, motion=False, aperture=0.0)
    img = run(still, method=method, device=device, **{knob: on}).image
    want = run(still, method="box", device=device, **{knob: on}).image if box_takes else \
        still.color.mean(2)
    assert_close(img, want, rtol=1e-5, atol=1e-6, what="box plan")
    if box_takes:  # and the step did something to box's image
        assert np.abs(want - still.color.mean(2)).max() > 1e-4


def check_refusals(device, buf, one, method: str, knob: str, on, bad, radius_msg: str,
                   box_refused=True, **one_knobs):
    """A step's knob: box has no image to give it (unless not ``box_refused``); each of
    ``bad`` is refused with ``radius_msg``; ``one`` (a frame of one sample a pixel) is
    refused: the step needs two halves."""
    if box_refused:
        with pytest.raises(ValueError, match=f"{knob}: box has no image"):
            run(buf, method="box", device=device, **{knob: on})
    for b in bad:
        with pytest.raises(ValueError, match=radius_msg):
            run(buf, method=method, device=device, **{knob: b})
    with pytest.raises(ValueError, match=f"{knob}: needs >= 2 samples"):
        run(one, method=method, device=device, **{knob: on}, **one_knobs)
