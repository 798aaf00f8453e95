"""One run of a plan on a host frame, and its temporaries read back: what the tests of the
steps inside the safeguard (the guided refinement, the non-local means) compare with their
NumPy references."""
from __future__ import annotations

import numpy as np
import pyopencl as cl

from clrecon.api import make_pipeline
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


def read_buffer(pipe, queue, name: str, shape) -> np.ndarray:
    """The pipeline's temporary ``name`` as float32 of ``shape``."""
    a = np.empty(shape, np.float32)
    cl.enqueue_copy(queue, a, pipe.buffer(name))
    return a
